"""The car never drives into the vehicle ahead (vehicle.forward_guard): it brakes as hard as constant-deceleration
kinematics need to match the lead's speed 2 m behind it, whatever its command planned (e2e_bench process seed 9:
without the guard the AV pulls over behind a car braking for the EV and runs into it at 1 m/s)."""

import math

import pytest

from protocol.corridor import load_corridor
from vehicle.forward_guard import (
    GUARD_MARGIN_M,
    GUARD_MIN_DECEL_MPS2,
    braking_for_lead,
    guarded_accel,
    lead_vehicle,
)

ROAD = load_corridor().road


def _at(s, d):
    x, y, _ = ROAD.pose_at(s, d)
    return float(x), float(y)


def test_braking_for_lead_is_constant_deceleration_kinematics():
    assert braking_for_lead(10.0, 2.0 + 8.0, 6.0) == pytest.approx(16.0 / 16.0)
    assert braking_for_lead(6.0, 5.0, 6.0) == 0.0 and braking_for_lead(5.0, 5.0, 7.0) == 0.0  # not closing
    assert math.isinf(braking_for_lead(5.0, GUARD_MARGIN_M - 0.1, 4.0))


def test_guard_brakes_harder_than_the_plan_only_when_needed():
    assert guarded_accel(-0.5, GUARD_MIN_DECEL_MPS2 * 0.9, 6.0) == -0.5  # gentle closing: the controller's
    assert guarded_accel(-3.0, 4.0, 6.0) == pytest.approx(-5.0)  # 1.25 x the need
    assert guarded_accel(-3.0, math.inf, 6.0) == -6.0  # capped at the emergency deceleration
    assert guarded_accel(-6.0, 2.0, 6.0) == -6.0  # never softer than the plan


def test_lead_is_the_nearest_vehicle_ahead_in_the_cars_footprint_and_never_the_car_itself():
    lane0, lane1 = 0.5 * ROAD.lane_width_m, 1.5 * ROAD.lane_width_m
    x, y = _at(100.0, lane0)
    own = (x + 0.4, y - 0.2, 4.8, 1.9)                   # the car itself, as an RSU sees it
    ahead = (*_at(112.0, lane0 - 0.4), 4.5, 1.8, 5.0, 0.0)  # 7.35 m bumper to bumper, 5 m/s
    farther = (*_at(140.0, lane0), 4.5, 1.8)
    beside = (*_at(106.0, lane1), 4.5, 1.8)               # the next lane (the EV overtaking)
    behind = (*_at(90.0, lane0), 4.5, 1.8)
    gap, speed = lead_vehicle([own, farther, beside, behind, ahead], ROAD, x, y, 4.9, 1.9)
    assert gap == pytest.approx(12.0 - 4.7, abs=0.05) and speed == pytest.approx(5.0, abs=0.05)
    assert lead_vehicle([own, beside, behind], ROAD, x, y, 4.9, 1.9) is None


def test_the_car_brakes_for_a_slower_car_ahead_beyond_the_comfort_rate():
    """A car 10 m ahead at 5 m/s, the AV cruising at 13.4 m/s in lane keeping: at the comfort rate (3 m/s^2) it
    would need 11.8 m to match the car's speed; with the picture it brakes harder and stays clear of it."""
    from tests.vehicle.test_vehicle_service import Harness

    h = Harness()
    h.run(0.5)
    core = h.svc.sim.core
    assert core.speed_mps > 13.0
    lead_s = [None]

    def picture(now):
        x, y, _ = core.estimator.pose
        s, d = (float(v) for v in ROAD.to_frenet(x, y))
        if lead_s[0] is None:
            lead_s[0] = s + 4.9 / 2 + 10.0 + 4.5 / 2
        lx, ly = _at(lead_s[0] + 5.0 * (now - t0), d)
        h_rad = float(ROAD.pose_at(lead_s[0], d)[2])
        core.on_picture(now, [(x, y, 4.9, 1.9), (lx, ly, 4.5, 1.8, 5.0 * math.cos(h_rad), 5.0 * math.sin(h_rad))], "rsu1")

    t0 = h.clock.now()
    accels, gaps = [], []
    for _ in range(150):
        now = h.clock.now()
        picture(now)
        h.svc.step(now)
        accels.append(core.last.accel_cmd_mps2)
        x, y, _ = core.estimator.pose
        s = float(ROAD.to_frenet(x, y)[0])
        gaps.append(lead_s[0] + 5.0 * (now - t0) - s - (4.9 + 4.5) / 2)
        h.clock.advance(0.01)
    assert min(accels) < -3.5  # beyond the comfort rate
    assert min(gaps) > 0.5  # no contact
