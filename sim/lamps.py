"""Signal lamps of ordinary vehicles: hazard flashers and US-style red rear turn signals.

They are decoys for the RSU's EV identification: a lamp that blinks at 1-2 Hz, as a naive
flashing-light rule would take for a light bar. The vehicles stay ordinary traffic (``kind`` car, van,
truck or bus; label class ``vehicle``; never an EV in ground truth or datasets).

- **hazard**: four amber lamps (BGR ``AMBER_ON_BGR`` when lit), one at each corner of the lower body:
  rear ones beside (below, or above where the body ends) each tail light, front ones at headlight
  height at the outer edges of the front face; all four blink together.
- **left** / **right**: one red lamp (``TURN_ON_BGR``) over the tail light of that rear corner (the
  tail light itself blinks brighter, as on US cars), nothing at the front.

Lit: ``on`` for the first ``DUTY`` of each period ``1 / frequency_hz`` after ``phase_s``. A lit lamp is
bright and saturated with a halo (``SIGNAL_GLOW``); an unlit amber lamp is a dark orange lens, an unlit
turn signal is just the tail light under it.

The state travels in ``Actor.style`` above the livery and detail bits (``sim.vehicles``), so the wire
format is unchanged: bits 12-13 the mode (0 none, 1 hazard, 2 left, 3 right), bits 14-17 the frequency
(1.0 + code / 15 Hz), bits 18-25 the phase (code / 256 of a period). ``assign_signal_lamps`` gives a
seeded fraction of the background traffic such lamps (``TrafficSpec.hazard_flasher_fraction``,
``turn_signal_fraction``).
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import NamedTuple

import numpy as np

from sim.vehicles import SimVehicle

MODES = ("", "hazard", "left", "right")
FREQ_MIN_HZ, FREQ_MAX_HZ = 1.0, 2.0
"""Flash rate of real turn signals and hazard flashers (60-120 flashes a minute, FMVSS 108)."""
DUTY = 0.5
AMBER_ON_BGR = (0, 140, 255)
AMBER_OFF_BGR = (40, 80, 125)
TURN_ON_BGR = (45, 45, 255)
SIGNAL_LAMPS = ("hazard", "turn")
"""``Decal.lamp`` names of the signal lamps (render.py)."""
SIGNAL_GLOW = 0.6
"""Halo strength of a lit signal lamp (render: tail 0.3, brake 0.55, light bar 1.0)."""

_SHIFT = 12
_MODE_MASK, _FREQ_BITS, _PHASE_BITS = 0x3, 4, 8
_FREQ_STEPS = (1 << _FREQ_BITS) - 1

FRONT_LAMPS = {
    "car": (1, (0.02, 0.15), (0.5, 0.78)),
    "av": (1, (0.02, 0.15), (0.5, 0.78)),
    "van": (2, (0.02, 0.14), (0.5, 0.8)),
    "truck": (2, (0.02, 0.12), (0.05, 0.2)),
    "bus": (1, (0.02, 0.1), (0.1, 0.28)),
}
"""Per body kind: the part whose front face carries the front corner lamps (``sim.bodies.body_parts``), the
u range of the left one seen from outside (the vehicle's right corner; mirrored for the other) and v."""


class SignalLamps(NamedTuple):
    mode: str  # "hazard", "left" or "right"
    frequency_hz: float
    phase_s: float


def with_signal_lamps(style: int, mode: str, frequency_hz: float, phase_frac: float) -> int:
    """``style`` with signal lamps set (mode "" clears them). The frequency is clipped to 1-2 Hz and
    quantised to 1/15 Hz, the phase (a fraction of a period) to 1/256."""
    base = int(style) & ((1 << _SHIFT) - 1)
    if not mode:
        return base
    f_code = int(round((float(np.clip(frequency_hz, FREQ_MIN_HZ, FREQ_MAX_HZ)) - FREQ_MIN_HZ)
                       / (FREQ_MAX_HZ - FREQ_MIN_HZ) * _FREQ_STEPS))
    p_code = int(phase_frac * (1 << _PHASE_BITS)) % (1 << _PHASE_BITS)
    bits = MODES.index(mode) | f_code << 2 | p_code << (2 + _FREQ_BITS)
    return base | bits << _SHIFT


def style_signal(style: int) -> SignalLamps | None:
    """The signal lamps encoded in ``style``; None when it has none."""
    bits = int(style) >> _SHIFT
    mode = bits & _MODE_MASK
    if mode == 0:
        return None
    f = FREQ_MIN_HZ + ((bits >> 2) & _FREQ_STEPS) / _FREQ_STEPS * (FREQ_MAX_HZ - FREQ_MIN_HZ)
    phase = ((bits >> (2 + _FREQ_BITS)) & ((1 << _PHASE_BITS) - 1)) / (1 << _PHASE_BITS)
    return SignalLamps(MODES[mode], f, phase / f)


def signal_on(style: int, t_s: float) -> bool:
    """Whether the signal lamps of a vehicle with this style are lit at sim time t_s."""
    sig = style_signal(style)
    if sig is None:
        return False
    return ((t_s - sig.phase_s) * sig.frequency_hz) % 1.0 < DUTY


def signal_decals(kind: str, style: int, tails: Iterable[tuple[int, float, float, float, float]]) -> list[tuple]:
    """Decal fields ``(part, face, u0, u1, v0, v1, colour, lamp)`` of a vehicle's signal lamps, from its
    tail lights ``(part, u0, u1, v0, v1)`` on the rear face (sim.bodies.body_parts)."""
    sig = style_signal(style)
    if sig is None or kind not in FRONT_LAMPS:
        return []
    out: list[tuple] = []
    tails = list(tails)
    if sig.mode == "hazard":
        for part, u0, u1, v0, v1 in tails:
            h = (v1 - v0) * 0.6
            vv = (v0 - h, v0) if v0 - h >= 0.05 else (v1, min(1.0, v1 + h))
            out.append((part, "rear", u0, u1, *vv, AMBER_OFF_BGR, "hazard"))
        part, (u0, u1), (v0, v1) = FRONT_LAMPS[kind]
        for uu in ((u0, u1), (1.0 - u1, 1.0 - u0)):
            out.append((part, "front", *uu, v0, v1, AMBER_OFF_BGR, "hazard"))
        return out
    # rear face: u = 0 is the vehicle's left side (seen from behind), u = 1 its right
    left = sig.mode == "left"
    for part, u0, u1, v0, v1 in tails:
        if ((u0 + u1) / 2 < 0.5) == left:
            out.append((part, "rear", u0, u1, v0, v1, TURN_ON_BGR, "turn"))
    return out


def assign_signal_lamps(vehicles: Iterable[SimVehicle], hazard_fraction: float, turn_fraction: float,
                        rng: np.random.Generator) -> int:
    """Give a seeded fraction of ``vehicles`` hazard flashers and another one a blinking turn signal
    (side, 1-2 Hz rate and phase random per vehicle); returns how many got lamps. Four draws per vehicle
    whatever the fractions, so a larger fraction keeps the vehicles a smaller one picked."""
    n = 0
    for v in vehicles:
        r, f, ph, side = rng.random(), rng.uniform(FREQ_MIN_HZ, FREQ_MAX_HZ), rng.random(), rng.random()
        if v.kind == "ev" or v.is_static:
            continue
        if r < hazard_fraction:
            mode = "hazard"
        elif r < hazard_fraction + turn_fraction:
            mode = "left" if side < 0.5 else "right"
        else:
            continue
        v.style = with_signal_lamps(v.style, mode, f, ph)
        n += 1
    return n
