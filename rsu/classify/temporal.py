"""Per-track temporal EV evidence: flashing light bars and accumulated crop scores, with hysteresis.

None of the source documents decide per *track over time*; this module does (Framework B, thesis 2.3,
classifies tracks, not frames). Two cues are combined:

1. **Lamp signal.** In the top band of the box (where a light bar sits when seen from an elevated
   camera) we measure the fraction of pixels that are *bright, saturated* red and blue (lamps, not
   paint: V >= 240 and S >= 120; tuned on simulator renders, seeds 1-2, where sunlit red paint
   reaches V ~ 239 and lamps saturate). Emergency lamps flash at 1-4 Hz, alternating red/blue or strobing;
   so the lamp signal of an EV *modulates*: it switches between clearly-on and clearly-off within a
   fraction of a second. Brake and tail lights switch once and then stay steady (and sit low on the
   body, mostly outside the band), a red or blue car is steady paint that is rarely lamp-bright. A
   frame gives **flash evidence** when, within the last ``flash_window_s``, a lamp colour has been
   both clearly on (fraction >= ``lamp_on_fraction``) and clearly off (<= ``lamp_off_ratio`` of that
   peak) at least ``min_transitions`` times over at least ``min_on_samples`` lit frames, i.e. it
   blinked (a brake light switching on once, or one glint, does not); once a long enough history exists the
   blink rate must also lie in ``[flash_min_hz, flash_max_hz]``.
2. **Crop score.** Any per-crop classifier's EV probability (the CNN of thesis 2.4.2.3 or a feature
   classifier), accumulated as log-odds.

The rule (per track, each frame):

    L <- clamp(L + logit(score) - logit(prior) + (flash_gain if flash evidence else -decay), L_min, L_max)

- ``none`` -> ``candidate`` when L > ``candidate_level``;
- ``candidate`` -> ``confirmed`` when L >= ``confirm_level`` **and** flash evidence is present now
  (a light bar that is not flashing never confirms, whatever a crop classifier says);
- ``confirmed`` -> ``cleared`` when no lamp has been lit for ``clear_after_s`` (lights off; a
  flashing bar is never dark that long) — the RSU also clears a track that leaves the view;
- ``candidate`` -> ``none`` when L falls back below ``candidate_level``.

Because L is clamped and moves by bounded steps, one bad frame can neither raise an alert nor clear
one: confirming needs several consistent frames, clearing needs ``clear_after_s`` without flashes.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

import cv2
import numpy as np

from protocol.messages import EvState, LightState


@dataclass(frozen=True)
class LampMeasurement:
    """Bright saturated red and blue pixel fractions in the top band of one crop."""

    red: float
    blue: float


def measure_lamps(crop_bgr: np.ndarray, top_fraction: float = 0.4, min_value: int = 240,
                  min_saturation: int = 120) -> LampMeasurement:
    """Fractions of the top band's pixels that are lamp-bright saturated red / blue."""
    if crop_bgr.ndim != 3 or crop_bgr.shape[0] < 2 or crop_bgr.shape[1] < 2:
        return LampMeasurement(0.0, 0.0)
    rows = max(1, int(round(crop_bgr.shape[0] * top_fraction)))
    hsv = cv2.cvtColor(np.ascontiguousarray(crop_bgr[:rows]), cv2.COLOR_BGR2HSV)
    h, s, v = hsv[..., 0], hsv[..., 1], hsv[..., 2]
    bright = (s >= min_saturation) & (v >= min_value)
    red = bright & ((h <= 10) | (h >= 170))
    blue = bright & (h >= 100) & (h <= 130)
    n = float(h.size)
    return LampMeasurement(float(np.count_nonzero(red)) / n, float(np.count_nonzero(blue)) / n)


@dataclass(frozen=True)
class EvidenceConfig:
    lamp_on_fraction: float = 0.025
    """A lamp colour counts as on above this fraction of the band's pixels."""
    lamp_off_ratio: float = 0.2
    """... and as off below this share of its recent peak."""
    flash_window_s: float = 1.5
    min_on_samples: int = 2
    """... and a single bright frame (a glint) is not a blink."""
    min_transitions: int = 2
    """A blink is on->off or off->on->off: a brake light switching on once is a single transition."""
    flash_min_hz: float = 0.7
    flash_max_hz: float = 6.0
    rate_check_after_s: float = 1.4
    """The blink rate is checked once this much history shows the lamp."""
    prior: float = 0.05
    flash_gain: float = 1.6
    decay: float = 0.5
    level_min: float = -1.0
    level_max: float = 6.0
    candidate_level: float = 0.5
    confirm_level: float = 2.0
    clear_after_s: float = 2.0
    max_history: int = 256


