"""Message models shared by every service (docs/architecture.md §Messages).

Every message carries the common envelope ``v`` (schema version), ``src`` (publisher id), ``seq``
(per publisher and key) and ``stamp`` (seconds on the publisher's clock). All quantities are SI
(metres, seconds, radians, metres per second); where a unit is not obvious it is in the field name.
Field names follow the SAE V2X messages RSU software already speaks:

- ``ObjectList`` / ``DetectedObject`` after SAE J3224 Sensor Data Sharing Message (SDSM):
  ``object_id`` (objectID), ``obj_type`` / ``obj_type_cfd`` (objType / objTypeCfd),
  ``measurement_time`` (measurementTime), position offsets, ``speed_mps``, ``heading_rad``, size.
- ``EvAlert`` after SAE J2735 EmergencyVehicleAlert: ``alert_id``, ``response_type``, ``state``,
  position, ``confidence`` and the vision ``evidence``.

Models validate on construction and on decoding: every number lies in its physical range (one
named type per quantity, ``protocol/ranges.py``: clock readings up to the year 2100, positions within
1,000 km, speeds up to 1,000 m/s ...), lists and strings are bounded. A service therefore cannot
publish, nor accept, a message that is out of range, and arithmetic on a decoded value cannot overflow.
"""

from __future__ import annotations

import math
from typing import Annotated, ClassVar, Literal

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    StrictBool,
    StrictInt,
    field_validator,
    model_validator,
)
from pydantic.dataclasses import dataclass as _pydantic_dataclass

from protocol.enums import (
    AckStatus,
    ActorKind,
    AlertState,
    ClearReason,
    EvCue,
    EvState,
    HazardState,
    HealthStatus,
    Lighting,
    LightState,
    Manoeuvre,
    ObjectType,
    Role,
    VehicleMode,
)
from protocol.ranges import (
    AccelMps2,
    ActorHeightM,
    ActorLengthM,
    ActorWidthM,
    Angle,
    ColourByte,
    Count,
    CovarianceM2,
    DurationS,
    FlashHz,
    ImageCoordPx,
    Lane,
    LatencyMs,
    Latitude,
    LightBarHz,
    Longitude,
    OffsetM,
    PhaseS,
    PositionM,
    Probability,
    RateHz,
    SimTimeS,
    SizeM,
    SpeedMps,
    TimeS,
    VarianceM2,
    VelocityMps,
    YawRateRps,
)

SCHEMA_VERSION = 1
"""Version carried in ``v``; a decoder refuses any other."""

MAX_OBJECTS = 256
MAX_WAYPOINTS = 512
MAX_ACTORS = 1024
MAX_HEALTH_ENTRIES = 64
MAX_TEXT = 256

# ---------------------------------------------------------------- scalar types
# Every number has a physical range: the types live in protocol/ranges.py.
Ident = Annotated[str, Field(strict=True, min_length=1, max_length=64, pattern=r"^[A-Za-z0-9_.\-]+$")]
Text = Annotated[str, Field(strict=True, max_length=MAX_TEXT)]
Point2 = tuple[PositionM, PositionM]
"""(x, y) in the corridor frame, m."""


_CONFIG = ConfigDict(extra="forbid", allow_inf_nan=False, validate_default=False)


class _Model(BaseModel):
    model_config = _CONFIG


record = _pydantic_dataclass(config=_CONFIG)
"""Nested value records (one per object/actor) are pydantic dataclasses: the codec sends them as
positional arrays in field order and validates them in one pass (see protocol/codec.py)."""


class Envelope(_Model):
    """Common header: schema version, publisher id, per-key sequence number, publisher stamp (s)."""

    KIND: ClassVar[str] = ""

    v: StrictInt = SCHEMA_VERSION
    src: Ident
    seq: Count = 0
    stamp: TimeS

    @field_validator("v")
    @classmethod
    def _known_version(cls, value: int) -> int:
        if value != SCHEMA_VERSION:
            raise ValueError(f"unknown schema version {value}; this build speaks v{SCHEMA_VERSION}")
        return value


# ---------------------------------------------------------------- authentication
@record
class Signature:
    """Ed25519 signature over the message's canonical encoding and its key (protocol/security.py),
    after IEEE 1609.2: the signer's key id and a validity window on the signer's clock."""

    key_id: Ident
    not_before: TimeS
    not_after: TimeS
    sig: Annotated[bytes, Field(strict=True, min_length=64, max_length=64)]


