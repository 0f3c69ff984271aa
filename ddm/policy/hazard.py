"""Hazard response policy: what each autonomous vehicle should do about road hazards. Pure.

Per autonomous vehicle, on the road (Frenet) frame, from the picture's hazards (Clemson hazard navigation
report, eq. 2-3; docs/architecture.md §DDM):

- a hazard *blocks* the AV when, driving at its lane centre, the lateral clearance between the car's
  side and the hazard's side would be under ``min_clearance_m + position_margin_m``; hazards behind the
  car or under its own footprint (an RSU seeing the stopped AV itself) are ignored;
- threat (report eq. 2-3, :mod:`ddm.threat`): lx from the car's front bumper to the hazard's near edge,
  ly between centre lines, lx_max 60 m, ly_max one lane width; the AV responds to a blocking hazard
  once ``T_f > threat_threshold``;
- response (``avoid_or_stop``): LANE_CHANGE to a neighbouring lane when the hazard does not block that
  lane, the planned path keeps ``min_clearance_m + position_margin_m`` beside the hazard all along it, and
  the gap check (:func:`ddm.manoeuvre.gap_check`) passes; otherwise STOP_IN_LANE with the front bumper
  ``stop_gap_m`` before the hazard (slow and stop). While stopping or stopped the lane change is tried
  again every cycle (``keep_stopping``; ``keep_avoiding`` while the change is under way); RESUME (back to
  cruise in the lane the car is in) once every hazard it responded to is passed by ``pass_margin_m`` or
  cleared (``resume``).

Its intents are ``ddm.intent.Intent``s ``about="hazard"`` that carry their path, its memory per vehicle a
``ddm.intent.Response`` (``commit`` when a command is issued). The EV policy has precedence: the decider
(:mod:`ddm.decider`) asks this policy only about vehicles the EV policy leaves alone.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from ddm.config import DdmConfig, HazardConfig
from ddm.geometry import RoadFrame
from ddm.intent import Ego, Intent, Response
from ddm.manoeuvre import gap_check, road_pose, stop_before_s_m, traffic
from ddm.paths import MIN_PLAN_SPEED_MPS, PlannedPath, plan_lane_change, plan_resume, plan_stop_at
from ddm.picture import Hazard, Picture
from ddm.policy import NEIGHBOUR_RADIUS_M, PolicyContext
from ddm.threat import av_hazard_distances, threat_value
from ddm.tracks import Track
from protocol.enums import Manoeuvre


@dataclass(frozen=True)
class HazardThreat:
    """A hazard ahead of the AV in the road frame, its threat value and whether it blocks the AV's lane."""

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
                   hazards: Sequence[Hazard], frame: RoadFrame, cfg: HazardConfig) -> list[HazardThreat]:
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


def describe(t: HazardThreat) -> str:
    return (f"hazard {t.hazard_id} {t.lx_m:.0f} m ahead, {t.ly_m:.1f} m off the centre line, "
            f"T_f {t.threat:.2f}, clearance in lane {t.clearance_m:.1f} m")


@dataclass(frozen=True)
class Situation:
    """One AV and the hazards ahead of it, in the road frame: what every rule reads."""

    frame: RoadFrame
    ddm_cfg: DdmConfig
    cfg: HazardConfig
    width_m: float
    length_m: float
    s_m: float
    d_m: float
    heading_error_rad: float
    speed_along_mps: float
    """Never negative."""
    lane: int
    """The AV's lane (off the carriageway: the nearest lane)."""
    lane_d_m: float
    """The centre offset of the lane the AV drives at (the one it changes to, while avoiding)."""
    cruise_speed_mps: float
    base: dict[str, Any]
    threats: list[HazardThreat]
    known: frozenset[int]
    """The ids of every hazard in the picture."""
    traffic: list[Track]

    @property
    def need_m(self) -> float:
        """The lateral clearance kept beside a hazard."""
        return self.cfg.min_clearance_m + self.cfg.position_margin_m

    @property
    def acting(self) -> list[HazardThreat]:
        """The threats that block the lane and exceed the threat threshold."""
        return [t for t in self.threats if t.blocks and t.threat > self.cfg.threat_threshold]

    def about(self, t: HazardThreat) -> dict[str, Any]:
        return dict(self.base, hazard_id=t.hazard_id, threat=t.threat)