def _logit(p: float) -> float:
    p = min(max(p, 1e-4), 1 - 1e-4)
    return math.log(p / (1 - p))


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


@dataclass
class TrackEvidence:
    """The temporal EV state of one track (see the module docstring for the rule)."""

    config: EvidenceConfig = field(default_factory=EvidenceConfig)
    state: EvState = EvState.NONE
    level: float = 0.0
    frames: int = 0
    score_sum: float = 0.0
    last_flash_s: float | None = None
    last_lamp_on_s: float | None = None
    confirmed_at_s: float | None = None
    flash_hz: float | None = None
    _t: deque = field(default_factory=deque)
    _red: deque = field(default_factory=deque)
    _blue: deque = field(default_factory=deque)

    def _flashing(self, now_s: float) -> bool:
        cfg = self.config
        t = np.fromiter(self._t, float)
        keep = t >= now_s - cfg.flash_window_s
        t = t[keep]
        if len(t) < 3:
            return False
        best_hz = None
        flashing = False
        for series in (self._red, self._blue):
            x = np.fromiter(series, float)[keep]
            peak = float(x.max())
            if peak < cfg.lamp_on_fraction:
                continue
            on_level = max(cfg.lamp_on_fraction, 0.6 * peak)
            n = blink_transitions(x, on_level, cfg.lamp_off_ratio * peak)
            if n < cfg.min_transitions or int(np.count_nonzero(x >= on_level)) < cfg.min_on_samples:
                continue
            lit = np.flatnonzero(x >= on_level)
            span = float(t[-1] - t[lit[0]])  # history since the lamp was first seen lit in the window
            hz = n / (2.0 * span) if span > 0 else None
            if span >= cfg.rate_check_after_s and hz is not None and not (cfg.flash_min_hz <= hz <= cfg.flash_max_hz):
                continue
            flashing = True
            if hz is not None and span >= cfg.rate_check_after_s:
                best_hz = hz if best_hz is None else max(best_hz, hz)
        if best_hz is not None:
            self.flash_hz = best_hz
        return flashing

    def update(self, now_s: float, lamps: LampMeasurement, crop_score: float | None = None) -> EvState:
        cfg = self.config
        self._t.append(now_s)
        self._red.append(lamps.red)
        self._blue.append(lamps.blue)
        while len(self._t) > cfg.max_history or (self._t and self._t[0] < now_s - 2 * cfg.flash_window_s):
            self._t.popleft()
            self._red.popleft()
            self._blue.popleft()
        self.frames += 1
        flashing = self._flashing(now_s)
        if flashing:
            self.last_flash_s = now_s
        if max(lamps.red, lamps.blue) >= cfg.lamp_on_fraction:
            self.last_lamp_on_s = now_s
        step = cfg.flash_gain if flashing else -cfg.decay
        if crop_score is not None:
            self.score_sum += crop_score
            step += _logit(crop_score) - _logit(cfg.prior) if crop_score > cfg.prior else 0.0
        self.level = min(max(self.level + step, cfg.level_min), cfg.level_max)

        if self.state in (EvState.NONE, EvState.CLEARED, EvState.CANDIDATE):
            if self.level >= cfg.confirm_level and flashing:
                self.state = EvState.CONFIRMED
                self.confirmed_at_s = now_s
            elif self.level > cfg.candidate_level:
                self.state = EvState.CANDIDATE
            elif self.state == EvState.CANDIDATE:
                self.state = EvState.NONE
        elif self.state == EvState.CONFIRMED:
            if self.last_lamp_on_s is None or now_s - self.last_lamp_on_s >= cfg.clear_after_s:
                self.state = EvState.CLEARED
                self.level = min(self.level, 0.0)
        return self.state

    @property
    def light_state(self) -> LightState:
        if self.frames == 0:
            return LightState.UNKNOWN
        recent = self.last_flash_s is not None and self._t and self._t[-1] - self.last_flash_s < self.config.clear_after_s
        return LightState.FLASHING if recent else LightState.OFF

    @property
    def ev_score(self) -> float:
        """A probability-like summary of the evidence level for ``DetectedObject.ev_score``."""
        return 1.0 / (1.0 + math.exp(-(self.level - self.config.candidate_level)))

    @property
    def mean_crop_score(self) -> float:
        return self.score_sum / self.frames if self.frames else 0.0
