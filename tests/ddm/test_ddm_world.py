"""World model: fusion across RSUs, handover, duplicates, time alignment, EV marking, stale RSUs."""

from __future__ import annotations

import numpy as np
import pytest
from ddm_rig import det, lane_y, object_list

from ddm.config import DdmConfig
from ddm.world import CorridorWorld
from protocol.corridor import load_corridor
from protocol.enums import AlertState, VehicleMode
from protocol.messages import EvAlert, VehicleState

COR = load_corridor()


def drive(world: CorridorWorld, cover: dict[str, tuple[float, float]], cars: dict[str, tuple[float, float, float]],
          t0: float, seconds: float, dt: float = 0.1, ids: dict | None = None, offsets: dict | None = None):
    """Move cars (x, y, vx) and feed each RSU's list; returns the set of track ids per car per step."""
    ids = {} if ids is None else ids
    offsets = offsets or {}
    seen: dict[str, list[set[int]]] = {n: [] for n in cars}
    t = t0
    for step in range(int(round(seconds / dt))):
        t += dt
        cars = {n: (x + vx * dt, y, vx) for n, (x, y, vx) in cars.items()}
        for rsu, (lo, hi) in cover.items():
            objs = []
            for n, (x, y, vx) in cars.items():
                if lo <= x <= hi:
                    oid = ids.setdefault((rsu, n), 1000 + len(ids))
                    ox, oy = offsets.get(rsu, (0.0, 0.0))
                    objs.append(det(COR, oid, x + ox, y + oy, vx))
            world.ingest_objects(object_list(rsu, step, t, objs), t)
        world.maintain(t)
        for n, (x, y, _) in cars.items():
            near = [tr.track_id for tr in world.tracks(t) if abs(tr.x_m - x) < 3 and abs(tr.y_m - y) < 1.5]
            seen[n].append(set(near))
    return seen, cars, t


def test_handover_between_overlapping_rsus_keeps_one_global_id():
    w = CorridorWorld(DdmConfig())
    cover = {"rsu1": (-60, 60), "rsu2": (40, 160)}
    ids: dict = {}
    seen, cars, t = drive(w, cover, {"a": (0.0, lane_y(1), 13.4)}, 0.0, 3.5, ids=ids)
    assert w.tracks(t)[0].rsus == ("rsu1", "rsu2")  # in the overlap: one track fed by both
    seen2, _, t = drive(w, cover, cars, t, 4.5, ids=ids)
    ids_seen = set().union(*seen["a"], *seen2["a"])
    assert ids_seen == {1}, f"car got tracks {ids_seen}"
    assert all(len(s) == 1 for s in seen["a"] + seen2["a"])  # one track at every step, also in the overlap
    assert w.track_count == 1
    assert w.tracks(t)[0].rsus == ("rsu2",)  # rsu1 lost it 3 s ago: its binding is forgotten


def test_handover_across_a_gap_between_fields_of_view_keeps_id():
    w = CorridorWorld(DdmConfig())
    # 60..70 m is seen by no RSU: 0.75 s of coasting on the constant-velocity prediction
    seen, _, _ = drive(w, {"rsu1": (-60, 60), "rsu2": (70, 160)}, {"a": (20.0, lane_y(0), 13.4)}, 0.0, 6.0)
    assert set().union(*seen["a"]) == {1}


def test_duplicate_seen_by_two_rsus_is_one_track_but_neighbours_stay_apart():
    w = CorridorWorld(DdmConfig())
    cars = {"a": (60.0, lane_y(0), 10.0), "b": (60.0, lane_y(1), 10.0), "c": (68.0, lane_y(0), 10.0)}
    # rsu2's calibration is off by (0.6, -0.4) m: the same cars, slightly elsewhere
    seen, _, t = drive(w, {"rsu1": (-60, 120), "rsu2": (40, 160)}, cars, 0.0, 2.0, offsets={"rsu2": (0.6, -0.4)})
    assert w.track_count == 3
    for n in cars:
        assert len(set().union(*seen[n])) == 1
    assert all(len(tr.rsus) == 2 for tr in w.tracks(t))


def test_opposite_direction_cars_passing_do_not_swap_ids():
    w = CorridorWorld(DdmConfig())
    cars = {"east": (0.0, lane_y(0), 12.0), "west": (60.0, lane_y(0) + 1.0, -12.0)}
    _, _, t = drive(w, {"rsu1": (-60, 120)}, cars, 0.0, 5.0)  # they meet at t = 2.5 s
    a, b = w.tracks(t)
    assert w.stats.new_tracks == 2
    assert a.vx_mps > 11 and b.vx_mps < -11  # track 1 is still the eastbound car
    assert abs(a.x_m - 60.0) < 0.5 and abs(b.x_m - 0.0) < 0.5


