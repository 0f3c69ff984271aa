"""The Clemson comparison: the driving export (augmentation, split), the ONNX steering nets, learned mode under the fail-safe."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from protocol.enums import VehicleMode
from studies.clemson.driving import make_scenario
from studies.clemson.export import DrivingExportConfig, augment, export_driving, side_correction_rad
from studies.clemson.learned_steering import MODELS_DIR, LearnedSteering, LearnedVehicle

pytestmark = pytest.mark.serial  # processes, Zenoh or its own timing: make test runs it alone



def test_augmentation_flips_the_image_and_mask_and_negates_the_angle():
    rng = np.random.default_rng(1)
    img = np.zeros((66, 200, 3), np.uint8)
    img[30:40, 20:40] = 200
    mask = np.zeros((66, 200), np.uint8)
    mask[30:40, 20:40] = 1
    seen = set()
    for _ in range(20):
        a_img, a_mask, steer, flipped = augment(img, mask, 0.05, rng)
        seen.add(flipped)
        cols = np.nonzero(a_mask)[1]
        if flipped:
            assert steer == -0.05 and cols.mean() > 150
        else:
            assert steer == 0.05 and cols.mean() < 50
        assert a_img.dtype == np.uint8 and a_img.shape == img.shape
    assert seen == {True, False}


def test_side_cameras_are_labelled_to_steer_back():
    assert side_correction_rad(0.8) < 0 < side_correction_rad(-0.8)  # left of the path: steer right
    assert side_correction_rad(0.0) == 0.0


def test_export_writes_splits_by_seed_with_doubled_train(tmp_path):
    counts = export_driving(DrivingExportConfig(out=str(tmp_path), train_episodes=1, val_episodes=0, test_episodes=1,
                                                stride_s=2.0), progress=False)
    tr = np.load(tmp_path / "train.npz")
    te = np.load(tmp_path / "test.npz")
    assert counts == {"train": len(tr["images"]), "val": 0, "test": len(te["images"])}
    assert set(tr["seed"]) == {0} and set(te["seed"]) == {2000}, "split by episode seed"
    n = len(tr["images"]) // 2
    assert tr["augmented"][n:].all() and not tr["augmented"][:n].any() and not te["augmented"].any()
    orig, aug = tr["steer_rad"][:n], tr["steer_rad"][n:]
    flipped = tr["flipped"][n:]
    assert np.allclose(aug[flipped], -orig[flipped]) and np.allclose(aug[~flipped], orig[~flipped])
    assert sorted(set(tr["camera"])) == [-1, 0, 1]
    assert te["masks"].any(axis=(1, 2)).sum() > 0 and (te["radar_tf"] > 0).any()
    assert json.loads((tmp_path / "meta.json").read_text())["counts"] == counts


def test_export_config_says_what_is_wrong():
    with pytest.raises(ValueError, match="stride_s"):
        DrivingExportConfig(out="x", stride_s=0.25)
    with pytest.raises(ValueError, match="nothing to export"):
        DrivingExportConfig(out="x", train_episodes=0, val_episodes=0, test_episodes=0)


def _car(seed: int = 2001) -> LearnedVehicle:
    sc = make_scenario(seed)
    return LearnedVehicle(sc.road, "av1", sc.start_s_m, sc.start_lane, sc.speed_mps, seed=0)


def test_learned_angle_steers_while_driving_and_the_failsafe_takes_over():
    car = _car()
    car.learned_steer_rad = 0.05
    t = 0.0
    for _ in range(50):
        car.core.on_link(t)
        out = car.step(t, 0.01)
        t += 0.01
    assert out.mode == VehicleMode.DRIVING and car.applied_steer_rad == 0.05 and car.learned_steps == 50
    car.learned_steer_rad = math.nan  # a broken net: the thesis controller steers
    out = car.step(t, 0.01)
    assert car.applied_steer_rad == pytest.approx(out.steer_cmd_rad)
    car.learned_steer_rad = 0.05
    car.fix_source_enabled = False  # localisation lost: the fail-safe's minimal-risk stop
    for _ in range(300):
        car.core.on_link(t)
        out = car.step(t, 0.01)
        t += 0.01
        if out.mode == VehicleMode.MINIMAL_RISK:
            break
    assert out.mode == VehicleMode.MINIMAL_RISK
    out = car.step(t, 0.01)
    assert car.applied_steer_rad == pytest.approx(out.steer_cmd_rad) and car.applied_steer_rad != 0.05


@pytest.fixture(scope="module")
def nets():
    if not (MODELS_DIR / "driving_case1.onnx").is_file():
        pytest.skip("models/driving_*.onnx not trained (models/train_driving.py)")
    return {c: LearnedSteering(c) for c in (1, 2, 3)}


def test_onnx_nets_load_and_steer_back_towards_the_lane(nets):
    from studies.clemson.dashcam import DashCamera

    sc = make_scenario(2003, with_debris=False)
    cam = DashCamera(sc.road, seed=sc.seed, noise=False)
    x, y, h = (float(v) for v in sc.road.pose_at(60.0, sc.road.lane_centre_offset_m(sc.start_lane)))
    for case, net in nets.items():
        left, _ = net(cam.render(x, y, h, [], 0.0, 0.8), None)  # the car 0.8 m left of its lane centre
        right, _ = net(cam.render(x, y, h, [], 0.0, -0.8), None)
        assert math.isfinite(left) and math.isfinite(right)
        assert left < right, f"case {case}: steers right when left of the lane, left when right of it"


def test_case_2_and_3_see_the_threat_of_debris_ahead(nets):
    from studies.clemson.dashcam import DashCamera
    from studies.clemson.driving import simulated_radar

    sc = make_scenario(2000)
    d = sc.debris[0]
    x, y, h = (float(v) for v in sc.road.pose_at(d.s_m - 20.0, sc.road.lane_centre_offset_m(sc.start_lane)))
    img = DashCamera(sc.road, seed=sc.seed).render(x, y, h, sc.actors(), 0.0)
    radar = simulated_radar(x, y, h, sc.actors(), np.random.default_rng(0))
    assert nets[1](img, radar)[1] == 0.0
    assert nets[2](img, radar)[1] > 0.5, "radar threat of debris 20 m ahead in the lane"
    assert nets[3](img, radar)[1] > 0.3, "the on-board segmentation finds it: image threat of eq. 4"


def test_camera_loop_of_the_vehicle_process_steers_from_the_world_and_withdraws_when_it_is_stale():
    from protocol.messages import WorldSnapshot
    from studies.clemson.learned_steering import CameraLoop

    sc = make_scenario(2000)
    car = _car(2000)
    seen = []

    def steering(image, radar):
        seen.append((image.shape, radar))
        return 0.03, 0.5

    loop = CameraLoop(car, sc.road, steering, "av1")
    assert loop.tick(0.0) is None and car.learned_steer_rad is None, "no world yet: the thesis controller steers"
    snap = WorldSnapshot(src="sim", stamp=0.0, scenario="t", sim_time_s=0.0, actors=sc.actors())
    loop.on_world(snap, 0.0)
    assert loop.tick(0.1) == 0.03 and car.learned_steer_rad == 0.03
    assert seen[-1][0] == (66, 200, 3)
    assert seen[-1][1] is None, "debris 100+ m ahead is beyond the radar's 60 m"
    assert loop.tick(1.0) is None and car.learned_steer_rad is None, "world stale for > 0.5 s: withdrawn"


@pytest.mark.timeout(60)
def test_vehicle_process_steers_from_its_dashcam_over_zenoh(nets):
    """``python -m studies.clemson vehicle --case 2`` (iea-vehicle run with the learned steering attached) as a real
    process: the world published over Zenoh (the test plays the simulator) engages the learned steering, the car
    keeps publishing its state, and it exits cleanly."""
    import os
    import subprocess
    import sys
    import time
    from pathlib import Path
    from uuid import uuid4

    from deploy.procs import stop_process
    from protocol.corridor import load_corridor
    from protocol.keys import sim_world_key, vehicle_key
    from protocol.messages import WorldSnapshot
    from protocol.zenoh_transport import ZenohSettings, ZenohTransport
    from studies.clemson.dashcam import debris_actor

    root = Path(__file__).resolve().parents[2]
    cid = f"t{uuid4().hex[:8]}"
    proc = subprocess.Popen([sys.executable, "-m", "studies.clemson", "vehicle", "--case", "2", "--corridor-id", cid,
                             "--duration", "8"], cwd=root, env={**os.environ, "PYTHONPATH": str(root)},
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    transport = ZenohTransport(ZenohSettings())
    states = []
    try:
        transport.subscribe(vehicle_key(cid, "av1", "state"), lambda k, m: states.append(m))
        road = load_corridor().road
        deadline = time.monotonic() + 20.0
        while not states and time.monotonic() < deadline:
            assert proc.poll() is None, proc.stdout.read().decode(errors="replace")
            time.sleep(0.05)
        assert states, "no VehicleState from the vehicle process"
        s_car = float(np.atleast_1d(road.to_frenet(states[-1].pos_x_m, states[-1].pos_y_m)[0])[0])
        debris = debris_actor(road, "hz0", s_car + 80.0, road.lane_centre_offset_m(1), "box", 1.2, 0.9, 0.45)
        for k in range(20):  # 2 s of world at 10 Hz
            transport.publish(sim_world_key(cid), WorldSnapshot(src="sim", stamp=time.time(), seq=k, scenario="t",
                                                                sim_time_s=0.1 * k, actors=[debris]))
            time.sleep(0.1)
        n = len(states)
        time.sleep(0.5)
        assert len(states) > n, "the car keeps publishing its state while the camera loop runs"
        out, _ = proc.communicate(timeout=20)
        text = out.decode(errors="replace")
        assert proc.returncode == 0, text
        assert "learned steering engaged" in text and "Traceback" not in text, text
    finally:
        transport.close()
        if proc.poll() is None:
            stop_process(proc)
