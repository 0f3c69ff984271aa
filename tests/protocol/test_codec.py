"""Codec: round trips of every model, and nothing but ProtocolError out of any input."""

from __future__ import annotations

import dataclasses

import msgpack
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from protocol import keys
from protocol import ranges as R
from protocol.codec import MAX_PAYLOAD_BYTES, ProtocolError, decode, encode
from protocol.examples import example_messages, object_list
from protocol.messages import (
    MAX_OBJECTS,
    Actor,
    CommandAck,
    DetectedObject,
    EvAlert,
    EvEvidence,
    HazardAlert,
    Health,
    LightBar,
    ObjectList,
    PathSwitchCommand,
    VehicleState,
    WorldSnapshot,
)


# ------------------------------------------------------------------ strategies
# Every number over its whole physical range (protocol/ranges.py), bounds included.
def span(lo, hi):
    return st.floats(min_value=lo, max_value=hi, allow_nan=False, allow_infinity=False)


ident = st.text(alphabet="abcdefghijklmnopqrstuvwxyzABCXYZ0123456789_-.", min_size=1, max_size=24)
time_s = span(0.0, R.MAX_TIME_S)
duration_s = span(0.0, R.MAX_TIME_S)
position = span(-R.MAX_POSITION_M, R.MAX_POSITION_M)
offset = span(-R.MAX_OFFSET_M, R.MAX_OFFSET_M)
size = span(0.0, R.MAX_SIZE_M)
speed = span(0.0, R.MAX_SPEED_MPS)
velocity = span(-R.MAX_SPEED_MPS, R.MAX_SPEED_MPS)
accel = span(-R.MAX_ACCEL_MPS2, R.MAX_ACCEL_MPS2)
yaw_rate = span(-R.MAX_YAW_RATE_RPS, R.MAX_YAW_RATE_RPS)
variance = span(0.0, R.MAX_VARIANCE_M2)
covariance = span(-R.MAX_VARIANCE_M2, R.MAX_VARIANCE_M2)
pixel = span(-R.MAX_IMAGE_COORD_PX / 2, R.MAX_IMAGE_COORD_PX / 2)
prob = st.floats(min_value=0.0, max_value=1.0)
angle = span(-R.MAX_ANGLE_RAD, R.MAX_ANGLE_RAD)
lat = st.floats(min_value=-90.0, max_value=90.0)
lon = st.floats(min_value=-180.0, max_value=180.0)
lane = st.none() | st.integers(min_value=0, max_value=15)
count = st.integers(min_value=0, max_value=R.MAX_COUNT)
text = st.text(max_size=64)


def envelope(**fields):
    return dict(src=ident, seq=count, stamp=time_s, **fields)


@st.composite
def boxes(draw):
    x1, y1 = draw(pixel), draw(pixel)
    return (x1, y1, x1 + draw(span(0.0, R.MAX_IMAGE_COORD_PX / 2)), y1 + draw(span(0.0, R.MAX_IMAGE_COORD_PX / 2)))


detected = st.builds(
    DetectedObject, object_id=count, pos_x_m=position, pos_y_m=position, lat_deg=lat, lon_deg=lon, bbox_px=boxes(),
    obj_type=st.sampled_from(["unknown", "vehicle", "ev", "debris"]), obj_type_cfd=prob, ev_score=prob,
    ev_state=st.sampled_from(["none", "candidate", "confirmed", "cleared"]),
    light_state=st.sampled_from(["unknown", "off", "flashing"]), vel_x_mps=velocity, vel_y_mps=velocity,
    speed_mps=speed, heading_rad=angle, length_m=size, width_m=size, height_m=size,
    pos_cov_m2=st.tuples(variance, covariance, variance), lane=lane, age_s=duration_s, hits=count,
)
object_lists = st.builds(ObjectList, **envelope(rsu_id=ident, frame=count, measurement_time=time_s,
                                                  objects=st.lists(detected, max_size=8)))
ev_alerts = st.builds(EvAlert, **envelope(
    alert_id=ident, state=st.sampled_from(["active", "cleared"]), rsu_id=ident, object_id=count, pos_x_m=position,
    pos_y_m=position, lat_deg=lat, lon_deg=lon, vel_x_mps=velocity, vel_y_mps=velocity, speed_mps=speed,
    heading_rad=angle, lane=lane, confidence=prob, first_seen=time_s,
    evidence=st.builds(EvEvidence, frames=count, flash_hz=st.none() | span(0.0, R.MAX_FLASH_HZ), mean_score=prob)))
hazards = st.builds(HazardAlert, **envelope(
    hazard_id=ident, state=st.sampled_from(["appear", "persist", "clear"]), rsu_id=ident, pos_x_m=position,
    pos_y_m=position, lat_deg=lat, lon_deg=lon, lane=lane, length_m=size, width_m=size, confidence=prob,
    first_seen=time_s))


