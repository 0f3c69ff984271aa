"""Pure builders and readers of CAM, DENM and CPM values (asn1tools form) from and to the corridor's quantities.

Units (TS 102 894-2 CDD): latitude / longitude in 1e-7 deg; heading and WGS84 angles in 0.1 deg clockwise from
north; speeds and velocity components in 0.01 m/s; Cartesian coordinates in 0.01 m; object dimensions and
vehicle length in 0.1 m; TimestampIts in ms of TAI since 2004-01-01T00:00:00Z; GenerationDeltaTime that
timestamp modulo 65,536. Out-of-range quantities take the type's ``outOfRange`` value, never a wrong number.

The corridor frame is x east, y north (``protocol/geodesy.py``); its angles count counter-clockwise from +x.
CPM object positions are offsets from the RSU (the CPM's reference position) along east and north
(TS 103 324 6.x: an RSU's CPM uses the reference position's east/north axes).
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass
from typing import Any

from protocol.enums import AlertState, ObjectType
from protocol.messages import EvAlert, ObjectList
from protocol.v2x.codec import MESSAGE_ID, RELEASE2_VERSION, V2xMessage

ITS_EPOCH_UNIX_S = 1_072_915_200.0
"""2004-01-01T00:00:00Z as UNIX seconds: the TimestampIts origin (TS 102 894-2 A.159)."""
LEAP_SECONDS_SINCE_ITS_EPOCH = 5
"""TAI - UTC grew by 5 s from 2004 (32 s) to 2017 onwards (37 s): TimestampIts counts them."""
MAX_TIMESTAMP_ITS_MS = 4_398_046_511_103

STATION_TYPE = {"unknown": 0, "passengerCar": 5, "specialVehicle": 10, "roadSideUnit": 15}
"""TrafficParticipantType values used here (TS 102 894-2 A.?: 15 is ``infrastructure``, the RSU)."""
VEHICLE_ROLE_EMERGENCY = "emergency"
CAUSE_EMERGENCY_VEHICLE_APPROACHING = 95
SUB_CAUSE_EMERGENCY_VEHICLE_APPROACHING = 1

_OBJECT_CLASS = {ObjectType.VEHICLE: ("vehicleSubClass", 5), ObjectType.EV: ("vehicleSubClass", 10),
                 ObjectType.VRU: ("vruSubClass", ("pedestrian", 0)), ObjectType.UNKNOWN: ("vehicleSubClass", 0),
                 ObjectType.ANIMAL: ("otherSubClass", 1), ObjectType.DEBRIS: ("otherSubClass", 1)}


# ----------------------------------------------------------------------------- scalar conversions
def _clamp_int(x: float, lo: int, hi: int, out_of_range: int | None = None) -> int:
    if not math.isfinite(x):
        return out_of_range if out_of_range is not None else lo
    v = round(x)
    if v < lo or v > hi:
        return out_of_range if out_of_range is not None else min(max(v, lo), hi)
    return v


def timestamp_its_ms(stamp_s: float) -> int:
    """TimestampIts of a clock reading: UNIX seconds (wall clock) or, below the ITS epoch, seconds since it
    (a simulation clock that starts at 0)."""
    if stamp_s >= ITS_EPOCH_UNIX_S:
        ms = (stamp_s - ITS_EPOCH_UNIX_S + LEAP_SECONDS_SINCE_ITS_EPOCH) * 1000.0
    else:
        ms = stamp_s * 1000.0
    return _clamp_int(ms, 0, MAX_TIMESTAMP_ITS_MS)


def station_id(name: str) -> int:
    """A stable 32-bit StationId for a corridor station name (first 4 bytes of its SHA-256)."""
    return int.from_bytes(hashlib.sha256(name.encode("utf-8")).digest()[:4], "big")


def latitude(lat_deg: float) -> int:
    return _clamp_int(lat_deg * 1e7, -900_000_000, 900_000_000, 900_000_001)


def longitude(lon_deg: float) -> int:
    return _clamp_int(lon_deg * 1e7, -1_800_000_000, 1_800_000_000, 1_800_000_001)


def wgs84_angle_decideg(heading_rad: float) -> int:
    """Corridor heading (counter-clockwise from east) -> 0.1 deg clockwise from north, 0..3599."""
    if not math.isfinite(heading_rad):
        return 3601
    return round((90.0 - math.degrees(heading_rad)) * 10.0) % 3600


def heading_rad_from_decideg(value: int) -> float | None:
    """Inverse of :func:`wgs84_angle_decideg`; None for ``unavailable`` (3601) / ``doNotUse`` (3600)."""
    if value >= 3600:
        return None
    return math.atan2(math.sin(math.radians(90.0 - value / 10.0)), math.cos(math.radians(90.0 - value / 10.0)))


def speed_value(speed_mps: float) -> int:
    return _clamp_int(abs(speed_mps) * 100.0, 0, 16_382, 16_382)


def _reference_position(lat_deg: float, lon_deg: float, semi_axis_m: float | None = None) -> dict[str, Any]:
    axis = 4095 if semi_axis_m is None else _clamp_int(semi_axis_m * 100.0, 1, 4093, 4094)
    return {"latitude": latitude(lat_deg), "longitude": longitude(lon_deg),
            "positionConfidenceEllipse": {"semiMajorConfidence": axis, "semiMinorConfidence": axis,
                                          "semiMajorOrientation": 3601},
            "altitude": {"altitudeValue": 800_001, "altitudeConfidence": "unavailable"}}


def _header(kind: str, station: int) -> dict[str, Any]:
    return {"protocolVersion": RELEASE2_VERSION, "messageId": MESSAGE_ID[kind], "stationId": station}


# ----------------------------------------------------------------------------- CAM
def ev_cam(station: int, stamp_s: float, lat_deg: float, lon_deg: float, heading_rad: float, speed_mps: float,
           light_bar: bool, siren: bool, length_m: float = 5.5, width_m: float = 2.1,
           position_sigma_m: float = 1.0) -> dict[str, Any]:
    """The CAM of an emergency vehicle (TS 103 900 6.1: BasicContainer, BasicVehicleContainerHighFrequency,
    BasicVehicleContainerLowFrequency with vehicleRole ``emergency``, EmergencyContainer with
    ``lightBarSirenInUse``)."""
    semi_m = 2.45 * position_sigma_m  # 95 % circle of a 2-D Gaussian: sqrt(chi2_2(0.95)) sigma
    axis = _clamp_int(semi_m * 100.0, 1, 4093, 4094)
    return {
        "header": _header("CAM", station),
        "cam": {
            "generationDeltaTime": timestamp_its_ms(stamp_s) % 65536,
            "camParameters": {
                "basicContainer": {
                    "stationType": STATION_TYPE["specialVehicle"],
                    "referencePosition": {
                        "latitude": latitude(lat_deg), "longitude": longitude(lon_deg),
                        "positionConfidenceEllipse": {"semiMajorAxisLength": axis, "semiMinorAxisLength": axis,
                                                      "semiMajorAxisOrientation": 0},
                        "altitude": {"altitudeValue": 800_001, "altitudeConfidence": "unavailable"}}},
                "highFrequencyContainer": ("basicVehicleContainerHighFrequency", {
                    "heading": {"headingValue": wgs84_angle_decideg(heading_rad), "headingConfidence": 10},
                    "speed": {"speedValue": speed_value(speed_mps), "speedConfidence": 10},
                    "driveDirection": "forward" if speed_mps >= 0 else "backward",
                    "vehicleLength": {"vehicleLengthValue": _clamp_int(length_m * 10.0, 1, 1022, 1022),
                                      "vehicleLengthConfidenceIndication": "noTrailerPresent"},
                    "vehicleWidth": _clamp_int(width_m * 10.0, 1, 60, 61),
                    "longitudinalAcceleration": {"value": 161, "confidence": 102},
                    "curvature": {"curvatureValue": 1023, "curvatureConfidence": "unavailable"},
                    "curvatureCalculationMode": "unavailable",
                    "yawRate": {"yawRateValue": 32767, "yawRateConfidence": "unavailable"}}),
                "lowFrequencyContainer": ("basicVehicleContainerLowFrequency", {
                    "vehicleRole": VEHICLE_ROLE_EMERGENCY,
                    "exteriorLights": (b"\x00", 8),
                    "pathHistory": []}),
                "specialVehicleContainer": ("emergencyContainer", {
                    "lightBarSirenInUse": (bytes([(0x80 if light_bar else 0) | (0x40 if siren else 0)]), 2)}),
            },
        },
    }


@dataclass(frozen=True)
class CamInfo:
    """What the corridor reads from a CAM: who, where, how fast, and whether it is an EV on duty."""

    station_id: int
    station_type: int
    generation_delta_ms: int
    lat_deg: float | None
    lon_deg: float | None
    heading_rad: float | None
    """Counter-clockwise from east (the corridor's convention); None when unavailable."""
    speed_mps: float | None
    position_semi_major_m: float | None
    emergency_role: bool
    light_bar: bool
    siren: bool

    @property
    def ev_on_duty(self) -> bool:
        return self.emergency_role and (self.light_bar or self.siren)


def _bit(bits: tuple[bytes, int], index: int) -> bool:
    data, n = bits
    return index < n and bool(data[index // 8] & (0x80 >> (index % 8)))


def cam_info(msg: V2xMessage) -> CamInfo:
    """The corridor's reading of a decoded CAM (TS 103 900)."""
    params = msg.value["cam"]["camParameters"]
    basic = params["basicContainer"]
    ref = basic["referencePosition"]
    lat = None if ref["latitude"] == 900_000_001 else ref["latitude"] / 1e7
    lon = None if ref["longitude"] == 1_800_000_001 else ref["longitude"] / 1e7
    semi = ref["positionConfidenceEllipse"]["semiMajorAxisLength"]
    heading = speed = None
    hf_name, hf = params["highFrequencyContainer"]
    if hf_name == "basicVehicleContainerHighFrequency":
        heading = heading_rad_from_decideg(hf["heading"]["headingValue"])
        speed = None if hf["speed"]["speedValue"] == 16_383 else hf["speed"]["speedValue"] / 100.0
        if speed is not None and hf.get("driveDirection") == "backward":
            speed = -speed
    role = False
    if "lowFrequencyContainer" in params:
        lf_name, lf = params["lowFrequencyContainer"]
        role = lf_name == "basicVehicleContainerLowFrequency" and lf["vehicleRole"] == VEHICLE_ROLE_EMERGENCY
    light_bar = siren = False
    if "specialVehicleContainer" in params:
        _name, sv = params["specialVehicleContainer"]
        if "lightBarSirenInUse" in sv:
            light_bar, siren = _bit(sv["lightBarSirenInUse"], 0), _bit(sv["lightBarSirenInUse"], 1)
    return CamInfo(station_id=msg.header.station_id, station_type=basic["stationType"],
                   generation_delta_ms=msg.value["cam"]["generationDeltaTime"], lat_deg=lat, lon_deg=lon,
                   heading_rad=heading, speed_mps=speed,
                   position_semi_major_m=None if semi >= 4094 else semi / 100.0,
                   emergency_role=role, light_bar=light_bar, siren=siren)


# ----------------------------------------------------------------------------- DENM
def ev_denm(alert: EvAlert, station: int, stamp_s: float) -> dict[str, Any]:
    """The DENM of an RSU's EV alert (TS 103 831 7; cause 95 ``emergencyVehicleApproaching``, sub-cause 1), with
    the EV's position, heading and speed; a cleared alert is the same event's cancellation (``termination``
    ``isCancellation``, situation and location absent)."""
    management: dict[str, Any] = {
        "actionId": {"originatingStationId": station, "sequenceNumber": station_id(alert.alert_id) % 65536},
        "detectionTime": timestamp_its_ms(alert.first_seen),
        "referenceTime": timestamp_its_ms(stamp_s),
        "eventPosition": _reference_position(alert.lat_deg, alert.lon_deg),
        "validityDuration": 2,
        "stationType": STATION_TYPE["roadSideUnit"],
    }
    if alert.state == AlertState.CLEARED:
        management["termination"] = "isCancellation"
        return {"header": _header("DENM", station), "denm": {"management": management}}
    return {
        "header": _header("DENM", station),
        "denm": {
            "management": management,
            "situation": {
                "informationQuality": _clamp_int(alert.confidence * 7.0, 0, 7),
                "eventType": {"ccAndScc": ("emergencyVehicleApproaching95", SUB_CAUSE_EMERGENCY_VEHICLE_APPROACHING)}},
            "location": {
                "eventSpeed": {"speedValue": speed_value(alert.speed_mps), "speedConfidence": 127},
                "eventPositionHeading": {"value": wgs84_angle_decideg(alert.heading_rad), "confidence": 127},
                "detectionZonesToEventPosition": [[]]},
        },
    }


# ----------------------------------------------------------------------------- CPM
def _coordinate(value_m: float, sigma_m: float) -> dict[str, Any]:
    return {"value": _clamp_int(value_m * 100.0, -131_071, 131_070, 131_071 if value_m > 0 else -131_072),
            "confidence": _clamp_int(1.96 * sigma_m * 100.0, 1, 4094, 4095)}


def _velocity(v_mps: float) -> dict[str, Any]:
    return {"value": _clamp_int(v_mps * 100.0, -16_382, 16_381, 16_382 if v_mps > 0 else -16_383),
            "confidence": 127}


def _dimension(size_m: float) -> dict[str, Any] | None:
    if not size_m > 0:
        return None
    return {"value": _clamp_int(size_m * 10.0, 1, 254, 255), "confidence": 32}


def rsu_cpm(objects: ObjectList, station: int, rsu_lat_deg: float, rsu_lon_deg: float, rsu_x_m: float,
            rsu_y_m: float) -> dict[str, Any]:
    """The CPM of one RSU frame (TS 103 324 6.x): management container at the RSU, an OriginatingRsuContainer and
    a PerceivedObjectContainer with each object's offset east/north of the RSU, velocity, yaw, size, age and
    class (``ObjectClass.vehicleSubClass`` passengerCar / specialVehicle for an EV)."""
    perceived = []
    for o in objects.objects[:255]:
        sx, sy = math.sqrt(max(o.pos_cov_m2[0], 0.0)), math.sqrt(max(o.pos_cov_m2[2], 0.0))
        p: dict[str, Any] = {
            "objectId": o.object_id % 65536,
            "measurementDeltaTime": 0,
            "position": {"xCoordinate": _coordinate(o.pos_x_m - rsu_x_m, sx),
                         "yCoordinate": _coordinate(o.pos_y_m - rsu_y_m, sy)},
            "velocity": ("cartesianVelocity", {"xVelocity": _velocity(o.vel_x_mps), "yVelocity": _velocity(o.vel_y_mps)}),
            "angles": {"zAngle": {"value": round(math.degrees(o.heading_rad) * 10.0) % 3600, "confidence": 127}},
            "objectAge": _clamp_int(o.age_s * 1000.0, 0, 2047),
            "classification": [{"objectClass": _OBJECT_CLASS.get(o.obj_type, ("vehicleSubClass", 0)),
                                "confidence": _clamp_int(o.obj_type_cfd * 100.0, 1, 100)}],
        }
        for field, size in (("objectDimensionX", o.length_m), ("objectDimensionY", o.width_m),
                            ("objectDimensionZ", o.height_m)):
            dim = _dimension(size)
            if dim is not None:
                p[field] = dim
        perceived.append(p)
    return {
        "header": _header("CPM", station),
        "payload": {
            "managementContainer": {"referenceTime": timestamp_its_ms(objects.measurement_time),
                                    "referencePosition": _reference_position(rsu_lat_deg, rsu_lon_deg, 0.1)},
            "cpmContainers": [
                {"containerId": 2, "containerData": {}},
                {"containerId": 5, "containerData": {"numberOfPerceivedObjects": len(perceived),
                                                     "perceivedObjects": perceived}},
            ],
        },
    }
