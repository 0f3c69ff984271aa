"""The Foxglove builders: every derived message validates against Foxglove's own JSON Schema, the scene
draws what the corridor holds (lanes, RSU fields of view, tracks coloured by kind with the alerted EV
red, the AV's commanded path), map fixes come from the corridor's WGS84 conversion, and the JSON view
of a payload gives its bytes back. Pure: no processes, no network."""

from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from deploy import foxglove_scene as fs
from deploy.record import foxglove_schema
from protocol import foxglove_msgs as fx
from protocol import record_view
from protocol.codec import encode
from protocol.corridor import load_corridor
from protocol.examples import example_messages
from protocol.json_view import JsonViewError, to_json, to_view, to_wire, view_roundtrips
from protocol.keys import is_camera_key, parse_camera_key, rsu_camera_key

jsonschema = pytest.importorskip("jsonschema")


def _validate(schema_name: str, data: bytes | dict) -> dict:
    obj = json.loads(data) if isinstance(data, bytes) else data
    jsonschema.Draft202012Validator(json.loads(foxglove_schema(schema_name))).validate(obj)
    return obj


@pytest.fixture(scope="module")
def corridor():
    return load_corridor()


def _messages(stamp: float = 10.0) -> dict[str, tuple[str, object]]:
    return {m.KIND: (k, m) for k, m in example_messages("rellis", stamp=stamp)}


def test_json_view_gives_the_wire_bytes_back_and_refuses_what_has_no_json_form():
    for _key, msg in example_messages("rellis"):
        payload = encode(msg)
        view = to_json(payload)
        assert json.loads(view)["kind"] == msg.KIND and to_wire(view) == payload and view_roundtrips(payload, view)
    with pytest.raises(JsonViewError):
        to_view(b"\xc1 not msgpack")
    with pytest.raises(JsonViewError):
        to_view(b"\x93\x01\x02\x03")  # an array, not a map
    import msgpack

    with pytest.raises(JsonViewError, match="no JSON form"):
        to_json(msgpack.packb({"kind": "Health", "x": float("nan")}))
    assert not view_roundtrips(msgpack.packb({"kind": "Health", "x": 1.5}, use_single_float=True),
                               to_json(msgpack.packb({"kind": "Health", "x": 1.5}, use_single_float=True)))


def test_camera_key_is_its_own_layout_entry():
    key = rsu_camera_key("rellis", "rsu2")
    assert key == "iea/rellis/rsu/rsu2/camera/jpeg" and is_camera_key(key)
    assert parse_camera_key(key) == ("rellis", "rsu2")
    assert not is_camera_key("iea/rellis/rsu/rsu2/objects")


def test_road_scene_has_every_lane_edge_and_each_rsu_field_of_view(corridor):
    scene = _validate("foxglove.SceneUpdate", json.loads(json.dumps(fs.road_scene(corridor, 3.0))))
    road = scene["entities"][0]
    assert road["id"] == "road" and road["frame_id"] == "corridor"
    lanes = corridor.road.lanes
    assert len(road["lines"]) == (lanes + 2) + lanes  # shoulder, edges and lane lines; lane centres
    rsus = {e["id"]: e for e in scene["entities"][1:]}
    assert set(rsus) == {f"rsu/{r.rsu_id}" for r in corridor.rsus}
    for r in corridor.rsus:
        cam = r.camera
        fov = rsus[f"rsu/{r.rsu_id}"]["lines"][0]
        assert fov["type"] == fx.LINE_LOOP
        apex = fov["points"][0]
        assert (apex["x"], apex["y"]) == pytest.approx((cam.x_m, cam.y_m), abs=0.01)
        hfov = 2 * math.atan(cam.width_px / (2 * cam.fx_px))
        bearings = [math.atan2(p["y"] - apex["y"], p["x"] - apex["x"]) for p in fov["points"][1:]]
        spread = (bearings[-1] - bearings[0] + math.pi) % (2 * math.pi) - math.pi
        assert abs(spread) == pytest.approx(hfov, abs=1e-3)


