"""EV response policy (issue 7 step 2): what each autonomous vehicle should do about emergency vehicles. Pure.

For one AV, from the fused EV tracks (road frame via ``RoadFrame``):

- an EV is *relevant* when it moves (>= ``min_ev_speed_mps``) in the road's direction (velocity within
  60 deg of the lane direction), is on the carriageway, and is behind the AV by at most
  ``ev_lookbehind_m``. Opposite-direction EVs and EVs already ahead are not threats.
- time until it passes, as CARMA's approaching-emergency-vehicle plugin does (SPEC.md):
  ``ttp = (s_ego - s_ev) / (v_ev - v_ego)`` (infinite when not closing).
- it *triggers* a response when ``ttp <= act_time_to_pass_s`` or it is within ``act_gap_m``.

Responses (Texas Transportation Code 545.156: move to the right-hand edge or curb and stop until the
EV has passed):

- AV in lane 0 (or on the shoulder): PULL_OVER - stop at the curb side of lane 0 / on the shoulder.
- AV in lane k > 0, ``ttp >= too_late_s`` and a safe gap in lane 0: PULL_OVER (change to lane 0 and stop).
- ... no safe gap in lane 0 because of a faster car there: SLOW_IN_LANE (let it pass), re-checked every
  cycle; PULL_OVER once the gap opens while there is still time. Because of a slower car: no command,
  the AV keeps its speed past it (slowing would keep it beside that car and in the EV's way) and pulls
  over as soon as the gap behind the AV is safe.
- ... no safe gap in lane 0 because of a slower car there: keep speed past it; of a faster one: keep speed and
  let it pass (``let_faster_pass``, issue 18: slowing in the EV's lane brings the EV on sooner); then pull over.
- ... ``ttp < too_late_s``: SLOW_IN_LANE (CARMA: stay in lane and slow to 4.47 m/s when too late); if
  the EV then stops closing (it is held up behind the AV) and lane 0 has a gap, PULL_OVER after all.
- ... the EV itself drives in lane 0: pulling into its path is wrong: LANE_CHANGE one lane left when
  there is one and a safe gap, else SLOW_IN_LANE.
- RESUME once no EV is behind the AV or less than ``pass_margin_m`` ahead of it (whatever its track id:
  a track may switch ids while the EV passes), none has been for ``resume_hold_s`` (a track lost
  for a moment next to the AV is not a pass), and an EV lost from view (an RSU died) is, driving on
  at its last speed, predicted ``pass_margin_m`` ahead (for up to ``ev_predict_s``); RESUME waits for a
  safe gap in the lane it merges into.

Gap check (lane change / merge into lane L): every other track in lane L needs a bumper-to-bumper
clearance of at least ``gap_min_m + gap_time_s * v_follower + max(0, v_follower - v_leader) * t_change``
(the headway the follower needs plus what the speed difference eats during the manoeuvre).

``decide`` is stateless except for ``ddm.decision.Response``, the per-vehicle memory of what was commanded,
which the decider updates when a command is issued (``Response.commit``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ddm.config import DdmConfig
from ddm.decision import Decision, Ego, Response
from ddm.geometry import RoadFrame
from ddm.paths import (
    PlannedPath,
    lane_change_length,
    min_stop_distance_m,
    plan_keep_lane_slow,
    plan_lane_change,
    plan_resume,
    plan_stop,
    plan_stop_holding_speed,
    stop_offset_m,
)
from ddm.tracks import Track
from protocol.enums import Manoeuvre

SELF_RADIUS_M = 2.0
"""A track whose centre is this close to the AV's is the AV itself (two cars' centres never are)."""


@dataclass(frozen=True)
class Threat:
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


def _wrap(a: float) -> float:
    return (a + math.pi) % (2 * math.pi) - math.pi


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


ENTER_FRACTION = 0.3
"""When the AV's body starts to enter the target lane, as a fraction of its lane change (quintic from one lane
centre to the next: the near side of a 1.9 m wide car crosses the line at 24 % of the shift, 35 % of the time)."""
MIN_START_GAP_M = 1.0
"""Whatever the speeds, a pull-over does not start with a follower closer than this behind the AV's rear."""