def situation(ego: Ego, hazards: Sequence[Hazard], others: list[Track], frame: RoadFrame, ddm_cfg: DdmConfig,
              cfg: HazardConfig, response: Response, cruise_speed_mps: float) -> Situation:
    pose = road_pose(ego, frame)
    s_e, d_e, h_err = pose.s_m, pose.d_m, pose.heading_error_rad
    v_e = max(pose.speed_along_mps, 0.0)
    lane_e = pose.lane_raw if pose.lane_raw >= 0 else (0 if d_e < 0 else frame.lanes - 1)
    base = dict(about="hazard", ego_s_m=s_e, ego_d_m=d_e, ego_heading_error_rad=h_err, ego_speed_mps=v_e)
    lane_d = frame.lane_centre_offset(lane_e)
    if response.phase == "avoiding" and response.target_lane is not None:
        lane_d = frame.lane_centre_offset(response.target_lane)  # what blocks is judged in the lane it goes to
    threats = assess_hazards(s_e, d_e, ego.length_m, ego.width_m, lane_d, list(hazards), frame, cfg)
    return Situation(frame, ddm_cfg, cfg, ego.width_m, ego.length_m, s_e, d_e, h_err, v_e, lane_e, lane_d,
                     cruise_speed_mps, base, threats, frozenset(h.hazard_id for h in hazards), traffic(ego, others))


def decide_hazard(ego: Ego, hazards: Sequence[Hazard], others: list[Track], frame: RoadFrame,
                  ddm_cfg: DdmConfig, cfg: HazardConfig, response: Response,
                  cruise_speed_mps: float) -> Intent:
    """One vehicle's hazard response (module docstring); an intent with a manoeuvre carries its path."""
    sit = situation(ego, hazards, others, frame, ddm_cfg, cfg, response, cruise_speed_mps)
    if response.phase == "normal":
        return first_response(sit)
    held = keep_stopping(sit, response) if response.phase == "stopping" else keep_avoiding(sit, response)
    return held or resume(sit, response)


def first_response(sit: Situation) -> Intent:
    """Not responding yet: go around or stop for the first acting hazard, else say why not."""
    acting = sit.acting
    if not acting:
        if sit.threats:
            t = sit.threats[0]
            return Intent("none", f"no action: {describe(t)}", **sit.about(t))
        return Intent("none", "no hazard ahead", **sit.base)
    return avoid_or_stop(sit, acting[0])


def avoid_or_stop(sit: Situation, t: HazardThreat) -> Intent:
    dec, why = try_lane_change(sit, t)
    return dec if dec is not None else stop(sit, t, why)


def try_lane_change(sit: Situation, t: HazardThreat) -> tuple[Intent | None, str]:
    """LANE_CHANGE to a neighbouring lane (the side away from the hazard first) that no hazard blocks,
    whose path passes every hazard with the clearance and whose gap is safe; else (None, why not)."""
    frame, cfg, need = sit.frame, sit.cfg, sit.need_m
    why = []
    cands = [ln for ln in (sit.lane + 1, sit.lane - 1) if 0 <= ln < frame.lanes]
    cands.sort(key=lambda ln: -abs(frame.lane_centre_offset(ln) - t.d_m))  # the side away from it first
    for ln in cands:
        d_t = frame.lane_centre_offset(ln)
        other_block = [o for o in sit.threats if lateral_clearance(d_t, sit.width_m, o.d_m, o.width_m) < need
                       and o.lx_m < cfg.lx_max_m]
        if other_block:
            why.append(f"lane {ln} blocked by hazard {other_block[0].hazard_id}")
            continue
        path = plan_lane_change(frame, sit.s_m, sit.d_m, sit.heading_error_rad, sit.speed_along_mps, d_t,
                                sit.cruise_speed_mps, sit.ddm_cfg)
        pc = min((path_clearance(path, frame, sit.length_m, sit.width_m, o) for o in sit.threats), default=math.inf)
        if pc < need:
            why.append(f"lane {ln}: the change passes {t.hazard_id} with {pc:.1f} m < {need:.1f} m")
            continue
        v_plan = max(sit.speed_along_mps, MIN_PLAN_SPEED_MPS)
        ok, gap_why = gap_check(sit.s_m, v_plan, v_plan, sit.length_m, ln, sit.traffic, frame,
                                path.lane_change_length_m / v_plan, sit.ddm_cfg)
        if not ok:
            why.append(gap_why)
            continue
        return Intent(Manoeuvre.LANE_CHANGE, f"change to lane {ln} around it ({gap_why}, passes with "
                      f"{pc:.1f} m): {describe(t)}", target_lane=ln, path=path, **sit.about(t)), ""
    return None, "; ".join(why) or "no neighbouring lane"


