"""The larger scenario's corridor: a SUMO network with an on-ramp, eight RSUs, its road the network's."""

from __future__ import annotations

import pytest

from protocol.corridor import load_corridor
from sim.scenario import load_scenario
from sim.sumo.samples import MAIN_ROUTE, RAMP_ROUTE


def test_motorway_scenario_is_the_larger_one_the_straight_road_cannot_express():
    sc = load_scenario("motorway_ev_ramp")
    road = sc.corridor.road
    assert sc.traffic_model == "sumo" and road.length_m >= 3000.0 and road.lanes >= 2
    assert len(sc.corridor.rsus) >= 8 and all(len(r.calibration) > 50 for r in sc.corridor.rsus)
    assert sc.traffic.flow_veh_per_h >= 1500.0 and sc.traffic.side_flow_route == RAMP_ROUTE
    assert sc.ev.sumo_route[0] == "ramp" and sc.ev.lights_on_at_s == 0.0  # the EV comes from the side road


@pytest.mark.usefixtures("need_sumo")
def test_the_shipped_corridor_is_its_networks_road():
    from sim.sumo.corridor import sumo_section
    from sim.sumo.network import read_net

    corridor = load_corridor(load_scenario("motorway_ev_ramp").corridor.source)
    section = sumo_section(corridor)  # raises when the road drifted from the network
    assert section.route == MAIN_ROUTE and section.net.name == "motorway_ramp.net.xml"
    net = read_net(section.net)
    assert {e.getID() for e in net.getEdge("ramp").getOutgoing()} == {"main_b"}
    assert section.edge_at_s(section.edge_starts_m[1] + 10.0) == ("main_b", pytest.approx(10.0))
