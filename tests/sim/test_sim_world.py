"""World, traffic and scenarios: determinism, EV behaviour, driver reactions, hazards, validation."""

import math

import numpy as np
import pytest

from protocol.codec import decode, encode
from protocol.enums import VehicleMode
from protocol.messages import VehicleState, WorldSnapshot
from sim.scenario import ScenarioError, list_scenarios, load_scenario, parse_scenario
from sim.traffic import IdmTraffic, TrafficModel, idm_accel
from sim.world import World

REQUIRED = {"rellis_ev_yield", "ev_two_lanes_dense", "hazard_in_lane", "ev_lights_never_on", "night_ev"}


def test_required_scenarios_load():
    assert REQUIRED <= set(list_scenarios())
    for name in REQUIRED:
        sc = load_scenario(name)
        assert sc.name == name and sc.corridor.corridor_id == "rellis"
    assert load_scenario("night_ev").lighting == "night"
    assert load_scenario("ev_lights_never_on").ev.lights_on_at_s is None


def test_rellis_ev_yield_matches_the_thesis_test():
    sc = load_scenario("rellis_ev_yield")
    assert sc.av.vehicle_id == "av1" and sc.av.lane == 1 and sc.av.speed_mps == pytest.approx(13.4)
    assert sc.ev.start_offset_m == pytest.approx(-50.0) and sc.ev.lane == 1 and sc.ev.speed_mps > 13.4
    assert sc.ev.lights_on_at_s > 0 and 1.0 <= sc.ev.frequency_hz <= 4.0


@pytest.mark.parametrize("data, field", [
    ({"scenario": {"name": "x", "lighting": "noon"}}, "scenario.lighting"),
    ({"scenario": {"name": "x", "duration_s": -1}}, "scenario.duration_s"),
    ({"scenario": {"name": "x"}, "ev": {"frequency_hz": 9.0}}, "ev.frequency_hz"),
    ({"scenario": {"name": "x"}, "ev": {"pattern": "rotating"}}, "ev.pattern"),
    ({"scenario": {"name": "x"}, "av": {"lane": 5}}, "av.lane"),
    ({"scenario": {"name": "x"}, "hazard": [{"lane": 0}]}, "hazard[0].s_m"),
    ({"scenario": {"name": "x"}, "distractor": [{"kind": "ufo", "s_m": 10, "lane": 0}]}, "distractor[0].kind"),
    ({"scenario": {"name": "x", "corridor": "nowhere"}}, "scenario.corridor"),
    ({"scenario": {"name": "x"}, "trafic": {}}, "trafic"),
    ({"scenario": {"name": "x"}, "traffic": {"density_veh_per_km_lane": "lots"}}, "traffic.density_veh_per_km_lane"),
])
def test_bad_scenarios_fail_with_the_field_named(data, field):
    with pytest.raises(ScenarioError, match=field.replace("[", r"\[").replace("]", r"\]")):
        parse_scenario(data, "bad.toml")


def _trace(sc, seed, t_end=12.0):
    w = World(sc, seed=seed)
    out = []
    while w.t_s < t_end - 1e-9:
        w.step(0.05)
        out.append([(v.vehicle_id, v.s_m, v.d_m, v.speed_mps) for v in w.vehicles()])
    return w, out


def test_world_is_deterministic_per_seed():
    sc = load_scenario("ev_two_lanes_dense")
    _, a = _trace(sc, 3, 6.0)
    _, b = _trace(sc, 3, 6.0)
    _, c = _trace(sc, 4, 6.0)
    assert a == b and a != c


def test_world_time_and_snapshot_round_trip():
    w = World(load_scenario("rellis_ev_yield"))
    for _ in range(200):
        w.step(0.05)
    assert w.t_s == pytest.approx(10.0, abs=1e-12)
    snap = w.snapshot(stamp=123.0)
    back = decode(encode(snap), WorldSnapshot)
    assert back.sim_time_s == pytest.approx(10.0) and back.scenario == "rellis_ev_yield"
    kinds = {a.kind.value for a in back.actors}
    assert {"av", "ev"} <= kinds


