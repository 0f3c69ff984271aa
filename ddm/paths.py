"""Path planner: commanded reference paths (waypoints + speed profile) in the corridor frame. Pure.

Lateral motion is a quintic in the road frame, d(s) from the current offset (and heading error) to
the target offset with zero lateral slope and curvature at the end (minimum-jerk lane change,
Werling et al. 2010). For a unit-free quintic the largest d'' is 5.7735 * delta_d / L^2, so the
lane-change length is chosen as

    L = max(lane_change_min_m, v * lane_change_min_s, sqrt(5.7735 |delta_d| / kappa_allowed))
    kappa_allowed = min(max_curvature_1pm, max_lat_accel_mps2 / v^2) - |road curvature|

which keeps the commanded curvature within the vehicle's limit and the lateral acceleration within
comfort at the speed the manoeuvre starts with (the speed only decreases afterwards). Speed profiles
are constant-deceleration (v^2 = v0^2 - 2 a s) to a stop point, or to a slow speed, or an
acceleration back to cruise on resume.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ddm.config import DdmConfig
from ddm.geometry import RoadFrame
from protocol.messages import MAX_WAYPOINTS

QUINTIC_PEAK = 5.773502691896258  # max over u of |60u - 180u^2 + 120u^3| (at u = (3 - sqrt 3) / 6)
MIN_PLAN_SPEED_MPS = 2.0
"""A stopped car still needs a speed to move along a path: plans start at least at this speed."""


@dataclass(frozen=True)
class PlannedPath:
    waypoints: list[tuple[float, float]]
    speeds_mps: list[float]
    target_speed_mps: float
    stop_point: tuple[float, float] | None
    target_offset_m: float
    lane_change_length_m: float
    stop_distance_m: float | None
    decel_mps2: float
    max_curvature_1pm: float
    """Largest curvature of the waypoint polyline (numerical, three-point circle)."""


def quintic_offset(u: np.ndarray, d0: float, d1: float, slope0: float = 0.0) -> np.ndarray:
    """d(u), u in [0, 1]: d(0)=d0, d'(0)=slope0 (per unit u), d''(0)=0, d(1)=d1, d'(1)=d''(1)=0."""
    a0, a1 = d0, slope0
    rhs = np.array([d1 - a0 - a1, -a1, 0.0])
    m = np.array([[1.0, 1.0, 1.0], [3.0, 4.0, 5.0], [6.0, 12.0, 20.0]])
    a3, a4, a5 = np.linalg.solve(m, rhs)
    u = np.clip(u, 0.0, 1.0)
    return a0 + a1 * u + a3 * u**3 + a4 * u**4 + a5 * u**5


def curvature_allowed(speed_mps: float, road_curvature_1pm: float, cfg: DdmConfig,
                      lat_accel_mps2: float | None = None) -> float:
    v = max(speed_mps, 1.0)
    a = cfg.max_lat_accel_mps2 if lat_accel_mps2 is None else lat_accel_mps2
    return max(1e-4, min(cfg.max_curvature_1pm, a / (v * v)) - abs(road_curvature_1pm))


def lane_change_length(delta_d_m: float, speed_mps: float, road_curvature_1pm: float, cfg: DdmConfig) -> float:
    kappa = curvature_allowed(speed_mps, road_curvature_1pm, cfg)
    return max(cfg.lane_change_min_m, speed_mps * cfg.lane_change_min_s,
               math.sqrt(QUINTIC_PEAK * abs(delta_d_m) / kappa) if delta_d_m else 0.0)


def polyline_curvature(xs: np.ndarray, ys: np.ndarray) -> np.ndarray:
    """Menger curvature of each interior point (1/m)."""
    if len(xs) < 3:
        return np.zeros(0)
    ax, ay = xs[:-2], ys[:-2]
    bx, by = xs[1:-1], ys[1:-1]
    cx, cy = xs[2:], ys[2:]
    cross = (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)
    la = np.hypot(bx - ax, by - ay)
    lb = np.hypot(cx - bx, cy - by)
    lc = np.hypot(cx - ax, cy - ay)
    return 2.0 * np.abs(cross) / np.maximum(la * lb * lc, 1e-12)


def _sample(s0: float, length_m: float, cfg: DdmConfig) -> np.ndarray:
    step = max(cfg.waypoint_step_m, length_m / (MAX_WAYPOINTS - 2))
    n = max(2, int(math.ceil(length_m / step)) + 1)
    return s0 + np.linspace(0.0, length_m, n)


def _build(frame: RoadFrame, s: np.ndarray, d: np.ndarray, v: np.ndarray, target_speed: float,
           stop: tuple[float, float] | None, d1: float, lc_len: float, stop_dist: float | None,
           decel: float) -> PlannedPath:
    x, y, _ = frame.road.pose_at(s, d)
    kappa = polyline_curvature(np.asarray(x), np.asarray(y))
    return PlannedPath(
        waypoints=[(float(a), float(b)) for a, b in zip(x, y, strict=True)],
        speeds_mps=[float(max(0.0, w)) for w in v],
        target_speed_mps=float(target_speed),
        stop_point=stop,
        target_offset_m=float(d1),
        lane_change_length_m=float(lc_len),
        stop_distance_m=stop_dist,
        decel_mps2=float(decel),
        max_curvature_1pm=float(kappa.max()) if len(kappa) else 0.0,
    )


def braking_lane_change_length(delta_d_m: float, v0_mps: float, decel_mps2: float, road_curvature_1pm: float,
                               cfg: DdmConfig, lat_accel_mps2: float | None = None) -> float:
    """Length of a lane change driven while braking at ``decel_mps2`` from ``v0_mps``: it lasts
    ``lane_change_min_s`` at the average speed over that time, and its peak curvature keeps the lateral
    acceleration at that average speed within comfort."""
    v_avg = max(MIN_PLAN_SPEED_MPS, v0_mps - decel_mps2 * cfg.lane_change_min_s / 2.0)
    # the quintic's curvature peaks about a fifth of the way in, where the car is still fast
    v_peak = max(MIN_PLAN_SPEED_MPS, v0_mps - decel_mps2 * cfg.lane_change_min_s / 5.0)
    kappa = curvature_allowed(v_peak, road_curvature_1pm, cfg, lat_accel_mps2)
    return max(cfg.lane_change_min_m, v_avg * cfg.lane_change_min_s,
               math.sqrt(QUINTIC_PEAK * abs(delta_d_m) / kappa) if delta_d_m else 0.0)


def min_stop_distance_m(delta_d_m: float, v0_mps: float, road_curvature_1pm: float, cfg: DdmConfig) -> float:
    """Shortest pull-over: braking at ``max_decel_mps2``, lane change done 5 m before the stop."""
    v0 = max(v0_mps, MIN_PLAN_SPEED_MPS)
    lc = braking_lane_change_length(delta_d_m, v0, cfg.max_decel_mps2, road_curvature_1pm, cfg,
                                    cfg.urgent_lat_accel_mps2)
    return max(lc + 5.0, v0 * v0 / (2.0 * cfg.max_decel_mps2))


def plan_stop_holding_speed(frame: RoadFrame, s0: float, d0: float, heading_error_rad: float, speed_mps: float,
                            d_target: float, cfg: DdmConfig, *, stop_within_s: float | None = None,
                            max_stop_dist_m: float | None = None) -> PlannedPath | None:
    """Move to offset d_target at the current speed, then stop there (an AV braking in the EV's lane brings
    the EV onto it sooner): the speed profile holds ``speed_mps`` over the lane change and brakes after it at
    the comfort deceleration; with a car ahead (``max_stop_dist_m``) it holds as long as braking at up to
    ``max_decel_mps2`` still stops in the room. With the EV's time to pass below ``urgent_within_s`` the
    change steers at ``urgent_lat_accel_mps2`` (peak curvature 5.77 dd / L^2) without the
    ``lane_change_min_s`` floor. None when the room ahead is too short for that (``plan_stop`` then)."""
    v0 = max(speed_mps, MIN_PLAN_SPEED_MPS)
    kroad = frame.road.curvature_at(s0)
    dd = d_target - d0
    urgent = stop_within_s is not None and math.isfinite(stop_within_s) and stop_within_s < cfg.urgent_within_s
    if urgent:
        kappa = curvature_allowed(v0, kroad, cfg, cfg.urgent_lat_accel_mps2)
        lc = max(cfg.lane_change_min_m, math.sqrt(QUINTIC_PEAK * abs(dd) / kappa) if dd else 0.0)
    else:
        lc = braking_lane_change_length(dd, v0, 0.0, kroad, cfg)
    hold = lc  # speed held this far, then braking to the stop
    brake = max(5.0, v0 * v0 / (2.0 * cfg.comfort_decel_mps2))
    if max_stop_dist_m is not None and max_stop_dist_m > 0 and lc + brake > max_stop_dist_m:
        # a car ahead in lane 0: stop within the room, braking as late as max_decel_mps2 allows (the
        # braking may start before the change is over); the change itself must end 5 m before the stop
        if max_stop_dist_m < lc + 5.0:
            return None
        brake = max(min(max_stop_dist_m - lc, v0 * v0 / (2.0 * cfg.comfort_decel_mps2)),
                    v0 * v0 / (2.0 * cfg.max_decel_mps2))
        hold = max(0.0, max_stop_dist_m - brake)
        brake = max_stop_dist_m - hold
    stop_dist = hold + brake
    decel = v0 * v0 / (2.0 * brake)
    s = _sample(s0, stop_dist + cfg.path_tail_m, cfg)
    rel = s - s0
    d = quintic_offset(rel / lc, d0, d_target, math.tan(heading_error_rad) * lc)
    v = np.where(rel <= hold, v0, np.sqrt(np.maximum(0.0, v0 * v0 - 2.0 * decel * (rel - hold))))
    v[rel >= stop_dist - 1e-6] = 0.0
    sx, sy, _ = frame.road.pose_at(s0 + stop_dist, d_target)
    return _build(frame, s, d, v, 0.0, (float(sx), float(sy)), d_target, lc, stop_dist, decel)


def plan_stop(frame: RoadFrame, s0: float, d0: float, heading_error_rad: float, speed_mps: float,
              d_target: float, cfg: DdmConfig, *, stop_within_s: float | None = None,
              max_stop_dist_m: float | None = None) -> PlannedPath:
    """Move from (s0, d0) to offset d_target and stop there at a constant deceleration.

    The deceleration is the comfort one, raised (up to ``max_decel_mps2``) to be stopped within
    ``stop_within_s`` (e.g. before the EV arrives) and within ``max_stop_dist_m`` (e.g. behind a car
    that is stopping ahead in the target lane; never shorter than ``min_stop_distance_m``). The lane
    change is ``braking_lane_change_length`` long and ends at least 5 m before the stop. When the lane
    change needs more road than ``max_stop_dist_m`` leaves, the speed profile brakes at
    ``max_decel_mps2`` to ``creep_speed_mps``, creeps on and stops at the comfort deceleration.
    """
    v0 = max(speed_mps, MIN_PLAN_SPEED_MPS)
    decel = cfg.comfort_decel_mps2
    if stop_within_s is not None and math.isfinite(stop_within_s) and stop_within_s > 0:
        decel = max(decel, v0 / stop_within_s)
    if max_stop_dist_m is not None and max_stop_dist_m > 0:
        decel = max(decel, v0 * v0 / (2.0 * max_stop_dist_m))
    decel = min(decel, cfg.max_decel_mps2)
    kroad = frame.road.curvature_at(s0)

    def layout(a: float, lat: float | None = None) -> tuple[float, float]:
        lc_a = braking_lane_change_length(d_target - d0, v0, a, kroad, cfg, lat)
        return lc_a, max(lc_a + 5.0, v0 * v0 / (2.0 * a))

    lc, stop_dist = layout(decel)
    if stop_within_s is not None and math.isfinite(stop_within_s) and 2.0 * stop_dist / v0 > stop_within_s:
        # the lane change, not the brakes, sets the stop: brake harder and steer more briskly (up to
        # max_decel_mps2 and urgent_lat_accel_mps2) to shorten it
        for k in np.linspace(0.0, 1.0, 8)[1:]:
            a = decel + k * (cfg.max_decel_mps2 - decel)
            lat = cfg.max_lat_accel_mps2 + k * (cfg.urgent_lat_accel_mps2 - cfg.max_lat_accel_mps2)
            lc, stop_dist = layout(float(a), float(lat))
            if 2.0 * stop_dist / v0 <= stop_within_s:
                break
    creep = False
    if max_stop_dist_m is not None and max_stop_dist_m > 0 and stop_dist > max_stop_dist_m:
        shortest = min_stop_distance_m(d_target - d0, v0, kroad, cfg)
        stop_dist = max(max_stop_dist_m, shortest)
        lc = min(lc, stop_dist - 5.0)
        # the lane change needs more road than the room behind the car ahead: brake at max_decel_mps2
        # anyway and cover the rest at a creep (the DDM plans again as that car moves on or stops)
        creep = max_stop_dist_m < stop_dist - 1e-6 and v0 > cfg.creep_speed_mps
    s = _sample(s0, stop_dist + cfg.path_tail_m, cfg)
    rel = s - s0
    d = quintic_offset(rel / lc, d0, d_target, math.tan(heading_error_rad) * lc)
    if creep:
        decel = cfg.max_decel_mps2
        v = np.maximum(cfg.creep_speed_mps, np.sqrt(np.maximum(0.0, v0 * v0 - 2.0 * decel * rel)))
        v = np.minimum(v, np.sqrt(np.maximum(0.0, 2.0 * cfg.comfort_decel_mps2 * (stop_dist - rel))))
    else:
        decel = v0 * v0 / (2.0 * stop_dist)
        v = np.sqrt(np.maximum(0.0, v0 * v0 - 2.0 * decel * rel))
    v[rel >= stop_dist - 1e-6] = 0.0
    sx, sy, _ = frame.road.pose_at(s0 + stop_dist, d_target)
    return _build(frame, s, d, v, 0.0, (float(sx), float(sy)), d_target, lc, stop_dist, decel)


def plan_keep_lane_slow(frame: RoadFrame, s0: float, d0: float, heading_error_rad: float, speed_mps: float,
                        d_lane: float, slow_speed_mps: float, cfg: DdmConfig, hold_m: float = 80.0) -> PlannedPath:
    """Stay in the lane (re-centre on it) and slow to ``slow_speed_mps`` at the comfort deceleration."""
    v0 = max(speed_mps, 0.0)
    vs = min(slow_speed_mps, max(v0, slow_speed_mps))
    decel_dist = max(0.0, (v0 * v0 - vs * vs) / (2.0 * cfg.comfort_decel_mps2))
    lc = lane_change_length(d_lane - d0, max(v0, MIN_PLAN_SPEED_MPS), frame.road.curvature_at(s0), cfg)
    s = _sample(s0, decel_dist + hold_m, cfg)
    rel = s - s0
    d = quintic_offset(rel / lc, d0, d_lane, math.tan(heading_error_rad) * lc)
    v = np.maximum(vs, np.sqrt(np.maximum(0.0, v0 * v0 - 2.0 * cfg.comfort_decel_mps2 * rel)))
    return _build(frame, s, d, v, vs, None, d_lane, lc, None, cfg.comfort_decel_mps2 if v0 > vs else 0.0)


def plan_lane_change(frame: RoadFrame, s0: float, d0: float, heading_error_rad: float, speed_mps: float,
                     d_target: float, target_speed_mps: float, cfg: DdmConfig, hold_m: float = 80.0) -> PlannedPath:
    """Change to offset d_target and keep driving, slowing (or not) to ``target_speed_mps``."""
    v0 = max(speed_mps, MIN_PLAN_SPEED_MPS)
    lc = lane_change_length(d_target - d0, v0, frame.road.curvature_at(s0), cfg)
    s = _sample(s0, lc + hold_m, cfg)
    rel = s - s0
    d = quintic_offset(rel / lc, d0, d_target, math.tan(heading_error_rad) * lc)
    vt = min(target_speed_mps, v0)
    v = np.maximum(vt, np.sqrt(np.maximum(0.0, v0 * v0 - 2.0 * cfg.comfort_decel_mps2 * rel)))
    return _build(frame, s, d, v, vt, None, d_target, lc, None, cfg.comfort_decel_mps2 if v0 > vt else 0.0)


def plan_resume(frame: RoadFrame, s0: float, d0: float, heading_error_rad: float, speed_mps: float,
                d_target: float, cruise_speed_mps: float, cfg: DdmConfig) -> PlannedPath:
    """Back to the lane centre d_target and accelerate to cruise at ``resume_accel_mps2``."""
    v0 = max(speed_mps, 0.0)
    lc = lane_change_length(d_target - d0, max(cruise_speed_mps * 0.6, MIN_PLAN_SPEED_MPS),
                            frame.road.curvature_at(s0), cfg)
    s = _sample(s0, max(cfg.resume_length_m, lc + 20.0), cfg)
    rel = s - s0
    d = quintic_offset(rel / lc, d0, d_target, math.tan(heading_error_rad) * lc)
    v = np.minimum(cruise_speed_mps, np.sqrt(max(v0, MIN_PLAN_SPEED_MPS) ** 2 + 2.0 * cfg.resume_accel_mps2 * rel))
    return _build(frame, s, d, v, cruise_speed_mps, None, d_target, lc, None, 0.0)


def stop_offset_m(frame: RoadFrame, vehicle_width_m: float, shoulder_width_m: float, cfg: DdmConfig) -> float:
    """Lateral offset of the stop (car centre): on the shoulder when it fits the car with clearance on
    both sides, else at the curb side of lane 0 with ``curb_clearance_m`` to the edge."""
    half = vehicle_width_m / 2.0
    if cfg.stop_on_shoulder and shoulder_width_m >= vehicle_width_m + 2 * cfg.curb_clearance_m:
        return -(cfg.curb_clearance_m + half)
    return cfg.curb_clearance_m + half


def plan_stop_at(frame: RoadFrame, s0: float, d0: float, heading_error_rad: float, speed_mps: float,
                 d_lane: float, s_stop: float, cfg: DdmConfig, max_decel_mps2: float) -> PlannedPath:
    """Re-centre on the lane (quintic) and stop the car's centre at road s ``s_stop`` with a constant
    deceleration (at most ``max_decel_mps2``; harder needs stop earlier than possible, then the stop
    comes where that deceleration ends)."""
    v0 = max(speed_mps, 0.0)
    dist = max(s_stop - s0, 0.5)
    decel = v0 * v0 / (2.0 * dist) if v0 > 0 else 0.0
    if decel > max_decel_mps2:
        decel = max_decel_mps2
        dist = v0 * v0 / (2.0 * decel)
    lc = lane_change_length(d_lane - d0, max(v0, MIN_PLAN_SPEED_MPS), frame.road.curvature_at(s0), cfg)
    length = dist + cfg.path_tail_m
    n = max(3, int(math.ceil(length / cfg.waypoint_step_m)) + 1)
    s = s0 + np.linspace(0.0, length, min(n, 200))
    rel = s - s0
    d = quintic_offset(rel / lc, d0, d_lane, math.tan(heading_error_rad) * lc)
    v = np.sqrt(np.maximum(0.0, v0 * v0 - 2.0 * decel * rel)) if decel > 0 else np.zeros_like(rel)
    v[rel >= dist - 1e-6] = 0.0
    x, y, _ = frame.road.pose_at(s, d)
    sx, sy, _ = frame.road.pose_at(s0 + dist, d_lane)
    kappa = polyline_curvature(np.asarray(x), np.asarray(y))
    return PlannedPath(waypoints=[(float(a), float(b)) for a, b in zip(x, y, strict=True)],
                       speeds_mps=[float(max(0.0, w)) for w in v], target_speed_mps=0.0,
                       stop_point=(float(sx), float(sy)), target_offset_m=float(d_lane),
                       lane_change_length_m=float(lc), stop_distance_m=float(dist), decel_mps2=float(decel),
                       max_curvature_1pm=float(kappa.max()) if len(kappa) else 0.0)