@st.composite
def commands(draw):
    n = draw(st.integers(min_value=2, max_value=20))
    issued = draw(span(0.0, R.MAX_TIME_S - 1e3))
    return PathSwitchCommand(
        src=draw(ident), seq=draw(count), stamp=draw(time_s), command_id=draw(ident), command_seq=draw(count),
        vehicle_id=draw(ident), manoeuvre=draw(st.sampled_from(["pull_over", "lane_change", "slow_in_lane",
                                                                 "stop_in_lane", "resume"])),
        reason=draw(text), target_lane=draw(st.integers(0, 15)),
        waypoints=draw(st.lists(st.tuples(position, position), min_size=n, max_size=n)),
        speed_profile_mps=draw(st.just([]) | st.lists(speed, min_size=n, max_size=n)),
        target_speed_mps=draw(speed), stop_point=draw(st.none() | st.tuples(position, position)),
        issued_at=issued, valid_until=issued + draw(st.floats(0.01, 1e3)),
        supersedes=draw(st.none() | ident))


acks = st.builds(CommandAck, **envelope(command_id=ident, vehicle_id=ident,
                                        status=st.sampled_from(["accepted", "rejected", "completed"]), reason=text))
states = st.builds(VehicleState, **envelope(
    vehicle_id=ident, pos_x_m=position, pos_y_m=position, lat_deg=lat, lon_deg=lon, heading_rad=angle,
    speed_mps=speed, yaw_rate_rps=yaw_rate, accel_mps2=accel, steer_rad=angle, lane=lane,
    mode=st.sampled_from(["driving", "manoeuvre", "stopped", "minimal_risk"]), active_command_id=st.none() | ident,
    lateral_error_m=offset, yaw_error_rad=angle, yaw_rate_error_rps=yaw_rate, localisation_age_s=duration_s,
    detail=text))
healths = st.builds(Health, **envelope(
    role=st.sampled_from(["rsu", "ddm", "vehicle", "sim", "router"]), status=st.sampled_from(["ok", "degraded", "error"]),
    uptime_s=duration_s, rates_hz=st.dictionaries(ident, span(0.0, R.MAX_RATE_HZ), max_size=5),
    latency_ms=st.dictionaries(ident, span(0.0, R.MAX_LATENCY_MS), max_size=5),
    drops=st.dictionaries(ident, count, max_size=5),
    rejected=st.dictionaries(ident, count, max_size=5), stale=st.lists(ident, max_size=5), detail=text))
actors = st.builds(
    Actor, actor_id=ident, kind=st.sampled_from(["car", "van", "truck", "bus", "ev", "av", "debris"]),
    pos_x_m=position, pos_y_m=position, heading_rad=angle, length_m=st.floats(0.1, 30.0),
    width_m=st.floats(0.1, 5.0), height_m=st.floats(0.1, 6.0), speed_mps=speed, lane=lane,
    colour_bgr=st.tuples(st.integers(0, 255), st.integers(0, 255), st.integers(0, 255)), brake_on=st.booleans(),
    light_bar=st.none() | st.builds(LightBar, on=st.booleans(), pattern=st.sampled_from(["alternating", "strobe"]),
                                    frequency_hz=span(0.0, R.MAX_LIGHT_BAR_HZ),
                                    phase_s=span(-R.MAX_SIM_TIME_S, R.MAX_SIM_TIME_S)), style=count)
worlds = st.builds(WorldSnapshot, **envelope(
    scenario=ident, sim_time_s=span(0.0, R.MAX_SIM_TIME_S), lighting=st.sampled_from(["day", "dusk", "night"]),
    seed=count, actors=st.lists(actors, max_size=6)))

ALL = {
    "ObjectList": object_lists, "EvAlert": ev_alerts, "HazardAlert": hazards, "PathSwitchCommand": commands(),
    "CommandAck": acks, "VehicleState": states, "Health": healths, "WorldSnapshot": worlds,
}


@pytest.mark.parametrize("kind", sorted(ALL))
def test_round_trip_every_model(kind):
    @settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
    @given(ALL[kind])
    def check(message):
        payload = encode(message)
        back = decode(payload, type(message))
        assert back == message
        assert encode(back) == payload

    check()


@settings(max_examples=400, deadline=None)
@given(st.binary(max_size=2048))
def test_random_bytes_raise_only_protocol_error(data):
    for _, msg in example_messages():
        try:
            decode(data, type(msg))
        except ProtocolError:
            pass


@settings(max_examples=300, deadline=None)
@given(st.data())
def test_mutated_payloads_raise_only_protocol_error(data):
    key, msg = data.draw(st.sampled_from(example_messages()))
    payload = bytearray(encode(msg))
    for _ in range(data.draw(st.integers(1, 8))):
        i = data.draw(st.integers(0, len(payload) - 1))
        payload[i] = data.draw(st.integers(0, 255))
    cut = data.draw(st.integers(1, len(payload)))
    try:
        out = decode(bytes(payload[:cut]), keys.message_type_for_key(key))
    except ProtocolError:
        return
    assert type(out) is type(msg)  # a mutation that still decodes is a valid message of the right kind


