"""SUMO's vehicle state in the project's terms. Pure.

SUMO (``TraCI`` vehicle value retrieval): ``position`` is the middle of the vehicle's front bumper, ``angle``
is in degrees clockwise from north (0 = +y, 90 = +x); ``signals`` is a bit set (bit 0 right blinker,
1 left blinker, 2 emergency blinker, 3 brake light, ...). The project (``protocol.messages.Actor``): x, y is
the centre of the footprint, heading in radians counter-clockwise from +x.
"""

from __future__ import annotations

import math
import zlib
from typing import NamedTuple

SIGNAL_BLINKER_RIGHT = 1 << 0
SIGNAL_BLINKER_LEFT = 1 << 1
SIGNAL_BLINKER_EMERGENCY = 1 << 2
SIGNAL_BRAKELIGHT = 1 << 3
BLINKER_FREQUENCY_HZ = 1.5
"""SUMO switches a blinker on or off, not each flash: the rendered lamp flashes at this rate (FMVSS 108: 1-2 Hz)."""

KIND_OF_VCLASS = {"emergency": "ev", "bus": "bus", "coach": "bus", "truck": "truck", "trailer": "truck",
                  "delivery": "van", "evehicle": "car", "passenger": "car", "taxi": "car", "private": "car",
                  "custom1": "debris"}
"""SUMO vehicle class -> ``ActorKind``; others (motorcycles, bicycles) are drawn as cars."""


def heading_rad_of_angle(angle_deg: float) -> float:
    """SUMO angle (degrees clockwise from north) -> heading (radians counter-clockwise from +x, in (-pi, pi])."""
    return math.remainder(math.radians(90.0 - angle_deg), 2 * math.pi)


def angle_deg_of_heading(heading_rad: float) -> float:
    """Heading (radians counter-clockwise from +x) -> SUMO angle (degrees clockwise from north, in [0, 360))."""
    return (90.0 - math.degrees(heading_rad)) % 360.0


def centre_of_front(x_m: float, y_m: float, heading_rad: float, length_m: float) -> tuple[float, float]:
    """Footprint centre of a vehicle whose front bumper middle is at (x, y)."""
    return x_m - 0.5 * length_m * math.cos(heading_rad), y_m - 0.5 * length_m * math.sin(heading_rad)


def front_of_centre(x_m: float, y_m: float, heading_rad: float, length_m: float) -> tuple[float, float]:
    """Front bumper middle of a vehicle whose footprint centre is at (x, y) (what ``moveToXY`` places)."""
    return x_m + 0.5 * length_m * math.cos(heading_rad), y_m + 0.5 * length_m * math.sin(heading_rad)


def kind_of(vclass: str, type_id: str = "") -> str:
    """``ActorKind`` value of a SUMO vehicle class (a type id ``van*`` is a van whatever its class)."""
    if type_id.startswith("van"):
        return "van"
    return KIND_OF_VCLASS.get(vclass, "car")


def brake_on(signals: int) -> bool:
    return bool(signals & SIGNAL_BRAKELIGHT)


def lamp_mode(signals: int) -> str:
    """Signal lamps of ``sim.lamps``: "hazard", "left", "right" or "" (none)."""
    if signals & SIGNAL_BLINKER_EMERGENCY:
        return "hazard"
    if signals & SIGNAL_BLINKER_LEFT:
        return "left"
    if signals & SIGNAL_BLINKER_RIGHT:
        return "right"
    return ""


def lamp_phase_frac(vehicle_id: str) -> float:
    """A fixed phase (fraction of a period) per vehicle, so that blinkers of different vehicles do not flash in step."""
    return (zlib.crc32(vehicle_id.encode()) % 256) / 256.0


def bgr_of_rgba(rgba: tuple[int, ...]) -> tuple[int, int, int]:
    r, g, b = (int(c) for c in rgba[:3])
    return b, g, r


class SumoState(NamedTuple):
    """What the shell reads of one vehicle each step."""

    x_m: float
    y_m: float
    angle_deg: float
    speed_mps: float
    signals: int
    accel_mps2: float = 0.0


class Pose(NamedTuple):
    x_m: float
    y_m: float
    heading_rad: float
    speed_mps: float
    brake_on: bool
    lamp_mode: str


def pose_of(state: SumoState, length_m: float) -> Pose:
    """The project's pose of a vehicle from SUMO's state (centre, heading, speed, brake light, blinker)."""
    h = heading_rad_of_angle(state.angle_deg)
    x, y = centre_of_front(state.x_m, state.y_m, h, length_m)
    return Pose(x, y, h, max(0.0, state.speed_mps), brake_on(state.signals), lamp_mode(state.signals))
