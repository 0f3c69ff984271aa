"""The SUMO backend's pure parts: frames and signals, road <-> network geometry, the route file, the scenario keys.
None of these needs SUMO installed."""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET

import numpy as np
import pytest

from protocol.road import Road, Segment
from sim.scenario import ScenarioError, load_scenario
from sim.sumo import TRAFFIC_MODELS, check_traffic_model, convert, demand
from sim.sumo.corridor import SumoSection, parse_rsu, rsu_on_road
from sim.sumo.network import offset_polyline, plain_xml, road_deviation_m, road_of_polyline
from sim.vehicles import SimVehicle


@pytest.mark.parametrize("angle_deg, heading_rad", [(0.0, math.pi / 2), (90.0, 0.0), (180.0, -math.pi / 2),
                                                    (270.0, math.pi), (45.0, math.pi / 4)])
def test_sumo_angle_is_clockwise_from_north(angle_deg, heading_rad):
    assert math.isclose(math.cos(convert.heading_rad_of_angle(angle_deg)), math.cos(heading_rad), abs_tol=1e-12)
    assert math.isclose(math.sin(convert.heading_rad_of_angle(angle_deg)), math.sin(heading_rad), abs_tol=1e-12)
    assert math.isclose(convert.angle_deg_of_heading(convert.heading_rad_of_angle(angle_deg)), angle_deg % 360.0,
                        abs_tol=1e-9)


def test_position_is_the_front_bumper_and_round_trips():
    # a 5 m car heading east with its front bumper at x = 10: its centre is at x = 7.5
    x, y = convert.centre_of_front(10.0, 2.0, 0.0, 5.0)
    assert (x, y) == pytest.approx((7.5, 2.0))
    h = 0.7
    fx, fy = convert.front_of_centre(3.0, -1.0, h, 4.4)
    assert convert.centre_of_front(fx, fy, h, 4.4) == pytest.approx((3.0, -1.0))


def test_pose_of_a_sumo_state():
    p = convert.pose_of(convert.SumoState(100.0, 5.0, 90.0, 12.0, convert.SIGNAL_BRAKELIGHT), 4.0)
    assert (p.x_m, p.y_m, p.heading_rad, p.speed_mps) == pytest.approx((98.0, 5.0, 0.0, 12.0))
    assert p.brake_on and p.lamp_mode == ""
    assert convert.pose_of(convert.SumoState(0, 0, 90.0, -0.1, 0), 4.0).speed_mps == 0.0  # reversing noise


@pytest.mark.parametrize("signals, mode, brake", [
    (0, "", False), (convert.SIGNAL_BLINKER_LEFT, "left", False), (convert.SIGNAL_BLINKER_RIGHT, "right", False),
    (convert.SIGNAL_BLINKER_EMERGENCY | convert.SIGNAL_BLINKER_LEFT | convert.SIGNAL_BLINKER_RIGHT, "hazard", False),
    (convert.SIGNAL_BRAKELIGHT | convert.SIGNAL_BLINKER_RIGHT, "right", True)])
def test_signals(signals, mode, brake):
    assert convert.lamp_mode(signals) == mode
    assert convert.brake_on(signals) is brake


def test_vehicle_classes_map_to_actor_kinds():
    assert convert.kind_of("emergency") == "ev"
    assert convert.kind_of("bus") == convert.kind_of("coach") == "bus"
    assert convert.kind_of("truck") == "truck" and convert.kind_of("delivery") == "van"
    assert convert.kind_of("passenger") == convert.kind_of("motorcycle") == "car"
    assert convert.kind_of("passenger", "van") == "van"
    assert convert.bgr_of_rgba((10, 20, 30, 255)) == (30, 20, 10)
    assert 0.0 <= convert.lamp_phase_frac("v1") < 1.0 and convert.lamp_phase_frac("v1") != convert.lamp_phase_frac("v2")


def test_traffic_model_names():
    assert TRAFFIC_MODELS == ("project", "sumo")
    with pytest.raises(ValueError, match="sumo"):
        check_traffic_model("vissim")


# ----------------------------------------------------------------------------- geometry
def test_plain_xml_of_a_straight_road_spreads_lanes_round_the_carriageway_middle():
    road = Road(-100.0, 0.0, 0.0, (Segment("straight", 500.0),), lanes=2, lane_width_m=3.7, speed_limit_mps=13.4)
    nodes, edges = plain_xml(road)
    e = ET.fromstring(edges).find("edge")
    assert e.get("numLanes") == "2" and float(e.get("width")) == 3.7 and e.get("spreadType") == "center"
    pts = [tuple(map(float, p.split(","))) for p in e.get("shape").split()]
    assert pts == [(-100.0, 3.7), (400.0, 3.7)]  # the middle of two 3.7 m lanes above the curb line y = 0
    assert len(ET.fromstring(nodes).findall("node")) == 2


def test_polyline_to_road_is_exact_on_straights_and_close_on_curves():
    road = road_of_polyline([(0, 0), (100, 0), (200, 0)], lanes=3, lane_width_m=3.5, speed_limit_mps=25.0)
    assert road.segments == (Segment("straight", 200.0),) and road.lanes == 3
    # an arc of radius 300 m sampled every 2 m, as a network's lane shape is
    theta = np.linspace(0.0, 0.5, 76)
    pts = list(zip(300 * np.sin(theta), 300 * (1 - np.cos(theta)), strict=True))
    curved = road_of_polyline(pts, lanes=2, lane_width_m=3.5, speed_limit_mps=25.0)
    exact = Road(0.0, 0.0, 0.0, (Segment("arc", 150.0, 300.0),), lanes=2, lane_width_m=3.5)
    assert road_deviation_m(exact, curved, step_m=1.0) < 0.01
    assert curved.length_m == pytest.approx(150.0, abs=0.05)
    assert all(s.kind == "straight" or s.radius_m > 0 for s in curved.segments)  # turns left throughout


