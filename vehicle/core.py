"""The vehicle's driving logic (pure core): modes, reference switching, controllers, fail-safe.

``VehicleCore`` sees only what a car's computer sees: odometry (wheel speed, yaw-rate gyro),
position fixes (own GNSS or the RSU's track of the car) and commands. Each control step
(``control(now, ...)``, 100 Hz) it dead-reckons the pose, checks the watchdog, picks the reference
for its mode and returns steering and acceleration commands.

Modes (``VehicleMode``): DRIVING keeps the centre of the current lane at cruise speed (and stops
before the end of the corridor's road); MANOEUVRE follows a commanded path and speed profile and
stops at its stop point; STOPPED is reached when a commanded stop is done; MINIMAL_RISK is the
fail-safe stop at the right edge of the road (``curb_offset_m``; in the current lane when the car's last
picture shows that side occupied). While no DDM heartbeat is heard for ``link_timeout_s`` the car is
*degraded* (``vehicle.failsafe``): speed capped, said in ``detail``. A ``resume`` command returns to
DRIVING in the current lane.

The closed loop of the simulator, the tests and the service (plant, simulated sensors and this core) is
``vehicle.simulated.SimulatedVehicle``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from protocol.enums import AckStatus, Manoeuvre, VehicleMode
from protocol.messages import PathSwitchCommand
from vehicle.commands import CommandBook, CommandLimits, Decision
from vehicle.failsafe import FailsafeConfig, Watchdog
from vehicle.forward_guard import OWN_RADIUS_M, braking_for_lead, guarded_accel, lead_vehicle
from vehicle.lateral import LateralController, LateralGains, LateralOutput
from vehicle.localisation import (
    Fix,
    PoseEstimator,
)
from vehicle.longitudinal import LongitudinalController, LongitudinalOutput
from vehicle.plant import VehicleParams
from vehicle.reference import ReferencePath, lane_centre_waypoints, offset_change_waypoints

ROAD_END_MARGIN_M = 10.0
PICTURE_MAX_AGE_S = 2.0
"""The car's picture (objects the RSUs reported) counts for the fail-safe's curb check this long."""
GUARD_PICTURE_AGE_S = 0.5
"""The forward guard uses only objects reported this recently (positions moved on at their velocity)."""
MRM_LAT_ACCEL_MPS2 = 2.0
MRM_MAX_CURVATURE_1PM = 0.08
CURB_CHECK_BEHIND_M = 10.0
"""An object from this far behind the car up to its stop point, on the curb side, occupies the curb."""


@dataclass(frozen=True)
class CoreConfig:
    params: VehicleParams = field(default_factory=VehicleParams)
    gains: LateralGains = field(default_factory=LateralGains)
    failsafe: FailsafeConfig = field(default_factory=FailsafeConfig)
    limits: CommandLimits = field(default_factory=CommandLimits)
    stop_tolerance_m: float = 1.0
    """A commanded stop is complete when stopped within this distance of the stop point."""
    stopped_speed_mps: float = 0.05


@dataclass(frozen=True, slots=True)
class ControlOutput:
    time_s: float
    steer_cmd_rad: float
    accel_cmd_mps2: float
    lateral: LateralOutput
    longitudinal: LongitudinalOutput
    mode: VehicleMode
    decisions: tuple[Decision, ...]
    """Acks produced during this step (completion, abort)."""


class VehicleCore:
    def __init__(self, road, vehicle_id: str, cruise_speed_mps: float, config: CoreConfig = CoreConfig()) -> None:
        self.road = road
        self.vehicle_id = vehicle_id
        self.cruise_speed_mps = cruise_speed_mps
        self.config = config
        self.estimator = PoseEstimator()
        self.lateral = LateralController(config.params, config.gains)
        self.longitudinal = LongitudinalController(comfort_decel_mps2=3.0)
        self.book = CommandBook(vehicle_id, config.limits)
        self.watchdog = Watchdog(config.failsafe)
        self.mode = VehicleMode.DRIVING
        self.detail = "lane keeping"
        self.lane = 0
        self.target_speed_mps = cruise_speed_mps
        self.path: ReferencePath | None = None
        self.stop_s_m: float | None = None
        self.plan_decel_mps2 = self.longitudinal.plan_decel_mps2
        self.speed_mps = 0.0
        self.yaw_rate_rps = 0.0
        self.last: ControlOutput | None = None
        self.path_version = 0
        """Increments whenever the reference path changes (for recording)."""
        self._lane_paths: dict[int, ReferencePath] = {}
        self._vy = 0.0
        self._accel = 0.0
        self.pictures: dict[str, tuple[float, list[tuple[float, ...]]]] = {}
        """Per source (RSU): (time, [(x, y, length, width[, vx, vy])]) of the objects it last reported
        (``on_picture``)."""
        self._detail_undegraded: str | None = None
        self.mrm_where = ""
        """Where the minimal-risk stop ends: at the curb, or in its lane when the curb side was occupied."""
        self.mrm_reason = ""

    # ------------------------------------------------------------------ setup
    def lane_path(self, lane: int) -> ReferencePath:
        if lane not in self._lane_paths:
            wp = lane_centre_waypoints(self.road, lane, 0.0, self.road.length_m, step_m=2.0)
            self._lane_paths[lane] = ReferencePath(wp)
        return self._lane_paths[lane]

    def initialise(self, now_s: float, x_m: float, y_m: float, yaw_rad: float, speed_mps: float) -> None:
        self.estimator.initialise(now_s, x_m, y_m, yaw_rad)
        self.estimator.last_fix_s = now_s  # the start pose counts as a fix
        self.speed_mps = speed_mps
        lane = self.road.lane_at(x_m, y_m)
        self._keep_lane(0 if lane is None else lane, self.cruise_speed_mps, "lane keeping")

    def _set_path(self, path: ReferencePath, stop_s_m: float | None) -> None:
        self.path, self.stop_s_m = path, stop_s_m
        self.lateral.reset()
        self.path_version += 1

    def _keep_lane(self, lane: int, speed_mps: float, detail: str) -> None:
        self.lane = lane
        path = self.lane_path(lane)
        self.target_speed_mps = speed_mps
        self.mode, self.detail = VehicleMode.DRIVING, detail
        self.plan_decel_mps2 = self.longitudinal.plan_decel_mps2
        self._set_path(path, path.length_m - ROAD_END_MARGIN_M)

    def current_lane(self) -> int:
        x, y, _ = self.estimator.pose
        lane = self.road.lane_at(x, y)
        if lane is None:
            _, d = self.road.to_frenet(x, y)
            lane = 0 if d < 0 else self.road.lanes - 1
        return lane

    # ------------------------------------------------------------------ inputs
    def on_fix(self, fix: Fix) -> bool:
        return self.estimator.update(fix)

    def on_link(self, now_s: float) -> None:
        """A valid, authenticated DDM heartbeat heard."""
        self.watchdog.link_seen(now_s)

    def on_picture(self, now_s: float, objects: list[tuple[float, ...]], source: str = "") -> None:
        """The objects (x, y, length, width[, vx, vy]) of one source's (an RSU's) latest report: the car's picture
        of its surroundings, for the fail-safe's curb check and the forward guard (the car itself is among them and
        is left out)."""
        self.pictures[source] = (now_s, list(objects))

    def lead_braking_mps2(self, now_s: float, speed_mps: float) -> float:
        """Deceleration needed not to run into the nearest vehicle ahead in the car's last picture
        (``vehicle.forward_guard``): objects reported within ``GUARD_PICTURE_AGE_S``, moved on at their reported
        velocity to now; only those within the car's braking reach ahead of it are placed on the road."""
        x, y, yaw = self.estimator.pose
        reach = 10.0 + speed_mps * speed_mps / 2.0
        c, s = math.cos(yaw), math.sin(yaw)
        near = []
        for t, objects in self.pictures.values():
            age = now_s - t
            if age > GUARD_PICTURE_AGE_S:
                continue
            for o in objects:
                ox, oy = (o[0] + o[4] * age, o[1] + o[5] * age) if len(o) >= 6 else (o[0], o[1])
                dx, dy = ox - x, oy - y
                if dx * c + dy * s > -OWN_RADIUS_M and dx * dx + dy * dy <= reach * reach:
                    near.append((ox, oy, *o[2:]))
        if not near:
            return 0.0
        lead = lead_vehicle(near, self.road, x, y, self.config.params.length_m, self.config.params.width_m)
        return 0.0 if lead is None else braking_for_lead(speed_mps, *lead)

    def curb_offset_m(self) -> float:
        """Lateral offset d of the minimal-risk stop: the middle of the shoulder when the car fits on it
        with ``curb_margin_m`` either side, else the curb side of the rightmost lane."""
        w = self.config.params.width_m
        margin = self.config.failsafe.curb_margin_m
        shoulder = getattr(self.road, "shoulder_width_m", 0.0)
        if shoulder >= w + 2 * margin:
            return -shoulder / 2.0
        return w / 2.0 + margin

    def curb_side_occupied(self, now_s: float, s_now: float, d_now: float, d_curb: float, s_stop: float,
                           behind_m: float = CURB_CHECK_BEHIND_M) -> bool:
        """Whether the car's last picture shows an object between its side and the curb, from a little
        behind it (``behind_m``) to its stop point (the car itself, the object nearest its own pose within 3 m,
        is left out)."""
        x, y, _ = self.estimator.pose
        picture = []
        for t, objects in self.pictures.values():
            if now_s - t > PICTURE_MAX_AGE_S:
                continue
            own = min(objects, key=lambda o: math.hypot(o[0] - x, o[1] - y), default=None)
            picture += [o for o in objects if o is not own or math.hypot(o[0] - x, o[1] - y) > 3.0]
        half_w = self.config.params.width_m / 2.0
        if d_curb < d_now:  # the strip from the car's right side to where its right side will stop
            lo, hi = d_curb - half_w, d_now - half_w
        else:
            lo, hi = d_now + half_w, d_curb + half_w
        for obj in picture:
            s, d = (float(v) for v in self.road.to_frenet(obj[0], obj[1]))
            if s_now - behind_m <= s <= s_stop + obj[2] / 2 and d - obj[3] / 2 < hi and d + obj[3] / 2 > lo:
                return True
        return False

    def on_command(self, cmd: PathSwitchCommand, now_s: float) -> list[Decision]:
        if cmd.vehicle_id == self.vehicle_id:
            self.watchdog.link_seen(now_s)
        blocked = self.watchdog.healthy(now_s, self.estimator.age_s(now_s))
        decisions = self.book.offer(cmd, now_s, self.estimator.pose, self.speed_mps, blocked)
        if decisions and decisions[-1].status == AckStatus.ACCEPTED and decisions[-1].command_id == cmd.command_id \
                and self.book.active is cmd:
            decisions += self._engage(cmd)
        return decisions

    def _engage(self, cmd: PathSwitchCommand) -> list[Decision]:
        self.watchdog.clear()
        own, self.mrm_reason = self.mode == VehicleMode.MINIMAL_RISK and bool(self.mrm_reason), ""
        if own and cmd.manoeuvre == Manoeuvre.PULL_OVER and self.path is not None and self.stop_s_m is not None:
            # already pulling over to the curb on its own (a signed EvAlert, the command late): keep that path,
            # whose lane change is under way (the command's, planned from where the car was, would start it
            # again), and stop at the nearer of the two stop points
            if cmd.stop_point is not None:
                self.stop_s_m = min(self.stop_s_m, self.path.project(*cmd.stop_point).s_m)
            self.mode, self.detail = VehicleMode.MANOEUVRE, f"pull_over (on its own path): {cmd.reason}"[:200]
            return []
        if cmd.manoeuvre == Manoeuvre.RESUME:
            self._keep_lane(self.current_lane(), self.cruise_speed_mps, f"resumed ({cmd.command_id})")
            return [self.book.complete("resumed cruise")]
        path = self.book.active_path
        assert path is not None
        self.target_speed_mps = cmd.target_speed_mps
        self.mode = VehicleMode.MANOEUVRE
        self.detail = f"{cmd.manoeuvre.value}: {cmd.reason}"[:200]
        self.plan_decel_mps2 = self.longitudinal.plan_decel_mps2
        if path.stop_s_m is not None and path.speeds is not None and path.stop_s_m > 1.0:
            # brake to the stop as the command planned it (the DDM may brake harder than our default
            # to stop before the EV arrives, or hold its speed over the lane change and brake after it),
            # never beyond the comfort cap
            planned = planned_braking_mps2(path)
            self.plan_decel_mps2 = min(max(planned, self.plan_decel_mps2), self.longitudinal.comfort_decel_mps2)
        self._set_path(path, path.stop_s_m)
        return []

    # ------------------------------------------------------------------ control step
    def lateral_speed_model(self, speed_mps: float, yaw_rate_rps: float, steer_rad: float | None,
                            dt_s: float) -> float:
        """The car's estimate of its body-frame v_y (for dead reckoning).

        With the steering-angle sensor: eq. 4.11 driven by the measured steering and yaw rate (a
        first-order filter, time constant m v_x / (C_f + C_r)); without it, the steady-state sideslip.
        """
        p = self.config.params
        if speed_mps <= p.kinematic_below_mps:
            self._vy = p.cg_to_rear_m * yaw_rate_rps
        elif steer_rad is None:
            self._vy = p.steady_sideslip_rad(yaw_rate_rps / speed_mps, speed_mps) * speed_mps
        else:
            m, a, b = p.mass_kg, p.cg_to_front_m, p.cg_to_rear_m
            cf, cr, v = p.cornering_front_npr, p.cornering_rear_npr, speed_mps
            n = max(1, int(dt_s / 0.002 + 0.999))
            for _ in range(n):
                dvy = (cf * steer_rad - (cf + cr) / v * self._vy - (a * cf - b * cr) / v * yaw_rate_rps) / m \
                    - v * yaw_rate_rps
                self._vy += dvy * dt_s / n
        return self._vy

    def _accel_model(self, dt_s: float) -> float:
        """The car's longitudinal acceleration: its own last command through the actuator lag."""
        cmd = 0.0 if self.last is None else self.last.accel_cmd_mps2
        lag = self.config.params.accel_lag_s
        self._accel += (cmd - self._accel) * (min(1.0, dt_s / lag) if lag > 0 else 1.0)
        return self._accel

    def control(self, now_s: float, speed_mps: float, yaw_rate_rps: float, dt_s: float,
                steer_rad: float | None = None) -> ControlOutput:
        """One control step from odometry (and the steering-angle sensor); returns actuator commands and
        any acks due."""
        self.speed_mps, self.yaw_rate_rps = speed_mps, yaw_rate_rps
        vy_model = self.lateral_speed_model(speed_mps, yaw_rate_rps, steer_rad, dt_s)
        self.estimator.predict(now_s, speed_mps, yaw_rate_rps, vy_model)
        decisions: list[Decision] = []
        reason = self.watchdog.check(now_s, self.mode == VehicleMode.MANOEUVRE, self.estimator.age_s(now_s))
        if reason is not None and self.mode != VehicleMode.MINIMAL_RISK:
            decisions += self._minimal_risk(reason, now_s)
        self._degrade(self.watchdog.degraded)
        assert self.path is not None
        x, y, yaw = self.estimator.pose
        lat = self.lateral.step(self.path, x, y, yaw, speed_mps, yaw_rate_rps, dt_s, self._accel_model(dt_s))
        dist = None if self.stop_s_m is None else self.stop_s_m - lat.s_m
        if self.mode == VehicleMode.STOPPED:
            dist = 0.0
        ff = 0.0
        if self.mode == VehicleMode.MANOEUVRE:
            target = self.path.speed_at(lat.s_m, self.target_speed_mps)
            ahead = self.path.speed_at(lat.s_m + 1.0, self.target_speed_mps)
            ff = target * (ahead - target)  # v dv/ds over the next metre of the profile
        else:
            target = self.target_speed_mps
        if self.watchdog.degraded is not None and self.mode != VehicleMode.MINIMAL_RISK:
            target = min(target, self.config.failsafe.degraded_speed_mps)
        self.longitudinal.plan_decel_mps2 = self.plan_decel_mps2
        lon = self.longitudinal.step(speed_mps, target, dist, ff)
        accel = guarded_accel(lon.accel_cmd_mps2, self.lead_braking_mps2(now_s, speed_mps),
                              self.longitudinal.emergency_decel_mps2)
        if accel < lon.accel_cmd_mps2:  # the vehicle ahead needs harder braking than the plan (vehicle.forward_guard)
            lon = replace(lon, accel_cmd_mps2=accel, emergency=True)
        decisions += self._progress(lat, speed_mps, dist)
        out = ControlOutput(now_s, lat.steer_cmd_rad, lon.accel_cmd_mps2, lat, lon, self.mode, tuple(decisions))
        self.last = out
        return out

    def _progress(self, lat: LateralOutput, speed_mps: float, dist: float | None) -> list[Decision]:
        cfg = self.config
        stopped = speed_mps <= cfg.stopped_speed_mps
        if self.mode == VehicleMode.MANOEUVRE:
            assert self.path is not None and self.book.active is not None
            if dist is not None:
                if stopped and abs(dist) <= cfg.stop_tolerance_m:
                    self.mode, self.detail = VehicleMode.STOPPED, f"stopped {dist:+.2f} m from the stop point"
                    return [self.book.complete(self.detail)]
            elif lat.s_m >= self.path.length_m - 10.0:  # 10 m run-out added by validate_command
                cmd = self.book.active
                done = self.book.complete("end of path reached")
                self._keep_lane(self.current_lane(), cmd.target_speed_mps, f"lane keeping after {cmd.command_id}")
                return [done]
        elif self.mode == VehicleMode.DRIVING and dist is not None and stopped and dist < 2.0:
            self.detail = "stopped at the end of the road"
        elif self.mode == VehicleMode.MINIMAL_RISK and stopped:
            self.detail = f"minimal-risk stop done {self.mrm_where}: {self.watchdog.reason or self.mrm_reason}"[:250]
        return []

    def _degrade(self, why: str | None) -> None:
        """Say in ``detail`` (VehicleState) that the car is degraded, and stop saying it when it is not."""
        if why is not None and self.mode != VehicleMode.MINIMAL_RISK:
            if self._detail_undegraded is None:
                self._detail_undegraded = self.detail
            self.detail = f"{why}; {self._detail_undegraded}"[:250]
        elif self._detail_undegraded is not None:
            if self.mode != VehicleMode.MINIMAL_RISK and self.detail.startswith("degraded:"):
                self.detail = self._detail_undegraded
            self._detail_undegraded = None

    def _minimal_risk(self, reason: str, now_s: float) -> list[Decision]:
        """Fail-safe: stop at the right edge of the road (``curb_offset_m``) at up to ``mrm_decel``, or in
        the current lane when the last picture shows the curb side occupied; abort the active command."""
        out = []
        if self.book.active is not None:
            out.append(self.book.abort(reason))
        decel = self.config.failsafe.mrm_decel_mps2
        x, y, _ = self.estimator.pose
        v = max(self.speed_mps, 0.0)
        curb = self._curb_stop(now_s, MRM_LAT_ACCEL_MPS2, CURB_CHECK_BEHIND_M, hold_speed=False)
        self.lane = self.current_lane()
        where = "in its lane (the curb side is occupied)" if curb is None else "at the curb"
        self.mrm_where = where
        self.mode, self.detail = VehicleMode.MINIMAL_RISK, f"minimal-risk stop {where}: {reason}"[:250]
        self.target_speed_mps = 0.0
        if curb is None:
            path = self.lane_path(self.lane)
            self.plan_decel_mps2 = decel
            self._set_path(path, min(path.length_m, path.project(x, y).s_m + v * v / (2.0 * decel) + 1.0))
            return out
        path, stop_s, self.plan_decel_mps2 = curb
        self.target_speed_mps = v  # the braking curve to the stop point sets the speed, not a step to 0
        self._set_path(path, stop_s)
        return out

    def direct_pull_over(self, reason: str, now_s: float, lat_accel_mps2: float, check_behind_m: float) -> bool:
        """Pull over to the curb on the car's own authority (a signed EvAlert heard while the command is late,
        ``vehicle.ev_direct``): the fail-safe's stop at the curb, holding the speed over the lane change;
        only when the picture shows the curb side free (False: the car keeps driving, never stops in lane)."""
        curb = self._curb_stop(now_s, lat_accel_mps2, check_behind_m, hold_speed=True)
        if curb is None:
            return False
        path, stop_s, self.plan_decel_mps2 = curb
        self.lane = self.current_lane()
        self.mrm_where = "at the curb"
        self.mode, self.detail = VehicleMode.MINIMAL_RISK, f"pull-over at the curb on its own: {reason}"[:250]
        self.mrm_reason = reason
        self.target_speed_mps = max(self.speed_mps, 0.0)
        self._set_path(path, stop_s)
        return True

    def _curb_stop(self, now_s: float, lat_accel_mps2: float, check_behind_m: float,
                   hold_speed: bool) -> tuple[ReferencePath, float, float] | None:
        """(path, stop s on it, braking) of a stop at ``curb_offset_m``, or None when the car's picture shows
        the curb side occupied (from ``check_behind_m`` behind the car to the stop). The quintic's peak
        curvature 5.77 shift / L^2 keeps the lateral acceleration at the starting speed within
        ``lat_accel_mps2`` (the curvature within MRM_MAX_CURVATURE_1PM at a crawl); ``hold_speed`` brakes
        only after the lane change (at ``mrm_decel``), else along the whole way."""
        decel = self.config.failsafe.mrm_decel_mps2
        x, y, _ = self.estimator.pose
        s_now, d_now = (float(v) for v in self.road.to_frenet(x, y))
        v = max(self.speed_mps, 0.0)
        d_curb = self.curb_offset_m()
        shift = abs(d_now - d_curb)
        kappa = min(MRM_MAX_CURVATURE_1PM, lat_accel_mps2 / max(v * v, 1e-6))
        change_m = max(15.0, math.sqrt(5.77 * shift / kappa))
        brake_m = v * v / (2.0 * decel)
        stop_len = (change_m + brake_m if hold_speed else max(brake_m, change_m + 5.0)) + 1.0
        if shift >= 0.3 and self.curb_side_occupied(now_s, s_now, d_now, d_curb, s_now + stop_len, check_behind_m):
            return None
        plan_decel = decel if hold_speed else min(decel, max(0.5, v * v / (2.0 * stop_len)))
        path = ReferencePath(offset_change_waypoints(self.road, s_now, d_now, d_curb, change_m, stop_len + 20.0))
        return path, min(path.length_m - 10.0, path.project(x, y).s_m + stop_len), plan_decel


def planned_braking_mps2(path: ReferencePath) -> float:
    """The steepest braking of a path's speed profile before its stop point (max of -v dv/ds), so the
    braking curve to the stop starts where the profile brakes, not at the profile's average deceleration."""
    assert path.speeds is not None and path.stop_s_m is not None
    k = max(2, int(np.searchsorted(path.s, path.stop_s_m - 0.5)))
    v2, ds = path.speeds[:k] ** 2, np.diff(path.s[:k])
    steepest = float(np.max((v2[:-1] - v2[1:]) / (2.0 * np.maximum(ds, 1e-6)), initial=0.0))
    return max(steepest, float(path.speeds[0]) ** 2 / (2.0 * path.stop_s_m))
