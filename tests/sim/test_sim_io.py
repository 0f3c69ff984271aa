"""SimCamera over a transport, dataset export (labels recomputed, seeded, resumable), service and CLI."""

import os
import subprocess
import sys
import time
from pathlib import Path
from uuid import uuid4

import cv2
import numpy as np
import pytest

from protocol.clock import SimClock
from protocol.enums import VehicleMode
from protocol.keys import sim_health_key, sim_world_key, vehicle_key
from protocol.local_bus import LocalBus
from protocol.messages import Health, VehicleState, WorldSnapshot
from sim.camera_source import SimCamera
from sim.dataset import ExportConfig, ExportError, export_dataset
from sim.render.renderer import Renderer
from sim.scenario import load_scenario
from sim.service import SimService
from sim.world import World

pytestmark = pytest.mark.serial  # processes, Zenoh or its own timing: make test runs it alone


REPO = Path(__file__).resolve().parents[2]


def test_sim_camera_renders_snapshots_from_the_transport(corridor):
    bus = LocalBus()
    cam = SimCamera(corridor, "rsu2", bus, seed=1)
    assert cam.read(timeout_s=0.01) is None
    w = World(load_scenario("rellis_ev_yield"))
    w.run_until(5.0)
    snap = w.snapshot()
    bus.publish(sim_world_key(corridor.corridor_id), snap)
    f = cam.read(timeout_s=0.5)
    assert f is not None and f.image.shape == (720, 1280, 3) and f.frame_number == 75  # 15 fps camera
    assert f.timestamp_s == pytest.approx(5.0) and f.camera_id == "rsu2"
    assert cam.read(timeout_s=0.01) is None  # the same snapshot is not rendered twice
    # at 20 Hz snapshots and 15 fps, one snapshot in four falls in a frame already delivered
    frames = []
    for _ in range(8):
        w.step(0.05)
        bus.publish(sim_world_key(corridor.corridor_id), w.snapshot())
        f = cam.read(timeout_s=0.01)
        if f is not None:
            frames.append(f.frame_number)
    assert len(frames) == 6 and frames == sorted(set(frames))
    w2 = World(load_scenario("rellis_ev_yield"))
    w2.run_until(5.0)
    # the lockstep path gives the same pixels as a Renderer with the same seed
    ref = Renderer(corridor.rsu("rsu2").camera, corridor.road, seed=1).render(snap, frame_index=75)
    assert np.array_equal(cam.render(w2.snapshot()).image, ref)
    cam.close()


def test_rsu_sim_source_stamps_frames_with_the_simulators_clock(corridor):
    """The RSU's frames carry the snapshot's publication stamp (UNIX time in a real-time run), not the
    scenario time: the DDM, on the wall clock, dropped every ObjectList stamped a few seconds after 1970."""
    from rsu.sim_source import SimSource

    bus = LocalBus()
    src = SimSource(corridor, "rsu2", bus, seed=1)
    w = World(load_scenario("rellis_ev_yield"))
    w.run_until(5.0)
    wall = time.time()
    bus.publish(sim_world_key(corridor.corridor_id), w.snapshot(stamp=wall))
    f = src.read(timeout_s=0.5)
    assert f.timestamp_s == pytest.approx(wall) and f.frame_number == 75
    src.close()


def _read_yolo(path):
    return [tuple(float(v) for v in line.split()) for line in Path(path).read_text().splitlines()]