def test_tracks_are_boxes_coloured_by_kind_and_the_alerted_ev_is_red(corridor):
    scene = fs.CorridorScene(corridor)
    msgs = _messages()
    k_obj, objects = msgs["ObjectList"]
    scene.on_message(k_obj, objects, 10.0)
    tracks = {t["id"]: t for t in scene.tracks(10.0)}
    assert len(tracks) == len(objects.objects) and not any(t["alerted"] for t in tracks.values())
    k_ev, alert = msgs["EvAlert"]  # object 7 of rsu1
    logs = scene.on_message(k_ev, alert, 10.1)
    assert [json.loads(d)["level"] for _t, _s, d, _ in logs] == [fx.LOG_LEVEL["warning"]]
    assert scene.on_message(k_ev, alert, 10.4) == []  # a repeat of the alert logs nothing
    update = _validate("foxglove.SceneUpdate", fs.objects_scene(scene.tracks(10.5), [], {}, 10.5))
    assert update["deletions"][0]["type"] == fx.DELETE_ALL  # replaces the previous picture
    colours = {e["id"]: e["cubes"][0]["color"] for e in update["entities"]}
    red = fx.color(fs.COLOURS["ev_alerted"])
    assert colours["track/rsu1/7"] == red
    assert all(c == fx.color(fs.COLOURS["vehicle"]) for i, c in colours.items() if i != "track/rsu1/7")
    # the alert no longer repeated: the EV is no longer drawn alerted
    scene.on_message(k_obj, objects, 10.5 + fs.ALERT_STALE_S)
    assert not any(t["alerted"] for t in scene.tracks(10.5 + fs.ALERT_STALE_S))
    # the DDM's fused tracks replace the RSUs' while fresh
    scene.on_ddm_state({"tracks": [{"id": 4, "x_m": 50.0, "y_m": 1.8, "speed_mps": 12.0, "type": "vehicle",
                                    "ev": True}]}, 14.0)
    (fused,) = scene.tracks(14.5)
    assert fused["id"] == "ddm/4" and fused["ev"] and abs(fused["yaw_rad"]) < math.pi


def test_av_with_its_commanded_path_transforms_and_wgs84_fixes(corridor):
    scene = fs.CorridorScene(corridor, scene_hz=10.0, static_period_s=2.0)
    msgs = _messages()
    for kind in ("VehicleState", "PathSwitchCommand", "EvAlert", "CommandAck"):
        k, m = msgs[kind]
        scene.on_message(k, m, 10.0)
    out = scene.tick(10.0)
    by_topic = {}
    for topic, schema, data, t in out:
        assert t == 10.0
        by_topic.setdefault(topic, []).append(_validate(schema, data))
    assert set(by_topic) == {"/scene/road", "/scene/objects", "/tf", "/map/av1", "/map/ev"}
    (objects,) = by_topic["/scene/objects"]
    (av,) = [e for e in objects["entities"] if e["id"] == "av/av1"]
    _k, cmd = msgs["PathSwitchCommand"]
    path = av["lines"][0]["points"]
    assert [c for p in path for c in (p["x"], p["y"])] == pytest.approx([c for w in cmd.waypoints for c in w])
    assert len(av["cubes"]) == 2  # the AV and its stop point
    (fix,) = by_topic["/map/av1"]
    _k, state = msgs["VehicleState"]
    assert (fix["latitude"], fix["longitude"]) == pytest.approx(corridor.to_latlon(state.pos_x_m, state.pos_y_m))
    (ev_fix,) = by_topic["/map/ev"]
    _k, alert = msgs["EvAlert"]
    assert (ev_fix["latitude"], ev_fix["longitude"]) == pytest.approx(corridor.to_latlon(alert.pos_x_m, alert.pos_y_m))
    (tf,) = by_topic["/tf"]
    assert {t["child_frame_id"] for t in tf["transforms"]} == {f"rsu/{r.rsu_id}" for r in corridor.rsus} | {"av/av1"}
    # rates: objects at 10 Hz, the road every 2 s
    assert [t for t, *_ in scene.tick(10.05)] == []
    assert {t for t, *_ in scene.tick(10.1)} == {"/scene/objects", "/tf", "/map/av1", "/map/ev"}
    assert "/scene/road" in {t for t, *_ in scene.tick(12.0)}


def test_feed_decodes_payloads_and_logs_commands_once(corridor):
    scene = fs.CorridorScene(corridor)
    msgs = _messages()
    k, cmd = msgs["PathSwitchCommand"]
    first = [t for t, *_ in scene.feed(k, encode(cmd), 10.0)]
    assert "/log" in first and "/scene/objects" in first
    assert "/log" not in [t for t, *_ in scene.feed(k, encode(cmd), 10.5)]  # a retransmission
    assert [t for t, *_ in scene.feed(k, b"\xc1 junk", 10.51)] == []  # skipped, nothing due yet


