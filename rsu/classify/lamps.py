"""Lamp signals of one vehicle crop and their flash patterns.

:func:`measure_lamps` reads the *lamp band* of a crop (the top rows, where a light bar sits when the
camera looks down at a vehicle; the caller grows the box upwards first, since a roof bar sits above a
COCO car box): the fractions of its pixels that are lamp-bright red and blue, and the share of those
pixels in the central half of the band's width (and white, with the light-bar definition). A light bar sits on the roof,
in the middle; tail, brake and turn lamps and hazard flashers sit at the corners of the body, so a
lamp whose light lies at the sides (centre share < 0.5) is a corner lamp and gives no EV evidence
(:class:`rsu.classify.temporal.TrackEvidence`).

Two colour definitions are used. :data:`LAMP_BRIGHT` (HSV: V >= 240, S >= 120) is a lamp that
saturates the sensor, as every lit lamp does in the simulator's renders; a flash pattern in it is strong
enough to confirm an EV alone. :data:`BAR_COLOURED` is what a real light bar looks like in compressed
video: a bright red or blue *chroma* (the channel >= 180 and R - max(G, B) or B - max(R, G) >= 50; a red one
within 20 degrees of hue, so that an amber beacon is not red).
Measured frame by frame (the escort, Japanese-ambulance and NYC-police clips are
the tuning clips of this definition): the escort's bars have S ~ 100-115; the Japanese ambulance's lit
lamps are pink-red points (RGB ~ (233, 101, 120), (255, 164, 195): hue 160-170, S ~ 90-140) on a
dark-red dome (R ~ 120-150). The HSV test misses those; the chroma test sees them. A channel floor of
100 also saw the NYC police bars, dark red domes (R ~ 100-180) that never look lit, but it saw the
simulator's *unlit* bars too: with a confident body the sim EV alerted before its lights went on
(ev_bench seeds 301/302: 3 false alerts); at 180 it does not. The chroma test also sees red and blue
paint, so it counts only together with a confident EV body, a compact central blob (not paint over the
body) and the corner-lamp rejection (:class:`rsu.classify.temporal.TrackEvidence`).

:func:`lamp_runs` cuts a lamp signal into lit runs with hysteresis and :func:`flash_pattern` names the
cue a window of runs shows: ``flash`` or ``alternation``; :func:`median_of` is the exact median of a window's
samples at a tenth of numpy's per-call cost.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


@dataclass(frozen=True)
class LampMeasurement:
    """Red, blue (and, with the light-bar definition, white) lamp pixel fractions in the lamp band of one
    crop, and the share of each colour's lamp pixels in the central half of the band's width (1.0 when none
    is lit)."""

    red: float
    blue: float
    red_centre: float = 1.0
    blue_centre: float = 1.0
    white: float = 0.0
    white_centre: float = 1.0
    red_core: float = 1.0
    """Share of the red lamp pixels whose channel reaches ``LampColours.core_min_value`` (1.0 when none is lit
    or the definition has no core): a lit lamp clips the sensor, paint does not."""
    blue_core: float = 1.0
    red_peak: float = 1.0
    """The red lamp pixels' brightest red channel, as a share of 255 (1.0 when none is lit or with the ``hsv``
    definition): a lit lamp clips the sensor (255) at its brightest point, sunlit paint stays below."""
    blue_peak: float = 1.0

    @property
    def coloured(self) -> float:
        """The larger of the red and blue fractions."""
        return max(self.red, self.blue)


@dataclass(frozen=True)
class LampColours:
    """What counts as a lamp pixel. ``hsv``: OpenCV HSV (H 0-180, S and V 0-255) with ``min_value`` and
    ``min_saturation``; ``chroma``: the red (blue) channel at least ``min_value`` and at least ``min_chroma``
    above the larger of the other two."""

    kind: str = "hsv"
    min_value: int = 240
    min_saturation: int = 120
    min_chroma: int = 50
    white_min_value: int = 0
    """``chroma`` only: a white lamp pixel has every channel at least this (0: white not measured)."""
    white_max_chroma: int = 40
    """... and its channels at most this far apart."""
    core_min_value: int = 0
    """``chroma`` only: a red (blue) pixel whose channel reaches this is a lamp's *core* (0: not measured)."""


LAMP_BRIGHT = LampColours()
"""A lamp that saturates the sensor (tuned on simulator seeds 1-2, where sunlit red paint reaches V 239)."""
BAR_COLOURED = LampColours(kind="chroma", min_value=180, min_chroma=50, white_min_value=245, core_min_value=220)
"""A red or blue light bar in compressed real video, lit or dim, and white lamps (every channel >= 245, within
40 of each other: a lit white strobe clips the sensor) (module docstring)."""


