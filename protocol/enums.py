"""The wire protocol's enumerations (docs/architecture.md §Messages): object classes, EV and hazard states, manoeuvres,
acknowledgements, vehicle modes, roles, health and the simulator's actor kinds and lighting.

A module of its own so that code needing only the enumerations does not load the pydantic models.
"""

from __future__ import annotations

from enum import StrEnum


class ObjectType(StrEnum):
    """SDSM ObjectType, extended with the emergency-vehicle and hazard classes this system needs."""

    UNKNOWN = "unknown"
    VEHICLE = "vehicle"
    EV = "ev"
    VRU = "vru"
    ANIMAL = "animal"
    DEBRIS = "debris"


class LightState(StrEnum):
    """Emergency light bar state as seen by the camera."""

    UNKNOWN = "unknown"
    OFF = "off"
    FLASHING = "flashing"
    STEADY = "steady"
    """Lit without a flash pattern the camera can resolve (many LED bars at video frame rates)."""


class EvCue(StrEnum):
    """Which evidence confirmed an EV: a lamp flashing, alternating (left/right or colour) or
    lit steady on the roof, and a classifier's confident EV body."""

    FLASH = "flash"
    ALTERNATION = "alternation"
    STEADY_BAR = "steady_bar"
    EV_BODY = "ev_body"


class EvState(StrEnum):
    NONE = "none"
    CANDIDATE = "candidate"
    CONFIRMED = "confirmed"
    CLEARED = "cleared"


class AlertState(StrEnum):
    ACTIVE = "active"
    CLEARED = "cleared"


class ClearReason(StrEnum):
    """Why an RSU cleared an EV alert: the lights went off (the vehicle is no longer an EV on duty),
    or the vehicle left this RSU's view (it may still be an EV, seen by the next RSU)."""

    LIGHTS_OFF = "lights_off"
    OUT_OF_VIEW = "out_of_view"


class HazardState(StrEnum):
    APPEAR = "appear"
    PERSIST = "persist"
    CLEAR = "clear"


class Manoeuvre(StrEnum):
    PULL_OVER = "pull_over"  # move to the rightmost lane and stop at the curb (Texas 545.156)
    LANE_CHANGE = "lane_change"  # change to the target lane and keep driving
    SLOW_IN_LANE = "slow_in_lane"  # too late to change safely: slow down in the current lane
    STOP_IN_LANE = "stop_in_lane"  # stop before a point in the current lane
    RESUME = "resume"  # back to normal driving


class AckStatus(StrEnum):
    ACCEPTED = "accepted"
    REJECTED = "rejected"
    COMPLETED = "completed"


class VehicleMode(StrEnum):
    DRIVING = "driving"  # normal lane keeping at cruise speed
    MANOEUVRE = "manoeuvre"  # following a commanded path
    STOPPED = "stopped"  # stopped where a command asked
    MINIMAL_RISK = "minimal_risk"  # fail-safe stop in lane


class Role(StrEnum):
    RSU = "rsu"
    DDM = "ddm"
    VEHICLE = "vehicle"
    SIM = "sim"
    ROUTER = "router"


class HealthStatus(StrEnum):
    OK = "ok"
    DEGRADED = "degraded"
    ERROR = "error"


class ActorKind(StrEnum):
    CAR = "car"
    VAN = "van"
    TRUCK = "truck"
    BUS = "bus"
    EV = "ev"
    AV = "av"
    DEBRIS = "debris"


class Lighting(StrEnum):
    DAY = "day"
    DUSK = "dusk"
    NIGHT = "night"
