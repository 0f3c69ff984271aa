"""The camera sensor's effects on a rendered frame: auto-exposure drift and sensor noise.

Exposure: a slow gain oscillation ``g(t)`` and a per-lighting gamma: ``255 (min(1, x g / 255)) ** gamma`` per
channel value x. Since ``(x g / 255) ** gamma = g ** gamma (x / 255) ** gamma``, it is also a fixed gamma table
followed by one scale per frame, clipped at 255: a saturating scale of a kept image costs 4.1 M instructions for
a 1280x720 frame against 16.7 M for a 256-entry LUT pass (callgrind). Only the pixels a frame drew on
(``DirtyBands``) go through a table, this frame's ``exposure_table``. ``exposure_lut`` is the direct form, kept for
``bench.render_reference``; a renderer without noise scales the static scene's gamma image (``expose``).

Noise: a Gaussian field a little larger than the image, generated once per lighting, added (saturating) at an
offset: one of ``NOISE_SLOTS`` offsets, drawn per frame (``noise_slot``). With noise on, ``sim.render.renderer.Renderer``
keeps the static scene exposed at unit gain with each slot's noise added (``noise_bank``) and scales it by the
frame's gain (``expose_bank``: one pass over the frame instead of a scale and the noise's add and subtract); the
pixels a frame drew on take the exposure table and then the slot's noise. ``ReferenceRenderer`` exposes and then adds
the noise everywhere."""

from __future__ import annotations

import math
from functools import cache

import cv2
import numpy as np

EXPOSURE_GAMMA = {"day": 0.95, "dusk": 0.9, "night": 0.85}
NOISE_PAD_PX = 64
"""How much larger than the image the noise field is, either way: the range of its per-frame offset."""
NOISE_SLOTS = 8
"""How many noise offsets a camera's frames take theirs from (``noise_slot``): the static scene is kept exposed at
unit gain with each slot's noise added (``noise_bank``, 8 x 2.8 MB at 1280x720), so a frame's static part is one
scale of a kept image (the exposure's and the noise's three passes over the frame cost ~2 ms)."""
GAMMA_SCALE = 256
"""The gamma table's fixed-point scale: its uint16 entries are 256 x the 0-255 value, so that one scale per frame
loses under 1/256 of a level to the table's rounding."""


def exposure_gain(t_s: float, seed: int) -> float:
    """Auto-exposure drift: a 9 s and a 2.3 s oscillation (+-7 % and +-3 %) with a phase from the camera's seed."""
    phase = (seed % 97) * 0.37
    return 1.0 + 0.07 * math.sin(2 * math.pi * t_s / 9.0 + phase) + 0.03 * math.sin(2 * math.pi * t_s / 2.3 + phase)


def exposure_lut(t_s: float, seed: int, lighting: str) -> np.ndarray:
    """The exposure at ``t_s`` as one 256-entry uint8 table (the direct form, in float32)."""
    x = np.arange(256, dtype=np.float32) / 255.0
    gain = exposure_gain(t_s, seed)
    return np.clip(255.0 * np.power(np.clip(x * gain, 0, 1), EXPOSURE_GAMMA[lighting]), 0, 255).astype(np.uint8)


@cache
def gamma_table(lighting: str) -> np.ndarray:
    """The lighting's gamma as a 256-entry uint16 table in ``GAMMA_SCALE`` fixed point: round(256 * 255 (x/255)^g)."""
    x = np.arange(256, dtype=np.float64) / 255.0
    table = np.round(GAMMA_SCALE * 255.0 * np.power(x, EXPOSURE_GAMMA[lighting])).astype(np.uint16)
    table.flags.writeable = False
    return table


def exposure_scale(t_s: float, seed: int, lighting: str) -> float:
    """The per-frame factor that takes a ``gamma_table`` value to the exposed 0-255 value: g(t) ** gamma / 256."""
    return exposure_gain(t_s, seed) ** EXPOSURE_GAMMA[lighting] / GAMMA_SCALE


