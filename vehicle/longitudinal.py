"""Longitudinal controller: speed tracking and a comfortable stop at a commanded point.

The reference speed is the lower of the path's speed (cruise or the command's profile) and the
braking curve v_stop(d) = sqrt(2 a_plan d) to the stop point d metres ahead; a proportional term
tracks it and the braking curve's own deceleration (or the commanded profile's) is fed forward. Deceleration is capped at
``comfort_decel_mps2`` (3 m/s^2); only when the stop point cannot be reached at that rate
(v^2 / 2d above it) may it rise to ``emergency_decel_mps2``. Within ``hold_distance_m`` of the
point at walking pace it holds the brake.
"""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class LongitudinalOutput:
    accel_cmd_mps2: float
    speed_ref_mps: float
    distance_to_stop_m: float | None
    emergency: bool
    holding: bool


@dataclass
class LongitudinalController:
    plan_decel_mps2: float = 2.0
    """Deceleration the braking curve is planned with (stays below the comfort cap)."""
    comfort_decel_mps2: float = 3.0
    emergency_decel_mps2: float = 6.0
    max_accel_mps2: float = 1.5
    speed_gain_1ps: float = 0.8
    """Proportional gain on the speed error (m/s^2 per m/s)."""
    hold_distance_m: float = 0.3
    hold_speed_mps: float = 0.3

    def step(self, speed_mps: float, target_speed_mps: float,
             distance_to_stop_m: float | None, accel_ff_mps2: float = 0.0) -> LongitudinalOutput:
        """``accel_ff_mps2``: the reference's own acceleration (a commanded speed profile's v dv/ds), fed
        forward so a braking profile is tracked without the lag of the proportional term alone."""
        v_ref, ff = max(0.0, target_speed_mps), accel_ff_mps2
        cap, emergency = self.comfort_decel_mps2, False
        if distance_to_stop_m is not None:
            d = max(0.0, distance_to_stop_m)
            if d <= self.hold_distance_m and speed_mps <= self.hold_speed_mps or distance_to_stop_m < -0.5:
                return LongitudinalOutput(-self.comfort_decel_mps2, 0.0, distance_to_stop_m, False, True)
            v_curve = math.sqrt(2.0 * self.plan_decel_mps2 * d)
            if v_curve < v_ref:
                v_ref = v_curve
                ff = -self.plan_decel_mps2
            needed = speed_mps ** 2 / (2.0 * d) if d > 0 else math.inf
            if needed > self.comfort_decel_mps2 and speed_mps > 2.0:  # not the last creep to the point
                emergency = True
                cap = self.emergency_decel_mps2
                ff = -min(needed, cap)
        accel = ff + self.speed_gain_1ps * (v_ref - speed_mps)
        accel = min(self.max_accel_mps2, max(-cap, accel))
        return LongitudinalOutput(accel, v_ref, distance_to_stop_m, emergency, False)
