"""Simulated vehicles: state, body types and appearance.

Appearance travels in ``Actor.style`` (protocol has no livery field): ``style = livery << 8 | detail``
where ``detail`` (0..255) seeds the body details (car shape: sedan / hatchback / SUV) and ``livery`` is
one of ``LIVERY_*``; bits 12 and up hold the blinking hazard flashers or turn signal of an ordinary
vehicle and its roof lamps (a works vehicle's amber beacon, a bus's LED strip), if any (``sim.lamps``). The renderer derives everything else deterministically from kind,
size, colour and style.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

LIVERY_PLAIN = 0
LIVERY_AMBULANCE = 1  # white body, red band (real EV or lookalike van without a light bar)
LIVERY_POLICE = 2  # black and white
LIVERY_TWO_TONE = 3  # roof lighter than body
LIVERY_WORKS = 4  # works vehicle: red and yellow chevrons on the rear (with an amber roof beacon: sim.lamps)

# (length, width, height) ranges per kind (m)
SIZE_RANGES = {
    "car": ((4.0, 4.9), (1.7, 1.9), (1.4, 1.65)),
    "van": ((4.8, 6.0), (1.9, 2.1), (2.0, 2.6)),
    "truck": ((7.5, 10.0), (2.4, 2.55), (3.0, 3.6)),
    "bus": ((11.0, 12.5), (2.5, 2.55), (3.0, 3.3)),
    "av": ((4.9, 4.9), (1.9, 1.9), (1.5, 1.5)),
}

# common car colours (BGR) and their weights: white, silver, grey, black, dark blue, red, beige, green
CAR_COLOURS = [
    ((235, 235, 232), 0.24), ((190, 190, 188), 0.18), ((110, 110, 108), 0.17), ((30, 30, 32), 0.18),
    ((90, 50, 30), 0.07), ((40, 40, 170), 0.06), ((150, 185, 205), 0.05), ((60, 90, 50), 0.05),
]
RED_BGR = (35, 30, 185)
BLUE_BGR = (170, 70, 25)
WORKS_BGR = (40, 205, 235)
"""Body colour of a works vehicle (highway yellow)."""


def make_style(livery: int, detail: int) -> int:
    return (int(livery) & 0xF) << 8 | (int(detail) & 0xFF)


def style_livery(style: int) -> int:
    return (style >> 8) & 0xF


def style_detail(style: int) -> int:
    return style & 0xFF


@dataclass
class SimVehicle:
    """One vehicle in road (Frenet) coordinates: s along the reference line, d to the left of it."""

    vehicle_id: str
    kind: str  # ActorKind value
    s_m: float
    d_m: float
    speed_mps: float
    lane: int
    length_m: float
    width_m: float
    height_m: float
    colour_bgr: tuple[int, int, int]
    style: int = 0
    desired_speed_mps: float = 12.0
    target_lane: int | None = None
    target_d_m: float | None = None
    accel_mps2: float = 0.0
    lateral_speed_mps: float = 0.0
    brake_on: bool = False
    yields_to_ev: bool = False
    yielding: bool = False
    is_static: bool = False
    external: bool = False
    """Pose set from outside (the vehicle process); the traffic model does not move it."""
    light_bar: dict | None = None
    """EV light bar: {"pattern", "frequency_hz", "phase_s", "on_at_s"}; None for other vehicles."""
    brake_period_s: float = 0.0
    wave_period_s: float = 0.0
    """Stop-and-go traffic: the driver slows to ``sim.traffic.STOP_GO_SLOW_FACTOR`` of its speed for half of every
    period of a wave that runs upstream (``TrafficSpec.stop_and_go_period_s``); 0: never."""
    politeness: float = 0.3
    idm_time_gap_s: float = 1.4
    idm_max_accel_mps2: float = 1.4
    next_lane_check_s: float = 0.0
    x_m: float = 0.0
    y_m: float = 0.0
    heading_rad: float = 0.0
    extra: dict = field(default_factory=dict)

    def light_bar_on(self, t_s: float) -> bool:
        lb = self.light_bar
        return bool(lb and lb.get("on_at_s") is not None and t_s >= lb["on_at_s"])


def random_size(kind: str, rng: np.random.Generator) -> tuple[float, float, float]:
    (l0, l1), (w0, w1), (h0, h1) = SIZE_RANGES[kind]
    return float(rng.uniform(l0, l1)), float(rng.uniform(w0, w1)), float(rng.uniform(h0, h1))


def random_colour(rng: np.random.Generator) -> tuple[int, int, int]:
    cols, weights = zip(*CAR_COLOURS, strict=True)
    w = np.asarray(weights) / np.sum(weights)
    base = np.asarray(cols[int(rng.choice(len(cols), p=w))], dtype=float)
    base = np.clip(base * rng.uniform(0.9, 1.08) + rng.normal(0, 4, 3), 0, 255)
    return tuple(int(c) for c in base)  # type: ignore[return-value]