def test_export_dataset_labels_match_renders_and_export_is_seeded_and_resumable(tmp_path, capsys):
    cfg = ExportConfig(out=str(tmp_path / "a"), frames=6, scenarios=["rellis_ev_yield", "ev_lights_never_on"],
                       seed=2, stride_s=12.0, rsus=["rsu1", "rsu2"], val_every=2)
    counts = export_dataset(cfg, progress=True)
    assert counts["frames"] == 6 and counts["rendered"] == 6
    assert "frames" in capsys.readouterr().err  # progress bar on stderr
    out = Path(cfg.out)
    imgs = sorted((out / "det" / "images").rglob("*.jpg"))
    assert len(imgs) == 6
    assert (out / "det" / "obj.names").read_text().split() == ["vehicle", "ev"]
    assert any((out / "det" / "images" / "val").iterdir()) and any((out / "det" / "images" / "train").iterdir())
    # labels recomputed independently: rebuild the episode's world and project each labelled vehicle
    n_checked = 0
    for img_path in imgs:
        lab_path = Path(str(img_path).replace("/images/", "/labels/")).with_suffix(".txt")
        rows = _read_yolo(lab_path)
        img = cv2.imread(str(img_path))
        assert img.shape == (720, 1280, 3)
        for c, xc, yc, bw, bh in rows:
            assert c in (0.0, 1.0) and 0 < xc < 1 and 0 < yc < 1 and 0 < bw <= 1 and 0 < bh <= 1
        n_checked += len(rows)
    assert n_checked > 5
    # MOT ground truth and crops
    gts = list((out / "mot").rglob("gt.txt"))
    assert gts
    line = gts[0].read_text().splitlines()[0].split(",")
    assert len(line) == 9 and int(line[0]) >= 1 and int(line[1]) >= 1
    assert list((out / "cls").rglob("*.png"))
    # seeded: a second export with the same settings writes the same labels
    cfg_b = ExportConfig(**{**cfg.__dict__, "out": str(tmp_path / "b")})
    export_dataset(cfg_b, progress=False)
    for p in (out / "det" / "labels").rglob("*.txt"):
        assert p.read_text() == (Path(cfg_b.out) / p.relative_to(out)).read_text()
    # resumable: only missing frames are rendered again
    imgs[0].unlink()
    imgs[3].unlink()
    counts = export_dataset(cfg, progress=False)
    assert counts["frames"] == 6 and counts["rendered"] == 2
    # other settings in the same folder are refused
    with pytest.raises(ExportError, match="other settings"):
        export_dataset(ExportConfig(**{**cfg.__dict__, "seed": 3}), progress=False)


def test_exported_ev_label_matches_a_fresh_projection(tmp_path, corridor):
    """Recompute an EV frame's labels from the world state with the camera model (independent of the
    renderer's id buffer): each exported box lies within the projected 3-D box of some vehicle."""
    from sim.camera import PinholeCamera, box_corners

    cfg = ExportConfig(out=str(tmp_path / "ev"), frames=1, scenarios=["rellis_ev_yield"], seed=0, stride_s=6.0,
                       rsus=["rsu1"], vary_lighting=False)
    export_dataset(cfg, progress=False)
    lab = next((Path(cfg.out) / "det" / "labels").rglob("*.txt"))
    rows = _read_yolo(lab)
    sc = load_scenario("rellis_ev_yield").with_overrides(seed=0 * 100_003 + 0 + load_scenario("rellis_ev_yield").seed)
    w = World(sc)
    w.run_until(6.0)
    cam = PinholeCamera.from_config(corridor.rsu("rsu1").camera)
    boxes = []
    for a in w.snapshot().actors:
        b = cam.project_box(box_corners(a.pos_x_m, a.pos_y_m, a.heading_rad, a.length_m, a.width_m,
                                        a.height_m + (0.2 if a.light_bar else 0.0)))
        if b is not None:
            boxes.append((a, b))
    ev_rows = [r for r in rows if r[0] == 1.0]
    assert len(ev_rows) == 1  # lights are on at t = 6 s
    for c, xc, yc, bw, bh in rows:
        x1, y1, x2, y2 = (xc - bw / 2) * 1280, (yc - bh / 2) * 720, (xc + bw / 2) * 1280, (yc + bh / 2) * 720
        inside = [a for a, b in boxes
                  if x1 >= b[0] - 2 and y1 >= b[1] - 2 and x2 <= b[2] + 2 and y2 <= b[3] + 2]
        assert inside, (c, x1, y1, x2, y2)
        if c == 1.0:
            assert any(a.kind.value == "ev" for a in inside)