class GapCheck(tuple):
    """``(ok, explanation)`` of ``gap_check``; ``blocker_speed_mps`` is the speed along the road of the
    vehicle that makes the gap unsafe (None when the gap is safe)."""

    def __new__(cls, ok: bool, why: str, blocker_speed_mps: float | None = None,
                room_ahead_m: float | None = None, blocker_role: str | None = None) -> GapCheck:
        self = super().__new__(cls, (ok, why))
        self.blocker_speed_mps = blocker_speed_mps
        self.blocker_role = blocker_role
        """``leader`` or ``follower``: where the vehicle that makes the gap unsafe is (None when safe)."""
        self.room_ahead_m = room_ahead_m
        """``stopping`` checks: how far the AV may travel before it must be stopped behind the leader
        (None: no leader in the lane)."""
        return self


def _lane_neighbours(ego_s: float, ego_len: float, others: list[Track], frame: RoadFrame,
                     lane: int) -> list[tuple[Track, float, float, float]]:
    """(track, station offset from the AV m, bumper-to-bumper clearance m, speed along the road m/s) of every
    track whose width overlaps ``lane``."""
    if not others:
        return []
    s, d = frame.to_frenet(np.array([o.x_m for o in others]), np.array([o.y_m for o in others]))
    vl = frame.longitudinal_speed(s, [o.vx_mps for o in others], [o.vy_mps for o in others])
    lo = lane * frame.lane_width_m
    hi = lo + frame.lane_width_m
    out = []
    for k, o in enumerate(others):
        half_w = max(o.width_m, 1.5) / 2.0
        if d[k] + half_w <= lo or d[k] - half_w >= hi:
            continue  # not in that lane
        ds = float(s[k]) - ego_s
        out.append((o, ds, abs(ds) - (ego_len + max(o.length_m, 3.0)) / 2.0, float(vl[k])))
    return out


def _room_behind_m(clearance_m: float, leader_speed_mps: float, cfg: DdmConfig) -> float:
    """How far the AV may travel before standing gap_min behind a leader that brakes now at the comfort
    deceleration: clearance + v_l^2 / (2 comfort) - gap_min (a leader moving backwards counts as stopped)."""
    v_l = max(leader_speed_mps, 0.0)
    return clearance_m + v_l * v_l / (2.0 * cfg.comfort_decel_mps2) - cfg.gap_min_m