def stop(sit: Situation, t: HazardThreat, why: str) -> Intent:
    """STOP_IN_LANE with the front bumper ``stop_gap_m`` before the hazard."""
    cfg = sit.cfg
    s_stop = stop_before_s_m(t.s_m, t.length_m, cfg.stop_gap_m, sit.length_m)
    path = plan_stop_at(sit.frame, sit.s_m, sit.d_m, sit.heading_error_rad, sit.speed_along_mps, sit.lane_d_m,
                        s_stop, sit.ddm_cfg, cfg.max_stop_decel_mps2)
    return Intent(Manoeuvre.STOP_IN_LANE, f"{why}; slow and stop {cfg.stop_gap_m:.0f} m before it "
                  f"({path.decel_mps2:.1f} m/s^2): {describe(t)}", target_lane=sit.lane, stop_s_m=s_stop, path=path,
                  **sit.about(t))


def keep_stopping(sit: Situation, response: Response) -> Intent | None:
    """Stopping (or stopped) before a hazard: go around once a lane change is possible, stop for a nearer
    hazard, or hold; None when every hazard it stopped for is gone."""
    acting = sit.acting
    if acting:
        t = acting[0]
        dec, _why = try_lane_change(sit, t)
        if dec is not None:
            return dec
        if t.hazard_id not in response.cause_ids:  # a nearer hazard than the one it stops for
            return stop(sit, t, "another hazard")
        return Intent("hold", f"keep stopping: {describe(t)}", target_lane=response.target_lane, **sit.about(t))
    mine = [t for t in sit.threats if t.hazard_id in response.cause_ids]
    if any(t.blocks for t in mine):
        t = next(t for t in mine if t.blocks)
        return Intent("hold", f"stopped before {describe(t)}", target_lane=response.target_lane, **sit.about(t))
    return None


def keep_avoiding(sit: Situation, response: Response) -> Intent | None:
    """Changing lane around a hazard: respond to a new one ahead, or hold while passing; None once every
    hazard it went around is passed or gone."""
    new = [t for t in sit.acting if t.hazard_id not in response.cause_ids]
    if new:
        return avoid_or_stop(sit, new[0])
    mine = [t for t in sit.threats if t.hazard_id in response.cause_ids]
    if mine:
        t = mine[0]
        return Intent("hold", f"passing {describe(t)}", target_lane=response.target_lane, **sit.about(t))
    return None


def resume(sit: Situation, response: Response) -> Intent:
    """RESUME in the AV's lane: the hazards it responded to are passed or cleared."""
    gone = sorted(response.cause_ids - sit.known)
    what = f"hazard {', '.join(map(str, gone))} cleared" if gone else "hazard passed"
    path = plan_resume(sit.frame, sit.s_m, sit.d_m, sit.heading_error_rad, sit.speed_along_mps, sit.lane_d_m,
                       sit.cruise_speed_mps, sit.ddm_cfg)
    return Intent(Manoeuvre.RESUME, f"resume in lane {sit.lane}: {what}", target_lane=sit.lane, path=path,
                  **sit.base)


def hazard_intents(picture: Picture, egos: Sequence[Ego], memory: Mapping[str, Response],
                   ctx: PolicyContext) -> list[Intent]:
    """The hazard intents of ``egos`` (``memory``: each one's hazard response so far), in their order, each
    with its vehicle id; a vehicle with no hazard in the picture and nothing to resume from gets none."""
    out = []
    for ego in egos:
        response = memory[ego.vehicle_id]
        if not picture.hazards and response.phase == "normal":
            continue
        others = picture.tracks_near(ego.x_m, ego.y_m, NEIGHBOUR_RADIUS_M)
        intent = decide_hazard(ego, picture.hazards, others, ctx.frame, ctx.config, ctx.hazard_config, response,
                               ctx.cruise_of(ego.vehicle_id))
        out.append(replace(intent, vehicle_id=ego.vehicle_id))
    return out