def test_camera_feed_publishes_jpeg_at_its_rate_and_is_off_for_a_real_camera():
    from rsu.camera_feed import CameraFeed, default_rate_hz

    class Bus:
        def __init__(self, watched=True):
            self.sent, self.watched = [], watched

        def publish_bytes(self, key, payload):
            self.sent.append((key, payload))

        def wait_for_subscribers(self, key, timeout_s):
            return self.watched

    class SimSource:
        last_render_times_s = (0.0, 0.0)

    assert default_rate_hz(SimSource(), None) == 2.0 and default_rate_hz(object(), None) == 0.0
    assert default_rate_hz(object(), 5.0) == 5.0
    with pytest.raises(ValueError, match="outside"):
        default_rate_hz(object(), -1.0)
    bus = Bus()
    feed = CameraFeed(bus, "rellis", "rsu1", rate_hz=2.0)
    image = np.zeros((720, 1280, 3), np.uint8)
    cv2.rectangle(image, (100, 100), (300, 200), (0, 0, 255), -1)
    made = [feed.offer(i / 15.0, lambda: image) for i in range(30)]  # 2 s of a 15 fps camera
    assert sum(made) == 4 and len(bus.sent) == 4
    key, payload = bus.sent[0]
    assert key == "iea/rellis/rsu/rsu1/camera/jpeg"
    msg = _validate("foxglove.CompressedImage", payload)
    assert msg["format"] == "jpeg" and msg["frame_id"] == "rsu1"
    import base64

    decoded = cv2.imdecode(np.frombuffer(base64.b64decode(msg["data"]), np.uint8), cv2.IMREAD_COLOR)
    assert decoded.shape == (360, 640, 3) and decoded[75, 100, 2] > 200  # scaled, the red box still there
    off = CameraFeed(Bus(), "rellis", "rsu1", rate_hz=0.0)
    assert not any(off.offer(i / 15.0, lambda: image) for i in range(30))
    nobody = Bus(watched=False)  # no subscriber: no frame made, encoded or sent
    quiet = CameraFeed(nobody, "rellis", "rsu1", rate_hz=2.0)
    assert not any(quiet.offer(i / 15.0, lambda: pytest.fail("made an unwatched frame")) for i in range(30))
    assert nobody.sent == [] and quiet.unwatched == 4


def test_log_and_location_builders_validate():
    _validate("foxglove.Log", fx.log_line(1.5, "error", "ddm", "x"))
    fix = _validate("foxglove.LocationFix", fx.location_fix(2.0, "av/av1", 30.6, -96.4, sigma_m=1.0))
    assert fix["position_covariance"][0] == 1.0 and fix["position_covariance_type"] == 2
    assert fx.time_of(1.25) == {"sec": 1, "nsec": 250_000_000} and fx.time_of(-1.0) == {"sec": 0, "nsec": 0}


def test_layout_shows_channels_the_bridge_serves():
    """deploy/foxglove/corridor_layout.json: the 3D, image, map, plot, log and command panels, each on a
    channel the bridge advertises (and a recording holds) for the corridor rellis."""
    from pathlib import Path

    from deploy.foxglove_bridge import corridor_channels

    layout = json.loads((Path(fs.__file__).parent / "foxglove" / "corridor_layout.json").read_text())
    panels = layout["configById"]
    assert {p.split("!")[0] for p in panels} == {"3D", "Image", "map", "Plot", "RosOut", "RawMessages"}

    def leaves(node):
        return [node] if isinstance(node, str) else leaves(node["first"]) + leaves(node["second"])

    assert sorted(leaves(layout["layout"])) == sorted(panels)  # every panel placed, none twice
    served = dict(corridor_channels(load_corridor(), "rellis"))
    used = set(panels["3D!corridor"]["topics"]) | {panels["Image!camera"]["imageMode"]["imageTopic"],
                                                   panels["map!corridor"]["followTopic"],
                                                   panels["RosOut!log"]["topicToRender"],
                                                   panels["RawMessages!cmd"]["topicPath"]}
    used |= {p["value"].split(".")[0] for p in panels["Plot!av"]["paths"]}
    assert used <= set(served), used - set(served)
    assert served[panels["Image!camera"]["imageMode"]["imageTopic"]] == "foxglove.CompressedImage"
    fields = {p["value"].split(".")[1] for p in panels["Plot!av"]["paths"]}
    assert fields == {"lateral_error_m", "speed_mps"} and served["/vehicle/av1/state"] == "VehicleState"
    assert panels["3D!corridor"]["followTf"] == "av/av1"  # a frame /tf carries