def gap_check(ego_s: float, ego_v: float, ego_v_after: float, ego_len: float, target_lane: int,
              others: list[Track], frame: RoadFrame, change_time_s: float, cfg: DdmConfig,
              exclude: set[int] = frozenset(), stopping: bool = False, av_stop_m: float | None = None) -> GapCheck:
    """Is there a safe gap for the AV in ``target_lane``? (ok, explanation).

    ``stopping``: the AV will stop in that lane (pull-over), so a leader only has to leave it room
    to stop behind it even if the leader brakes too: clearance + v_l^2 / (2 comfort) >= gap_min +
    v_AV^2 / (2 max_decel); the room left is returned (``room_ahead_m``) to place the stop point. A
    follower needs a gap that does not close during the change (a slower one: ``gap_min_m`` by the time the
    AV's body enters its lane, ``ENTER_FRACTION``) and room to stop behind the AV's stop
    (``av_stop_m`` ahead: a held-speed pull-over's lane change and comfort stop; default the shortest stop
    at ``max_decel_mps2``)."""
    cand = [o for o in others if o.track_id not in exclude]
    if not cand:
        return GapCheck(True, f"lane {target_lane} empty")
    worst = ""
    room: float | None = None
    for o, ds, clearance, v_long in _lane_neighbours(ego_s, ego_len, cand, frame, target_lane):
        if ds >= 0 and stopping:  # leader of a stop: room to stop behind it
            v_l = max(v_long, 0.0)
            r = _room_behind_m(clearance, v_l, cfg)
            need_m = min_stop_distance_m(frame.lane_width_m, ego_v, 0.0, cfg)
            if r < need_m or clearance < cfg.gap_min_m:
                return GapCheck(False, f"no room to stop in lane {target_lane}: leader track {o.track_id} "
                                f"{clearance:.1f} m ahead, {r:.1f} m < {need_m:.1f} m needed", v_l,
                                blocker_role="leader")
            room = r if room is None else min(room, r)
            worst = worst or f"room to stop in lane {target_lane}"
            continue
        if ds >= 0:  # leader: the AV follows it
            v_f, v_l = ego_v, v_long
            role = "leader"
        else:  # lag: it follows the AV, which slows during the manoeuvre
            v_f, v_l = v_long, ego_v_after
            role = "follower"
        need = cfg.gap_min_m + cfg.gap_time_s * max(v_f, 0.0) + max(0.0, v_f - v_l) * change_time_s
        if stopping and role == "follower":
            # the AV ends stopped at least v^2 / (2 max_decel) ahead: the follower needs room to stop
            # behind that (reacting after gap_time_s), and a gap that does not close during the change
            v_f = max(v_f, 0.0)
            av_stop = ego_v * ego_v / (2.0 * cfg.max_decel_mps2) if av_stop_m is None else av_stop_m
            follower_stop_m = v_f * cfg.gap_time_s + v_f * v_f / (2.0 * cfg.comfort_decel_mps2)
            # a slower follower drops back while the AV crosses: gap_min is needed when the AV's body enters
            # the lane (ENTER_FRACTION of the change; issue 18, e2e seed 7), not when the change starts
            grows = max(0.0, v_l - v_f) * ENTER_FRACTION * change_time_s
            need = max(cfg.gap_min_m + max(0.0, v_f - v_l) * change_time_s - grows,
                       cfg.gap_min_m + follower_stop_m - av_stop, MIN_START_GAP_M)
        if clearance < need:
            return GapCheck(False, f"unsafe gap in lane {target_lane}: {role} track {o.track_id} "
                            f"{clearance:.1f} m < {need:.1f} m needed", v_long, blocker_role=role)
        worst = worst or f"gaps in lane {target_lane} ok"
    return GapCheck(True, worst or f"lane {target_lane} clear", None, room)


def leader_room_m(ego_s: float, ego_len: float, lane: int, others: list[Track], frame: RoadFrame,
                  cfg: DdmConfig) -> float | None:
    """How far the AV may still travel in ``lane`` before it must stand behind the nearest vehicle ahead
    there, should that vehicle brake now at the comfort deceleration: min over leaders of clearance +
    v_l^2 / (2 comfort) - gap_min (the room of ``gap_check(stopping=True)``, also when it is short or
    negative). None: nobody ahead in that lane."""
    rooms = [_room_behind_m(clearance, v_long, cfg)
             for _, ds, clearance, v_long in _lane_neighbours(ego_s, ego_len, others, frame, lane) if ds >= 0]
    return min(rooms) if rooms else None