def _centre_share(mask: np.ndarray, count: int | None = None) -> float:
    """The share of the mask's pixels in the middle half of its columns (1.0 for an empty mask); ``count``: the
    mask's pixel count when the caller has it (an empty mask, the common case, then costs nothing)."""
    if count == 0:
        return 1.0
    cols = np.count_nonzero(mask, axis=0)
    total = int(cols.sum())
    if total == 0:
        return 1.0
    w = mask.shape[1]
    return float(cols[w // 4: w - w // 4].sum()) / total


def measure_band(crop_bgr: np.ndarray, top_fraction: float, colour_sets: tuple[LampColours, ...],
                 ignore: np.ndarray | None = None) -> tuple[LampMeasurement, ...]:
    """One :class:`LampMeasurement` per colour definition of the top ``top_fraction`` band of a crop, the band
    cut out (and converted to HSV, when a definition needs it) once. ``ignore`` (a boolean mask of the crop)
    leaves pixels out: those of nearer vehicles that occlude it."""
    if crop_bgr.ndim != 3 or crop_bgr.shape[0] < 2 or crop_bgr.shape[1] < 2:
        return tuple(LampMeasurement(0.0, 0.0) for _ in colour_sets)
    rows = max(1, int(round(crop_bgr.shape[0] * top_fraction)))
    band = np.ascontiguousarray(crop_bgr[:rows])
    keep = None if ignore is None else ~ignore[:rows]
    n = float(band.shape[0] * band.shape[1]) if keep is None else float(max(np.count_nonzero(keep), 1))
    hsv = cv2.cvtColor(band, cv2.COLOR_BGR2HSV) if any(c.kind != "chroma" for c in colour_sets) else None
    bgr = band.astype(np.int16) if any(c.kind == "chroma" for c in colour_sets) else None
    out = []
    for c in colour_sets:
        if c.kind == "chroma":
            b, g, r = bgr[..., 0], bgr[..., 1], bgr[..., 2]
            # hue within 20 degrees of red (60 (g - b) / (r - min(g, b)) <= 20), as the HSV test's: an amber
            # works beacon (hue ~30 degrees) has as much red chroma as a red bar
            red = (r >= c.min_value) & (r - np.maximum(g, b) >= c.min_chroma) & (3 * (g - b) <= r - np.minimum(g, b))
            blue = (b >= c.min_value) & (b - np.maximum(r, g) >= c.min_chroma)
        else:
            h, s, v = hsv[..., 0], hsv[..., 1], hsv[..., 2]
            bright = (s >= c.min_saturation) & (v >= c.min_value)
            red = bright & ((h <= 10) | (h >= 170))
            blue = bright & (h >= 100) & (h <= 130)
        white = None
        if c.kind == "chroma" and c.white_min_value > 0:
            lo, hi = np.minimum(np.minimum(b, g), r), np.maximum(np.maximum(b, g), r)
            white = (lo >= c.white_min_value) & (hi - lo <= c.white_max_chroma)
        if keep is not None:
            red, blue = red & keep, blue & keep
            white = None if white is None else white & keep
        n_white = 0 if white is None else int(np.count_nonzero(white))
        w_frac, w_centre = (0.0, 1.0) if white is None else (float(n_white) / n, _centre_share(white, n_white))
        n_red, n_blue = int(np.count_nonzero(red)), int(np.count_nonzero(blue))
        red_core = blue_core = 1.0
        red_peak = blue_peak = 1.0
        if c.kind == "chroma":
            if c.core_min_value > 0:
                red_core = float(np.count_nonzero(red & (r >= c.core_min_value))) / n_red if n_red else 1.0
                blue_core = float(np.count_nonzero(blue & (b >= c.core_min_value))) / n_blue if n_blue else 1.0
            red_peak = float(r[red].max()) / 255.0 if n_red else 1.0
            blue_peak = float(b[blue].max()) / 255.0 if n_blue else 1.0
        out.append(LampMeasurement(float(n_red) / n, float(n_blue) / n, _centre_share(red, n_red),
                                   _centre_share(blue, n_blue),
                                   w_frac, w_centre, red_core, blue_core, red_peak, blue_peak))
    return tuple(out)


def measure_lamps(crop_bgr: np.ndarray, top_fraction: float = 0.4, min_value: int = 240,
                  min_saturation: int = 120, *, colours: LampColours | None = None,
                  ignore: np.ndarray | None = None) -> LampMeasurement:
    """Fractions of the top ``top_fraction`` band's pixels that are red / blue lamp pixels and their central
    shares (:func:`measure_band` with one definition; ``colours`` overrides the keyword thresholds)."""
    c = colours or LampColours(min_value=min_value, min_saturation=min_saturation)
    return measure_band(crop_bgr, top_fraction, (c,), ignore)[0]


def median_of(x: np.ndarray) -> float:
    """``float(np.median(x))`` of a short 1-D array, the same value (the middle one, or the mean of the two middle
    ones; NaN when any value is NaN) at a tenth of numpy's per-call cost on the few dozen samples of a window."""
    v = sorted(x.tolist())
    n = len(v)
    if n == 0 or any(a != a for a in v):
        return float(np.median(x))  # empty (numpy's warning and NaN) or NaN present: numpy's answer
    m = n // 2
    return float(v[m]) if n % 2 else (v[m - 1] + v[m]) / 2.0


def blink_transitions(values: np.ndarray, on_level: float, off_level: float) -> int:
    """Number of on<->off switches of a signal with hysteresis (on above ``on_level``, off below ``off_level``)."""
    state = None
    n = 0
    for v in values:
        new = True if v >= on_level else False if v <= off_level else state
        if state is not None and new is not None and new != state:
            n += 1
        if new is not None:
            state = new
    return n


@dataclass(frozen=True)
class LampRun:
    """One lit stretch of a lamp colour: first and last lit sample times, lit samples, and whether it
    was seen dark just before it and just after it (a *complete* flash)."""

    start_s: float
    end_s: float
    samples: int
    dark_before: bool
    dark_after: bool
    frame_s: float
    dark_before_s: float = 0.0
    """How long it was dark before this run (since the previous run, or the start of the window)."""

    @property
    def duration_s(self) -> float:
        return self.end_s - self.start_s + self.frame_s

    @property
    def complete(self) -> bool:
        return self.dark_before and self.dark_after

    def is_flash(self, min_dark_ratio: float) -> bool:
        """A complete run that was dark before it for at least ``min_dark_ratio`` of its own length:
        flashers have duty cycles near or below 50 %, a steady lamp dropping out for a frame has not."""
        return self.complete and self.dark_before_s >= min_dark_ratio * self.duration_s


def lamp_runs(t: np.ndarray, x: np.ndarray, on_level: float, off_level: float, frame_s: float) -> list[LampRun]:
    """Lit runs of a lamp signal with hysteresis (lit at or above ``on_level``, dark at or below
    ``off_level``, in between: unchanged)."""
    runs: list[LampRun] = []
    state: bool | None = None
    start = last = 0
    n = 0
    before = False
    prev_end = float(t[0]) - frame_s if len(t) else 0.0
    for i, v in enumerate(x):
        new = True if v >= on_level else False if v <= off_level else state
        if new and not state:
            start, n, before = i, 0, state is False
        if new:
            n += 1 if v >= on_level else 0
            last = i
        if state and new is False:
            runs.append(LampRun(float(t[start]), float(t[last]), n, before, True, frame_s,
                                float(t[start]) - prev_end - frame_s))
            prev_end = float(t[last])
        if new is not None:
            state = new
    if state:
        runs.append(LampRun(float(t[start]), float(t[last]), n, before, False, frame_s,
                            float(t[start]) - prev_end - frame_s))
    return runs


def flash_pattern(red: list[LampRun], blue: list[LampRun], cfg) -> str | None:
    """The flash cue in the short lit runs of the two lamp colours in the window (``temporal`` module
    docstring): ``"flash"`` for two complete flashes of one colour at most ``max_dark_s`` apart,
    ``"alternation"`` for a complete flash of one colour handing over to (or lit together with) the other
    colour, each with at least ``min_on_samples`` lit samples in all (one glitch frame is not a flash);
    None when neither. ``cfg`` is a :class:`rsu.classify.evidence_config.EvidenceConfig`."""
    for runs in (red, blue):
        flashes = [r for r in runs if r.is_flash(cfg.min_dark_ratio)]
        for a, b in zip(flashes, flashes[1:], strict=False):
            if b.start_s - a.end_s <= cfg.max_dark_s and a.samples + b.samples > cfg.min_on_samples:
                return "flash"
    for first, other in ((red, blue), (blue, red)):
        for a in first:
            if not a.is_flash(cfg.min_dark_ratio):
                continue
            for b in other:
                lit = a.samples + b.samples
                if a.start_s <= b.start_s <= a.end_s + cfg.handover_s and lit >= cfg.min_on_samples and (
                        b.start_s > a.start_s or lit > cfg.min_on_samples):
                    return "alternation"
    return None