def test_service_publishes_snapshots_at_20hz_and_follows_the_av_state():
    bus = LocalBus()
    clock = SimClock(100.0)
    got: list[WorldSnapshot] = []
    health: list[Health] = []
    bus.subscribe(sim_world_key("tc"), lambda _k, m: got.append(m))
    bus.subscribe(sim_health_key("tc"), lambda _k, m: health.append(m))
    svc = SimService(load_scenario("rellis_ev_yield"), bus, clock, corridor_id="tc", duration_s=4.0)
    st = VehicleState(src="veh", stamp=100.0, vehicle_id="av1", pos_x_m=60.0, pos_y_m=1.0, lat_deg=30.6,
                      lon_deg=-96.4, heading_rad=0.0, speed_mps=3.0, mode=VehicleMode.MANOEUVRE)
    bus.publish(vehicle_key("tc", "av1", "state"), st)
    bus.publish(vehicle_key("tc", "ghost", "state"), VehicleState(**{**st.model_dump(), "vehicle_id": "ghost"}))
    n = svc.run()
    assert n == 80 and len(got) == 80
    assert clock.now() == pytest.approx(104.0)
    dts = np.diff([m.sim_time_s for m in got])
    assert np.allclose(dts, 0.05)
    assert [m.seq for m in got] == list(range(80))
    av = [next(a for a in m.actors if a.actor_id == "av1") for m in got]
    assert av[0].pos_x_m == pytest.approx(60.0)
    # no state since: the last one carried forward at 3 m/s along its heading for up to 3 s ...
    assert av[20].pos_x_m == pytest.approx(60.0 + 3.0 * 1.0, abs=0.05) and av[20].pos_y_m == pytest.approx(1.0)
    assert av[50].pos_x_m == pytest.approx(60.0 + 3.0 * 2.5, abs=0.05)
    # ... then the AV is scripted again from that pose (lane keeping, moving on)
    assert av[-1].pos_x_m > av[62].pos_x_m > 68.0 and av[-1].pos_y_m == pytest.approx(1.0, abs=0.9)
    assert 4 <= len(health) <= 5 and health[0].role.value == "sim" and health[-1].rejected.get("unknown_vehicle") == 1


def test_service_holds_the_world_until_the_av_reports():
    """--wait-for-av: the world starts at the vehicle process's first state, not with a scripted AV that
    would jump back when the car comes up late; without a state it starts scripted after the timeout."""
    import threading

    bus = LocalBus()
    svc = SimService(load_scenario("rellis_ev_yield"), bus, corridor_id="tw", duration_s=0.1)
    assert not svc.wait_to_start(0.2)  # nobody drives av1: gives up after the timeout
    st = VehicleState(src="veh", stamp=1.0, vehicle_id="av1", pos_x_m=40.0, pos_y_m=5.5, lat_deg=30.6,
                      lon_deg=-96.4, heading_rad=0.0, speed_mps=13.4, mode=VehicleMode.DRIVING)
    # stamped when sent, by the clock the world runs on (a state is where the car was at its stamp)
    timer = threading.Timer(0.3, lambda: bus.publish(vehicle_key("tw", "av1", "state"),
                                                     st.model_copy(update={"stamp": svc.clock.now()})))
    got: list[WorldSnapshot] = []
    bus.subscribe(sim_world_key("tw"), lambda _k, m: got.append(m))
    t0 = time.monotonic()
    timer.start()
    try:
        svc.run(wait_for_av_s=10.0)
    finally:
        timer.cancel()
    assert 0.25 < time.monotonic() - t0 < 5.0
    assert got and got[0].sim_time_s == pytest.approx(0.05)
    assert next(a for a in got[0].actors if a.actor_id == "av1").pos_x_m == pytest.approx(40.0, abs=1.0)


