"""The V2X UPER codec (CAM, DENM, CPM; ETSI Release 2): captured messages from other stacks, the asn1tools pitfalls,
clean refusals, and round trips over random valid values."""

from __future__ import annotations

import csv
import math

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from protocol.enums import AlertState, ObjectType
from protocol.examples import example_messages
from protocol.messages import DetectedObject, EvAlert, ObjectList
from protocol.v2x.build import cam_info, ev_cam, ev_denm, rsu_cpm, wgs84_angle_decideg
from protocol.v2x.codec import MAX_V2X_BYTES, V2xError, decode, encode, read_header
from protocol.v2x.schema import specification
from tests.conftest import require_shared


def _captures() -> list[dict[str, str]]:
    path = require_shared("data", "v2x", "captures", "captures.tsv")
    with path.open(encoding="utf-8") as f:
        return list(csv.DictReader(f, delimiter="\t"))


def _r2_status(row: dict[str, str]) -> str:
    for entry in row["decode_status"].split():
        if entry.startswith(("r2_cam:", "r2_denm:")):
            return entry.split(":", 1)[1]
    raise AssertionError(f"{row['id']}: no Release 2 entry in {row['decode_status']!r}")


def test_every_capture_decodes_reencodes_or_is_refused_as_its_table_says():
    rows = _captures()
    assert len(rows) >= 13
    for row in rows:
        data = bytes.fromhex(row["payload_hex"])
        status = _r2_status(row)
        if status == "ERR":
            with pytest.raises(V2xError) as err:
                decode(data)
            if data[0] == 1:
                assert "protocolVersion 1" in str(err.value), row["id"]
            continue
        msg = decode(data)
        assert msg.kind == ("CAM" if row["message"].startswith("CAM") else "DENM"), row["id"]
        again = encode(msg.kind, msg.value)
        if status == "OK+reenc":
            assert again == data, row["id"]
        else:  # OK+reenc(pad): the same bytes but for trailing zero padding
            assert status == "OK+reenc(pad)", row["id"]
            assert data.startswith(again) and not any(data[len(again):]), row["id"]


def test_a_capture_as_a_file_of_hex_names_its_station_and_kind():
    row = next(r for r in _captures() if r["id"] == "vanetza_v3_vw_golf8_cam")
    info = cam_info(decode(bytes.fromhex(row["payload_hex"]), expected="CAM"))
    assert info.station_type == 5 and 40.0 < info.lat_deg < 60.0 and not info.ev_on_duty


# ----------------------------------------------------------------------------- the pitfalls, fixed
def test_a_passenger_car_object_class_takes_its_four_bits():
    spec = specification()
    assert spec.encode("ObjectClass", ("vehicleSubClass", 5)) == b"\x0a"  # 0 00 0101 0: not b"\x00"
    assert spec.decode("ObjectClass", b"\x0a") == ("vehicleSubClass", 5)
    assert spec.decode("ObjectClass", spec.encode("ObjectClass", ("vehicleSubClass", 14))) == ("vehicleSubClass", 14)


def test_a_polygon_length_counts_from_three():
    spec = specification()
    point = {"xCoordinate": 0, "yCoordinate": 0}
    bits = "".join(f"{b:08b}" for b in spec.encode("PolygonalShape", {"polygon": [point] * 3}))
    assert bits[2:7] == "00000"  # two presence bits, extension bit, 4-bit length 3 - 3 (not 3 - 1 = 0010)


def test_an_absent_validity_duration_is_600_s():
    alert = _alert()
    value = ev_denm(alert, 9, 12.0)
    del value["denm"]["management"]["validityDuration"]
    msg = decode(encode("DENM", value))
    assert msg.value["denm"]["management"]["validityDuration"] == 600


# ----------------------------------------------------------------------------- refusals
@pytest.mark.parametrize("data, why", [
    (b"", "too short"),
    (b"\x02\x02\x00", "too short"),
    (b"\x03\x02\x00\x00\x00\x01" + b"\x00" * 30, "no codec for protocolVersion 3"),
    (b"\x02\x63\x00\x00\x00\x01" + b"\x00" * 30, "messageId 99"),
    (b"\x01\x02\x00\x00\x00\x01" + b"\x00" * 30, "protocolVersion 1"),
    (b"\x02\x02\x00\x00\x00\x01", "not a valid CAM"),
    (b"\x02\x02" + b"\xff" * (MAX_V2X_BYTES + 1), "larger than"),
], ids=["empty", "short", "version3", "unknown-id", "version1", "truncated", "oversize"])
def test_bad_bytes_are_one_clear_error(data, why):
    """Each refusal says why (``ids``: the reason)."""
    with pytest.raises(V2xError, match=why):
        decode(data)


def test_trailing_bytes_other_than_padding_are_refused_and_the_kind_is_checked():
    data = encode("CAM", ev_cam(5, 20.0, 30.6, -96.4, 0.0, 10.0, True, True))
    assert decode(data + b"\x00\x00").kind == "CAM"
    with pytest.raises(V2xError, match="not zero padding"):
        decode(data + b"\x01")
    with pytest.raises(V2xError, match="expected a DENM, got a CAM"):
        decode(data, expected="DENM")
    with pytest.raises(V2xError, match="bytes, not str"):
        decode("0202")  # type: ignore[arg-type]
    assert read_header(data).station_id == 5


