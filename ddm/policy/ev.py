"""EV response policy: what each autonomous vehicle should do about emergency vehicles. Pure.

For one AV, from the picture's EV tracks (road frame via ``RoadFrame``):

- an EV is *relevant* when it moves (>= ``min_ev_speed_mps``) in the road's direction (velocity within
  60 deg of the lane direction), is on the carriageway, and is behind the AV by at most
  ``ev_lookbehind_m``. Opposite-direction EVs and EVs already ahead are not threats.
- time until it passes, as CARMA's approaching-emergency-vehicle plugin does (docs/architecture.md §DDM):
  ``ttp = (s_ego - s_ev) / (v_ev - v_ego)`` (infinite when not closing).
- it *triggers* a response when ``ttp <= act_time_to_pass_s`` or it is within ``act_gap_m``.

Responses (Texas Transportation Code 545.156: move to the right-hand edge or curb and stop until the
EV has passed), one named rule each:

- AV in lane 0 (or on the shoulder): PULL_OVER, stop at the curb side of lane 0 (``stop_at_curb``).
- AV in lane k > 0, ``ttp < too_late_s``: SLOW_IN_LANE (CARMA: stay in lane and slow to 4.47 m/s when
  too late; ``too_late``).
- ... the EV itself drives in lane 0, or right of it (the shoulder, or an on-ramp that joins lane 0): pulling
  into its path is wrong: LANE_CHANGE one lane left when there is one and a safe gap, else SLOW_IN_LANE
  (``ev_in_lane_0``).
- ... a safe gap in lane 0: PULL_OVER (change to lane 0 and stop; ``pull_over``). No safe gap because of
  a slower car there: no command, the AV keeps its speed past it (slowing would keep it beside that car
  and in the EV's way); because of a faster car or a follower: keep speed and let it pass or drop back
  (``let_faster_pass``: slowing in the EV's lane brings the EV on sooner); otherwise SLOW_IN_LANE for
  the gap. Re-checked every cycle.
- While yielding (``keep_yielding``): a slowed AV pulls over once lane 0 has a gap and the EV is not right of
  the AV's lane (``gap_opened``: never across the EV's path); a
  pull-over whose lane ahead filled up is planned anew with a shorter stop (``shorter_stop``).
- RESUME once no EV is behind the AV or less than ``pass_margin_m`` ahead of it (whatever its track id:
  a track may switch ids while the EV passes), none has been for ``resume_hold_s`` (a track lost
  for a moment next to the AV is not a pass), and an EV lost from view (an RSU died) is, driving on
  at its last speed, predicted ``pass_margin_m`` ahead (for up to ``ev_predict_s``); RESUME waits for a
  safe gap in the lane it merges into (``after_the_ev``).

The gap check and the other shared manoeuvre rules are in :mod:`ddm.manoeuvre`. ``decide`` reads only its
arguments, among them ``ddm.intent.Response``, the vehicle's memory of what was commanded, which the
decider updates when a command is issued; :func:`ev_intents` runs it over a picture and plans the path of
every intent with a manoeuvre (:func:`plan`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from ddm.config import DdmConfig
from ddm.geometry import RoadFrame
from ddm.intent import Ego, Intent, Response
from ddm.manoeuvre import (
    SELF_RADIUS_M,
    gap_check,
    lane_change_time_s,
    leader_room_m,
    road_pose,
    traffic,
)
from ddm.paths import (
    PlannedPath,
    lane_change_length,
    plan_keep_lane_slow,
    plan_lane_change,
    plan_resume,
    plan_stop,
    plan_stop_holding_speed,
    stop_offset_m,
)
from ddm.picture import Picture
from ddm.policy import NEIGHBOUR_RADIUS_M, PolicyContext
from ddm.tracks import Track
from protocol.enums import Manoeuvre


@dataclass(frozen=True)
class Threat:
    """An EV behind the AV in the road's direction, with its time to pass and whether it triggers a response."""

    track_id: int
    s_m: float
    d_m: float
    lane: int | None
    speed_mps: float
    gap_m: float
    """Centre-to-centre distance behind the AV along the road (m)."""
    closing_mps: float
    time_to_pass_s: float
    triggered: bool

    @property
    def path_in_lane_0(self) -> bool:
        """Its path is lane 0: it drives there, or right of it (on the shoulder, or on a ramp joining lane 0)."""
        return self.lane == 0 or (self.lane is None and self.d_m < 0.0)