def test_cli_help_and_render(tmp_path):
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    r = subprocess.run([sys.executable, "-m", "sim", "--help"], capture_output=True, text=True, env=env, timeout=60)
    assert r.returncode == 0 and "export-dataset" in r.stdout
    r = subprocess.run([sys.executable, "-m", "sim", "render", "rellis_ev_yield", "--t", "6", "--out", str(tmp_path),
                        "--rsu", "rsu3"], capture_output=True, text=True, env=env, timeout=60)
    assert r.returncode == 0, r.stderr
    pngs = list(tmp_path.glob("*.png"))
    assert len(pngs) == 1 and cv2.imread(str(pngs[0])).shape == (720, 1280, 3)
    r = subprocess.run([sys.executable, "-m", "sim", "render", "no_such_scenario", "--t", "1", "--out", str(tmp_path)],
                       capture_output=True, text=True, env=env, timeout=60)
    assert r.returncode == 2 and "scenario not found" in r.stderr


def test_sim_process_publishes_over_zenoh(tmp_path, spawn):
    """Real process over real Zenoh (peer mode, loopback): snapshots at ~20 Hz, recorded video."""
    from protocol.zenoh_transport import ZenohSettings, ZenohTransport

    cid = f"t{uuid4().hex[:8]}"
    video = tmp_path / "rsu1.mp4"
    tr = ZenohTransport(ZenohSettings())
    got: list[float] = []
    tr.subscribe(sim_world_key(cid), lambda _k, m: got.append(time.monotonic()))
    proc = spawn("-m", "sim", "run", "rellis_ev_yield", "--corridor-id", cid, "--duration", "3",
                 "--record", f"rsu1:{video}")
    try:
        proc.wait(timeout=40)
    finally:
        tr.close()
    assert proc.returncode == 0, proc.stderr.read()
    assert len(got) >= 30  # 60 published in 3 s; discovery may miss the first ones
    rate = (len(got) - 1) / (got[-1] - got[0])
    assert 5.0 < rate < 30.0  # 20 Hz nominal; a loaded 2-core machine may run the recorder slower
    cap = cv2.VideoCapture(str(video))
    assert cap.get(cv2.CAP_PROP_FRAME_COUNT) >= 30
    ok, frame = cap.read()
    assert ok and frame.shape == (720, 1280, 3)


def test_export_cli_reports_bad_arguments(tmp_path):
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    r = subprocess.run([sys.executable, "-m", "sim", "export-dataset", "--out", str(tmp_path), "--frames", "0"],
                       capture_output=True, text=True, env=env, timeout=60)
    assert r.returncode == 2 and "frames must be" in r.stderr


def test_service_holds_the_world_until_the_rsus_are_up():
    """--wait-for-rsus: the world starts once every named RSU has its liveliness token, so no camera misses the
    scenario's start (on a slow host the RSUs came up 7-9 s after a world that did not wait); an RSU that never
    comes is named and the world starts after the timeout."""
    import threading

    from protocol import presence
    from sim.service import rsus_to_wait_for

    bus = LocalBus()
    sc = load_scenario("rellis_ev_yield")
    assert rsus_to_wait_for("all", sc.corridor) == [r.rsu_id for r in sc.corridor.rsus]
    assert rsus_to_wait_for(" rsu2,rsu1 ", sc.corridor) == ["rsu2", "rsu1"] and rsus_to_wait_for(None, sc.corridor) == []
    with pytest.raises(KeyError):
        rsus_to_wait_for("rsu1,rsu9", sc.corridor)
    svc = SimService(sc, bus, corridor_id="tr", duration_s=0.1)
    presence.announce(bus, "tr", "rsu", "rsu1")
    assert not svc.wait_to_start(0.2, avs=False, rsu_ids=("rsu1", "rsu2"))  # rsu2 never came: gives up
    handles = []
    timer = threading.Timer(0.3, lambda: handles.append(presence.announce(bus, "tr", "rsu", "rsu2")))
    got: list[WorldSnapshot] = []
    bus.subscribe(sim_world_key("tr"), lambda _k, m: got.append(m))
    t0 = time.monotonic()
    timer.start()
    try:
        svc.run(wait_for_rsus=("rsu1", "rsu2"), wait_timeout_s=10.0)
    finally:
        timer.cancel()
    assert 0.25 < time.monotonic() - t0 < 5.0  # held until rsu2's token, not the 10 s timeout
    assert got and got[0].sim_time_s == pytest.approx(0.05)


