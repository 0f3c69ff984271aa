"""e2e seed 7: passing a slower car in lane 0, the AV pulls over as soon as the gap it leaves is safe.

The AV keeps its speed 7-9 s past a car 3.5 m/s slower (no room to stop behind it); waiting then for the full
minimum gap ahead of it before moving over lets the EV reach the AV 0.30 s before it leaves the lane. A slower
follower drops back during the lane change: it needs the minimum gap only when the AV's body enters its lane.
"""

from __future__ import annotations

from ddm_rig import lane_y

from ddm.config import DdmConfig
from ddm.geometry import RoadFrame
from ddm.intent import Ego, Response
from ddm.manoeuvre import ENTER_FRACTION, MIN_START_GAP_M, gap_check
from ddm.policy.ev import decide
from ddm.tracks import Track
from protocol.corridor import load_corridor
from protocol.enums import Manoeuvre, ObjectType

CFG = DdmConfig()
FRAME = RoadFrame(load_corridor().road)


def trk(tid: int, x: float, lane: int, vx: float, *, ev: bool = False) -> Track:
    return Track(tid, x, lane_y(lane), vx, 0.0, 4.8, 1.9, ObjectType.EV if ev else ObjectType.VEHICLE, ev, None, lane,
                 None, 10, 0.0, 0.0, 0.1)


EGO = Ego("av1", 100.0, lane_y(1), 0.0, 13.4, track_id=1)


def test_seed7_pulls_over_in_front_of_the_slower_car_it_has_just_passed():
    ev = trk(2, 71.0, 1, 16.8, ev=True)  # 29 m behind, closing 3.4 m/s (seed 7, 8.7 s time to pass)
    passed = trk(3, 100.0 - 4.8 - 4.0, 0, 9.9)  # 4.0 m behind the AV's rear, 3.5 m/s slower
    d = decide(EGO, [ev], [ev, passed], FRAME, CFG, Response())
    assert d.action == Manoeuvre.PULL_OVER and d.target_lane == 0, d.reason
    same_speed = trk(3, 100.0 - 4.8 - 4.0, 0, 13.4)  # one that keeps up needs the full gap now
    d = decide(EGO, [ev], [ev, same_speed], FRAME, CFG, Response())
    assert d.action != Manoeuvre.PULL_OVER and "unsafe gap in lane 0: follower" in d.reason


def test_a_slower_follower_needs_the_minimum_gap_only_when_the_av_enters_its_lane():
    t_change = 2.5
    ego_s = float(FRAME.to_frenet(100.0, lane_y(1))[0][0])
    grows = 3.5 * ENTER_FRACTION * t_change  # 2.6 m
    for clearance, v_f, ok in ((CFG.gap_min_m - grows + 0.2, 9.9, True),  # slower: the gap grows in time
                               (CFG.gap_min_m - grows - 0.2, 9.9, False),
                               (CFG.gap_min_m - 0.2, 13.4, False),  # at the AV's speed: the full gap now
                               (MIN_START_GAP_M - 0.2, 1.0, False)):  # never closer, however slow
        follower = trk(5, 100.0 - 4.8 - clearance, 0, v_f)
        g = gap_check(ego_s, 13.4, 13.4, 4.8, 0, [follower], FRAME, t_change, CFG, stopping=True, av_stop_m=80.0)
        assert g[0] is ok, (clearance, v_f, g[1])