def expose(gamma_image: np.ndarray, scale: float, dst: np.ndarray | None = None) -> np.ndarray:
    """uint8 exposed image from a ``gamma_table`` image (uint16): saturate(scale x v), rounded down as the direct
    table's float-to-uint8 cast does (``convertScaleAbs`` rounds to nearest: hence the -0.5)."""
    return cv2.convertScaleAbs(gamma_image, dst=dst, alpha=scale, beta=-0.5)


def exposure_table(lighting: str, scale: float) -> np.ndarray:
    """The exposed value of every 0-255 canvas value at this frame's ``scale``: ``expose`` of the lighting's
    ``gamma_table`` (a 256-entry uint8 table). A pixel's exposed value depends on its canvas value alone, so one
    table pass over the pixels a frame drew on gives what the table to uint16 and the scale gave, in one pass
    instead of two (a 16 x 900 band: 29 us against 81)."""
    return expose(gamma_table(lighting).reshape(1, 256), scale).reshape(256)


def expose_spans(out: np.ndarray, canvas: np.ndarray, spans: list[tuple[int, int, int, int]], table: np.ndarray,
                 field: tuple[np.ndarray, np.ndarray] | None = None, offset: tuple[int, int] = (0, 0)) -> np.ndarray:
    """``out`` (changed in place and returned) with each span (y1, y2, x1, x2: ``DirtyBands.spans``) of ``canvas``
    through the frame's ``exposure_table`` and, when a noise ``field`` is given, the field cut at ``offset`` added
    (saturating)."""
    dx, dy = offset
    for y1, y2, x1, x2 in spans:
        o = cv2.LUT(canvas[y1:y2, x1:x2], table, dst=out[y1:y2, x1:x2])
        if field is not None:
            add_noise(o, field, (dx + x1, dy + y1))
    return out


def standard_noise(seed: int, height_px: int, width_px: int) -> np.ndarray:
    """The N(0, 1) field (float64, ``NOISE_PAD_PX`` larger than the image either way, 3 channels) that every lighting's
    sensor noise scales (``noise_field``): made once for all a camera's lightings, the costly part (~50 ms)."""
    return np.random.default_rng(seed + 7).standard_normal((height_px + NOISE_PAD_PX, width_px + NOISE_PAD_PX, 3))