def test_out_of_order_list_is_time_aligned():
    w = CorridorWorld(DdmConfig())
    y = lane_y(1)
    w.ingest_objects(object_list("rsu1", 1, 10.0, [det(COR, 1, 100.0, y, 10.0)]), 10.0)
    w.ingest_objects(object_list("rsu1", 2, 10.2, [det(COR, 1, 102.0, y, 10.0)]), 10.2)
    # rsu2's older frame (captured at 10.1 s) arrives late: it must join the track and not pull it back
    w.ingest_objects(object_list("rsu2", 1, 10.1, [det(COR, 7, 101.0, y, 10.0)]), 10.25)
    [tr] = w.tracks(10.2)
    assert abs(tr.x_m - 102.0) < 0.3
    assert tr.rsus == ("rsu1", "rsu2")


def test_too_old_lists_are_dropped():
    w = CorridorWorld(DdmConfig())
    n = w.ingest_objects(object_list("rsu1", 1, 10.0, [det(COR, 1, 100.0, 2.0, 10.0)]), 12.0)
    assert n == 0 and w.track_count == 0 and w.stats.dropped_old == 1


def test_filter_converges_on_noisy_measurements():
    w = CorridorWorld(DdmConfig())
    rng = np.random.default_rng(1)
    for k in range(50):
        t = k * 0.1
        x = 10.0 + 15.0 * t
        w.ingest_objects(object_list("rsu1", k, t, [det(COR, 1, x + rng.normal(0, 0.5), 2.0 + rng.normal(0, 0.5),
                                                         15.0 + rng.normal(0, 1.0))]), t)
    [tr] = w.tracks(4.9)
    assert abs(tr.x_m - (10 + 15 * 4.9)) < 0.6 and abs(tr.vx_mps - 15.0) < 0.8


def test_ev_alert_marks_track_and_clear_unmarks_it():
    w = CorridorWorld(DdmConfig())
    w.ingest_objects(object_list("rsu1", 1, 1.0, [det(COR, 5, 30.0, lane_y(1), 20.0, ev=False)]), 1.0)
    lat, lon = COR.to_latlon(30.0, lane_y(1))

    def alert(state, t):
        return EvAlert(src="rsu1", stamp=t, alert_id="a1", state=state, rsu_id="rsu1", object_id=5, pos_x_m=30.0,
                       pos_y_m=lane_y(1), lat_deg=lat, lon_deg=lon, vel_x_mps=20.0, confidence=0.9, first_seen=t)

    tid = w.ingest_ev_alert(alert(AlertState.ACTIVE, 1.0), 1.0)
    assert [t.track_id for t in w.snapshot(1.0).evs] == [tid] and w.snapshot(1.0).track(tid).ev_alert_id == "a1"
    w.ingest_ev_alert(alert(AlertState.CLEARED, 1.5), 1.5)
    assert w.snapshot(1.5).evs == ()
    # an alert alone (object never reported) starts an EV track; not refreshed, it is forgotten
    w2 = CorridorWorld(DdmConfig())
    w2.ingest_ev_alert(alert(AlertState.ACTIVE, 1.0), 1.0)
    assert len(w2.snapshot(1.0).evs) == 1
    assert w2.snapshot(1.0 + DdmConfig().ev_alert_timeout_s + 0.1).evs == ()


def test_object_level_ev_state_alone_marks_no_track():
    """An object list's (unsigned) EV state never makes an EV on its own; ev_from_objects_alone lets it (to
    measure the cost)."""
    w = CorridorWorld(DdmConfig())
    w.ingest_objects(object_list("rsu1", 1, 1.0, [det(COR, 5, 30.0, lane_y(1), 20.0, ev=True)]), 1.0)
    assert w.snapshot(1.0).evs == ()
    old = CorridorWorld(DdmConfig(ev_from_objects_alone=True))
    old.ingest_objects(object_list("rsu1", 1, 1.0, [det(COR, 5, 30.0, lane_y(1), 20.0, ev=True)]), 1.0)
    assert len(old.snapshot(1.0).evs) == 1


def test_object_level_ev_state_holds_the_mark_of_a_track_an_alert_named():
    cfg = DdmConfig()
    w = CorridorWorld(cfg)
    w.ingest_objects(object_list("rsu1", 1, 1.0, [det(COR, 5, 30.0, lane_y(1), 20.0, ev=True)]), 1.0)
    lat, lon = COR.to_latlon(30.0, lane_y(1))
    tid = w.ingest_ev_alert(EvAlert(src="rsu1", stamp=1.0, alert_id="rsu1-ev-5", state=AlertState.ACTIVE,
                                    rsu_id="rsu1", object_id=5, pos_x_m=30.0, pos_y_m=lane_y(1), lat_deg=lat,
                                    lon_deg=lon, vel_x_mps=20.0, speed_mps=20.0, confidence=0.9, first_seen=1.0), 1.0)
    assert [t.track_id for t in w.snapshot(1.0).evs] == [tid]
    # after the alert has timed out, the object lists' EV state keeps the named track an EV
    t = 1.0 + cfg.ev_alert_timeout_s + 0.1
    w.ingest_objects(object_list("rsu1", 2, t, [det(COR, 5, 30.0 + 20.0 * (t - 1.0), lane_y(1), 20.0, ev=True)]), t)
    assert [x.track_id for x in w.snapshot(t).evs] == [tid]