def _fmt_t(t: float) -> str:
    return "inf" if not math.isfinite(t) else f"{t:.1f}"


def assess_evs(ego_s: float, ego_v_long: float, ego_len: float, evs: list[Track], frame: RoadFrame,
               cfg: DdmConfig) -> tuple[list[Threat], dict[int, float]]:
    """Relevant EVs behind (threats) and, for the others in the same direction, how far ahead they are."""
    if not evs:
        return [], {}
    xs = np.array([e.x_m for e in evs])
    ys = np.array([e.y_m for e in evs])
    s, d = frame.to_frenet(xs, ys)
    vlong = frame.longitudinal_speed(s, [e.vx_mps for e in evs], [e.vy_mps for e in evs])
    lanes = frame.lane_of(d)
    road_w = frame.lanes * frame.lane_width_m
    threats: list[Threat] = []
    ahead: dict[int, float] = {}
    for k, ev in enumerate(evs):
        speed = ev.speed_mps
        if speed < cfg.min_ev_speed_mps or vlong[k] < cfg.same_direction_cos * speed:
            continue  # parked, crossing or opposite direction
        if d[k] < -frame.road.shoulder_width_m - 1.0 or d[k] > road_w + 1.0:
            continue  # not on this carriageway
        gap = ego_s - float(s[k])
        if gap < 0:
            ahead[ev.track_id] = -gap
            continue
        if gap > cfg.ev_lookbehind_m:
            continue
        closing = float(vlong[k]) - ego_v_long
        ttp = gap / closing if closing > cfg.min_closing_mps else math.inf
        trig = ttp <= cfg.act_time_to_pass_s or gap <= cfg.act_gap_m
        lane = int(lanes[k])
        threats.append(Threat(ev.track_id, float(s[k]), float(d[k]), None if lane < 0 else lane, speed, gap,
                              closing, ttp, trig))
    threats.sort(key=lambda t: (t.time_to_pass_s, t.gap_m))
    return threats, ahead


def describe(t: Threat) -> str:
    lane = "?" if t.lane is None else str(t.lane)
    return (f"EV track {t.track_id} {t.gap_m:.0f} m behind in lane {lane}, {t.speed_mps:.1f} m/s, "
            f"closing {t.closing_mps:.1f} m/s, time to pass {_fmt_t(t.time_to_pass_s)} s")


@dataclass(frozen=True)
class Situation:
    """One AV and the EVs around it, in the road frame: what every rule reads."""

    frame: RoadFrame
    cfg: DdmConfig
    s_m: float
    d_m: float
    speed_along_mps: float
    lane: int
    """The AV's lane; on the shoulder: 0."""
    length_m: float
    base: dict[str, Any]
    """The fields every intent of this situation carries (the AV's pose, whether an EV is near)."""
    ev_ids: frozenset[int]
    traffic: list[Track]
    """Other vehicles near the AV (not the AV, not an EV)."""
    others: list[Track]
    threats: list[Threat]
    ahead: dict[int, float]
    """EV track id -> how far ahead of the AV it is (same direction)."""
    passing: dict[int, float]
    """The EVs of ``ahead`` less than ``pass_margin_m`` ahead."""

    @property
    def urgent(self) -> list[Threat]:
        return [t for t in self.threats if t.triggered]

    def about(self, t: Threat) -> dict[str, Any]:
        """The fields of an intent that responds to ``t``."""
        return dict(self.base, ev_track_id=t.track_id, time_to_pass_s=t.time_to_pass_s, ev_gap_m=t.gap_m,
                    ev_s_m=t.s_m, ev_speed_mps=t.speed_mps)