# ---------------------------------------------------------------- RSU -> DDM
@record
class DetectedObject:
    """One tracked object (SDSM DetectedObjectCommonData + size), corridor frame."""

    object_id: Count
    pos_x_m: PositionM
    pos_y_m: PositionM
    lat_deg: Latitude
    lon_deg: Longitude
    bbox_px: tuple[ImageCoordPx, ImageCoordPx, ImageCoordPx, ImageCoordPx]
    """Image box (x1, y1, x2, y2) in pixels."""
    obj_type: ObjectType = ObjectType.VEHICLE
    obj_type_cfd: Probability = 1.0
    ev_score: Probability = 0.0
    ev_state: EvState = EvState.NONE
    light_state: LightState = LightState.UNKNOWN
    vel_x_mps: VelocityMps = 0.0
    vel_y_mps: VelocityMps = 0.0
    speed_mps: SpeedMps = 0.0
    heading_rad: Angle = 0.0
    length_m: SizeM = 0.0
    width_m: SizeM = 0.0
    height_m: SizeM = 0.0
    pos_cov_m2: tuple[VarianceM2, CovarianceM2, VarianceM2] = (1.0, 0.0, 1.0)
    """Position covariance (xx, xy, yy) in m^2."""
    lane: Lane | None = None
    """Lane index, 0 = rightmost; None when off the road or unknown."""
    age_s: DurationS = 0.0
    hits: Count = 0

    @field_validator("bbox_px")
    @classmethod
    def _ordered_box(cls, box: tuple[float, float, float, float]) -> tuple[float, float, float, float]:
        if box[2] < box[0] or box[3] < box[1]:
            raise ValueError("bbox_px must be (x1, y1, x2, y2) with x2 >= x1 and y2 >= y1")
        return box


class ObjectList(Envelope):
    """Every processed frame of one RSU (after SAE J3224 SDSM)."""

    KIND: ClassVar[str] = "ObjectList"

    rsu_id: Ident
    frame: Count
    measurement_time: TimeS
    """Capture time of the frame (s, RSU clock)."""
    objects: list[DetectedObject] = Field(default_factory=list, max_length=MAX_OBJECTS)


@record
class EvEvidence:
    frames: Count = 0
    flash_hz: FlashHz | None = None
    mean_score: Probability = 0.0
    cues: list[EvCue] = Field(default_factory=list, max_length=4)
    """The cues that confirmed the alert."""
    body_score: Probability | None = None
    """Mean EV-body classifier score of the track, when a body classifier ran on it."""


class EvAlert(Envelope):
    """Emergency vehicle alert (after SAE J2735 EmergencyVehicleAlert); on change and at 2 Hz."""

    KIND: ClassVar[str] = "EvAlert"

    alert_id: Ident
    state: AlertState
    rsu_id: Ident
    object_id: Count
    response_type: Literal["emergency"] = "emergency"
    pos_x_m: PositionM
    pos_y_m: PositionM
    lat_deg: Latitude
    lon_deg: Longitude
    vel_x_mps: VelocityMps = 0.0
    vel_y_mps: VelocityMps = 0.0
    speed_mps: SpeedMps = 0.0
    heading_rad: Angle = 0.0
    lane: Lane | None = None
    confidence: Probability
    first_seen: TimeS
    evidence: EvEvidence = Field(default_factory=lambda: EvEvidence())
    clear_reason: ClearReason | None = None
    """With state ``cleared``: why (None: not given, treated as lights off)."""
    auth: Signature | None = None


class HazardAlert(Envelope):
    """A static object in a lane (debris, a stopped object)."""

    KIND: ClassVar[str] = "HazardAlert"

    hazard_id: Ident
    state: HazardState
    rsu_id: Ident
    pos_x_m: PositionM
    pos_y_m: PositionM
    lat_deg: Latitude
    lon_deg: Longitude
    lane: Lane | None = None
    length_m: SizeM = 0.0
    width_m: SizeM = 0.0
    confidence: Probability
    first_seen: TimeS
    auth: Signature | None = None


# ---------------------------------------------------------------- DDM <-> vehicle
class PathSwitchCommand(Envelope):
    """A driving command from the DDM to one vehicle: a new reference path and speed profile."""

    KIND: ClassVar[str] = "PathSwitchCommand"

    command_id: Ident
    command_seq: Count
    """Per-vehicle command order: a vehicle never lets a lower value override a higher one."""
    vehicle_id: Ident
    manoeuvre: Manoeuvre
    reason: Text
    target_lane: Lane
    waypoints: list[Point2] = Field(max_length=MAX_WAYPOINTS)
    """Reference path (x, y) in the corridor frame, m, in driving order."""
    speed_profile_mps: list[SpeedMps] = Field(default_factory=list, max_length=MAX_WAYPOINTS)
    """Target speed at each waypoint (empty: keep ``target_speed_mps``)."""
    target_speed_mps: SpeedMps
    stop_point: Point2 | None = None
    issued_at: TimeS
    valid_until: TimeS
    supersedes: Ident | None = None
    auth: Signature | None = None

    @model_validator(mode="after")
    def _consistent(self) -> PathSwitchCommand:
        if self.valid_until <= self.issued_at:
            raise ValueError("valid_until must be later than issued_at")
        if self.manoeuvre != Manoeuvre.RESUME and len(self.waypoints) < 2:
            raise ValueError(f"a {self.manoeuvre.value} command needs at least 2 waypoints")
        if self.speed_profile_mps and len(self.speed_profile_mps) != len(self.waypoints):
            raise ValueError("speed_profile_mps must be empty or have one entry per waypoint")
        return self


