"""SUMO drives the world: snapshots, the EV's bluelight, the AV written into SUMO, one clock, one simulation."""

from __future__ import annotations

from dataclasses import replace

import pytest

from sim.scenario import DistractorSpec, TrafficSpec, load_scenario
from sim.world import World

pytestmark = pytest.mark.usefixtures("need_sumo")


def _empty_road(sc):
    """Only the scripted actors: no background traffic, no flows."""
    return replace(sc, traffic=replace(TrafficSpec(), density_veh_per_km_lane=0.0, flow_veh_per_h=0.0,
                                       speed_mps=0.0), traffic_model="sumo")


def test_rellis_on_sumo_snapshots_every_vehicle_and_the_ev_lights_on_time():
    sc = load_scenario("rellis_ev_yield").with_overrides(traffic="sumo")
    world = World(sc)
    try:
        import libsumo

        kinds_seen, lit = set(), {}
        while world.t_s < 6.0 - 1e-9:
            world.step(0.05)
            assert libsumo.simulation.getTime() == pytest.approx(world.t_s)  # one clock
            snap = world.snapshot()
            kinds_seen |= {a.kind.value for a in snap.actors}
            ev = next(a for a in snap.actors if a.kind.value == "ev")
            lit[round(world.t_s, 2)] = ev.light_bar.on
        assert {"av", "ev", "car"} <= kinds_seen
        assert not any(on for t, on in lit.items() if t < 4.0) and all(on for t, on in lit.items() if t >= 4.05)
        road = sc.corridor.road
        for a in snap.actors:  # every vehicle on the corridor's lanes, heading along it
            s, d = road.to_frenet(a.pos_x_m, a.pos_y_m)
            assert -0.5 < d < road.width_m + 0.5 and abs(a.heading_rad) < 0.3
            assert a.length_m > 0 and a.width_m > 0 and a.height_m > 0
        assert libsumo.vehicle.getVehicleClass("ev1") == "emergency"
        assert float(libsumo.vehicle.getParameter("ev1", "device.bluelight.reactiondist")) > 0
    finally:
        world.close()


def test_the_av_written_into_sumo_makes_sumo_drivers_react():
    """The AV stands still in lane 1 (its pose from outside every step); the SUMO car coming up behind it in that
    lane goes round it through lane 0, never through it."""
    base = _empty_road(load_scenario("rellis_ev_yield"))
    sc = replace(base, ev=None, distractors=(DistractorSpec("red_car", 110.0, 1, 12.0),))
    world = World(sc)
    try:
        import libsumo

        road = sc.corridor.road
        av_s = sc.av.start_s_m
        x, y, h = road.pose_at(av_s, road.lane_centre_offset_m(1))
        lanes_beside = set()
        while world.t_s < 12.0 - 1e-9:
            world.traffic.set_external_pose("av1", x, y, h, 0.0)  # the AV stands still
            world.step(0.05)
            car = next(v for v in world.vehicles() if v.vehicle_id == "d0")
            if abs(car.s_m - av_s) < (car.length_m + 4.9) / 2:  # alongside the AV
                lanes_beside.add(road.lane_of_offset(car.d_m))
                assert car.d_m + car.width_m / 2 < road.lane_width_m + 0.05  # not into the AV's lane
        assert lanes_beside == {0} and car.s_m > av_s  # it went round
        fx, fy = libsumo.vehicle.getPosition("av1")  # SUMO has the AV where the vehicle process put it (front bumper)
        assert fx == pytest.approx(x + 4.9 / 2, abs=0.05) and fy == pytest.approx(y, abs=0.05)
        assert libsumo.vehicle.getSpeed("av1") == pytest.approx(0.0, abs=1e-6)
    finally:
        world.close()


def test_one_simulation_per_process_and_one_clock():
    from sim.sumo.traffic import SumoTraffic

    sc = _empty_road(load_scenario("rellis_ev_yield"))
    first = World(sc)
    first.step(0.05)
    with pytest.raises(ValueError, match="one clock"):
        first.step(0.1)
    second = SumoTraffic(sc, 3)  # closes the first: libsumo runs one simulation per process
    try:
        with pytest.raises(RuntimeError, match="one simulation per process"):
            first.step(0.05)
        second.step(0.05, 0.0)
        assert {v.vehicle_id for v in second.vehicles()} >= {"av1", "ev1"}
    finally:
        second.close()
        first.close()