def situation(ego: Ego, evs: list[Track], others: list[Track], frame: RoadFrame, cfg: DdmConfig) -> Situation:
    """The AV's road pose, its traffic, and the EVs behind (threats) and ahead of it."""
    pose = road_pose(ego, frame)
    s_e, d_e, v_e = pose.s_m, pose.d_m, pose.speed_along_mps
    lane_e = 0 if pose.lane_raw < 0 and d_e < 0 else pose.lane_raw  # on the shoulder: treat as lane 0
    base = dict(ego_s_m=s_e, ego_d_m=d_e, ego_heading_error_rad=pose.heading_error_rad, ego_speed_mps=ego.speed_mps)
    # never yield to itself: its own track, or an 'EV' where the AV is (an RSU track that switched cars)
    evs = [e for e in evs if (ego.track_id is None or e.track_id != ego.track_id)
           and math.hypot(e.x_m - ego.x_m, e.y_m - ego.y_m) >= SELF_RADIUS_M]
    ev_ids = frozenset(e.track_id for e in evs)
    threats, ahead = assess_evs(s_e, v_e, ego.length_m, evs, frame, cfg)
    passing = {tid: dist for tid, dist in ahead.items() if dist < cfg.pass_margin_m}
    base["ev_near"] = bool(threats or passing)
    return Situation(frame, cfg, s_e, d_e, v_e, lane_e, ego.length_m, base, ev_ids,
                     traffic(ego, others, set(ev_ids)), others, threats, ahead, passing)


def decide(ego: Ego, evs: list[Track], others: list[Track], frame: RoadFrame, cfg: DdmConfig,
           response: Response, now: float | None = None) -> Intent:
    """One vehicle's EV response (see module docstring). ``others``: tracks near the AV (any kind).
    ``now``: with it, a yielding AV resumes only after no EV has been near for ``resume_hold_s``."""
    sit = situation(ego, evs, others, frame, cfg)
    urgent = sit.urgent
    if urgent:
        if response.phase == "yielding":
            return keep_yielding(sit, urgent[0], response)
        return respond(sit, urgent[0])
    if response.phase == "yielding":
        return after_the_ev(sit, response, now)
    return no_response(sit)


# ------------------------------------------------------------------ an EV triggers a response
def respond(sit: Situation, t: Threat) -> Intent:
    """The first response to an EV that triggers one."""
    if sit.lane <= 0:
        return stop_at_curb(sit, t)
    if t.time_to_pass_s < sit.cfg.too_late_s:
        return too_late(sit, t)
    if t.path_in_lane_0:
        return ev_in_lane_0(sit, t)
    return pull_over(sit, t)


def stop_at_curb(sit: Situation, t: Threat) -> Intent:
    """Already in lane 0: stop at the curb, within the room its leader leaves."""
    room = gap_check(sit.s_m, sit.speed_along_mps, sit.speed_along_mps, sit.length_m, 0, sit.traffic, sit.frame,
                     0.0, sit.cfg, stopping=True)
    return Intent(Manoeuvre.PULL_OVER, f"in lane 0, stop at the curb: {describe(t)}", target_lane=0,
                  stop_within_m=room.room_ahead_m, **sit.about(t))


def too_late(sit: Situation, t: Threat) -> Intent:
    """No time left to change lane: slow in lane (CARMA)."""
    return Intent(Manoeuvre.SLOW_IN_LANE, f"too late to change lane (< {sit.cfg.too_late_s:.0f} s): "
                  f"{describe(t)}", target_lane=sit.lane, slow_because="too_late", **sit.about(t))


def ev_in_lane_0(sit: Situation, t: Threat) -> Intent:
    """The EV's path is lane 0 (``Threat.path_in_lane_0``): move one lane left when there is a safe gap, else
    slow in lane."""
    left = sit.lane + 1
    if left < sit.frame.lanes:
        t_change = lane_change_time_s(sit.frame.lane_width_m, sit.speed_along_mps, sit.cfg)
        ok, why = gap_check(sit.s_m, sit.speed_along_mps, sit.speed_along_mps, sit.length_m, left, sit.traffic,
                            sit.frame, t_change, sit.cfg)
        if ok:
            return Intent(Manoeuvre.LANE_CHANGE, f"EV drives in lane 0, move left to lane {left} "
                          f"({why}): {describe(t)}", target_lane=left, **sit.about(t))
    return Intent(Manoeuvre.SLOW_IN_LANE, f"EV drives in lane 0, no safe lane to the left: "
                  f"{describe(t)}", target_lane=sit.lane, slow_because="ev_in_lane0", **sit.about(t))


