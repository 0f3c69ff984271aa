"""Hazard picture and hazard policy of the DDM (issue 10). Pure: no I/O, no clock.

:class:`HazardBook` fuses ``HazardAlert`` streams of every RSU into corridor hazards: an alert joins the
hazard whose fused position is within ``fuse_m`` (RSUs 50 m apart see the same debris, each with its own
id); the fused position is the confidence-weighted mean of each source's latest report, its size the
largest reported (conservative). A source leaves on ``clear`` or when it has not been refreshed for
``source_timeout_s`` (RSUs repeat ``persist`` at 1 Hz); a hazard without sources is gone.

:func:`decide_hazard`, per autonomous vehicle, on the road (Frenet) frame:

- a hazard *blocks* the AV when, driving at its lane centre, the lateral clearance between the car's
  side and the hazard's side would be under ``min_clearance_m + position_margin_m``; hazards behind the
  car or under its own footprint (an RSU seeing the stopped AV itself) are ignored;
- threat (report eq. 2-3, :mod:`ddm.threat`): lx from the car's front bumper to the hazard's near edge,
  ly between centre lines, lx_max 60 m, ly_max one lane width; the AV responds to a blocking hazard
  once ``T_f > threat_threshold``;
- response: LANE_CHANGE to a neighbouring lane when the hazard does not block that lane, the planned
  path keeps ``min_clearance_m + position_margin_m`` beside the hazard all along it, and the gap check
  of the EV policy (:func:`ddm.policy.gap_check`) passes; otherwise STOP_IN_LANE with the front bumper
  ``stop_gap_m`` before the hazard (slow and stop). While stopping or stopped the lane change is tried
  again every cycle; RESUME (back to cruise in the lane the car is in) once every hazard it responded
  to is passed by ``pass_margin_m`` or cleared.

Its decisions are ``ddm.decision.Decision``s ``about="hazard"``, its memory per vehicle a
``ddm.decision.Response`` (``commit`` when a command is issued). The EV policy has precedence: the decider
(:mod:`ddm.decider`) runs this policy only while the EV policy has nothing to do.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ddm.config import DdmConfig
from ddm.decision import Decision, Ego, Response
from ddm.geometry import RoadFrame
from ddm.paths import (
    MIN_PLAN_SPEED_MPS,
    PlannedPath,
    lane_change_length,
    plan_lane_change,
    plan_resume,
    polyline_curvature,
    quintic_offset,
)
from ddm.policy import gap_check
from ddm.threat import LX_MAX_M, av_hazard_distances, threat_value
from ddm.tracks import Track
from protocol.enums import HazardState, Manoeuvre
from protocol.messages import HazardAlert


@dataclass(frozen=True)
class HazardConfig:
    fuse_m: float = 3.0
    """Alerts of different RSUs within this distance are one hazard (RSU localisation differs by ~1 m)."""
    source_timeout_s: float = 3.5
    """A source not refreshed for this long is dropped (persist comes at 1 Hz: 3 missed + jitter)."""
    lx_max_m: float = LX_MAX_M
    ly_max_m: float | None = None
    """Report eq. 2-3 limits; None: the corridor's lane width."""
    threat_threshold: float = 0.3
    """Respond once T_f exceeds this (a hazard dead ahead has T_f = 0.71 at lx = 60 m; one 1.5 m off the
    centre line 0.42; one that barely blocks, 2.5 m off, reaches 0.3 at 43 m)."""
    min_clearance_m: float = 1.0
    """Lateral clearance the AV keeps between its side and a hazard's side (issue 10: >= 1 m)."""
    position_margin_m: float = 0.3
    """Added to the clearance for the RSU localisation error of the hazard (~0.2-0.3 m laterally)."""
    stop_gap_m: float = 10.0
    """Front bumper to the hazard's near edge when stopped before it (room to steer around it later)."""
    pass_margin_m: float = 5.0
    """A hazard is passed once the AV's rear bumper is this far beyond its far edge."""
    max_stop_decel_mps2: float = 4.5
    """Hardest deceleration a stop before a hazard may ask (Apollo's emergency stop: 4.5 m/s^2)."""

    def __post_init__(self) -> None:
        for name in ("fuse_m", "source_timeout_s", "lx_max_m", "min_clearance_m", "stop_gap_m",
                     "max_stop_decel_mps2"):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and math.isfinite(v) and v > 0):
                raise ValueError(f"HazardConfig.{name} must be > 0, got {v!r}")
        if not 0.0 <= self.threat_threshold < 1.0:
            raise ValueError("threat_threshold must be in [0, 1)")