class CommandAck(Envelope):
    KIND: ClassVar[str] = "CommandAck"

    command_id: Ident
    vehicle_id: Ident
    status: AckStatus
    reason: Text = ""


class VehicleState(Envelope):
    """Vehicle pose and controller state at 20 Hz."""

    KIND: ClassVar[str] = "VehicleState"

    vehicle_id: Ident
    pos_x_m: PositionM
    pos_y_m: PositionM
    lat_deg: Latitude
    lon_deg: Longitude
    heading_rad: Angle
    speed_mps: SpeedMps
    yaw_rate_rps: YawRateRps = 0.0
    accel_mps2: AccelMps2 = 0.0
    steer_rad: Angle = 0.0
    length_m: SizeM = 4.9
    width_m: SizeM = 1.9
    lane: Lane | None = None
    mode: VehicleMode
    active_command_id: Ident | None = None
    lateral_error_m: OffsetM = 0.0
    yaw_error_rad: Angle = 0.0
    yaw_rate_error_rps: YawRateRps = 0.0
    localisation_age_s: DurationS = 0.0
    detail: Text = ""

    def position_after(self, age_s: float) -> tuple[float, float]:
        """Where the car is ``age_s`` after this state's stamp, carried forward at its speed along its heading
        (constant velocity; a negative age counts as none)."""
        step_m = self.speed_mps * max(0.0, age_s)
        return (self.pos_x_m + step_m * math.cos(self.heading_rad), self.pos_y_m + step_m * math.sin(self.heading_rad))


# ---------------------------------------------------------------- every service
class Health(Envelope):
    """Liveness and load of one service at 1 Hz."""

    KIND: ClassVar[str] = "Health"

    role: Role
    status: HealthStatus = HealthStatus.OK
    uptime_s: DurationS = 0.0
    rates_hz: dict[Ident, RateHz] = Field(default_factory=dict, max_length=MAX_HEALTH_ENTRIES)
    latency_ms: dict[Ident, LatencyMs] = Field(default_factory=dict, max_length=MAX_HEALTH_ENTRIES)
    """Per-stage latency (mean over the last period)."""
    drops: dict[Ident, Count] = Field(default_factory=dict, max_length=MAX_HEALTH_ENTRIES)
    rejected: dict[Ident, Count] = Field(default_factory=dict, max_length=MAX_HEALTH_ENTRIES)
    """Inputs refused at the boundary, by reason."""
    stale: list[Ident] = Field(default_factory=list, max_length=MAX_HEALTH_ENTRIES)
    """Peers this service no longer hears from (e.g. RSUs at the DDM)."""
    counts: dict[Ident, Count] = Field(default_factory=dict, max_length=MAX_HEALTH_ENTRIES)
    """What the service holds now, by name (the DDM: fused ``tracks``, ``vehicles``, ``outstanding``
    commands, ``hazards``): for monitors, which should not parse ``detail``."""
    detail: Text = ""
    auth: Signature | None = None
    """A signed service's heartbeat (protocol/security.py): only a DDM Health signed by a trusted DDM key
    keeps a vehicle's link watchdog fed in a signed corridor."""


# ---------------------------------------------------------------- simulator only
@record
class LightBar:
    on: StrictBool = False
    pattern: Literal["alternating", "strobe"] = "alternating"
    frequency_hz: LightBarHz = 2.0
    phase_s: PhaseS = 0.0


@record
class Actor:
    """Ground truth of one actor; x, y is the centre of its footprint on the road."""

    actor_id: Ident
    kind: ActorKind
    pos_x_m: PositionM
    pos_y_m: PositionM
    heading_rad: Angle
    length_m: ActorLengthM
    width_m: ActorWidthM
    height_m: ActorHeightM
    speed_mps: SpeedMps = 0.0
    lane: Lane | None = None
    colour_bgr: tuple[ColourByte, ColourByte, ColourByte] = (128, 128, 128)
    brake_on: StrictBool = False
    light_bar: LightBar | None = None
    style: Count = 0
    """Seed of the actor's appearance (body shape details, livery)."""


class WorldSnapshot(Envelope):
    """Simulator ground truth. Only the simulated camera and evaluation code may read it."""

    KIND: ClassVar[str] = "WorldSnapshot"

    scenario: Ident
    sim_time_s: SimTimeS
    lighting: Lighting = Lighting.DAY
    seed: Count = 0
    actors: list[Actor] = Field(default_factory=list, max_length=MAX_ACTORS)


MESSAGE_TYPES: tuple[type[Envelope], ...] = (
    ObjectList,
    EvAlert,
    HazardAlert,
    PathSwitchCommand,
    CommandAck,
    VehicleState,
    Health,
    WorldSnapshot,
)
MESSAGE_BY_KIND: dict[str, type[Envelope]] = {m.KIND: m for m in MESSAGE_TYPES}
