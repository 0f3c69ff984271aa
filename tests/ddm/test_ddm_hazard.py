"""Hazard fusion and hazard policy of the DDM (pure), and the DdmService hook (lockstep, LocalBus)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from ddm_rig import lane_y

from ddm.config import DdmConfig, HazardConfig
from ddm.geometry import RoadFrame
from ddm.hazard_fusion import HazardFusion
from ddm.intent import Ego, Response
from ddm.picture import Hazard
from ddm.policy.hazard import assess_hazards, decide_hazard, path_clearance
from ddm.tracks import Track
from protocol.corridor import load_corridor
from protocol.enums import Manoeuvre, ObjectType
from protocol.messages import HazardAlert

CORRIDOR = load_corridor()
FRAME = RoadFrame(CORRIDOR.road)
DCFG = DdmConfig()
HCFG = HazardConfig()
CRUISE = 13.4


def alert(aid: str, x: float, y: float, state: str = "persist", conf: float = 0.5, rsu: str = "rsu3",
          length: float = 1.0, width: float = 0.8) -> HazardAlert:
    lat, lon = CORRIDOR.to_latlon(x, y)
    return HazardAlert(src=rsu, stamp=0.0, hazard_id=aid, state=state, rsu_id=rsu, pos_x_m=x, pos_y_m=y,
                       lat_deg=lat, lon_deg=lon, lane=None, length_m=length, width_m=width, confidence=conf,
                       first_seen=0.0)


def hz(hid: int, x: float, lane: int, y_off: float = 0.0, length: float = 1.2, width: float = 0.9) -> Hazard:
    return Hazard(hid, x, lane_y(lane) + y_off, length, width, lane, 0.5, 0.0, 0.0)


def trk(tid: int, x: float, lane: int, vx: float) -> Track:
    return Track(tid, x, lane_y(lane), vx, 0.0, 4.8, 1.9, ObjectType.VEHICLE, False, None, lane, None, 10, 0.0, 0.0,
                 0.1)


def ego(x: float = 100.0, lane: int = 1, v: float = 13.4) -> Ego:
    return Ego("av1", x, lane_y(lane), 0.0, v, track_id=1)


def decide(e, hazards, others=(), resp=None):
    return decide_hazard(e, hazards, list(others), FRAME, DCFG, HCFG, resp or Response(), CRUISE)


# ------------------------------------------------------------------------------------------------ fusion
def test_book_fuses_rsus_and_follows_the_life_cycle():
    book = HazardFusion(FRAME)
    a = book.ingest(alert("rsu2-hz-1", 119.0, 5.3, "appear", conf=0.25, rsu="rsu2"), 1.0)
    b = book.ingest(alert("rsu3-hz-4", 120.0, 5.6, "appear", conf=0.75), 1.1)
    assert a.hazard_id == b.hazard_id and len(book.records()) == 1
    h = book.records()[0]
    assert h.x_m == pytest.approx(0.25 * 119.0 + 0.75 * 120.0) and h.lane == 1   # confidence-weighted
    far = book.ingest(alert("rsu3-hz-5", 135.0, 1.6, "appear"), 1.2)           # another object: its own hazard
    assert far.hazard_id != h.hazard_id and far.lane == 0
    book.ingest(alert("rsu2-hz-1", 119.0, 5.3, "clear", rsu="rsu2"), 2.0)     # one RSU clears: still seen by rsu3
    assert h.hazard_id in book.hazards and set(book.hazards[h.hazard_id].sources) == {"rsu3-hz-4"}
    book.ingest(alert("rsu3-hz-4", 120.0, 5.6, "clear"), 2.1)
    assert h.hazard_id not in book.hazards
    book.ingest(alert("rsu3-hz-5", 135.0, 1.6), 3.0)
    book.maintain(3.0 + HCFG.source_timeout_s + 0.1)                          # no refresh: expires
    assert book.records() == ()
    assert [e[0] for e in book.drain()] == ["appeared", "appeared", "cleared", "expired"]


# ------------------------------------------------------------------------------------------------ policy
def test_far_hazard_is_no_action_until_the_threat_exceeds_the_threshold():
    h = hz(1, 170.0, 1)  # front bumper 102.45, near edge 169.4: lx 67 m > lx_max
    d = decide(ego(), [h])
    assert d.action == "none" and d.threat == 0.0
    d = decide(ego(x=115.0), [h])  # lx 51.95: T_f = sqrt((8.05/60)^2 + 1) / sqrt 2
    assert d.action == Manoeuvre.LANE_CHANGE
    assert d.threat == pytest.approx(math.sqrt((8.05 / 60) ** 2 + 1) / math.sqrt(2), abs=1e-6)


def test_blocking_hazard_lane_change_to_the_free_lane_with_clearance():
    h = hz(1, 150.0, 1)
    d = decide(ego(), [h])
    assert d.action == Manoeuvre.LANE_CHANGE and d.target_lane == 0 and d.hazard_id == 1
    t = assess_hazards(d.ego_s_m, d.ego_d_m, 4.9, 1.9, FRAME.lane_centre_offset(1), [h], FRAME, HCFG)[0]
    assert t.blocks and path_clearance(d.path, FRAME, 4.9, 1.9, t) >= HCFG.min_clearance_m + HCFG.position_margin_m
    assert "lane 0" in d.reason and "T_f" in d.reason


def test_hazard_in_the_other_lane_or_under_the_av_is_ignored():
    assert decide(ego(), [hz(1, 150.0, 0)]).action == "none"         # beside the path: 2.3 m clearance > 1.3 m
    assert decide(ego(), [hz(1, 100.5, 1)]).action == "none"         # under the car: the RSU sees the AV itself
    assert decide(ego(), [hz(1, 80.0, 1)]).action == "none"          # behind


def test_no_gap_in_the_neighbouring_lane_stops_before_the_hazard():
    h = hz(1, 150.0, 1)
    beside = trk(7, 100.0, 0, 13.0)  # a car alongside in lane 0
    d = decide(ego(), [h], [beside])
    assert d.action == Manoeuvre.STOP_IN_LANE and "unsafe gap in lane 0" in d.reason
    front_stop = d.stop_s_m + 4.9 / 2
    near_edge = FRAME.to_frenet(150.0, 0.0)[0][0] - 0.6
    assert front_stop == pytest.approx(near_edge - HCFG.stop_gap_m)
    v = np.array(d.path.speeds_mps)
    assert v[0] == pytest.approx(13.4, abs=0.1) and v[-1] == 0.0 and np.all(np.diff(v) <= 1e-9)
    assert d.path.decel_mps2 <= HCFG.max_stop_decel_mps2


def test_both_lanes_blocked_stops():
    d = decide(ego(lane=0), [hz(1, 150.0, 0), hz(2, 152.0, 1)])
    assert d.action == Manoeuvre.STOP_IN_LANE and "blocked by hazard 2" in d.reason


def test_stopping_then_gap_opens_then_hazard_cleared():
    h = hz(1, 150.0, 1)
    resp = Response()
    d = decide(ego(), [h], [trk(7, 100.0, 0, 13.0)], resp)
    resp.commit(d, 0.0)
    assert resp.phase == "stopping"
    stopped = ego(x=150.0 - 0.6 - HCFG.stop_gap_m - 2.45, v=0.0)
    assert decide(stopped, [h], [trk(7, 110.0, 0, 13.0)], resp).action == "hold"  # still no gap
    d = decide(stopped, [h], [], resp)  # lane 0 empty now
    assert d.action == Manoeuvre.LANE_CHANGE and d.target_lane == 0
    d = decide(stopped, [], [trk(7, 110.0, 0, 13.0)], resp)  # the hazard was cleared while waiting
    assert d.action == Manoeuvre.RESUME and "cleared" in d.reason


def test_avoiding_holds_until_passed_then_resumes():
    h = hz(1, 150.0, 1)
    resp = Response()
    resp.commit(decide(ego(), [h]), 0.0)
    assert resp.phase == "avoiding" and resp.cause_ids == {1}
    assert decide(ego(x=140.0, lane=0), [h], [], resp).action == "hold"
    d = decide(ego(x=160.0, lane=0), [h], [], resp)  # rear bumper 157.55 > far edge 150.6 + 5
    assert d.action == Manoeuvre.RESUME and d.target_lane == 0 and "passed" in d.reason


def test_config_validation():
    with pytest.raises(ValueError):
        HazardConfig(threat_threshold=1.5)
    with pytest.raises(ValueError):
        HazardConfig(min_clearance_m=0.0)


# ------------------------------------------------------------------------------------------------ service
def _rig_with_hazard(x_hz: float, lane_hz: int, *, beside: bool = False):
    from ddm_rig import Rig

    from protocol.keys import rsu_key

    rig = Rig()
    rig.add("av1", 40.0, 1, 13.4)
    if beside:
        rig.add("car", 112.0, 0, 0.0)  # stopped in lane 0 beside the hazard (a queue): no gap there
    state = {"on": True, "n": 0}

    def publish_hazard():
        if not state["on"]:
            return
        state["n"] += 1
        if state["n"] % 10 == 1:  # 1 Hz at the rig's 10 Hz
            rig.bus.publish(rsu_key(rig.c, "rsu3", "hazard"),
                            alert("rsu3-hz-1", x_hz, lane_y(lane_hz), "appear" if state["n"] == 1 else "persist",
                                  length=1.2, width=0.9).model_copy(update={"stamp": rig.clock.now()}))

    rig.hooks.append(publish_hazard)
    return rig, state


def test_service_lane_change_around_a_hazard_then_resume_with_clearance():
    rig, _ = _rig_with_hazard(120.0, 1)
    clearances = []
    for _ in range(90):  # 9 s: the AV drives from x = 40 m past the hazard
        rig.run(0.1)
        av = rig.cars["av1"]
        if abs(av.x - 120.0) < (4.9 + 1.2) / 2:
            clearances.append(abs(av.y - lane_y(1)) - (1.9 + 0.9) / 2)
    assert rig.manoeuvres()[:2] == ["lane_change", "resume"]
    assert rig.svc.counters["hazard_alerts"] >= 5 and len(rig.svc.world.hazards.hazards) == 1
    assert clearances and min(clearances) >= HCFG.min_clearance_m
    assert rig.cars["av1"].x > 130.0
    first = next(c for c in rig.commands if c.manoeuvre == Manoeuvre.LANE_CHANGE)
    assert first.target_lane == 0 and "hazard" in first.reason


def test_service_stops_before_a_hazard_without_a_gap_and_resumes_when_cleared():
    rig, state = _rig_with_hazard(120.0, 1, beside=True)
    rig.run(10.0)
    assert rig.manoeuvres()[0] == "stop_in_lane"
    av = rig.cars["av1"]
    assert av.vx == 0.0 and 120.0 - 0.6 - av.x - 2.45 >= HCFG.stop_gap_m - 0.5  # stopped before it
    state["on"] = False
    rig.bus.publish(rsu_key_of(rig), alert("rsu3-hz-1", 120.0, lane_y(1), "clear").model_copy(
        update={"stamp": rig.clock.now()}))
    rig.run(1.0)
    assert rig.manoeuvres()[-1] == "resume"


def rsu_key_of(rig):
    from protocol.keys import rsu_key

    return rsu_key(rig.c, "rsu3", "hazard")


def test_service_rejects_a_hazard_alert_from_the_wrong_rsu_key():
    from ddm_rig import Rig

    rig = Rig()
    rig.bus.publish(rsu_key_of(rig), alert("rsu2-hz-1", 120.0, 5.5, "appear", rsu="rsu2"))
    assert rig.svc.rejected["rsu_mismatch"] == 1 and not rig.svc.world.hazards.hazards


def test_a_second_hazard_beside_the_first_does_not_repeat_the_lane_change():
    box, rock = hz(1, 150.0, 1), hz(2, 153.7, 1, y_off=0.6, length=0.6, width=0.5)
    resp = Response()
    d = decide(ego(), [box, rock])
    assert d.action == Manoeuvre.LANE_CHANGE and d.target_lane == 0
    resp.commit(d, 0.0)
    assert decide(ego(x=110.0, lane=1), [box, rock], [], resp).action == "hold"  # still changing lanes
    assert decide(ego(x=163.0, lane=0), [box, rock], [], resp).action == Manoeuvre.RESUME