# ----------------------------------------------------------------------------------------------- fusion
@dataclass
class _Source:
    x_m: float
    y_m: float
    length_m: float
    width_m: float
    confidence: float
    seen_s: float


@dataclass
class HazardTrack:
    hazard_id: int
    x_m: float
    y_m: float
    length_m: float
    width_m: float
    lane: int | None
    confidence: float
    first_seen_s: float
    last_seen_s: float
    sources: dict[str, _Source] = field(default_factory=dict)
    """alert id -> its latest report."""

    def refuse(self) -> None:
        w = np.array([max(s.confidence, 0.05) for s in self.sources.values()])
        xs = np.array([s.x_m for s in self.sources.values()])
        ys = np.array([s.y_m for s in self.sources.values()])
        self.x_m, self.y_m = float(np.average(xs, weights=w)), float(np.average(ys, weights=w))
        self.length_m = max(s.length_m for s in self.sources.values())
        self.width_m = max(s.width_m for s in self.sources.values())
        self.confidence = float(max(s.confidence for s in self.sources.values()))


class HazardBook:
    """Corridor hazards fused from every RSU's ``HazardAlert``s."""

    def __init__(self, frame: RoadFrame, config: HazardConfig | None = None) -> None:
        self.frame = frame
        self.cfg = config or HazardConfig()
        self.hazards: dict[int, HazardTrack] = {}
        self._by_alert: dict[str, int] = {}
        self._next_id = 1
        self.events: list[tuple[str, int]] = []
        """(what, hazard id) since the last ``drain``: appeared, cleared, expired."""

    def _lane(self, x: float, y: float) -> int | None:
        _, d = self.frame.to_frenet(x, y)
        lane = int(self.frame.lane_of(d)[0])
        return None if lane < 0 else lane

    def ingest(self, alert: HazardAlert, now: float) -> HazardTrack | None:
        """Apply one alert; returns the hazard it belongs to (None after a clear or an unknown clear)."""
        aid = alert.hazard_id
        if alert.state == HazardState.CLEAR:
            hid = self._by_alert.pop(aid, None)
            if hid is not None and hid in self.hazards:
                hz = self.hazards[hid]
                hz.sources.pop(aid, None)
                if hz.sources:
                    hz.refuse()
                else:
                    del self.hazards[hid]
                    self.events.append(("cleared", hid))
            return None
        src = _Source(alert.pos_x_m, alert.pos_y_m, alert.length_m, alert.width_m, alert.confidence, now)
        hid = self._by_alert.get(aid)
        if hid is None or hid not in self.hazards:
            best, best_d = None, self.cfg.fuse_m
            for h in self.hazards.values():
                dist = math.hypot(h.x_m - src.x_m, h.y_m - src.y_m)
                if dist <= best_d:
                    best, best_d = h.hazard_id, dist
            if best is None:
                best = self._next_id
                self._next_id += 1
                self.hazards[best] = HazardTrack(best, src.x_m, src.y_m, src.length_m, src.width_m, None,
                                                 src.confidence, now, now)
                self.events.append(("appeared", best))
            hid = self._by_alert[aid] = best
        hz = self.hazards[hid]
        hz.sources[aid] = src
        hz.last_seen_s = now
        hz.refuse()
        hz.lane = self._lane(hz.x_m, hz.y_m)
        return hz

    def maintain(self, now: float) -> None:
        """Drop sources not refreshed for ``source_timeout_s`` and hazards left without sources."""
        for hid in list(self.hazards):
            hz = self.hazards[hid]
            for aid in [a for a, s in hz.sources.items() if now - s.seen_s > self.cfg.source_timeout_s]:
                del hz.sources[aid]
                self._by_alert.pop(aid, None)
            if not hz.sources:
                del self.hazards[hid]
                self.events.append(("expired", hid))
            else:
                hz.refuse()

    def active(self) -> list[HazardTrack]:
        return list(self.hazards.values())

    def drain(self) -> list[tuple[str, int]]:
        out, self.events = self.events, []
        return out


# ----------------------------------------------------------------------------------------------- policy
@dataclass(frozen=True)
class HazardThreat:
    hazard_id: int
    s_m: float
    d_m: float
    length_m: float
    width_m: float
    lx_m: float
    ly_m: float
    threat: float
    """T_f, report eq. 2-3."""
    blocks: bool
    clearance_m: float
    """Lateral clearance (side to side) if the AV kept its lane centre."""


def lateral_clearance(d_av: float, w_av: float, d_hz: float, w_hz: float) -> float:
    """Side-to-side gap (m) between an AV at offset d_av and a hazard at d_hz (negative: overlap)."""
    return abs(d_av - d_hz) - (w_av + w_hz) / 2.0