def test_ev_lights_switch_on_at_the_scripted_time_and_ev_is_faster():
    sc = load_scenario("rellis_ev_yield")
    w = World(sc)
    w.run_until(sc.ev.lights_on_at_s - 0.1)
    ev = next(a for a in w.snapshot().actors if a.kind.value == "ev")
    assert ev.light_bar is not None and not ev.light_bar.on
    w.run_until(sc.ev.lights_on_at_s + 0.1)
    ev = next(a for a in w.snapshot().actors if a.kind.value == "ev")
    assert ev.light_bar.on and ev.light_bar.pattern == "alternating"
    w.run_until(12.0)
    snap = w.snapshot()
    ev = next(a for a in snap.actors if a.kind.value == "ev")
    av = next(a for a in snap.actors if a.actor_id == "av1")
    assert ev.speed_mps > av.speed_mps - 0.5 or ev.pos_x_m > av.pos_x_m


def test_some_drivers_yield_to_the_ev_and_some_do_not():
    sc = load_scenario("ev_two_lanes_dense")
    w = World(sc)
    bg = [v for v in w.vehicles() if v.vehicle_id.startswith("v")]
    n_yield = sum(v.yields_to_ev for v in bg)
    assert 0 < n_yield < len(bg)
    ever_yielded: set[str] = set()
    moved_right: set[str] = set()
    start_d = {v.vehicle_id: v.d_m for v in bg}
    while w.t_s < 25.0:
        w.step(0.05)
        for v in bg:
            if v.yielding:
                ever_yielded.add(v.vehicle_id)
                if v.d_m < start_d[v.vehicle_id] - 1.0 or v.d_m < sc.corridor.road.lane_width_m / 2 - 0.3:
                    moved_right.add(v.vehicle_id)
    assert ever_yielded and all(next(v for v in bg if v.vehicle_id == i).yields_to_ev for i in ever_yielded)
    assert moved_right  # yielding drivers end up at the right edge of the rightmost lane


def test_no_collisions_and_traffic_avoids_debris():
    sc = load_scenario("hazard_in_lane")
    w = World(sc)
    road = sc.corridor.road
    hz = [v for v in w.vehicles() if v.kind == "debris"]
    assert hz
    passed_in_other_lane = 0
    while w.t_s < 30.0:
        w.step(0.05)
        vs = [v for v in w.vehicles()]
        for i, a in enumerate(vs):
            for b in vs[i + 1:]:
                if abs(a.d_m - b.d_m) < (a.width_m + b.width_m) / 2 - 0.2:
                    assert abs(a.s_m - b.s_m) > (a.length_m + b.length_m) / 2 - 0.3, (a.vehicle_id, b.vehicle_id)
        for v in vs:
            if v.kind == "car" and abs(v.s_m - hz[0].s_m) < 1.0 and road.lane_of_offset(v.d_m) == 0:
                passed_in_other_lane += 1
    assert passed_in_other_lane > 0


def test_idm_free_road_and_approach():
    v = np.array([10.0, 10.0])
    a = idm_accel(v, np.array([15.0, 15.0]), np.array([np.inf, 5.0]), np.array([0.0, 10.0]), np.array([1.4, 1.4]),
                  np.array([1.4, 1.4]))
    assert a[0] > 0 and a[1] < -3.0


def test_av_pose_comes_from_the_vehicle_process():
    w = World(load_scenario("rellis_ev_yield"))
    st = VehicleState(src="vehicle", stamp=1.0, vehicle_id="av1", pos_x_m=70.0, pos_y_m=1.2, lat_deg=30.6,
                      lon_deg=-96.4, heading_rad=0.05, speed_mps=4.0, mode=VehicleMode.MANOEUVRE)
    w.set_av_pose(st)
    w.step(0.05)
    av = next(a for a in w.snapshot().actors if a.actor_id == "av1")
    assert (av.pos_x_m, av.pos_y_m, av.heading_rad, av.speed_mps) == pytest.approx((70.0, 1.2, 0.05, 4.0))
    assert av.lane == 0
    with pytest.raises(KeyError):
        w.set_av_pose(VehicleState(**{**st.model_dump(), "vehicle_id": "nobody"}))


def test_traffic_model_interface_is_pluggable():
    assert isinstance(IdmTraffic.step, type(TrafficModel.step))

    class Frozen:
        def __init__(self, vs):
            self._vs = vs

        def step(self, dt_s, t_s):
            pass

        def vehicles(self):
            return self._vs

        def set_external_pose(self, *a):
            pass

    base = World(load_scenario("rellis_ev_yield"))
    w = World(load_scenario("rellis_ev_yield"), traffic=Frozen(base.vehicles()))
    x0 = [a.pos_x_m for a in w.snapshot().actors]
    w.step(0.05)
    assert [a.pos_x_m for a in w.snapshot().actors] == x0 and math.isclose(w.t_s, 0.05)