def test_vehicle_state_is_bound_to_its_track():
    w = CorridorWorld(DdmConfig())
    w.ingest_objects(object_list("rsu1", 1, 1.0, [det(COR, 5, 30.0, lane_y(1), 13.0),
                                                  det(COR, 6, 50.0, lane_y(1), 13.0)]), 1.0)
    lat, lon = COR.to_latlon(30.5, lane_y(1))
    vs = VehicleState(src="av1", stamp=1.0, vehicle_id="av1", pos_x_m=30.5, pos_y_m=lane_y(1), lat_deg=lat,
                      lon_deg=lon, heading_rad=0.0, speed_mps=13.0, mode=VehicleMode.DRIVING)
    tid = w.ingest_vehicle_state(vs, 1.0)
    assert w.snapshot(1.0).track(tid).vehicle_id == "av1" and abs(w.snapshot(1.0).track(tid).x_m - 30.0) < 0.1



def test_an_av_state_that_arrives_late_is_carried_forward_to_now():
    """On a lossy link a state arrives seconds after it was measured: the picture puts the car where it is now
    (a path planned from where it was would start behind it), at most EGO_PREDICTION_MAX_S ahead."""
    from ddm.world import EGO_PREDICTION_MAX_S

    w = CorridorWorld(DdmConfig())
    lat, lon = COR.to_latlon(30.0, lane_y(1))
    vs = VehicleState(src="av1", stamp=10.0, vehicle_id="av1", pos_x_m=30.0, pos_y_m=lane_y(1), lat_deg=lat,
                      lon_deg=lon, heading_rad=0.0, speed_mps=15.0, mode=VehicleMode.DRIVING)
    w.ingest_vehicle_state(vs, 11.5)  # measured at 10.0, heard at 11.5
    ego = w.snapshot(12.0).vehicles[0]
    assert ego.x_m == pytest.approx(30.0 + 15.0 * 2.0) and ego.y_m == pytest.approx(lane_y(1))
    assert ego.received_s == 11.5
    assert w.snapshot(20.0).vehicles[0].x_m == pytest.approx(30.0 + 15.0 * EGO_PREDICTION_MAX_S)
    assert w.snapshot(9.0).vehicles[0].x_m == pytest.approx(30.0)  # a clock behind the car's: not moved back

def test_stale_rsu_detection():
    w = CorridorWorld(DdmConfig(), rsu_ids=("rsu1", "rsu2"))
    w.ingest_objects(object_list("rsu1", 1, 1.0, []), 1.0)
    w.ingest_objects(object_list("rsu2", 1, 1.0, []), 1.0)
    assert w.stale_rsus(1.2) == []
    w.ingest_objects(object_list("rsu1", 2, 1.25, []), 1.25)
    assert w.stale_rsus(1.35) == ["rsu2"]


def test_tracks_time_out_and_slots_are_reused_without_id_reuse():
    w = CorridorWorld(DdmConfig(), capacity=2)
    for k in range(5):
        t = float(k * 3)
        w.ingest_objects(object_list("rsu1", k, t, [det(COR, k, 10.0 * k, 2.0, 10.0),
                                                    det(COR, 100 + k, 10.0 * k, 6.0, 10.0)]), t)
        w.maintain(t + 2.0)
    assert w.track_count == 0 and w.stats.new_tracks == 10


def test_the_track_store_grows_and_keeps_every_track():
    """7 objects into room for 2: the columns double to 8 slots and every track keeps its state."""
    w = CorridorWorld(DdmConfig(), capacity=2)
    w.ingest_objects(object_list("rsu1", 0, 1.0, [det(COR, k, 5.0 * k, lane_y(k % 2), 10.0 + k) for k in range(7)]),
                     1.0)
    tracks = w.tracks(1.0)
    assert w.sizes()["track_slots"] == 8 and [t.track_id for t in tracks] == list(range(1, 8))
    assert [round(t.x_m, 6) for t in tracks] == [5.0 * k for k in range(7)]
    assert [round(t.vx_mps, 6) for t in tracks] == [10.0 + k for k in range(7)]
    assert all(t.rsus == ("rsu1",) for t in tracks)
