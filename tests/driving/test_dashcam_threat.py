"""The Clemson comparison: the dashboard camera sees the debris ahead; the report's threat value and fusion equations."""

from __future__ import annotations

import math

import numpy as np
import pytest

from studies.clemson.dashcam import HEIGHT_PX, WIDTH_PX, DashCamera, hazard_mask
from studies.clemson.driving import make_scenario, simulated_radar
from studies.clemson.learned_steering import (
    SEGMENTED_BGR,
    case_input,
    denormalise_steer,
    normalise_steer,
    radar_threat,
    segmented_image,
)


def _pose_behind_debris(gap_m: float):
    sc = make_scenario(2000)
    d = sc.debris[0]
    x, y, h = sc.road.pose_at(d.s_m - gap_m, sc.road.lane_centre_offset_m(sc.start_lane))
    return sc, float(x), float(y), float(h)


def test_dashcam_renders_the_debris_ahead_where_its_mask_says():
    sc, x, y, h = _pose_behind_debris(12.0)
    cam = DashCamera(sc.road, seed=sc.seed, noise=False)
    with_debris = cam.render(x, y, h, sc.actors(), 0.0)
    without = cam.render(x, y, h, [], 0.0)
    mask = hazard_mask(x, y, h, sc.actors()).astype(bool)
    assert with_debris.shape == (HEIGHT_PX, WIDTH_PX, 3) and with_debris.dtype == np.uint8
    assert mask.sum() >= 20, "debris 12 m ahead covers some pixels"
    cols = np.nonzero(mask)[1]
    assert abs(cols.mean() - WIDTH_PX / 2) < WIDTH_PX / 6, "debris in the car's lane is ahead, near the centre"
    diff = np.abs(with_debris.astype(int) - without.astype(int)).sum(axis=2) > 30
    assert diff[mask].mean() > 0.6, "the rendered debris is where the mask is"
    assert diff[~mask].mean() < 0.02, "and nowhere else (its shadow aside)"


def test_side_cameras_see_the_scene_shifted():
    sc, x, y, h = _pose_behind_debris(20.0)
    left = np.nonzero(hazard_mask(x, y, h, sc.actors(), 0.8))[1].mean()
    centre = np.nonzero(hazard_mask(x, y, h, sc.actors(), 0.0))[1].mean()
    right = np.nonzero(hazard_mask(x, y, h, sc.actors(), -0.8))[1].mean()
    assert left > centre > right, "a camera further left sees the debris further right"


def test_radar_threat_is_eq_2_3():
    assert radar_threat((0.0, 0.0)) == pytest.approx(1.0)
    assert radar_threat((60.0, 3.7)) == pytest.approx(0.0)
    assert radar_threat((30.0, 0.0)) == pytest.approx(math.sqrt(0.25 + 1.0) / math.sqrt(2.0))
    assert radar_threat((61.0, 0.0)) == 0.0 and radar_threat((10.0, 3.8)) == 0.0 and radar_threat(None) == 0.0


def test_simulated_radar_measures_the_debris_ahead_with_small_noise():
    sc, x, y, h = _pose_behind_debris(30.0)
    rng = np.random.default_rng(0)
    d = sc.debris[0]
    lx_true = 30.0 - 4.9 / 2 - d.length_m / 2
    m = np.array([simulated_radar(x, y, h, sc.actors(), rng) for _ in range(200)])
    assert abs(m[:, 0].mean() - lx_true) < 0.1 and 0.1 < m[:, 0].std() < 0.5
    assert abs(m[:, 1].mean() - abs(d.d_m - sc.road.lane_centre_offset_m(sc.start_lane))) < 0.1
    behind = sc.road.pose_at(d.s_m + 10.0, d.d_m)
    assert simulated_radar(float(behind[0]), float(behind[1]), float(behind[2]), sc.actors(), rng) is None


def test_image_threat_eq_4_and_fusion_eq_1():
    img = np.full((HEIGHT_PX, WIDTH_PX, 3), 100, np.uint8)
    near = np.zeros((HEIGHT_PX, WIDTH_PX), bool)
    near[HEIGHT_PX - 1, WIDTH_PX // 2] = True
    x, tf = case_input(3, img, near, None)
    assert tf == pytest.approx(1.0, abs=0.02)
    far = np.zeros_like(near)
    far[0, 0] = True
    assert case_input(3, img, far, None)[1] == pytest.approx(0.0, abs=0.01)
    # eq. 1: T_f = 1 gives the segmented image; T_f = 0 the camera's
    assert np.array_equal(x, segmented_image(near)) or tf < 1.0
    x2, tf2 = case_input(2, img, far, (0.0, 0.0))
    assert tf2 == pytest.approx(1.0) and np.array_equal(x2, segmented_image(far))
    x0, tf0 = case_input(2, img, far, None)
    assert tf0 == 0.0 and np.array_equal(x0, img)
    assert tuple(segmented_image(far)[0, 0]) == SEGMENTED_BGR
    with pytest.raises(ValueError, match="case must be"):
        case_input(4, img, far, None)
    with pytest.raises(ValueError, match="uint8"):
        case_input(1, img.astype(np.float32), None, None)


def test_steering_normalisation_eq_5_round_trips_and_clips():
    th = np.array([-0.2, -0.05, 0.0, 0.07, 0.2])
    assert np.allclose(denormalise_steer(normalise_steer(th)), th)
    assert normalise_steer(0.0) == pytest.approx(0.0)
    assert normalise_steer(1.0) == pytest.approx(0.5) and normalise_steer(-1.0) == pytest.approx(-0.5)


def test_training_script_fuses_with_the_runtime_colour():
    from pathlib import Path

    text = (Path(__file__).resolve().parents[2] / "models" / "train_driving.py").read_text()
    assert f"SEGMENTED_BGR = {SEGMENTED_BGR}" in text
