"""EV response policy, pure: which manoeuvre for which EV situation, with its reason."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from ddm_rig import lane_y

from ddm.config import DdmConfig
from ddm.geometry import RoadFrame
from ddm.intent import Ego, Response
from ddm.manoeuvre import gap_check
from ddm.policy.ev import decide, plan
from ddm.tracks import Track
from protocol.corridor import load_corridor
from protocol.enums import Manoeuvre, ObjectType

CFG = DdmConfig()
FRAME = RoadFrame(load_corridor().road)


def trk(tid: int, x: float, lane: int, vx: float, *, ev: bool = False, y: float | None = None) -> Track:
    return Track(tid, x, lane_y(lane) if y is None else y, vx, 0.0, 4.8, 1.9,
                 ObjectType.EV if ev else ObjectType.VEHICLE, ev, None, lane, None, 10, 0.0, 0.0, 0.1)


def ego(x: float = 100.0, lane: int = 1, v: float = 13.4, y: float | None = None) -> Ego:
    return Ego("av1", x, lane_y(lane) if y is None else y, 0.0, v, track_id=1)


def test_ev_behind_same_lane_pull_over_with_carma_time_to_pass():
    ev = trk(2, 50.0, 1, 20.0, ev=True)
    d = decide(ego(), [ev], [ev], FRAME, CFG, Response())
    assert d.action == Manoeuvre.PULL_OVER and d.target_lane == 0
    assert d.time_to_pass_s == pytest.approx(50.0 / 6.6, rel=1e-3)  # (s_ego - s_ev) / (v_ev - v_ego)
    assert "50 m behind in lane 1" in d.reason and "time to pass 7.6 s" in d.reason


def test_not_imminent_far_ev_is_no_action_but_close_slow_ev_is():
    far = trk(2, -90.0, 1, 14.0, ev=True)  # 190 m behind, closing 0.6 m/s
    assert decide(ego(), [far], [], FRAME, CFG, Response()).action == "none"
    close = trk(3, 70.0, 1, 13.4, ev=True)  # 30 m behind, not closing: still 'immediate approach'
    assert decide(ego(), [close], [], FRAME, CFG, Response()).action == Manoeuvre.PULL_OVER


def test_too_late_to_change_lane_slows_in_lane():
    ev = trk(2, 80.0, 1, 20.0, ev=True)  # 20 m behind closing 6.6 m/s: 3 s
    d = decide(ego(), [ev], [], FRAME, CFG, Response())
    assert d.action == Manoeuvre.SLOW_IN_LANE and "too late" in d.reason and d.target_lane == 1
    p = plan(d, FRAME, CFG, 1.9, 13.4)
    assert p.target_speed_mps == pytest.approx(CFG.slow_speed_mps)


def test_av_in_lane_0_stops_at_the_curb():
    ev = trk(2, 60.0, 0, 20.0, ev=True)
    d = decide(ego(lane=0), [ev], [], FRAME, CFG, Response())
    assert d.action == Manoeuvre.PULL_OVER and "in lane 0" in d.reason


def test_ev_driving_in_lane_0_makes_av_move_left_not_into_its_path():
    road3 = load_corridor().road
    from dataclasses import replace

    frame3 = RoadFrame(replace(road3, lanes=3))
    ev = trk(2, 50.0, 0, 20.0, ev=True)
    d = decide(ego(lane=1), [ev], [ev], frame3, CFG, Response())
    assert d.action == Manoeuvre.LANE_CHANGE and d.target_lane == 2
    # two lanes only: nowhere to go left, slow in lane
    d2 = decide(ego(lane=1), [ev], [ev], FRAME, CFG, Response())
    assert d2.action == Manoeuvre.SLOW_IN_LANE and "lane 0" in d2.reason


def test_ev_joining_lane_0_from_the_right_is_not_pulled_in_front_of():
    """An EV right of lane 0 (on the shoulder, or an on-ramp joining lane 0) has lane 0 for its path: the AV in
    the leftmost lane does not cross into it (motorway_ev_ramp on SUMO: the pull-over into lane 0 blocked the EV
    that merged behind it), and while slowed it does not pull over there across the EV's path."""
    frame3 = RoadFrame(replace(load_corridor().road, lanes=3))
    ev = trk(2, 40.0, 0, 28.0, ev=True, y=-1.5)  # 60 m behind, 1.5 m right of lane 0's edge
    d = decide(ego(lane=2, v=18.0), [ev], [ev], frame3, CFG, Response())
    assert d.action == Manoeuvre.SLOW_IN_LANE and d.target_lane == 2 and "lane ?" in d.reason
    slowed = Response(phase="yielding", manoeuvre=Manoeuvre.SLOW_IN_LANE, target_lane=2)
    assert decide(ego(lane=2, v=4.5), [ev], [ev], frame3, CFG, slowed).action == "hold"
    # merged and moving left to pass, in the middle lane: the slowed AV does not cross its path to lane 0
    ev1 = trk(2, -20.0, 1, 28.0, ev=True)  # 120 m behind: 5.1 s to pass
    assert decide(ego(lane=2, v=4.5), [ev1], [ev1], frame3, CFG, slowed).action == "hold"
    # in the AV's own lane: pull over once lane 0 has a gap
    ev2 = trk(2, -20.0, 2, 28.0, ev=True)
    assert decide(ego(lane=2, v=4.5), [ev2], [ev2], frame3, CFG, slowed).action == Manoeuvre.PULL_OVER
    # from the middle lane: one lane left, away from it
    assert decide(ego(lane=1, v=18.0), [ev], [ev], frame3, CFG, Response()).target_lane == 2
    # an EV left of the last lane is not on lane 0's path: the usual pull-over
    far_left = trk(3, 40.0, 2, 28.0, ev=True, y=3 * 3.7 + 0.8)
    assert decide(ego(lane=1, v=18.0), [far_left], [far_left], frame3, CFG, Response()).target_lane == 0


