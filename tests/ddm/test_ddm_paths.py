"""Path planner: smooth lane-change curves within the curvature limit, stops at comfortable deceleration."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ddm.config import DdmConfig
from ddm.geometry import RoadFrame
from ddm.paths import (
    plan_keep_lane_slow,
    plan_resume,
    plan_stop,
    polyline_curvature,
    quintic_offset,
    stop_offset_m,
)
from protocol.corridor import load_corridor
from protocol.road import Road, Segment

CFG = DdmConfig()
FRAME = RoadFrame(load_corridor().road)


def test_quintic_boundary_conditions():
    u = np.linspace(0, 1, 1001)
    d = quintic_offset(u, 5.55, -1.25)
    assert d[0] == pytest.approx(5.55) and d[-1] == pytest.approx(-1.25)
    dd = np.gradient(d, u)
    assert abs(dd[0]) < 1e-2 and abs(dd[-1]) < 1e-2
    assert np.all(np.diff(d) <= 1e-12)  # monotonic: no overshoot


@pytest.mark.parametrize("speed", [4.0, 13.4, 25.0])
def test_pull_over_from_lane_1_stays_within_curvature_and_decel_limits(speed):
    s0, d0 = 120.0, FRAME.lane_centre_offset(1)
    d_stop = stop_offset_m(FRAME, 1.9, FRAME.road.shoulder_width_m, CFG)
    p = plan_stop(FRAME, s0, d0, 0.0, speed, d_stop, CFG)
    x0, y0, _ = FRAME.road.pose_at(s0, d0)
    assert p.waypoints[0] == pytest.approx((x0, y0))  # starts at the vehicle
    # the car brakes during the change: the comfort limit applies to v^2 kappa (checked below)
    assert p.max_curvature_1pm <= CFG.max_curvature_1pm
    assert p.decel_mps2 <= CFG.comfort_decel_mps2 + 1e-9 <= 3.0
    # speeds never increase and reach 0 at the stop point, which lies on the target offset
    v = np.array(p.speeds_mps)
    assert np.all(np.diff(v) <= 1e-9) and v[-1] == 0.0 and v[0] == pytest.approx(speed)
    s_stop, d_at_stop = FRAME.to_frenet(*p.stop_point)
    assert d_at_stop[0] == pytest.approx(d_stop, abs=0.05)
    assert s_stop[0] - s0 == pytest.approx(p.stop_distance_m, abs=0.1)
    # and the lateral acceleration v^2 kappa along the path is within comfort
    xs, ys = np.array(p.waypoints).T
    lat = v[1:-1] ** 2 * polyline_curvature(xs, ys)
    assert lat.max() <= CFG.max_lat_accel_mps2 * 1.05


def test_pull_over_brakes_harder_to_stop_before_the_ev_or_behind_a_leader():
    s0, d0 = 120.0, FRAME.lane_centre_offset(1)
    d_stop = stop_offset_m(FRAME, 1.9, FRAME.road.shoulder_width_m, CFG)
    relaxed = plan_stop(FRAME, s0, d0, 0.0, 13.4, d_stop, CFG)
    hurried = plan_stop(FRAME, s0, d0, 0.0, 13.4, d_stop, CFG, stop_within_s=6.0)
    assert relaxed.decel_mps2 <= CFG.comfort_decel_mps2 + 1e-9
    assert CFG.comfort_decel_mps2 < hurried.decel_mps2 <= CFG.max_decel_mps2
    assert 2.0 * hurried.stop_distance_m / 13.4 <= 6.0 + 1e-6  # stopped within the 6 s asked
    short = plan_stop(FRAME, s0, d0, 0.0, 13.4, d_stop, CFG, max_stop_dist_m=42.0)
    assert short.stop_distance_m == pytest.approx(42.0) and short.decel_mps2 <= CFG.max_decel_mps2
    for p in (hurried, short):  # urgent, but within the urgent lateral acceleration at the speed driven
        v = np.array(p.speeds_mps)
        xs, ys = np.array(p.waypoints).T
        assert (v[1:-1] ** 2 * polyline_curvature(xs, ys)).max() <= CFG.urgent_lat_accel_mps2 * 1.05


def test_stop_on_shoulder_only_when_it_fits():
    shoulder = DdmConfig(stop_on_shoulder=True)
    assert stop_offset_m(FRAME, 1.9, 2.5, shoulder) == pytest.approx(-1.25)  # RELLIS: 2.5 m shoulder fits 1.9 + 2 x 0.3
    assert stop_offset_m(FRAME, 1.9, 1.0, shoulder) == pytest.approx(1.25)  # too narrow: curb side of lane 0
    assert stop_offset_m(FRAME, 1.9, 2.5, CFG) == pytest.approx(1.25)  # default: curb side of lane 0


def test_paths_follow_a_curved_road():
    road = Road(0.0, 0.0, 0.0, (Segment("straight", 50.0), Segment("arc", 300.0, 150.0)), lanes=2)
    frame = RoadFrame(road)
    p = plan_stop(frame, 60.0, frame.lane_centre_offset(1), 0.0, 13.4, -1.25, CFG)
    s, d = frame.to_frenet(*np.array(p.waypoints).T)
    assert np.all(np.diff(s) > 0)
    assert d[-1] == pytest.approx(-1.25, abs=0.05)
    assert p.max_curvature_1pm <= 1 / 150.0 + CFG.max_lat_accel_mps2 / 13.4**2 + 1e-3


def test_slow_in_lane_and_resume_profiles():
    slow = plan_keep_lane_slow(FRAME, 50.0, FRAME.lane_centre_offset(1), 0.0, 13.4, FRAME.lane_centre_offset(1),
                               CFG.slow_speed_mps, CFG)
    assert slow.speeds_mps[0] == pytest.approx(13.4) and slow.speeds_mps[-1] == pytest.approx(CFG.slow_speed_mps)
    _, d = FRAME.to_frenet(*np.array(slow.waypoints).T)
    assert np.allclose(d, FRAME.lane_centre_offset(1), atol=0.01)
    res = plan_resume(FRAME, 90.0, -1.25, 0.0, 0.0, FRAME.lane_centre_offset(0), 13.4, CFG)
    assert res.speeds_mps[0] > 0 and res.speeds_mps[-1] == pytest.approx(13.4)
    _, d = FRAME.to_frenet(*np.array(res.waypoints[-5:]).T)
    assert np.allclose(d, FRAME.lane_centre_offset(0), atol=0.05)
    assert len(res.waypoints) <= 512


def test_road_frame_matches_the_corridor_road():
    road = Road(0.0, 0.0, 0.3, (Segment("straight", 40.0), Segment("arc", 100.0, -80.0)), lanes=3)
    frame = RoadFrame(road)
    rng = np.random.default_rng(0)
    s = rng.uniform(1, 139, 50)
    d = rng.uniform(-2, 10, 50)
    x, y, _ = road.pose_at(s, d)
    fs, fd = frame.to_frenet(x, y)
    for k in range(0, 50, 7):
        rs, rd = road.to_frenet(float(x[k]), float(y[k]))
        assert fs[k] == pytest.approx(rs, abs=0.05) and fd[k] == pytest.approx(rd, abs=0.05)
    assert np.allclose(fs, s, atol=0.05) and np.allclose(fd, d, atol=0.05)
    assert math.isclose(float(frame.heading_at(10.0)), 0.3, abs_tol=1e-6)


def test_pull_over_holding_speed_clears_the_lane_before_it_brakes():
    """The held-speed pull-over keeps 13.4 m/s over its lane change and brakes only after it; with
    the EV close (time to pass < urgent_within_s) the change is shorter (urgent lateral acceleration)."""
    from ddm.paths import plan_stop_holding_speed

    d0, d1 = 5.55, 1.25
    calm = plan_stop_holding_speed(FRAME, 100.0, d0, 0.0, 13.4, d1, CFG, stop_within_s=20.0)
    urgent = plan_stop_holding_speed(FRAME, 100.0, d0, 0.0, 13.4, d1, CFG, stop_within_s=3.0)
    for p in (calm, urgent):
        s = np.array([FRAME.road.to_frenet(x, y)[0] for x, y in p.waypoints]) - 100.0
        v = np.array(p.speeds_mps)
        in_change = s <= p.lane_change_length_m - 0.5
        assert np.all(v[in_change] == pytest.approx(13.4))  # no braking while still changing lanes
        assert v[-1] == 0.0 and p.decel_mps2 <= CFG.max_decel_mps2
    assert urgent.lane_change_length_m < calm.lane_change_length_m
    # peak lateral acceleration of the urgent change within urgent_lat_accel_mps2 (5.77 dd / L^2 x v^2)
    assert 5.77 * (d0 - d1) / urgent.lane_change_length_m ** 2 * 13.4 ** 2 <= CFG.urgent_lat_accel_mps2 + 1e-6
    # no room for it behind a car ahead: None (plan_stop brakes from the start instead)
    assert plan_stop_holding_speed(FRAME, 100.0, d0, 0.0, 13.4, d1, CFG, stop_within_s=3.0, max_stop_dist_m=30.0) is None
