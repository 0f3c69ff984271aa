"""Lamps of ordinary vehicles that are not EV light bars: hazard flashers, US-style red rear turn signals,
amber roof beacons of works vehicles and blue or white LED strips of buses.

They are decoys for the RSU's EV identification: a lamp that blinks at 1-2 Hz, as a naive
flashing-light rule would take for a light bar, an amber bar flashing on a roof, or a lamp-bright blue strip
along a bus's roof. The vehicles stay ordinary traffic (``kind`` car, van, truck or bus; label class
``vehicle``; never an EV in ground truth or datasets).

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

Roof lamps (``ROOF_MODES``), in bits 26-40 of ``style`` (bits 26-27 the mode, 28-31 the rate (code / 15 of
the mode's range), 32-39 the phase (code / 256 of a period), bit 40 white):

- **beacon**: an amber bar across the roof of a works vehicle (``sim.bodies``), all of it flashing together
  at 1.5-4 Hz (UN ECE R65 warning lamps: 2-4 Hz; rotating beacons from ~1.5 Hz), lit ``BEACON_DUTY`` of
  each period: a central, roof-height flasher, in amber (``BEACON_ON_BGR``: red channel clipped, green 135).
- **led**: a steady blue (or white) LED strip along the top of a bus's sides and its front and rear
  destination boards, lit all the time.
- **led_chase**: the same strip cut into ``LED_SEGMENTS`` segments per face of which half are lit, the lit
  block running along the strip once a period (1.5-4 Hz).

``assign_roof_lamps`` gives a seeded fraction of the background buses an LED strip
(``TrafficSpec.bus_led_fraction``, ``bus_led_chase_fraction``); works vehicles come from a scenario's
``[[works]]`` tables (``sim.traffic.build_population``).
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
_LAMP_FIELD_BITS = 2 + _FREQ_BITS + _PHASE_BITS
"""Bits of one lamp field of ``style``: the mode, the rate code and the phase code."""


def _pack_lamp(mode_code: int, frequency_hz: float, rate_range_hz: tuple[float, float], phase_frac: float) -> int:
    """A lamp field: the mode's code, the rate clipped to ``rate_range_hz`` and quantised to ``_FREQ_STEPS`` steps
    of it, the phase (a fraction of a period) to 1/256."""
    f_min, f_max = rate_range_hz
    f_code = int(round((float(np.clip(frequency_hz, f_min, f_max)) - f_min) / (f_max - f_min) * _FREQ_STEPS))
    p_code = int(phase_frac * (1 << _PHASE_BITS)) % (1 << _PHASE_BITS)
    return mode_code | f_code << 2 | p_code << (2 + _FREQ_BITS)


def _unpack_lamp(bits: int, rate_range_hz: tuple[float, float]) -> tuple[int, float, float]:
    """(mode code, rate in Hz, phase in s) of a lamp field (``bits`` shifted down to it)."""
    f_min, f_max = rate_range_hz
    f = f_min + ((bits >> 2) & _FREQ_STEPS) / _FREQ_STEPS * (f_max - f_min)
    phase = ((bits >> (2 + _FREQ_BITS)) & ((1 << _PHASE_BITS) - 1)) / (1 << _PHASE_BITS)
    return bits & _MODE_MASK, f, phase / f


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
    """``style`` with signal lamps set (mode "" clears them), its other bits kept. The frequency is clipped to
    1-2 Hz and quantised to 1/15 Hz, the phase (a fraction of a period) to 1/256."""
    base = int(style) & ~(((1 << _LAMP_FIELD_BITS) - 1) << _SHIFT)
    if not mode:
        return base
    return base | _pack_lamp(MODES.index(mode), frequency_hz, (FREQ_MIN_HZ, FREQ_MAX_HZ), phase_frac) << _SHIFT


def style_signal(style: int) -> SignalLamps | None:
    """The signal lamps encoded in ``style``; None when it has none."""
    bits = (int(style) >> _SHIFT) & ((1 << _LAMP_FIELD_BITS) - 1)
    if bits & _MODE_MASK == 0:
        return None
    mode, f, phase_s = _unpack_lamp(bits, (FREQ_MIN_HZ, FREQ_MAX_HZ))
    return SignalLamps(MODES[mode], f, phase_s)


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


ROOF_MODES = ("", "beacon", "led", "led_chase")
BEACON_FREQ_MIN_HZ, BEACON_FREQ_MAX_HZ = 1.5, 4.0
"""Flash rate of amber warning beacons (UN ECE R65: 2-4 Hz; rotating beacons from ~1.5 Hz) and chase rate of an
LED strip (one run along it per period)."""
BEACON_DUTY = 0.4
"""Lit share of a beacon's period (a rotating reflector sweeps past the camera for less than half a turn)."""
BEACON_ON_BGR = (0, 135, 255)
BEACON_OFF_BGR = (35, 95, 150)
LED_BLUE_BGR = (255, 120, 30)
LED_WHITE_BGR = (255, 245, 235)
LED_OFF_BGR = (60, 45, 40)
LED_SEGMENTS = 6
"""Segments per face of an LED strip; a chasing strip lights half of them, a block that runs along it."""
BEACON_GLOW = 0.6
LED_GLOW = 0.35
"""Halo strengths of a lit beacon and of a lit LED segment (render: signal lamps 0.6, light bar 1.0)."""
ROOF_LAMPS = ("beacon", "led_blue", "led_white")
"""``Decal.lamp`` names of the roof lamps (render.py)."""
ROOF_ALL_LIT = -1
"""``roof_state`` of a lit beacon or a steady strip: every segment lit."""