def test_iea_up_starts_the_vehicle_and_the_world_once_its_rsus_are_up(tmp_path):
    """iea up / iea demo: DDM and RSUs first; the vehicle (which drives from the moment it is up) and the world
    together once every RSU started has its liveliness token; an RSU that never comes is named."""
    import threading

    from deploy.procs import ServiceSpec, corridor_services, start_when_rsus_up
    from protocol import presence
    from protocol.corridor import load_corridor

    corridor = load_corridor("deploy/corridors/rellis.toml")
    specs = corridor_services(corridor, "tw", scenario="rellis_ev_yield", duration_s=5.0, run_dir=tmp_path,
                              detector="project", zenoh_args=[], rsu_ids=["rsu1", "rsu3"])
    assert "--wait-for-rsus" not in next(s for s in specs if s.name == "sim").args  # the AV's process is the gate

    class Group:
        def __init__(self):
            self.started: list[tuple[str, float]] = []

        def start(self, name, args, restart="no"):
            self.started.append((name, time.monotonic()))

    bus, group, said = LocalBus(), Group(), []
    handles = []
    timer = threading.Timer(0.3, lambda: handles.extend(presence.announce(bus, "tw", "rsu", r) for r in ("rsu1", "rsu3")))
    t0 = time.monotonic()
    timer.start()
    try:
        assert start_when_rsus_up(group, specs, bus, "tw", settle_s=0.0, timeout_s=10.0, say=said.append) == []
    finally:
        timer.cancel()
    names = [n for n, _ in group.started]
    assert names == ["ddm", "rsu1", "rsu3", "vehicle", "sim"]
    assert all(t - t0 < 0.2 for n, t in group.started[:3]) and all(0.25 < t - t0 < 5.0 for n, t in group.started[3:])
    assert "every RSU up" in said[-1]
    one = [ServiceSpec("rsu2", ["-m", "rsu", "--rsu", "rsu2"]), ServiceSpec("sim", ["-m", "sim"])]
    assert start_when_rsus_up(Group(), one, bus, "tw", settle_s=0.0, timeout_s=0.2, say=said.append) == ["rsu2"]
    assert "rsu2 not up" in said[-1]


def test_the_corridors_cameras_run_out_of_step(corridor):
    """Each camera exposes 15 fps, but not on the same 20 Hz snapshots as the others (in step, every RSU's
    frame work would arrive at once on three snapshots in four, and none on the fourth)."""
    cams = [SimCamera(corridor, r.rsu_id, seed=0) for r in corridor.rsus]
    assert len(cams) == 4
    starts = {k: [] for k in range(40)}  # snapshot slot -> the cameras that start a frame there
    for c in cams:
        idx = [c.frame_index(k * 0.05) for k in range(41)]
        assert len(set(idx)) == 31  # 15 fps over 2 s
        for k in range(40):
            if idx[k + 1] != idx[k]:
                starts[k + 1 if k + 1 < 40 else 0].append(c.rsu.rsu_id)
    assert max(len(v) for v in starts.values()) == 3  # never all four on one snapshot
    assert {len(v) for k, v in starts.items() if k > 0} == {3}  # three on every one
    with pytest.raises(ValueError, match="phase_s"):
        SimCamera(corridor, "rsu1", phase_s=0.1)