def test_gap_check_leader_and_follower():
    s_me = float(FRAME.to_frenet(100.0, lane_y(1))[0][0])  # the AV at x = 100 m
    ok, why = gap_check(s_me, 13.4, 8.0, 4.9, 0, [trk(5, 160.0, 0, 13.4)], FRAME, 4.0, CFG)
    assert ok
    ok, why = gap_check(s_me, 13.4, 8.0, 4.9, 0, [trk(5, 108.0, 0, 13.4)], FRAME, 4.0, CFG)
    assert not ok and "leader track 5" in why
    ok, why = gap_check(s_me, 13.4, 8.0, 4.9, 0, [trk(5, 80.0, 0, 13.4)], FRAME, 4.0, CFG)
    assert not ok and "follower track 5" in why  # 20 m behind, but the AV slows to 8 m/s while changing
    ok, _ = gap_check(s_me, 13.4, 8.0, 4.9, 0, [trk(5, 100.0, 1, 13.4)], FRAME, 4.0, CFG)
    assert ok  # a car in the other lane does not matter


def test_yielding_holds_then_resumes_after_pass_margin():
    resp = Response()
    ev = trk(2, 50.0, 1, 20.0, ev=True)
    d = decide(ego(), [ev], [ev], FRAME, CFG, resp)
    resp.commit(d, 0.0)
    stopped = ego(x=150.0, y=-1.25, v=0.0)
    assert decide(stopped, [trk(2, 120.0, 1, 20.0, ev=True)], [], FRAME, CFG, resp).action == "hold"
    assert decide(stopped, [trk(2, 170.0, 1, 20.0, ev=True)], [], FRAME, CFG, resp).action == "hold"  # 20 m ahead
    r = decide(stopped, [trk(2, 185.0, 1, 20.0, ev=True)], [], FRAME, CFG, resp)
    assert r.action == Manoeuvre.RESUME and r.target_lane == 0 and "35 m ahead" in r.reason
    # merging back from the shoulder waits for a gap in lane 0
    blocker = trk(9, 147.0, 0, 13.4)
    w = decide(stopped, [trk(2, 185.0, 1, 20.0, ev=True)], [blocker], FRAME, CFG, resp)
    assert w.action == "hold" and "waiting to resume" in w.reason