def test_debris_stops_in_its_lane_and_sumo_drivers_go_round_it():
    sc = load_scenario("hazard_in_lane").with_overrides(traffic="sumo")
    world = World(sc)
    try:
        while world.t_s < 3.0 - 1e-9:
            world.step(0.05)
        debris = [v for v in world.vehicles() if v.kind == "debris"]
        assert debris and all(v.speed_mps == 0.0 for v in debris)
        want = {f"hz{k}": sc.corridor.road.pose_at(h.s_m, sc.corridor.road.lane_centre_offset_m(h.lane) + h.offset_m)
                for k, h in enumerate(sc.hazards) if h.appear_s == 0.0}
        for v in debris:
            if v.vehicle_id in want:
                assert (v.x_m, v.y_m) == pytest.approx(want[v.vehicle_id][:2], abs=1e-6)
    finally:
        world.close()


def test_the_scenarios_yielding_drivers_move_right_and_slow_for_the_ev_on_sumo():
    sc = load_scenario("rellis_ev_yield").with_overrides(traffic="sumo")
    world = World(sc)
    try:
        road = sc.corridor.road
        s = sc.av.start_s_m
        while world.t_s < 9.0 - 1e-9:  # the AV keeps lane 1 at 13.4 m/s; the EV's lights come on at 4 s
            x, y, h = road.pose_at(s, road.lane_centre_offset_m(1))
            world.traffic.set_external_pose("av1", x, y, h, 13.4)
            world.step(0.05)
            s += 13.4 * 0.05
        ev = next(v for v in world.vehicles() if v.kind == "ev")
        near = [v for v in world.vehicles() if v.yields_to_ev and ev.s_m < v.s_m < ev.s_m + 60.0]
        assert near, "no yielding driver ahead of the EV to look at"
        for v in near:  # in lane 0, well below their own speed
            assert v.lane == 0 and v.speed_mps < 0.8 * v.desired_speed_mps, (v.vehicle_id, v.lane, v.speed_mps)
    finally:
        world.close()


def test_the_simulator_takes_the_vehicle_process_av_on_sumo_from_the_first_step():
    """The simulator service knows the AV at t = 0 (it accepts its state) and the snapshots carry the AV where the
    vehicle process says it is, not where SUMO would have driven it."""
    from protocol.clock import SimClock
    from protocol.enums import VehicleMode
    from protocol.local_bus import LocalBus
    from protocol.messages import VehicleState
    from sim.service import SimService

    sc = load_scenario("rellis_ev_yield").with_overrides(traffic="sumo")
    clock = SimClock(0.0)
    svc = SimService(sc, LocalBus(), clock)
    try:
        road = sc.corridor.road
        for k in range(40):  # the AV drifts into lane 0 and slows: what a pull-over looks like
            d = road.lane_centre_offset_m(1) - 0.09 * k
            x, y, h = road.pose_at(sc.av.start_s_m + 0.5 * k, d)
            svc.set_av_state(VehicleState(src="veh", stamp=clock.now(), vehicle_id="av1", pos_x_m=x, pos_y_m=y,
                                          lat_deg=0.0, lon_deg=0.0, heading_rad=h, speed_mps=10.0 - 0.2 * k,
                                          mode=VehicleMode.MANOEUVRE))
            svc.step_once()
            clock.advance(0.05)
            av = next(a for a in svc.last_snapshot.actors if a.kind.value == "av")
            assert (av.pos_x_m, av.pos_y_m) == pytest.approx((x, y), abs=1e-6)
        assert not svc.rejected and svc.av_updates == 40
        assert av.lane == 0 and av.speed_mps == pytest.approx(10.0 - 0.2 * 39)
    finally:
        svc.close()


def test_an_ev_that_leaves_the_road_is_gone_from_the_world():
    sc = _empty_road(load_scenario("rellis_ev_yield"))
    sc = replace(sc, av=None, traffic=replace(sc.traffic, flow_veh_per_h=1800.0, speed_mps=12.0))
    world = World(sc)
    try:
        while world.t_s < 40.0 - 1e-9:  # the EV (19 m/s from s = 0) leaves the 500 m road while the flow comes in
            world.step(0.05)
        kinds = {v.kind for v in world.vehicles()}
        assert "ev" not in kinds and "car" in kinds
    finally:
        world.close()