_ROOF_SHIFT = 26
_ROOF_FIELDS = _LAMP_FIELD_BITS + 1
"""A lamp field and the white bit."""


class RoofLamps(NamedTuple):
    mode: str  # "beacon", "led" or "led_chase"
    frequency_hz: float
    phase_s: float
    white: bool


def with_roof_lamps(style: int, mode: str, frequency_hz: float = 2.0, phase_frac: float = 0.0,
                    white: bool = False) -> int:
    """``style`` with roof lamps set (mode "" clears them), its other bits kept. The rate is clipped to
    1.5-4 Hz and quantised to 1/6 Hz, the phase (a fraction of a period) to 1/256; ``white``: a white LED strip
    (blue otherwise; a beacon is amber either way)."""
    if mode not in ROOF_MODES:
        raise ValueError(f"roof lamp mode must be one of {ROOF_MODES}, got {mode!r}")
    base = int(style) & ~(((1 << _ROOF_FIELDS) - 1) << _ROOF_SHIFT)
    if not mode:
        return base
    bits = (_pack_lamp(ROOF_MODES.index(mode), frequency_hz, (BEACON_FREQ_MIN_HZ, BEACON_FREQ_MAX_HZ), phase_frac)
            | int(bool(white)) << _LAMP_FIELD_BITS)
    return base | bits << _ROOF_SHIFT


def style_roof(style: int) -> RoofLamps | None:
    """The roof lamps encoded in ``style``; None when it has none."""
    bits = int(style) >> _ROOF_SHIFT
    if bits & _MODE_MASK == 0:
        return None
    mode, f, phase_s = _unpack_lamp(bits, (BEACON_FREQ_MIN_HZ, BEACON_FREQ_MAX_HZ))
    return RoofLamps(ROOF_MODES[mode], f, phase_s, bool(bits >> _LAMP_FIELD_BITS & 1))


def roof_state(style: int, t_s: float) -> int:
    """The roof lamps' state at sim time t_s: 0 dark (none, or a beacon between flashes), ``ROOF_ALL_LIT`` (a lit
    beacon, a steady strip), or 1 + the first lit segment of a chasing strip."""
    if int(style) >> _ROOF_SHIFT == 0:
        return 0
    roof = style_roof(style)
    cycle = ((t_s - roof.phase_s) * roof.frequency_hz) % 1.0
    if roof.mode == "beacon":
        return ROOF_ALL_LIT if cycle < BEACON_DUTY else 0
    if roof.mode == "led":
        return ROOF_ALL_LIT
    return 1 + min(LED_SEGMENTS - 1, int(cycle * LED_SEGMENTS))


def roof_segment_lit(state: int, segment: int) -> bool:
    """Whether segment ``segment`` of a roof lamp is lit in ``roof_state`` ``state`` (a chase lights half the
    segments, from the state's first one on, wrapping)."""
    if state == ROOF_ALL_LIT:
        return True
    return state > 0 and (segment - (state - 1)) % LED_SEGMENTS < LED_SEGMENTS // 2


def assign_roof_lamps(vehicles: Iterable[SimVehicle], led_fraction: float, chase_fraction: float,
                      rng: np.random.Generator) -> int:
    """Give a seeded fraction ``led_fraction`` of the buses among ``vehicles`` an LED strip, ``chase_fraction`` of
    those chasing, a third of them white (blue otherwise), rate and start phase seeded per bus; returns how many got
    one. Four draws per bus (none for other vehicles) whatever the fractions."""
    n = 0
    for v in vehicles:
        if v.kind != "bus" or v.is_static:
            continue
        r, chase, f, white = rng.random(), rng.random(), rng.uniform(BEACON_FREQ_MIN_HZ, BEACON_FREQ_MAX_HZ), rng.random()
        if r >= led_fraction:
            continue
        v.style = with_roof_lamps(v.style, "led_chase" if chase < chase_fraction else "led", f, float(r),
                                  white < 1 / 3)
        n += 1
    return n


DECOY_KINDS = ("hazard", "turn_signal", "beacon", "led_strip", "brake_lights")
"""The lamps ``decoy_kind`` names (``bench/ev_bench.py`` counts alerts on each)."""


def decoy_kind(style: int) -> str | None:
    """The decoy lamp of a vehicle with this style: ``beacon`` or ``led_strip`` (roof lamps, first), ``hazard`` or
    ``turn_signal``; None when it has none (brake lights are a state, not a style: the caller names them)."""
    roof = style_roof(style)
    if roof is not None:
        return "beacon" if roof.mode == "beacon" else "led_strip"
    sig = style_signal(style)
    if sig is not None:
        return "hazard" if sig.mode == "hazard" else "turn_signal"
    return None


def decoy_lit(style: int, t_s: float) -> bool:
    """Whether the decoy lamps of a vehicle with this style (``decoy_kind``) are lit at sim time t_s (a chasing
    strip always has half its segments lit)."""
    if style_roof(style) is not None:
        return roof_state(style, t_s) != 0
    return signal_on(style, t_s)