@settings(max_examples=200, deadline=None)
@given(st.recursive(st.none() | st.booleans() | st.integers(-(2**63), 2**64 - 1) | st.floats() | st.text(max_size=8) | st.binary(max_size=8),
                    lambda c: st.lists(c, max_size=4) | st.dictionaries(st.text(max_size=6), c, max_size=4),
                    max_leaves=30))
def test_arbitrary_msgpack_structures_raise_only_protocol_error(obj):
    payload = msgpack.packb(obj)
    with pytest.raises(ProtocolError):
        decode(payload, ObjectList)


# ------------------------------------------------------------------ each failure names the problem
FIELD = {f.name: i for i, f in enumerate(dataclasses.fields(DetectedObject))}


def _body(msg):
    return msgpack.unpackb(encode(msg), raw=False)


def _raises(body_or_bytes, expected, *fragments):
    payload = body_or_bytes if isinstance(body_or_bytes, bytes) else msgpack.packb(body_or_bytes)
    with pytest.raises(ProtocolError) as info:
        decode(payload, expected)
    for f in fragments:
        assert f in str(info.value), str(info.value)
    return info.value


def test_truncated_bytes():
    err = _raises(encode(object_list(3))[:-5], ObjectList, "not a msgpack message")
    assert err.reason == "format"


def test_trailing_bytes():
    _raises(encode(object_list(1)) + b"\x00", ObjectList, "trailing bytes")


def test_wrong_type_names_the_field():
    body = _body(object_list(3))
    body["objects"][1][FIELD["object_id"]] = "seven"
    _raises(body, ObjectList, "ObjectList.objects.1.object_id")


def test_missing_field_names_the_field():
    _, ack = example_messages()[4]
    body = _body(ack)
    del body["status"]
    _raises(body, CommandAck, "CommandAck.status", "Field required")


def test_extra_field_is_refused():
    _, ack = example_messages()[4]
    body = _body(ack)
    body["steer_now"] = 1.0
    _raises(body, CommandAck, "steer_now")


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), float("-inf")])
def test_non_finite_numbers_are_refused(bad):
    body = _body(object_list(2))
    body["objects"][0][FIELD["pos_x_m"]] = bad
    _raises(body, ObjectList, "objects.0.pos_x_m", "finite")


def test_out_of_range_values_are_refused():
    body = _body(object_list(2))
    body["objects"][1][FIELD["obj_type_cfd"]] = 1.5
    _raises(body, ObjectList, "objects.1.obj_type_cfd", "less than or equal to 1")
    body = _body(object_list(2))
    body["objects"][1][FIELD["lane"]] = -1
    _raises(body, ObjectList, "objects.1.lane")


def test_oversized_payload_is_refused_before_parsing():
    err = _raises(b"\x00" * (MAX_PAYLOAD_BYTES + 1), ObjectList, "exceeds")
    assert err.reason == "oversize"


def test_too_many_objects_are_refused():
    body = _body(object_list(1))
    body["objects"] = body["objects"] * (MAX_OBJECTS + 1)
    _raises(body, ObjectList, "ObjectList.objects", "at most")


def test_unknown_schema_version():
    body = _body(object_list(1))
    body["v"] = 99
    err = _raises(body, ObjectList, "unknown schema version 99")
    assert err.reason == "version"


def test_wrong_kind_for_the_key():
    _, ack = example_messages()[4]
    err = _raises(encode(ack), ObjectList, "got a CommandAck where a ObjectList was expected")
    assert err.reason == "kind"


def test_record_with_wrong_arity_is_refused():
    body = _body(object_list(2))
    body["objects"][0] = body["objects"][0][:-2]
    _raises(body, ObjectList, "objects.0", "array of 22 fields")


def test_command_consistency_is_validated():
    _, cmd = example_messages()[3]
    body = _body(cmd)
    body["valid_until"] = body["issued_at"] - 1.0
    _raises(body, PathSwitchCommand, "valid_until must be later than issued_at")
    body = _body(cmd)
    body["speed_profile_mps"] = body["speed_profile_mps"][:-1]
    _raises(body, PathSwitchCommand, "one entry per waypoint")


def test_models_refuse_bad_values_at_construction():
    with pytest.raises(ValueError):
        DetectedObject(object_id=1, pos_x_m=float("nan"), pos_y_m=0.0, lat_deg=0.0, lon_deg=0.0, bbox_px=(0, 0, 1, 1))
    with pytest.raises(ValueError):
        DetectedObject(object_id=1, pos_x_m=0.0, pos_y_m=0.0, lat_deg=0.0, lon_deg=0.0, bbox_px=(5, 0, 1, 1))
    with pytest.raises(ValueError):
        Health(src="bad id with spaces", stamp=0.0, role="rsu")


def test_encode_refuses_non_messages():
    with pytest.raises(ProtocolError):
        encode({"kind": "ObjectList"})  # type: ignore[arg-type]