def pull_over_gap(sit: Situation):
    """The gap check of a pull-over from the AV's lane into lane 0 (a stop there)."""
    cfg, v_e = sit.cfg, sit.speed_along_mps
    lc = lane_change_length(sit.frame.lane_centre_offset(0) - sit.d_m, max(v_e, 2.0), 0.0, cfg)
    t_change = lc / max(v_e, 2.0)
    # a held-speed pull-over does not slow during the change and stops after it, a lane change and a
    # comfort stop ahead: a follower has that much room to stop behind it
    if cfg.pull_over_hold_speed:
        av_stop = lc + v_e * v_e / (2.0 * cfg.comfort_decel_mps2)
        return gap_check(sit.s_m, v_e, v_e, sit.length_m, 0, sit.traffic, sit.frame, t_change, cfg, stopping=True,
                         av_stop_m=av_stop)
    v_after = max(0.0, v_e - cfg.comfort_decel_mps2 * t_change)
    return gap_check(sit.s_m, v_e, v_after, sit.length_m, 0, sit.traffic, sit.frame, t_change, cfg, stopping=True)


def pull_over(sit: Situation, t: Threat) -> Intent:
    """Into lane 0 and stop when the gap is safe; else keep speed past a slower car or let a faster one
    (or a follower) pass, or slow in lane for the gap."""
    cfg, v_e = sit.cfg, sit.speed_along_mps
    gap = pull_over_gap(sit)
    ok, why = gap
    if ok:
        return Intent(Manoeuvre.PULL_OVER, f"pull over to lane 0 ({why}): {describe(t)}", target_lane=0,
                      stop_within_m=gap.room_ahead_m, **sit.about(t))
    if gap.blocker_speed_mps is not None and gap.blocker_speed_mps < v_e - cfg.min_closing_mps:
        # slowing would keep the AV beside a slower car (and in the EV's way): drive on past it
        return Intent("none", f"{why}; keep speed past the slower vehicle, then pull over: {describe(t)}",
                      **sit.about(t))
    if cfg.let_faster_pass and gap.blocker_speed_mps is not None and (
            gap.blocker_speed_mps > v_e + cfg.min_closing_mps or gap.blocker_role == "follower"):
        # slowing in the EV's lane for a car in lane 0 brings the EV onto the AV sooner; a faster car is
        # by soon, a follower at the AV's speed or slower (drivers slow for an EV) drops back: keep speed,
        # then pull over
        what = "the faster vehicle in lane 0 pass" if gap.blocker_speed_mps > v_e + cfg.min_closing_mps \
            else "the vehicle behind in lane 0 pass or drop back"
        return Intent("none", f"{why}; keep speed: let {what}, then pull over: {describe(t)}", **sit.about(t))
    return Intent(Manoeuvre.SLOW_IN_LANE, f"{why}; slow in lane {sit.lane}: {describe(t)}",
                  target_lane=sit.lane, slow_because="gap", **sit.about(t))


# ------------------------------------------------------------------ yielding, the EV still coming
def keep_yielding(sit: Situation, t: Threat, response: Response) -> Intent:
    """Yielding while an EV still triggers: pull over after all, stop shorter, or hold the manoeuvre."""
    return (gap_opened(sit, t, response) or shorter_stop(sit, t, response)
            or Intent("hold", f"keep {response.manoeuvre.value if response.manoeuvre else 'manoeuvre'}: "
                      f"{describe(t)}", target_lane=response.target_lane, **sit.about(t)))


def gap_opened(sit: Situation, t: Threat, response: Response) -> Intent | None:
    """Slowed in lane k > 0 (for a gap, too late, or for an EV in lane 0 that has come into the AV's lane) and
    there is time again: pull over once lane 0 has a gap. Never across the EV's path: an EV right of the AV's
    lane (in a lane between it and lane 0, in lane 0, or joining it) stays where it is, and the AV in its lane."""
    if (response.manoeuvre == Manoeuvre.SLOW_IN_LANE and sit.lane > 0 and t.time_to_pass_s >= sit.cfg.too_late_s
            and t.d_m >= sit.lane * sit.frame.lane_width_m):
        gap = pull_over_gap(sit)
        ok, why = gap
        if ok:
            return Intent(Manoeuvre.PULL_OVER, f"gap opened ({why}); pull over to lane 0: {describe(t)}",
                          target_lane=0, stop_within_m=gap.room_ahead_m, **sit.about(t))
    return None