def test_reason_is_carried_by_every_decision():
    for evs in ([], [trk(2, 150.0, 1, 20.0, ev=True)], [trk(2, 50.0, 1, -20.0, ev=True)]):
        d = decide(ego(), evs, [], FRAME, CFG, Response())
        assert d.action == "none" and d.reason
    assert math.isfinite(CFG.act_time_to_pass_s)


def test_slower_car_beside_in_lane_0_keeps_speed_faster_one_is_let_by():
    ev = trk(2, 60.0, 1, 18.0, ev=True)  # 40 m behind
    slow = trk(3, 100.0, 0, 5.0)  # a yielding car beside the AV in lane 0
    d = decide(ego(), [ev], [ev, slow], FRAME, CFG, Response())
    assert d.action == "none" and "keep speed past the slower vehicle" in d.reason
    fast = trk(4, 96.0, 0, 22.0)  # a faster car coming up beside: keep speed and let it pass
    d = decide(ego(), [ev], [ev, fast], FRAME, CFG, Response())
    assert d.action == "none" and "let the faster vehicle in lane 0 pass" in d.reason
    # with let_faster_pass off: slow in the EV's lane for the gap
    d = decide(ego(), [ev], [ev, fast], FRAME, replace(CFG, let_faster_pass=False), Response())
    assert d.action == Manoeuvre.SLOW_IN_LANE and d.slow_because == "gap"


def test_pull_over_stops_behind_a_car_stopping_ahead_in_lane_0():
    ev = trk(2, 60.0, 1, 18.0, ev=True)
    leader = trk(3, 150.0, 0, 4.0)  # 45 m ahead, slowing to yield
    d = decide(ego(), [ev], [ev, leader], FRAME, CFG, Response())
    assert d.action == Manoeuvre.PULL_OVER and d.stop_within_m is not None
    p = plan(d, FRAME, CFG, 1.9, 13.4)
    # stopped behind where the leader would stop braking comfortably, with the minimum gap
    assert p.stop_distance_m <= d.stop_within_m + 1e-6
    too_close = trk(3, 112.0, 0, 0.0)  # stopped 7 m ahead: no room to stop behind it at 13.4 m/s
    d = decide(ego(), [ev], [ev, too_close], FRAME, CFG, Response())
    assert d.action != Manoeuvre.PULL_OVER and "no room to stop" in d.reason