def test_aliases_carry_the_json_view_under_corridor_free_topics(corridor):
    scene = fs.CorridorScene(corridor)
    msgs = _messages()
    for kind, topic in (("VehicleState", "/vehicle/av1/state"), ("PathSwitchCommand", "/vehicle/av1/cmd"),
                        ("EvAlert", "/alerts/ev")):
        k, m = msgs[kind]
        out = {t: (s, d) for t, s, d, _ in scene.feed(k, encode(m), 10.0)}
        assert out[topic] == (kind, record_view.to_json(encode(m)))


def test_ddm_state_poll_feeds_the_fused_tracks(corridor):
    import threading

    from deploy.foxglove_scene import DdmStatePoll

    asked = threading.Event()

    class Transport:
        def query_bytes(self, key, timeout_s):
            asked.set()
            assert key == "iea/rellis/ddm/state"
            doc = {"tracks": [{"id": 9, "x_m": 80.0, "y_m": 5.5, "speed_mps": 20.0, "type": "vehicle", "ev": True}]}
            return [(key, json.dumps(doc).encode())]

    scene = fs.CorridorScene(corridor)
    poll = DdmStatePoll(Transport(), "rellis", scene, period_s=0.01, clock=lambda: 50.0).start()
    try:
        assert asked.wait(5.0)
        for _ in range(500):
            if poll.answers:
                break
            threading.Event().wait(0.01)
    finally:
        poll.close()
    (track,) = scene.tracks(50.5)
    assert track["id"] == "ddm/9" and track["ev"]


def foxglove_readable(schema: dict, where: str = "") -> list[str]:
    """What keeps Foxglove's and Lichtblick's JSON Schema reader (their parseJsonSchema) from building a
    channel's fields: the root and every object must be ``type: object`` with ``properties``; every
    property one plain type (boolean, string - plain or base64 -, number, integer, object, or an array
    of one of those), or a ``oneOf`` of numeric constants."""
    if schema.get("type") != "object" or not isinstance(schema.get("properties"), dict):
        return [f"{where or '<root>'}: not an object with properties"]
    problems = []
    for name, field in schema["properties"].items():
        here = f"{where}.{name}" if where else name
        if isinstance(field.get("oneOf"), list):
            if not all(isinstance(a.get("const"), int | float) for a in field["oneOf"]):
                problems.append(f"{here}: oneOf of non-numbers")
            continue
        t = field.get("type")
        if t in ("boolean", "number", "integer"):
            continue
        if t == "string":
            if field.get("contentEncoding") not in (None, "base64"):
                problems.append(f"{here}: contentEncoding {field['contentEncoding']}")
        elif t == "object":
            problems += foxglove_readable(field, here)
        elif t == "array":
            item = field.get("items")
            it = item.get("type") if isinstance(item, dict) else None
            if it == "object":
                problems += foxglove_readable(item, here + "[]")
            elif it == "string" and item.get("contentEncoding") is not None or it not in (
                    "boolean", "string", "number", "integer", "object"):
                problems.append(f"{here}: array of {it}")
        else:
            problems.append(f"{here}: type {t!r}")
    return problems


def test_record_view_names_every_field_in_the_form_foxglove_reads_and_gives_the_bytes_back():
    from protocol.messages import MESSAGE_BY_KIND

    for kind in MESSAGE_BY_KIND:
        schema = record_view.record_view_schema(kind)
        assert foxglove_readable(schema) == [], kind
        committed = json.loads((Path(fs.__file__).parents[1] / "protocol" / "schema" / f"{kind}.json").read_text())
        assert set(schema["properties"]) == set(committed["properties"])  # the same fields
        assert foxglove_readable(committed) != []  # which the committed (wire) form does not give Foxglove
    for name in ("SceneUpdate", "FrameTransforms", "LocationFix", "CompressedImage", "Log"):
        assert foxglove_readable(json.loads(foxglove_schema(f"foxglove.{name}"))) == [], name
    for _key, msg in example_messages("rellis"):
        payload = encode(msg)
        view = record_view.to_json(payload)
        assert record_view.to_wire(view) == payload and record_view.view_roundtrips(payload, view)
        jsonschema.Draft202012Validator(record_view.record_view_schema(msg.KIND)).validate(json.loads(view))
    state = json.loads(record_view.to_json(encode(_messages()["VehicleState"][1])))
    assert state["lateral_error_m"] == 0.0 and "active_command_id" not in state  # None: left out
    with pytest.raises(JsonViewError):
        record_view.to_view(b"\xc1")