def shorter_stop(sit: Situation, t: Threat, response: Response) -> Intent | None:
    """A pull-over under way whose lane ahead now holds a vehicle the command did not allow for: stop
    within the room that vehicle leaves."""
    cfg = sit.cfg
    if (response.manoeuvre == Manoeuvre.PULL_OVER and response.stop_s_m is not None
            and sit.speed_along_mps > cfg.replan_min_speed_mps):
        room = leader_room_m(sit.s_m, sit.length_m, 0, sit.traffic, sit.frame, cfg)
        if room is not None and sit.s_m + room < response.stop_s_m - cfg.replan_shorter_m:
            return Intent(Manoeuvre.PULL_OVER, f"vehicle ahead in lane 0: stop within {max(room, 0.0):.0f} m "
                          f"instead of {response.stop_s_m - sit.s_m:.0f} m: {describe(t)}", target_lane=0,
                          stop_within_m=max(room, 0.1), **sit.about(t))
    return None


# ------------------------------------------------------------------ yielding, no EV triggers any more
def after_the_ev(sit: Situation, response: Response, now: float | None) -> Intent:
    """Hold while an EV is passing, still behind, lost but predicted near, or seen near too recently;
    then RESUME once the lane it merges into has a gap."""
    cfg, base = sit.cfg, sit.base
    # still passing: an EV (the one we yield to, or one with a new track id after a track switch)
    # is behind (not triggering any more) or less than the margin ahead
    for tid in sorted(sit.passing):
        return Intent("hold", f"EV track {tid} passing, {sit.passing[tid]:.0f} m ahead "
                      f"(< {cfg.pass_margin_m:.0f} m)", ev_track_id=tid, **base)
    if sit.threats:
        t = sit.threats[0]
        return Intent("hold", f"EV track {t.track_id} still behind", ev_track_id=t.track_id,
                      ev_s_m=t.s_m, ev_speed_mps=t.speed_mps, **base)
    held = lost_ev_held(sit, response, now) or resume_held(sit, response, now)
    return held or resume(sit, response)


def lost_ev_held(sit: Situation, response: Response, now: float | None) -> Intent | None:
    """The EV yielded to is out of sight (an RSU died, tracks switched): it drives on at its last speed;
    hold until it must be ``pass_margin_m`` ahead (within ``ev_predict_s``)."""
    cfg = sit.cfg
    still_seen = any(o.track_id in response.cause_ids for o in sit.others)  # seen, not an EV any more
    if now is not None and response.ev_last is not None and not still_seen:
        s_ev, v_ev, t_ev = response.ev_last
        age = now - t_ev
        ahead_m = s_ev + max(v_ev, cfg.min_ev_speed_mps) * age - sit.s_m
        if age <= cfg.ev_predict_s and ahead_m < cfg.pass_margin_m:
            return Intent("hold", f"EV out of sight for {age:.1f} s, predicted {ahead_m:+.0f} m from the AV "
                          f"(resume once {cfg.pass_margin_m:.0f} m ahead)", **sit.base)
    return None


def resume_held(sit: Situation, response: Response, now: float | None) -> Intent | None:
    """An EV was near less than ``resume_hold_s`` ago: hold."""
    if now is not None and now - response.ev_near_s < sit.cfg.resume_hold_s:
        return Intent("hold", f"no EV near for {now - response.ev_near_s:.1f} s "
                      f"(resume after {sit.cfg.resume_hold_s:.1f} s)", **sit.base)
    return None


def resume(sit: Situation, response: Response) -> Intent:
    """RESUME into the lane the AV is in, once that lane has a gap (when the AV is off its centre)."""
    frame, cfg = sit.frame, sit.cfg
    target = max(sit.lane, 0)
    if abs(sit.d_m - frame.lane_centre_offset(target)) > 0.5 * frame.lane_width_m:
        t_change = lane_change_time_s(frame.lane_centre_offset(target) - sit.d_m, 6.0, cfg)
        ok, why = gap_check(sit.s_m, sit.speed_along_mps, sit.speed_along_mps, sit.length_m, target, sit.traffic,
                            frame, t_change, cfg)
        if not ok:
            return Intent("hold", f"waiting to resume: {why}", target_lane=target, **sit.base)
    gone = [tid for tid in sorted(response.cause_ids) if tid not in sit.ev_ids]
    passed = [f"{tid} ({sit.ahead[tid]:.0f} m ahead)" for tid in sorted(response.cause_ids) if tid in sit.ahead]
    why = []
    if passed:
        why.append(f"EV track {', '.join(passed)} passed")
    if gone:
        why.append(f"EV track {', '.join(map(str, gone))} cleared or lost")
    return Intent(Manoeuvre.RESUME, "resume: " + ("; ".join(why) or "no EV to yield to"),
                  target_lane=target, **sit.base)