def test_a_sharp_vertex_becomes_an_arc_tangent_to_both_pieces():
    road = road_of_polyline([(0, 0), (100, 0), (100, 100)], lanes=1, lane_width_m=3.5, speed_limit_mps=10.0)
    kinds = [s.kind for s in road.segments]
    assert kinds == ["straight", "arc", "straight"]
    end = road.pose_at(road.length_m, 0.0)
    assert end[0] == pytest.approx(100.0, abs=1e-6) and end[1] == pytest.approx(100.0, abs=1e-6)
    assert end[2] == pytest.approx(math.pi / 2)


def test_offset_polyline_moves_to_the_right():
    out = offset_polyline(np.array([[0.0, 0.0], [10.0, 0.0]]), 1.5)
    assert out.tolist() == [[0.0, -1.5], [10.0, -1.5]]


def test_rsu_on_road_stands_right_of_the_curb_looking_along_it():
    road = Road(0.0, 0.0, math.pi / 2, (Segment("straight", 400.0),), lanes=2)
    rsu = rsu_on_road(road, "r1", 0.5, 150.0, side_m=4.5)
    assert (rsu.camera.x_m, rsu.camera.y_m) == pytest.approx((4.5, 150.0))
    assert rsu.camera.yaw_rad == pytest.approx(math.pi / 2 + 0.1802)
    assert parse_rsu("r1:E1:120") == ("r1", "E1", 120.0, 4.5)
    assert parse_rsu("r1:E1:120:6") == ("r1", "E1", 120.0, 6.0)
    with pytest.raises(ValueError, match="ID:EDGE:POS_M"):
        parse_rsu("r1:E1")


def test_section_maps_corridor_s_to_edge_positions():
    sec = SumoSection(net=None, route=("a", "b"), edge_lengths_m=(100.0, 50.0), edge_starts_m=(0.0, 112.0))
    assert sec.edge_at_s(30.0) == ("a", 30.0)
    assert sec.edge_at_s(130.0) == ("b", 18.0)
    assert sec.edge_at_s(105.0) == ("a", pytest.approx(99.9))  # inside the junction: the end of the edge before


# ----------------------------------------------------------------------------- demand
def test_route_file_has_every_vehicle_with_its_size_and_the_ev_its_bluelight():
    car = SimVehicle("v0", "car", 50.0, 1.85, 12.0, 0, 4.4, 1.8, 1.5, (1, 2, 3), desired_speed_mps=12.0)
    ev = SimVehicle("ev1", "ev", 20.0, 5.55, 17.0, 1, 6.2, 2.1, 2.6, (240, 240, 240), desired_speed_mps=19.0)
    box = SimVehicle("hz0", "debris", 80.0, 1.85, 0.0, 0, 0.8, 0.7, 0.35, (1, 1, 1), is_static=True)
    flows = [demand.FlowSpec("main", ("corridor",), 600.0, 0.0, 90.0)]
    xml = demand.routes_xml([(car, {"route": "r", "edge": "corridor", "lane": 0, "depart_pos_m": 52.2}),
                             (box, {"route": "r", "edge": "corridor", "lane": 0, "depart_pos_m": 80.4,
                                    "stop_pos_m": 80.4, "depart_s": 3.0}),
                             (ev, {"route": "r", "edge": "corridor", "lane": 1, "depart_pos_m": 23.1,
                                   "vtype": demand.ev_vtype(0.0)})], {"r": ["corridor"]}, flows)
    root = ET.fromstring(xml)
    types = {t.get("id"): t for t in root.iter("vType")}
    assert types["t_v0"].get("vClass") == "passenger" and float(types["t_v0"].get("length")) == 4.4
    t_ev = types["t_ev1"]
    assert t_ev.get("vClass") == "emergency" and t_ev.get("carFollowModel") == "IDM"
    params = {p.get("key"): p.get("value") for p in t_ev.iter("param")}
    assert params == {"has.bluelight.device": "true", "device.bluelight.reactiondist": "0.0"}
    vehicles = {v.get("id"): v for v in root.iter("vehicle")}
    assert vehicles["ev1"].get("departLane") == "1" and float(vehicles["ev1"].get("departPos")) == 23.1
    assert vehicles["hz0"].find("stop").get("lane") == "corridor_0" and vehicles["hz0"].get("depart") == "3.00"
    departs = [float(v.get("depart")) for v in root.iter("vehicle")]
    assert departs == sorted(departs)  # SUMO reads vehicles in departure order
    flow = root.find("flow")
    assert flow.get("route") == "r_main" and float(flow.get("vehsPerHour")) == 600.0
    probs = [float(t.get("probability")) for t in root.find("vTypeDistribution").iter("vType")]
    assert sum(probs) == pytest.approx(1.0)


def test_scenario_traffic_key_and_override():
    sc = load_scenario("rellis_ev_yield")
    assert sc.traffic_model == "project"  # the demo runs on the project's traffic unless asked
    assert sc.with_overrides(traffic="sumo").traffic_model == "sumo"
    with pytest.raises(ScenarioError, match="traffic"):
        sc.with_overrides(traffic="vissim")