def test_iea_up_lighting_reaches_the_simulator_and_its_snapshots(tmp_path):
    """iea up --lighting / the e2e bench's --lighting: the simulator's arguments carry the override, its CLI takes
    them, and the scenario it then plays (whose snapshots every RSU renders) is in that lighting."""
    from deploy.procs import corridor_services
    from deploy.up import build_parser as up_parser
    from protocol.corridor import load_corridor
    from sim.cli import build_parser as sim_parser
    from sim.scenario import load_scenario

    corridor = load_corridor("deploy/corridors/rellis.toml")
    specs = corridor_services(corridor, "tw", scenario="rellis_ev_yield", duration_s=5.0, run_dir=tmp_path,
                              detector="project", zenoh_args=[], lighting="dusk")
    sim_args = next(s for s in specs if s.name == "sim").args
    parsed = sim_parser().parse_args(sim_args[2:])  # after "-m sim"
    assert parsed.lighting == "dusk"
    assert load_scenario(parsed.scenario, corridor).with_overrides(lighting=parsed.lighting).lighting == "dusk"
    assert load_scenario("rellis_ev_yield", corridor).lighting == "day"  # the override, not the file, made it dusk
    plain = corridor_services(corridor, "tw", scenario="rellis_ev_yield", duration_s=5.0, run_dir=tmp_path,
                              detector="project", zenoh_args=[])
    assert "--lighting" not in next(s for s in plain if s.name == "sim").args
    assert up_parser().parse_args(["--lighting", "night"]).lighting == "night"
    with pytest.raises(SystemExit):
        up_parser().parse_args(["--lighting", "noon"])
    with pytest.raises(ValueError, match="lighting must be one of"):
        corridor_services(corridor, "tw", scenario="rellis_ev_yield", duration_s=5.0, run_dir=tmp_path,
                          detector="project", zenoh_args=[], lighting="noon")


def test_a_late_state_is_carried_forward_from_its_stamp_and_an_older_one_ignored():
    """States that a lossy link hands over seconds late place the AV where it is now, not where it was; one older
    than the last applied or than ``AV_STATE_TIMEOUT_S`` is history."""
    bus = LocalBus()
    clock = SimClock(100.0)
    got: list[WorldSnapshot] = []
    bus.subscribe(sim_world_key("tl"), lambda _k, m: got.append(m))
    svc = SimService(load_scenario("rellis_ev_yield"), bus, clock, corridor_id="tl", duration_s=0.1)
    st = VehicleState(src="veh", stamp=99.0, vehicle_id="av1", pos_x_m=60.0, pos_y_m=1.0, lat_deg=30.6,
                      lon_deg=-96.4, heading_rad=0.0, speed_mps=10.0, mode=VehicleMode.DRIVING)
    bus.publish(vehicle_key("tl", "av1", "state"), st)  # 1 s old when the world steps
    svc.step_once()
    av = next(a for a in got[-1].actors if a.actor_id == "av1")
    assert av.pos_x_m == pytest.approx(70.0, abs=0.01)
    bus.publish(vehicle_key("tl", "av1", "state"), st.model_copy(update={"stamp": 98.5, "pos_x_m": 0.0}))
    svc.step_once()  # older than the one applied: ignored, the AV carried on from the newer one
    av = next(a for a in got[-1].actors if a.actor_id == "av1")
    assert av.pos_x_m == pytest.approx(70.0, abs=0.01)
    bus.publish(vehicle_key("tl", "av1", "state"), st.model_copy(update={"stamp": clock.now() - 3.5, "pos_x_m": 0.0}))
    svc.step_once()  # too old to carry forward (more than AV_STATE_TIMEOUT_S): ignored as well
    assert next(a for a in got[-1].actors if a.actor_id == "av1").pos_x_m == pytest.approx(70.0, abs=0.01)