def test_a_pull_over_is_shortened_for_a_car_seen_in_lane_0_after_the_command():
    """The RSUs may see a slow car ahead in lane 0 only after the pull-over was commanded (it was beyond
    their range): the committed stop must not run into it (the AV has no car following of its own)."""
    ev = trk(2, 50.0, 1, 19.0, ev=True)
    resp = Response()
    d = decide(ego(), [ev], [ev], FRAME, CFG, resp)  # lane 0 empty: the comfort stop, ~45 m on
    assert d.action == Manoeuvre.PULL_OVER and d.stop_within_m is None
    p = plan(d, FRAME, CFG, 1.9, 13.4)
    resp.commit(d, 0.0)
    resp.note_stop(d, p.stop_distance_m)
    assert resp.stop_s_m == pytest.approx(d.ego_s_m + p.stop_distance_m)  # no room limit: the stop itself
    # 1 s later: still nothing ahead, or a car far enough ahead: keep the command
    moving = ego(x=113.0, y=lane_y(1) - 0.8, v=11.4)
    ev1 = trk(2, 69.0, 1, 19.0, ev=True)
    assert decide(moving, [ev1], [ev1], FRAME, CFG, resp).action == "hold"
    far = trk(7, 200.0, 0, 10.0)
    assert decide(moving, [ev1], [ev1, far], FRAME, CFG, resp).action == "hold"
    # a car yielding at 4.4 m/s, 20 m ahead in lane 0 (the demo's collision): stop shorter, behind it
    slow = trk(7, 129.2, 0, 4.4)  # 24.8 m ahead of the AV when the command was issued, unseen then
    r = decide(moving, [ev1], [ev1, slow], FRAME, CFG, resp)
    assert r.action == Manoeuvre.PULL_OVER and "vehicle ahead in lane 0" in r.reason
    p2 = plan(r, FRAME, CFG, 1.9, 11.4)
    s_move = r.ego_s_m
    assert s_move + p2.stop_distance_m < resp.stop_s_m - CFG.replan_shorter_m
    # the shortest stop the lane change allows; the AV on the new profile never reaches the slow car
    # (driving on at 4.4 m/s), where the old profile closed to within 1 m of it
    def min_clearance(path, v_leader: float, gap0: float) -> float:
        xy = np.asarray(path.waypoints)
        ds = np.hypot(*np.diff(xy, axis=0).T)
        v = np.asarray(path.speeds_mps)
        v_mid = np.maximum((v[:-1] + v[1:]) / 2.0, 0.05)
        t = np.concatenate([[0.0], np.cumsum(np.where(v[1:] > 0, ds / v_mid, np.inf))])
        s_av = np.concatenate([[0.0], np.cumsum(ds)])
        ok = np.isfinite(t)
        return float(np.min(gap0 + v_leader * t[ok] - s_av[ok])) - 4.8

    assert min_clearance(p, 4.4, 24.8) < 0.5 and min_clearance(p2, 4.4, 16.2) > 2.0
    resp.commit(r, 1.0)
    resp.note_stop(r, p2.stop_distance_m)
    assert decide(moving, [ev1], [ev1, slow], FRAME, CFG, resp).action == "hold"  # re-planned once, not every cycle


def test_an_ev_lost_from_view_is_predicted_before_resuming():
    resp = Response()
    ev = trk(2, 70.0, 1, 15.0, ev=True)
    d = decide(ego(v=0.0, lane=0), [ev], [ev], FRAME, CFG, resp, now=10.0)
    resp.commit(d, 10.0)
    resp.ev_last = (d.ev_s_m, d.ev_speed_mps, 10.0)
    # the EV's track is gone (its RSU died): 30 m behind at 15 m/s -> ahead by 30 m after 4 s
    held = decide(ego(v=0.0, lane=0), [], [], FRAME, CFG, resp, now=12.0)
    assert held.action == "hold" and "out of sight" in held.reason
    later = decide(ego(v=0.0, lane=0), [], [], FRAME, CFG, resp, now=14.5)
    assert later.action == Manoeuvre.RESUME


def test_an_ev_at_the_avs_own_position_is_the_av_itself():
    ghost = trk(9, 100.5, 1, 13.4, ev=True)  # an RSU track that switched onto the AV
    assert decide(ego(), [ghost], [ghost], FRAME, CFG, Response()).action == "none"


def test_gap_check_counts_a_stale_track_as_possibly_closer():
    """A track last seen 2.5 s ago may have braked since: its gap is judged 0.5 a t^2 = 6.25 m shorter."""
    from ddm.manoeuvre import staleness_margin_m

    s_me = float(FRAME.to_frenet(100.0, lane_y(1))[0][0])
    xs = np.arange(100.0, 200.0, 0.25)
    first_ok = next(x for x in xs if gap_check(s_me, 13.4, 8.0, 4.9, 0, [trk(5, x, 0, 13.4)], FRAME, 4.0, CFG)[0])
    stale = replace(trk(5, first_ok, 0, 13.4), age_s=2.5)
    assert staleness_margin_m(2.5) == pytest.approx(6.25) and staleness_margin_m(0.1) < 0.011
    assert not gap_check(s_me, 13.4, 8.0, 4.9, 0, [stale], FRAME, 4.0, CFG)[0]
    assert gap_check(s_me, 13.4, 8.0, 4.9, 0, [replace(stale, x_m=first_ok + 6.5)], FRAME, 4.0, CFG)[0]