def test_a_value_out_of_its_range_does_not_encode():
    value = ev_cam(5, 20.0, 30.6, -96.4, 0.0, 10.0, True, True)
    value["cam"]["camParameters"]["basicContainer"]["stationType"] = 300
    with pytest.raises(V2xError, match="cannot encode this CAM"):
        encode("CAM", value)
    with pytest.raises(V2xError, match="header says CAM"):
        encode("DENM", ev_cam(5, 20.0, 30.6, -96.4, 0.0, 10.0, True, True))


# ----------------------------------------------------------------------------- round trips
def _alert(**changes) -> EvAlert:
    alert = next(m for _k, m in example_messages("t", stamp=10.0) if isinstance(m, EvAlert))
    return alert.model_copy(update=changes)


finite = dict(allow_nan=False, allow_infinity=False)
lat_st = st.floats(-89.9, 89.9, **finite)
lon_st = st.floats(-179.9, 179.9, **finite)
angle_st = st.floats(-4 * math.pi, 4 * math.pi, **finite)
stamp_st = st.one_of(st.floats(0.0, 1e8, **finite), st.floats(1.1e9, 4e9, **finite))
SETTINGS = settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])


@SETTINGS
@given(station=st.integers(0, 2**32 - 1), stamp=stamp_st, lat=lat_st, lon=lon_st, heading=angle_st,
       speed=st.floats(-200.0, 200.0, **finite), light=st.booleans(), siren=st.booleans(),
       length=st.floats(0.0, 200.0, **finite), width=st.floats(0.0, 10.0, **finite))
def test_cam_round_trip(station, stamp, lat, lon, heading, speed, light, siren, length, width):
    value = ev_cam(station, stamp, lat, lon, heading, speed, light, siren, length, width)
    data = encode("CAM", value)
    msg = decode(data, expected="CAM")
    assert msg.value == value and encode("CAM", msg.value) == data
    info = cam_info(msg)
    assert (info.light_bar, info.siren, info.station_id) == (light, siren, station)
    assert abs(info.lat_deg - lat) <= 0.6e-7 and abs(info.lon_deg - lon) <= 0.6e-7
    assert wgs84_angle_decideg(info.heading_rad) == wgs84_angle_decideg(heading)
    expected_speed = math.copysign(min(abs(speed), 163.82), speed)
    assert info.speed_mps == pytest.approx(expected_speed, abs=0.006)


@SETTINGS
@given(station=st.integers(0, 2**32 - 1), stamp=stamp_st, lat=lat_st, lon=lon_st, heading=angle_st,
       speed=st.floats(0.0, 300.0, **finite), confidence=st.floats(0.0, 1.0), cleared=st.booleans())
def test_denm_round_trip(station, stamp, lat, lon, heading, speed, confidence, cleared):
    alert = _alert(lat_deg=lat, lon_deg=lon, heading_rad=heading, speed_mps=speed, confidence=confidence,
                   state=AlertState.CLEARED if cleared else AlertState.ACTIVE)
    value = ev_denm(alert, station, stamp)
    data = encode("DENM", value)
    msg = decode(data, expected="DENM")
    assert msg.value == value and encode("DENM", msg.value) == data
    if not cleared:
        assert msg.value["denm"]["situation"]["eventType"]["ccAndScc"] == ("emergencyVehicleApproaching95", 1)


object_st = st.builds(
    lambda i, x, y, vx, vy, h, t, cfd, length, age: DetectedObject(
        object_id=i, pos_x_m=x, pos_y_m=y, lat_deg=30.6, lon_deg=-96.4, bbox_px=(0.0, 0.0, 10.0, 10.0), obj_type=t,
        obj_type_cfd=cfd, vel_x_mps=vx, vel_y_mps=vy, heading_rad=h, length_m=length, width_m=length / 2.5,
        age_s=age),
    st.integers(0, 10**6), st.floats(-2000.0, 2000.0, **finite), st.floats(-2000.0, 2000.0, **finite),
    st.floats(-200.0, 200.0, **finite), st.floats(-200.0, 200.0, **finite), angle_st, st.sampled_from(list(ObjectType)),
    st.floats(0.0, 1.0), st.floats(0.0, 30.0, **finite), st.floats(0.0, 100.0, **finite))


@SETTINGS
@given(objects=st.lists(object_st, max_size=30), station=st.integers(0, 2**32 - 1), stamp=stamp_st, lat=lat_st,
       lon=lon_st)
def test_cpm_round_trip(objects, station, stamp, lat, lon):
    ol = ObjectList(src="rsu1", seq=0, stamp=stamp, rsu_id="rsu1", frame=1, measurement_time=stamp, objects=objects)
    value = rsu_cpm(ol, station, lat, lon, 10.0, -5.0)
    data = encode("CPM", value)
    msg = decode(data, expected="CPM")
    assert msg.value == value and encode("CPM", msg.value) == data
    container = msg.value["payload"]["cpmContainers"][1]["containerData"]
    assert container["numberOfPerceivedObjects"] == len(objects)
    for o, p in zip(objects, container["perceivedObjects"], strict=True):
        if abs(o.pos_x_m - 10.0) < 1300.0:
            assert p["position"]["xCoordinate"]["value"] == round((o.pos_x_m - 10.0) * 100.0)