def decide(ego: Ego, evs: list[Track], others: list[Track], frame: RoadFrame, cfg: DdmConfig,
           response: Response, now: float | None = None) -> Decision:
    """One vehicle's EV response (see module docstring). ``others``: tracks near the AV (any kind).
    ``now``: with it, a yielding AV resumes only after no EV has been near for ``resume_hold_s``."""
    s_arr, d_arr = frame.to_frenet(ego.x_m, ego.y_m)
    s_e, d_e = float(s_arr[0]), float(d_arr[0])
    h_err = _wrap(ego.heading_rad - float(frame.heading_at(s_e)))
    v_e = ego.speed_mps * math.cos(h_err)
    lane_e = int(frame.lane_of(d_e))
    lane_e = 0 if lane_e < 0 and d_e < 0 else lane_e  # on the shoulder: treat as lane 0
    base = dict(ego_s_m=s_e, ego_d_m=d_e, ego_heading_error_rad=h_err, ego_speed_mps=ego.speed_mps)
    # never yield to itself: its own track, or an 'EV' where the AV is (an RSU track that switched cars)
    evs = [e for e in evs if (ego.track_id is None or e.track_id != ego.track_id)
           and math.hypot(e.x_m - ego.x_m, e.y_m - ego.y_m) >= SELF_RADIUS_M]
    ev_ids = {e.track_id for e in evs}
    exclude = ev_ids | ({ego.track_id} if ego.track_id is not None else set())
    # tracks that are the AV itself but not bound (pose within a car length and a half width)
    near_self = {o.track_id for o in others if math.hypot(o.x_m - ego.x_m, o.y_m - ego.y_m) < SELF_RADIUS_M}
    traffic = [o for o in others if o.track_id not in exclude and o.track_id not in near_self]
    threats, ahead = assess_evs(s_e, v_e, ego.length_m, evs, frame, cfg)
    urgent = [t for t in threats if t.triggered]

    def describe(t: Threat) -> str:
        lane = "?" if t.lane is None else str(t.lane)
        return (f"EV track {t.track_id} {t.gap_m:.0f} m behind in lane {lane}, {t.speed_mps:.1f} m/s, "
                f"closing {t.closing_mps:.1f} m/s, time to pass {_fmt_t(t.time_to_pass_s)} s")

    def pull_over_gap(t: Threat) -> tuple[bool, str]:
        lc = lane_change_length(frame.lane_centre_offset(0) - d_e, max(v_e, 2.0), 0.0, cfg)
        t_change = lc / max(v_e, 2.0)
        # a held-speed pull-over (issue 18) does not slow during the change and stops after it, a lane
        # change and a comfort stop ahead: a follower has that much room to stop behind it
        if cfg.pull_over_hold_speed:
            av_stop = lc + v_e * v_e / (2.0 * cfg.comfort_decel_mps2)
            return gap_check(s_e, v_e, v_e, ego.length_m, 0, traffic, frame, t_change, cfg, stopping=True,
                             av_stop_m=av_stop)
        v_after = max(0.0, v_e - cfg.comfort_decel_mps2 * t_change)
        return gap_check(s_e, v_e, v_after, ego.length_m, 0, traffic, frame, t_change, cfg, stopping=True)

    passing = {tid: dist for tid, dist in ahead.items() if dist < cfg.pass_margin_m}
    base["ev_near"] = bool(threats or passing)
    if urgent:
        t = urgent[0]
        common = dict(base, ev_track_id=t.track_id, time_to_pass_s=t.time_to_pass_s, ev_gap_m=t.gap_m,
                      ev_s_m=t.s_m, ev_speed_mps=t.speed_mps)
        if response.phase == "yielding":
            if (response.manoeuvre == Manoeuvre.SLOW_IN_LANE and lane_e > 0 and t.time_to_pass_s >= cfg.too_late_s
                    and t.lane != 0):  # slowed for a gap, too late, or an EV in lane 0 that has left it
                gap = pull_over_gap(t)
                ok, why = gap
                if ok:
                    return Decision(Manoeuvre.PULL_OVER, f"gap opened ({why}); pull over to lane 0: {describe(t)}",
                                    target_lane=0, stop_within_m=gap.room_ahead_m, **common)
            if (response.manoeuvre == Manoeuvre.PULL_OVER and response.stop_s_m is not None
                    and v_e > cfg.replan_min_speed_mps):
                room = leader_room_m(s_e, ego.length_m, 0, traffic, frame, cfg)
                if room is not None and s_e + room < response.stop_s_m - cfg.replan_shorter_m:
                    return Decision(Manoeuvre.PULL_OVER, f"vehicle ahead in lane 0: stop within {max(room, 0.0):.0f} m "
                                    f"instead of {response.stop_s_m - s_e:.0f} m: {describe(t)}", target_lane=0,
                                    stop_within_m=max(room, 0.1), **common)
            return Decision("hold", f"keep {response.manoeuvre.value if response.manoeuvre else 'manoeuvre'}: "
                            f"{describe(t)}", target_lane=response.target_lane, **common)
        if lane_e <= 0:
            ahead = gap_check(s_e, v_e, v_e, ego.length_m, 0, traffic, frame, 0.0, cfg, stopping=True)
            return Decision(Manoeuvre.PULL_OVER, f"in lane 0, stop at the curb: {describe(t)}", target_lane=0,
                            stop_within_m=ahead.room_ahead_m, **common)
        if t.time_to_pass_s < cfg.too_late_s:
            return Decision(Manoeuvre.SLOW_IN_LANE, f"too late to change lane (< {cfg.too_late_s:.0f} s): "
                            f"{describe(t)}", target_lane=lane_e, slow_because="too_late", **common)
        if t.lane == 0:
            left = lane_e + 1
            if left < frame.lanes:
                lc = lane_change_length(frame.lane_width_m, max(v_e, 2.0), 0.0, cfg)
                t_change = lc / max(v_e, 2.0)
                ok, why = gap_check(s_e, v_e, v_e, ego.length_m, left, traffic, frame, t_change, cfg)
                if ok:
                    return Decision(Manoeuvre.LANE_CHANGE, f"EV drives in lane 0, move left to lane {left} "
                                    f"({why}): {describe(t)}", target_lane=left, **common)
            return Decision(Manoeuvre.SLOW_IN_LANE, f"EV drives in lane 0, no safe lane to the left: "
                            f"{describe(t)}", target_lane=lane_e, slow_because="ev_in_lane0", **common)
        gap = pull_over_gap(t)
        ok, why = gap
        if ok:
            return Decision(Manoeuvre.PULL_OVER, f"pull over to lane 0 ({why}): {describe(t)}", target_lane=0,
                            stop_within_m=gap.room_ahead_m, **common)
        if gap.blocker_speed_mps is not None and gap.blocker_speed_mps < v_e - cfg.min_closing_mps:
            # slowing would keep the AV beside a slower car (and in the EV's way): drive on past it
            return Decision("none", f"{why}; keep speed past the slower vehicle, then pull over: {describe(t)}",
                            **common)
        if cfg.let_faster_pass and gap.blocker_speed_mps is not None and (
                gap.blocker_speed_mps > v_e + cfg.min_closing_mps or gap.blocker_role == "follower"):
            # issue 18 (e2e seed 6): slowing in the EV's lane for a car in lane 0 brings the EV onto the AV
            # sooner; a faster car is by soon, a follower at the AV's speed or slower (drivers slow for an
            # EV) drops back: keep speed, then pull over
            what = "the faster vehicle in lane 0 pass" if gap.blocker_speed_mps > v_e + cfg.min_closing_mps \
                else "the vehicle behind in lane 0 pass or drop back"
            return Decision("none", f"{why}; keep speed: let {what}, then pull over: {describe(t)}", **common)
        return Decision(Manoeuvre.SLOW_IN_LANE, f"{why}; slow in lane {lane_e}: {describe(t)}",
                        target_lane=lane_e, slow_because="gap", **common)

    if response.phase == "yielding":
        # still passing: an EV (the one we yield to, or one with a new track id after a track switch)
        # is behind (not triggering any more) or less than the margin ahead
        for tid in sorted(passing):
            return Decision("hold", f"EV track {tid} passing, {passing[tid]:.0f} m ahead "
                            f"(< {cfg.pass_margin_m:.0f} m)", ev_track_id=tid, **base)
        if threats:
            t = threats[0]
            return Decision("hold", f"EV track {t.track_id} still behind", ev_track_id=t.track_id,
                            ev_s_m=t.s_m, ev_speed_mps=t.speed_mps, **base)
        still_seen = any(o.track_id in response.cause_ids for o in others)  # seen, not an EV any more
        if now is not None and response.ev_last is not None and not still_seen:
            # the EV we yield to is out of sight (an RSU died, tracks switched): it drives on at its
            # last speed; hold until it must be pass_margin_m ahead (within ev_predict_s)
            s_ev, v_ev, t_ev = response.ev_last
            age = now - t_ev
            ahead_m = s_ev + max(v_ev, cfg.min_ev_speed_mps) * age - s_e
            if age <= cfg.ev_predict_s and ahead_m < cfg.pass_margin_m:
                return Decision("hold", f"EV out of sight for {age:.1f} s, predicted {ahead_m:+.0f} m from the AV "
                                f"(resume once {cfg.pass_margin_m:.0f} m ahead)", **base)
        if now is not None and now - response.ev_near_s < cfg.resume_hold_s:
            return Decision("hold", f"no EV near for {now - response.ev_near_s:.1f} s "
                            f"(resume after {cfg.resume_hold_s:.1f} s)", **base)
        target = max(lane_e, 0)
        if abs(d_e - frame.lane_centre_offset(target)) > 0.5 * frame.lane_width_m:
            lc = lane_change_length(frame.lane_centre_offset(target) - d_e, 6.0, 0.0, cfg)
            ok, why = gap_check(s_e, v_e, v_e, ego.length_m, target, traffic, frame, lc / 6.0, cfg)
            if not ok:
                return Decision("hold", f"waiting to resume: {why}", target_lane=target, **base)
        gone = [tid for tid in sorted(response.cause_ids) if tid not in ev_ids]
        passed = [f"{tid} ({ahead[tid]:.0f} m ahead)" for tid in sorted(response.cause_ids) if tid in ahead]
        why = []
        if passed:
            why.append(f"EV track {', '.join(passed)} passed")
        if gone:
            why.append(f"EV track {', '.join(map(str, gone))} cleared or lost")
        return Decision(Manoeuvre.RESUME, "resume: " + ("; ".join(why) or "no EV to yield to"),
                        target_lane=target, **base)

    if threats:
        t = threats[0]
        return Decision("none", f"EV track {t.track_id} behind but not imminent (time to pass "
                        f"{_fmt_t(t.time_to_pass_s)} s, {t.gap_m:.0f} m)", **base)
    if ahead:
        return Decision("none", "EV ahead: nothing to do", **base)
    return Decision("none", "no EV approaching from behind", **base)