def noise_field(seed: int, lighting: str, sigma: float, height_px: int, width_px: int,
                standard: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The lighting's sensor-noise field, N(0, sigma) per pixel and channel (sigma x ``standard_noise``, made here when
    not given: the values numpy's ``normal(0, sigma)`` draws from the same generator), ``NOISE_PAD_PX`` larger than
    the image either way, as its positive and negative parts (uint8, truncated): added and subtracted with
    saturation."""
    z = standard_noise(seed, height_px, width_px) if standard is None else standard
    n = (sigma * z).astype(np.float32)
    return np.clip(n, 0, 255).astype(np.uint8), np.clip(-n, 0, 255).astype(np.uint8)


def _splitmix(seed: int, index: int) -> int:
    """A SplitMix64 hash of (seed, index) (a few microseconds; a seeded numpy generator costs ~50)."""
    z = (seed * 0x9E3779B97F4A7C15 + index * 0xBF58476D1CE4E5B9 + 0x94D049BB133111EB) & 0xFFFFFFFFFFFFFFFF
    z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & 0xFFFFFFFFFFFFFFFF
    z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & 0xFFFFFFFFFFFFFFFF
    return z ^ (z >> 31)


def noise_offset(seed: int, slot: int) -> tuple[int, int]:
    """Where noise slot ``slot`` (``noise_slot``) cuts the image out of the noise field: (dx, dy) in
    [0, NOISE_PAD_PX), from a hash of (seed, slot)."""
    z = _splitmix(seed, slot)
    return int(z % NOISE_PAD_PX), int((z >> 32) % NOISE_PAD_PX)


def noise_slot(seed: int, frame_index: int) -> int:
    """Which of the ``NOISE_SLOTS`` noise offsets frame ``frame_index`` takes: a hash of (seed, frame index)."""
    return int(_splitmix(seed + 0x632BE59BD9B4E019, frame_index) % NOISE_SLOTS)


def noise_bank(unit_exposed: np.ndarray, field: tuple[np.ndarray, np.ndarray], seed: int) -> list[np.ndarray]:
    """Per noise slot, ``unit_exposed`` (a static scene exposed at unit gain: ``exposure_table(lighting,
    1 / GAMMA_SCALE)``) with the slot's noise added: what a frame's static part is, before the frame's gain
    (``expose_bank``)."""
    return [add_noise(unit_exposed.copy(), field, noise_offset(seed, slot)) for slot in range(NOISE_SLOTS)]


def expose_bank(bank_image: np.ndarray, scale: float) -> np.ndarray:
    """A new uint8 image: a ``noise_bank`` image at this frame's exposure (``exposure_scale``): saturate(round(
    scale x GAMMA_SCALE x v)), the gain applied after the noise, as a sensor's analogue gain amplifies its read
    noise. Against the gain before the noise it differs by the gain's share of the noise (under 11 %) and a level of
    rounding, and where the value saturates (sensor noise: sigma 2.5-6 levels)."""
    return cv2.convertScaleAbs(bank_image, alpha=scale * GAMMA_SCALE)


def add_noise(img: np.ndarray, field: tuple[np.ndarray, np.ndarray], offset: tuple[int, int]) -> np.ndarray:
    """``img`` (uint8, changed in place and returned) plus the noise field cut at ``offset`` (saturating)."""
    (pos, neg), (dx, dy) = field, offset
    h, w = img.shape[:2]
    cv2.add(img, pos[dy:dy + h, dx:dx + w], dst=img)
    return cv2.subtract(img, neg[dy:dy + h, dx:dx + w], dst=img)


class DirtyBands:
    """The part of a frame drawn on, as one column span per band of ``band_px`` rows: rectangles are marked as
    they are drawn; ``spans`` gives, per band with a mark, its rows and the columns from its leftmost to its
    rightmost mark (a superset of the marks: everything drawn is in it)."""

    def __init__(self, height_px: int, width_px: int, band_px: int = 16) -> None:
        self.h, self.w, self.band_px = height_px, width_px, band_px
        self._marks: list[float] = []  # x1, y1, x2, y2 of each mark in turn
        self._spans: list[tuple[int, int, int, int]] | None = []

    def mark(self, x1: float, y1: float, x2: float, y2: float) -> None:
        """Mark the rectangle [x1, x2) x [y1, y2) (pixels; cut to the image by ``spans``)."""
        self._marks.extend((x1, y1, x2, y2))
        self._spans = None

    def spans(self) -> list[tuple[int, int, int, int]]:
        """(y1, y2, x1, x2) per band with a mark, top to bottom."""
        if self._spans is None:
            m = np.array(self._marks, float).reshape(-1, 4)
            x1, y1 = np.maximum(m[:, :2], 0).astype(int).T
            x2, y2 = np.minimum(np.ceil(m[:, 2:]), (self.w, self.h)).astype(int).T
            keep = (x2 > x1) & (y2 > y1)
            bp = self.band_px
            b1, b2 = y1[keep] // bp, (y2[keep] - 1) // bp
            band = np.arange(-(-self.h // bp))
            reach = (b1[:, None] <= band) & (band <= b2[:, None])  # (marks, bands): the mark reaches the band
            lo = np.where(reach, x1[keep][:, None], self.w).min(axis=0, initial=self.w)
            hi = np.where(reach, x2[keep][:, None], 0).max(axis=0, initial=0)
            self._spans = [(b * bp, min(self.h, (b + 1) * bp), int(lo[b]), int(hi[b]))
                           for b in np.flatnonzero(hi > lo).tolist()]
        return self._spans

    def clear(self) -> None:
        self._marks.clear()
        self._spans = []
