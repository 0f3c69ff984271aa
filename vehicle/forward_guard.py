"""The car never drives into the vehicle ahead (its own guard, beside the DDM's commands).

A DDM command is a path and a stop point planned from the corridor's picture a moment ago; the car ahead may brake
after it was planned (a driver slowing for the EV in the lane the AV pulls into: ``e2e_bench`` process seed 9,
where without this guard the AV braked at the comfort rate towards a stop point beyond that car and ran into it at
1 m/s). So on every control step the car looks at its own picture of the corridor (the RSUs' latest objects,
``VehicleCore.on_picture``) for the nearest vehicle ahead whose footprint overlaps its own across the road, and
brakes at least as hard as constant-deceleration kinematics need to match that vehicle's speed ``margin_m`` behind
it: ``a = (v - v_lead)^2 / 2 (gap - margin)``. Pure functions; ``vehicle.core`` applies them.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence

import numpy as np

GUARD_MARGIN_M = 2.0
"""Bumper-to-bumper gap the guard keeps to the vehicle ahead (RSU positions are good to about 0.5 m)."""
GUARD_MIN_DECEL_MPS2 = 1.0
"""The guard brakes only when more than this is needed: gentle closing is the longitudinal controller's."""
GUARD_GAIN = 1.25
"""The guard brakes this much harder than the kinematics need (actuator lag, the picture's age)."""
OWN_RADIUS_M = 3.0
"""The object nearest the car's own pose within this distance is the car itself."""
LATERAL_SLACK_M = 0.3


def lead_vehicle(objects: Iterable[Sequence[float]], road, x_m: float, y_m: float, length_m: float, width_m: float
                 ) -> tuple[float, float] | None:
    """(bumper-to-bumper gap m, speed along the road m/s) of the nearest vehicle ahead of the car at (x, y) whose
    footprint overlaps the car's across the road (within ``LATERAL_SLACK_M``), from ``objects`` (x, y, length,
    width[, vx, vy]: an object without a velocity is taken as standing); the car itself (the object nearest its pose
    within ``OWN_RADIUS_M``) is left out; None when none is ahead."""
    objects = [tuple(o) for o in objects]
    own = min(objects, key=lambda o: math.hypot(o[0] - x_m, o[1] - y_m), default=None)
    # the car and every object placed on the road by one query (the car steps at 100 Hz; per point it cost 5x more)
    s_all, d_all = road.to_frenet(np.array([x_m] + [o[0] for o in objects], float),
                                  np.array([y_m] + [o[1] for o in objects], float))
    s_car, d_car = float(s_all[0]), float(d_all[0])
    best = None
    for obj, s, d in zip(objects, s_all[1:].tolist(), d_all[1:].tolist(), strict=True):
        if obj is own and math.hypot(obj[0] - x_m, obj[1] - y_m) <= OWN_RADIUS_M:
            continue
        if abs(d - d_car) > (width_m + obj[3]) / 2.0 + LATERAL_SLACK_M:
            continue
        gap = s - s_car - (length_m + obj[2]) / 2.0
        if s <= s_car or (best is not None and gap >= best[0]):
            continue
        speed = 0.0
        if len(obj) >= 6:
            heading = float(road.pose_at(s, d)[2])
            speed = max(0.0, obj[4] * math.cos(heading) + obj[5] * math.sin(heading))
        best = (gap, speed)
    return best


def braking_for_lead(speed_mps: float, gap_m: float, lead_speed_mps: float, margin_m: float = GUARD_MARGIN_M
                     ) -> float:
    """Deceleration (m/s^2, >= 0) that brings the car to the lead's speed ``margin_m`` behind it, both at constant
    deceleration of the car and constant speed of the lead: (v - v_lead)^2 / 2 (gap - margin); 0 when not closing;
    infinite when already within the margin and closing."""
    closing = speed_mps - lead_speed_mps
    if closing <= 0.0:
        return 0.0
    room = gap_m - margin_m
    return math.inf if room <= 0.0 else closing * closing / (2.0 * room)


def guarded_accel(accel_cmd_mps2: float, needed_mps2: float, emergency_decel_mps2: float) -> float:
    """The controller's command, or the guard's braking when that is harder: ``GUARD_GAIN`` x the need, capped at
    the emergency deceleration, once the need exceeds ``GUARD_MIN_DECEL_MPS2``."""
    if needed_mps2 < GUARD_MIN_DECEL_MPS2:
        return accel_cmd_mps2
    return min(accel_cmd_mps2, -min(GUARD_GAIN * needed_mps2, emergency_decel_mps2))