def plan(decision: Decision, frame: RoadFrame, cfg: DdmConfig, vehicle_width_m: float,
         cruise_speed_mps: float) -> PlannedPath:
    """The commanded path for a decision that carries a manoeuvre."""
    m = decision.manoeuvre
    s0, d0, h, v = decision.ego_s_m, decision.ego_d_m, decision.ego_heading_error_rad, decision.ego_speed_mps
    if m == Manoeuvre.PULL_OVER:
        d_stop = stop_offset_m(frame, vehicle_width_m, frame.road.shoulder_width_m, cfg)
        # when the EV arrives: a just-lit EV is still accelerating, so assume it closes at least at
        # ev_closing_assumed_mps (pessimistic), whatever its closing speed now
        ttp = decision.time_to_pass_s
        if decision.ev_gap_m is not None:
            ttp_assumed = decision.ev_gap_m / cfg.ev_closing_assumed_mps
            ttp = ttp_assumed if ttp is None or not math.isfinite(ttp) else min(ttp, ttp_assumed)
        within_s = ttp - cfg.stop_margin_s if ttp is not None and math.isfinite(ttp) else None
        if cfg.pull_over_hold_speed:
            held = plan_stop_holding_speed(frame, s0, d0, h, v, d_stop, cfg, stop_within_s=within_s,
                                           max_stop_dist_m=decision.stop_within_m)
            if held is not None:
                return held
        return plan_stop(frame, s0, d0, h, v, d_stop, cfg, stop_within_s=within_s,
                         max_stop_dist_m=decision.stop_within_m)
    lane = decision.target_lane if decision.target_lane is not None else max(int(frame.lane_of(d0)), 0)
    centre = frame.lane_centre_offset(lane)
    if m == Manoeuvre.SLOW_IN_LANE:
        return plan_keep_lane_slow(frame, s0, d0, h, v, centre, cfg.slow_speed_mps, cfg)
    if m == Manoeuvre.LANE_CHANGE:
        return plan_lane_change(frame, s0, d0, h, v, centre, min(v, cruise_speed_mps), cfg)
    if m == Manoeuvre.RESUME:
        return plan_resume(frame, s0, d0, h, v, centre, cruise_speed_mps, cfg)
    raise ValueError(f"no plan for decision action {decision.action!r}")