def assess_hazards(ego_s: float, ego_d: float, ego_len: float, ego_w: float, lane_d: float,
                   hazards: list[HazardTrack], frame: RoadFrame, cfg: HazardConfig) -> list[HazardThreat]:
    """Hazards not yet passed and not under the AV, nearest first, with their threat and whether they
    block the AV's lane (``lane_d``: the centre offset it drives at)."""
    if not hazards:
        return []
    s, d = frame.to_frenet(np.array([h.x_m for h in hazards]), np.array([h.y_m for h in hazards]))
    ly_max = cfg.ly_max_m or frame.lane_width_m
    need = cfg.min_clearance_m + cfg.position_margin_m
    out = []
    for k, h in enumerate(hazards):
        hs, hd = float(s[k]), float(d[k])
        if hs + h.length_m / 2.0 + cfg.pass_margin_m < ego_s - ego_len / 2.0 or hs < ego_s:
            continue  # passed, or behind the AV's centre (it drives away from it: e.g. where it had stopped)
        if abs(hs - ego_s) < (ego_len + h.length_m) / 2.0 and abs(hd - ego_d) < (ego_w + h.width_m) / 2.0:
            continue  # under the AV's own footprint: the RSU sees the car, not debris
        lx, ly = av_hazard_distances(ego_s, ego_d, ego_len, hs, hd, h.length_m)
        clear = lateral_clearance(lane_d, ego_w, hd, h.width_m)
        out.append(HazardThreat(h.hazard_id, hs, hd, h.length_m, h.width_m, lx, ly,
                                threat_value(max(lx, 0.0), ly, cfg.lx_max_m, ly_max), clear < need, clear))
    out.sort(key=lambda t: t.lx_m)
    return out


def path_clearance(path: PlannedPath, frame: RoadFrame, ego_len: float, ego_w: float,
                   t: HazardThreat) -> float:
    """Smallest side-to-side clearance between the AV following ``path`` and hazard ``t`` while their
    extents along the road overlap (inf if the path ends before the hazard)."""
    xy = np.asarray(path.waypoints, dtype=float)
    s, d = frame.to_frenet(xy[:, 0], xy[:, 1])
    near = np.abs(s - t.s_m) <= (ego_len + t.length_m) / 2.0
    if not near.any():
        return math.inf if s[-1] < t.s_m else float(
            lateral_clearance(float(np.interp(t.s_m, s, d)), ego_w, t.d_m, t.width_m))
    lo, hi = t.s_m - (ego_len + t.length_m) / 2.0, t.s_m + (ego_len + t.length_m) / 2.0
    ss = np.linspace(lo, hi, 9)
    dd = np.interp(ss, s, d)
    return float(np.min(np.abs(dd - t.d_m)) - (ego_w + t.width_m) / 2.0)


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