# ------------------------------------------------------------------ not yielding, nothing triggers
def no_response(sit: Situation) -> Intent:
    """No command: say why."""
    if sit.threats:
        t = sit.threats[0]
        return Intent("none", f"EV track {t.track_id} behind but not imminent (time to pass "
                      f"{_fmt_t(t.time_to_pass_s)} s, {t.gap_m:.0f} m)", **sit.base)
    if sit.ahead:
        return Intent("none", "EV ahead: nothing to do", **sit.base)
    return Intent("none", "no EV approaching from behind", **sit.base)


# ------------------------------------------------------------------ over a picture
def ev_intents(picture: Picture, egos: Sequence[Ego], memory: Mapping[str, Response],
               ctx: PolicyContext) -> list[Intent]:
    """The EV intents of ``egos`` (vehicles of ``picture``; ``memory``: each one's EV response so far), in
    their order, each with its vehicle id and, with a manoeuvre, its planned path. A vehicle with no EV in
    the picture and nothing to resume from gets none (the hazard policy may act for it)."""
    evs = list(picture.evs)
    out = []
    for ego in egos:
        response = memory[ego.vehicle_id]
        if not evs and response.phase == "normal":
            continue
        others = picture.tracks_near(ego.x_m, ego.y_m, NEIGHBOUR_RADIUS_M)
        intent = decide(ego, evs, others, ctx.frame, ctx.config, response, picture.now)
        path = None if intent.manoeuvre is None else plan(intent, ctx.frame, ctx.config, ctx.width_of(ego.vehicle_id),
                                                          ctx.cruise_of(ego.vehicle_id))
        out.append(replace(intent, vehicle_id=ego.vehicle_id, path=path))
    return out


def plan(intent: Intent, frame: RoadFrame, cfg: DdmConfig, vehicle_width_m: float,
         cruise_speed_mps: float) -> PlannedPath:
    """The commanded path for an EV intent that carries a manoeuvre."""
    m = intent.manoeuvre
    s0, d0, h, v = intent.ego_s_m, intent.ego_d_m, intent.ego_heading_error_rad, intent.ego_speed_mps
    if m == Manoeuvre.PULL_OVER:
        d_stop = stop_offset_m(frame, vehicle_width_m, frame.road.shoulder_width_m, cfg)
        # when the EV arrives: a just-lit EV is still accelerating, so assume it closes at least at
        # ev_closing_assumed_mps (pessimistic), whatever its closing speed now
        ttp = intent.time_to_pass_s
        if intent.ev_gap_m is not None:
            ttp_assumed = intent.ev_gap_m / cfg.ev_closing_assumed_mps
            ttp = ttp_assumed if ttp is None or not math.isfinite(ttp) else min(ttp, ttp_assumed)
        within_s = ttp - cfg.stop_margin_s if ttp is not None and math.isfinite(ttp) else None
        if cfg.pull_over_hold_speed:
            held = plan_stop_holding_speed(frame, s0, d0, h, v, d_stop, cfg, stop_within_s=within_s,
                                           max_stop_dist_m=intent.stop_within_m)
            if held is not None:
                return held
        return plan_stop(frame, s0, d0, h, v, d_stop, cfg, stop_within_s=within_s,
                         max_stop_dist_m=intent.stop_within_m)
    lane = intent.target_lane if intent.target_lane is not None else max(int(frame.lane_of(d0)), 0)
    centre = frame.lane_centre_offset(lane)
    if m == Manoeuvre.SLOW_IN_LANE:
        return plan_keep_lane_slow(frame, s0, d0, h, v, centre, cfg.slow_speed_mps, cfg)
    if m == Manoeuvre.LANE_CHANGE:
        return plan_lane_change(frame, s0, d0, h, v, centre, min(v, cruise_speed_mps), cfg)
    if m == Manoeuvre.RESUME:
        return plan_resume(frame, s0, d0, h, v, centre, cruise_speed_mps, cfg)
    raise ValueError(f"no plan for intent action {intent.action!r}")
