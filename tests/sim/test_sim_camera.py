import math

import numpy as np
import pytest

from sim.camera import PinholeCamera, box_corners


@pytest.fixture(scope="module")
def cams(corridor):
    return {r.rsu_id: PinholeCamera.from_config(r.camera) for r in corridor.rsus}


def test_world_pixel_ground_round_trip_within_1cm_at_50m(cams, corridor):
    for rsu in corridor.rsus:
        cam = cams[rsu.rsu_id]
        xs = rsu.camera.x_m + np.array([20.0, 35.0, 50.0, 80.0, 120.0])
        ys = np.array([-2.5, 0.0, 1.85, 5.55, 7.0])
        xx, yy = np.meshgrid(xs, ys)
        pts = np.column_stack([xx.ravel(), yy.ravel(), np.zeros(xx.size)])
        uv, depth = cam.project(pts)
        assert np.all(depth > 0)
        back = cam.backproject_to_ground(uv)
        err = np.hypot(*(back[:, :2] - pts[:, :2]).T)
        dist = np.hypot(pts[:, 0] - rsu.camera.x_m, pts[:, 1] - rsu.camera.y_m)
        assert err[dist <= 55.0].max() < 0.01
        assert err.max() < 0.05  # float rounding only, even at 120 m


def test_projection_matches_corridor_projection_matrix_and_survey(cams, corridor):
    rsu = corridor.rsu("rsu2")
    cam = cams["rsu2"]
    pts = np.array([[80.0, 1.0, 0.0], [120.0, 5.0, 1.5]])
    uv, _ = cam.project(pts)
    h = (rsu.camera.projection_matrix @ np.column_stack([pts, np.ones(2)]).T).T
    assert np.allclose(uv, h[:, :2] / h[:, 2:], atol=1e-9)
    # the corridor's surveyed calibration pairs (RTK noise 2 cm) agree with the model
    cal = np.array(rsu.calibration)
    back = cam.backproject_to_ground(cal[:, :2])
    assert np.median(np.hypot(*(back[:, :2] - cal[:, 2:]).T)) < 0.1


def test_pixel_above_horizon_does_not_hit_ground(cams):
    cam = cams["rsu1"]
    v_h = cam.horizon_v_px()
    assert 0 < v_h < 360
    assert np.isnan(cam.backproject_to_ground(np.array([[640.0, v_h - 20]]))).all()
    assert np.isfinite(cam.backproject_to_ground(np.array([[640.0, v_h + 20]]))).all()


def test_project_box_contains_projected_corners_and_clips(cams):
    cam = cams["rsu1"]
    corners = box_corners(50.0, 1.85, 0.0, 4.5, 1.8, 1.5)
    assert corners.shape == (8, 3)
    assert np.allclose(corners[:4, 2], 0) and np.allclose(corners[4:, 2], 1.5)
    box = cam.project_box(corners)
    uv, _ = cam.project(corners)
    assert box == pytest.approx((uv[:, 0].min(), uv[:, 1].min(), uv[:, 0].max(), uv[:, 1].max()))
    # a heading of pi/2 swaps the footprint axes
    c2 = box_corners(0.0, 0.0, math.pi / 2, 4.0, 2.0, 1.0)
    assert np.ptp(c2[:, 0]) == pytest.approx(2.0) and np.ptp(c2[:, 1]) == pytest.approx(4.0)
    # behind the camera: not projectable
    assert cam.project_box(box_corners(-20.0, 0.0, 0.0, 4.5, 1.8, 1.5)) is None