def decide_hazard(ego: Ego, hazards: list[HazardTrack], others: list[Track], frame: RoadFrame,
                  ddm_cfg: DdmConfig, cfg: HazardConfig, response: Response,
                  cruise_speed_mps: float) -> Decision:
    """One vehicle's hazard response (module docstring); a decision with a manoeuvre carries its path."""
    s_arr, d_arr = frame.to_frenet(ego.x_m, ego.y_m)
    s_e, d_e = float(s_arr[0]), float(d_arr[0])
    h_err = (ego.heading_rad - float(frame.heading_at(s_e)) + math.pi) % (2 * math.pi) - math.pi
    v_e = max(ego.speed_mps * math.cos(h_err), 0.0)
    lane_raw = int(frame.lane_of(d_e))
    lane_e = lane_raw if lane_raw >= 0 else (0 if d_e < 0 else frame.lanes - 1)
    base = dict(about="hazard", ego_s_m=s_e, ego_d_m=d_e, ego_heading_error_rad=h_err, ego_speed_mps=v_e)
    lane_d = frame.lane_centre_offset(lane_e)
    if response.phase == "avoiding" and response.target_lane is not None:
        lane_d = frame.lane_centre_offset(response.target_lane)  # what blocks is judged in the lane it goes to
    threats = assess_hazards(s_e, d_e, ego.length_m, ego.width_m, lane_d, hazards, frame, cfg)
    known = {h.hazard_id for h in hazards}
    need = cfg.min_clearance_m + cfg.position_margin_m
    near_self = {o.track_id for o in others if math.hypot(o.x_m - ego.x_m, o.y_m - ego.y_m) < 2.0}
    traffic = [o for o in others if o.track_id != ego.track_id and o.track_id not in near_self]

    def describe(t: HazardThreat) -> str:
        return (f"hazard {t.hazard_id} {t.lx_m:.0f} m ahead, {t.ly_m:.1f} m off the centre line, "
                f"T_f {t.threat:.2f}, clearance in lane {t.clearance_m:.1f} m")

    def try_lane_change(t: HazardThreat) -> tuple[Decision | None, str]:
        why = []
        cands = [ln for ln in (lane_e + 1, lane_e - 1) if 0 <= ln < frame.lanes]
        cands.sort(key=lambda ln: -abs(frame.lane_centre_offset(ln) - t.d_m))  # the side away from it first
        for ln in cands:
            d_t = frame.lane_centre_offset(ln)
            other_block = [o for o in threats if lateral_clearance(d_t, ego.width_m, o.d_m, o.width_m) < need
                           and o.lx_m < cfg.lx_max_m]
            if other_block:
                why.append(f"lane {ln} blocked by hazard {other_block[0].hazard_id}")
                continue
            path = plan_lane_change(frame, s_e, d_e, h_err, v_e, d_t, cruise_speed_mps, ddm_cfg)
            pc = min((path_clearance(path, frame, ego.length_m, ego.width_m, o) for o in threats), default=math.inf)
            if pc < need:
                why.append(f"lane {ln}: the change passes {t.hazard_id} with {pc:.1f} m < {need:.1f} m")
                continue
            v_plan = max(v_e, MIN_PLAN_SPEED_MPS)
            ok, gap_why = gap_check(s_e, v_plan, v_plan, ego.length_m, ln, traffic, frame,
                                    path.lane_change_length_m / v_plan, ddm_cfg)
            if not ok:
                why.append(gap_why)
                continue
            return Decision(Manoeuvre.LANE_CHANGE, f"change to lane {ln} around it ({gap_why}, passes with "
                            f"{pc:.1f} m): {describe(t)}", hazard_id=t.hazard_id, threat=t.threat,
                            target_lane=ln, path=path, **base), ""
        return None, "; ".join(why) or "no neighbouring lane"

    def stop(t: HazardThreat, why: str) -> Decision:
        s_stop = t.s_m - t.length_m / 2.0 - cfg.stop_gap_m - ego.length_m / 2.0
        path = plan_stop_at(frame, s_e, d_e, h_err, v_e, lane_d, s_stop, ddm_cfg, cfg.max_stop_decel_mps2)
        return Decision(Manoeuvre.STOP_IN_LANE, f"{why}; slow and stop {cfg.stop_gap_m:.0f} m before it "
                        f"({path.decel_mps2:.1f} m/s^2): {describe(t)}", hazard_id=t.hazard_id, threat=t.threat,
                        target_lane=lane_e, stop_s_m=s_stop, path=path, **base)

    acting = [t for t in threats if t.blocks and t.threat > cfg.threat_threshold]
    if response.phase == "normal":
        if not acting:
            if threats:
                t = threats[0]
                return Decision("none", f"no action: {describe(t)}", hazard_id=t.hazard_id, threat=t.threat, **base)
            return Decision("none", "no hazard ahead", **base)
        t = acting[0]
        dec, why = try_lane_change(t)
        return dec if dec is not None else stop(t, why)

    mine = [t for t in threats if t.hazard_id in response.cause_ids]
    if response.phase == "stopping":
        if acting:
            t = acting[0]
            dec, _why = try_lane_change(t)
            if dec is not None:
                return dec
            if t.hazard_id not in response.cause_ids:  # a nearer hazard than the one it stops for
                return stop(t, "another hazard")
            return Decision("hold", f"keep stopping: {describe(t)}", hazard_id=t.hazard_id, threat=t.threat,
                            target_lane=response.target_lane, **base)
        if any(t.blocks for t in mine):
            t = next(t for t in mine if t.blocks)
            return Decision("hold", f"stopped before {describe(t)}", hazard_id=t.hazard_id, threat=t.threat,
                            target_lane=response.target_lane, **base)
    else:  # avoiding: the lane change is under way
        new = [t for t in acting if t.hazard_id not in response.cause_ids]
        if new:
            t = new[0]
            dec, why = try_lane_change(t)
            return dec if dec is not None else stop(t, why)
        if mine:
            t = mine[0]
            return Decision("hold", f"passing {describe(t)}", hazard_id=t.hazard_id, threat=t.threat,
                            target_lane=response.target_lane, **base)
    gone = sorted(response.cause_ids - known)
    what = f"hazard {', '.join(map(str, gone))} cleared" if gone else "hazard passed"
    path = plan_resume(frame, s_e, d_e, h_err, v_e, lane_d, cruise_speed_mps, ddm_cfg)
    return Decision(Manoeuvre.RESUME, f"resume in lane {lane_e}: {what}", target_lane=lane_e, path=path, **base)
