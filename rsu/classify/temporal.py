"""Per-track temporal EV evidence: flashing light bars and accumulated crop scores, with hysteresis.

None of the source documents decide per *track over time*; this module does (Framework B, thesis 2.3,
classifies tracks, not frames). Three cues are combined:

1. **Lamp signal.** In the top band of the box (where a light bar sits when seen from an elevated
   camera) we measure the fraction of pixels that are *bright, saturated* red and blue (lamps, not
   paint: V >= 240 and S >= 120; tuned on simulator renders, seeds 1-2, where sunlit red paint
   reaches V ~ 239 and lamps saturate). Emergency lamps flash at 1-4 Hz, alternating red/blue or strobing;
   so the lamp signal of an EV *modulates*: it switches between clearly-on and clearly-off within a
   fraction of a second, and each flash is *short* (at most half a period, 0.5 s at 1 Hz). Brake and
   tail lights switch once and then stay steady (and sit low on the body, mostly outside the band),
   a red or blue car is steady paint that is rarely lamp-bright. Each colour's signal is cut into lit
   runs with hysteresis (lit at >= max(``lamp_on_fraction``, half the window's peak), dark at <=
   ``lamp_off_ratio`` of the peak); a run seen dark before and after is a *complete flash*. A frame
   gives **flash evidence** when, within the last ``flash_window_s``:
   - no colour that counts was lit longer than ``max_on_s`` (a steady lamp that only *seems* to
     blink because the box around it jitters, or a merged blob shifts, is lit for long stretches; so
     is brake pumping, 0.3-0.5 Hz), and
   - a *flash* is a complete run that followed a dark stretch at least ``min_dark_ratio`` of its own
     length (flashers are dark about half the time or more; a steady lamp that drops out of the band
     for a frame is not), the dark stretch measured over the whole history kept, not only the window;
   - either one colour flashed twice at most ``max_dark_s`` apart, or a complete flash of
     one colour handed over to the other colour (it lit within ``handover_s`` of the flash's end, or
     together with it): red/blue alternation, seen after a single flash, which is what makes the
     confirmation fast (about half a period after the lights go on);
   - with at least ``min_on_samples`` lit samples in the pattern (a one-frame glint is no flash);
   once a long enough history shows the lamp, its blink rate must also lie in
   ``[flash_min_hz, flash_max_hz]``.
2. **Crop score.** Any per-crop classifier's EV probability (the CNN of thesis 2.4.2.3 or a feature
   classifier), accumulated as log-odds.
3. **EV body**. A classifier trained on real vehicles (``models/ev_body.onnx``,
   :class:`rsu.classify.body.EvBodyClassifier`) scores the track's crop while the track shows lamp
   activity, a few times a second; the body score is the mean of the last ``body_window`` scores.
   Real LED bars often read as *steady* at video frame rates (lit on every frame, or dipping for single
   frames at ~80 % duty), so a third lamp cue, the **steady bar**, is accepted *only* with a confident
   body: a red or blue lamp in the middle of the band, covering at most ``steady_max_fraction`` of it
   (a bar, not paint), lit on at least ``steady_min_share`` of the samples of the last ``steady_window_s``,
   with a lamp's clipped core in at least ``steady_min_core`` of its pixels (lit, not sunlit paint).
   White lamps (strobes) are measured in the light-bar definition too; they give a flash cue (two complete
   flashes), which, like every light-bar cue, counts only with a confident body; a steady white never counts
   (sky, a white roof, headlight glare).

Lamps at the corners of the band (centre share < ``centre_min_share``: tail, brake and turn lamps,
hazard flashers) give no cue of any kind.

The rule (per track, each frame):

    L <- clamp(L + logit(score) - logit(prior) + (flash_gain if flash evidence else -decay), L_min, L_max)

- ``none`` -> ``candidate`` when L > ``candidate_level``;
- ``candidate`` -> ``confirmed`` when L >= ``confirm_level`` **and** flash evidence is present now
  (a flash pattern alone: a light bar that is not flashing never confirms this way, whatever a crop
  classifier says; a flash of one colour only where the lamp-state model sees lit lamps,
  ``EvidenceConfig.lit_flash_min``, while red/blue alternation needs no model), **or** when the body score is at least ``body_threshold`` over at least
  ``body_min_scores`` scores (or the last ``body_sure_min_scores`` each reach ``body_sure_threshold``)
  **and** a lamp cue (flash, alternation or steady bar) is present now;
- ``confirmed`` -> ``cleared`` when no lamp has been lit for ``clear_after_s`` (lights off; a
  flashing bar is never dark that long) — the RSU also clears a track that leaves the view;
- ``candidate`` -> ``none`` when L falls back below ``candidate_level``.

Because L is clamped and moves by bounded steps, one bad frame can neither raise an alert nor clear
one: confirming needs several consistent frames, clearing needs ``clear_after_s`` without flashes.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field, replace

import numpy as np

from protocol.enums import EvCue, EvState, LightState
from rsu.classify.evidence_config import EvidenceConfig
from rsu.classify.lamps import (
    LampMeasurement,
    LampRun,
    blink_transitions,
    flash_pattern,
    lamp_runs,
    median_of,
)

COLOURS = {"bright": ("red", "blue"), "bar": ("red", "blue", "white")}
"""The lamp colours each measurement kind keeps (white only in the light-bar definition)."""
CORE = ("bar_red_core", "bar_blue_core", "bar_red_peak", "bar_blue_peak")
"""The light-bar signals that also keep the lamp-core share and the brightest channel of their pixels."""
SIGNALS = tuple(f"{k}_{c}{x}" for k, cs in COLOURS.items() for c in cs for x in ("", "_centre")) + CORE + ("lit_p",)
"""Per-frame signals a track keeps: lamp-bright red and blue, light-bar red, blue and white, and their centre shares."""


def _logit(p: float) -> float:
    p = min(max(p, 1e-4), 1 - 1e-4)
    return math.log(p / (1 - p))


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
    last_lamp_cue_s: float | None = None
    last_flash_cue_s: float | None = None
    """When the band last gave a flash or alternation cue (lamp-bright or light-bar colours), not a steady bar."""
    confirmed_at_s: float | None = None
    flash_hz: float | None = None
    cues: tuple[EvCue, ...] = ()
    """The cues that confirmed the track (refreshed while it stays confirmed); empty before."""
    body_scores: deque = field(default_factory=lambda: deque(maxlen=32))
    body_current: bool = True
    """False from a hand-over to another track id (:meth:`handed_over`) until that track's box is body-scored: the
    hand-over matches boxes by position, and the new box may be another vehicle."""
    _t: deque = field(default_factory=deque)
    _signals: dict = field(default_factory=lambda: {k: deque() for k in SIGNALS})
    _arrays: dict = field(default_factory=dict, repr=False, compare=False)
    """This frame's history as arrays (``"t"`` and each signal, made on first use), and its per-window masks and
    frame intervals: every cue reads the same history, so each is made once per :meth:`update`."""

    def _history(self, name: str) -> np.ndarray:
        a = self._arrays.get(name)
        if a is None:
            a = self._arrays[name] = np.fromiter(self._t if name == "t" else self._signals[name], float)
        return a

    def _window(self, now_s: float, window_s: float) -> np.ndarray:
        """The mask of the history's samples within ``window_s`` of ``now_s``."""
        key = ("keep", now_s, window_s)
        keep = self._arrays.get(key)
        if keep is None:
            keep = self._arrays[key] = self._history("t") >= now_s - window_s
        return keep

    def _frame_s(self, t: np.ndarray, window_s: float) -> float:
        """The median frame interval of the window's times ``t``."""
        key = ("frame_s", float(t[-1]), window_s)
        f = self._arrays.get(key)
        if f is None:
            f = self._arrays[key] = median_of(np.diff(t))
        return f

    def _series(self, now_s: float, window_s: float, kind: str = "bright"):
        """Times in the window and, per colour, the (fraction, centre share) series of one measurement kind."""
        keep = self._window(now_s, window_s)
        out = {c: (self._history(f"{kind}_{c}")[keep], self._history(f"{kind}_{c}_centre")[keep])
               for c in COLOURS[kind]}
        return self._history("t")[keep], out

    def _recent(self, name: str, now_s: float, window_s: float) -> np.ndarray:
        """One signal's samples in the window (aligned with the times :meth:`_series` returns)."""
        return self._history(name)[self._window(now_s, window_s)]

    def _lamp_lit(self, runs: list[LampRun], t: np.ndarray, x: np.ndarray, on_level: float, colour: str,
                  now_s: float, window_s: float) -> list[LampRun]:
        """The light-bar runs of ``colour`` whose lit samples have a median brightest channel of at least
        ``bar_flash_min_peak`` (a lamp lighting clips the sensor; red paint whose lit share wavers does not);
        white has no such measurement and keeps every run."""
        if colour not in ("red", "blue"):
            return runs
        peak = self._recent(f"bar_{colour}_peak", now_s, window_s)
        lit = x >= on_level
        return [r for r in runs if (m := lit & (t >= r.start_s) & (t <= r.end_s)).any()
                and median_of(peak[m]) >= self.config.bar_flash_min_peak]

    def _dark_before_in_history(self, runs: list[LampRun], name: str, on_level: float, off_level: float,
                                frame_s: float) -> list[LampRun]:
        """``runs`` (of the window) with the dark stretch before the first one measured over the whole history kept
        (``2 * flash_window_s``), not cut at the window's start: a slow flasher (a light bar cycling its lamps,
        0.5 s lit in 1.3 s) shows its second flash with its first one's dark stretch half outside the window, and
        without its full length the first one reads as no flash (``LampRun.is_flash``)."""
        if not runs or not runs[0].dark_before:
            return runs
        earlier = {r.start_s: r.dark_before_s for r in lamp_runs(self._history("t"), self._history(name), on_level,
                                                                 off_level, frame_s)}
        first = runs[0]
        dark_s = earlier.get(first.start_s, first.dark_before_s)
        return runs if dark_s <= first.dark_before_s else [replace(first, dark_before_s=dark_s), *runs[1:]]

    def _central(self, x: np.ndarray, centre: np.ndarray, on_level: float) -> bool:
        lit = x >= on_level
        return bool(lit.any()) and median_of(centre[lit]) >= self.config.centre_min_share

    def _flash_cue(self, now_s: float, kind: str = "bright") -> EvCue | None:
        cfg = self.config
        on_fraction = cfg.lamp_on_fraction if kind == "bright" else cfg.bar_on_fraction
        t, series = self._series(now_s, cfg.flash_window_s, kind)
        if len(t) < 3:
            return None
        frame_s = self._frame_s(t, cfg.flash_window_s)
        runs: dict[str, list[LampRun]] = {}
        best_hz = None
        for colour, (x, centre) in series.items():
            peak = float(x.max())
            if peak < on_fraction:
                continue
            on_level = max(on_fraction, 0.5 * peak)
            if not self._central(x, centre, on_level):
                continue  # lit at the corners of the body: tail, brake, turn or hazard lamps
            rs = lamp_runs(t, x, on_level, cfg.lamp_off_ratio * peak, frame_s)
            if any(r.duration_s > cfg.max_on_s for r in rs):
                continue  # lit longer than a 1 Hz flash: a steady lamp (tail/brake light, paint, glow)
            rs = self._dark_before_in_history(rs, f"{kind}_{colour}", on_level, cfg.lamp_off_ratio * peak, frame_s)
            if kind == "bar":
                rs = self._lamp_lit(rs, t, x, on_level, colour, now_s, cfg.flash_window_s)
            runs[colour] = rs
            lit = np.flatnonzero(x >= on_level)
            span = float(t[-1] - t[lit[0]])
            n = blink_transitions(x, on_level, cfg.lamp_off_ratio * peak)
            if span >= cfg.rate_check_after_s:
                hz = n / (2.0 * span)
                if not cfg.flash_min_hz <= hz <= cfg.flash_max_hz:
                    del runs[colour]
                    continue
                best_hz = hz if best_hz is None else max(best_hz, hz)
        if best_hz is not None and kind == "bright":
            self.flash_hz = best_hz
        cue = flash_pattern(runs.get("red", []), runs.get("blue", []), cfg)
        if cue is None and runs.get("white"):  # a white strobe: two flashes of its own (white alternates with nothing)
            cue = flash_pattern(runs["white"], [], cfg)
        return EvCue(cue) if cue else None

    def _strong_bar_flash(self, now_s: float) -> bool:
        """``strong_bar_flashes`` regular flashes of one light-bar colour in the window (see the config)."""
        cfg = self.config
        if cfg.strong_bar_flashes <= 0:
            return False
        t, series = self._series(now_s, cfg.flash_window_s, "bar")
        if len(t) < 2 * cfg.strong_bar_flashes:
            return False
        frame_s = self._frame_s(t, cfg.flash_window_s)
        for colour in ("red", "blue"):
            x, centre = series[colour]
            peak = float(x.max())
            if not cfg.bar_on_fraction <= peak <= cfg.steady_max_fraction:
                continue
            on_level = max(cfg.bar_on_fraction, 0.5 * peak)
            if not self._central(x, centre, on_level):
                continue
            runs = lamp_runs(t, x, on_level, cfg.lamp_off_ratio * peak, frame_s)
            if any(r.duration_s > cfg.max_on_s for r in runs):
                continue
            runs = self._lamp_lit(runs, t, x, on_level, colour, now_s, cfg.flash_window_s)
            flashes = [r for r in runs if r.is_flash(cfg.min_dark_ratio)]
            if len(flashes) >= cfg.strong_bar_flashes and all(
                    b.start_s - a.end_s <= cfg.max_dark_s for a, b in zip(flashes, flashes[1:], strict=False)):
                return True
        return False

    def _steady_bar(self, now_s: float) -> bool:
        cfg = self.config
        t, series = self._series(now_s, cfg.steady_window_s, "bar")
        if len(t) < 3:
            return False
        for colour, (x, centre) in series.items():
            if colour == "white":
                continue  # steady white is sky, a white roof or headlight glare, never a bar on its own
            lit = x >= cfg.bar_on_fraction
            core = self._recent(f"bar_{colour}_core", now_s, cfg.steady_window_s)
            peak = self._recent(f"bar_{colour}_peak", now_s, cfg.steady_window_s)
            if (lit.mean() >= cfg.steady_min_share and median_of(x[lit]) <= cfg.steady_max_fraction
                    and median_of(core[lit]) >= cfg.steady_min_core
                    and median_of(peak[lit]) >= cfg.steady_min_peak
                    and self._central(x, centre, cfg.bar_on_fraction)):
                return True
        return False

    def lit_level(self, now_s: float) -> float | None:
        """The ``lit_quantile`` of the lamp-state model's p(lit) over the last ``flash_window_s`` (None without any: no
        model, or no measured frame)."""
        x = self._recent("lit_p", now_s, self.config.flash_window_s)
        x = x[~np.isnan(x)]
        return float(np.quantile(x, self.config.lit_quantile)) if len(x) else None

    def looks_lit(self, now_s: float, min_level: float | None = None) -> bool:
        """Does the lamp-state model see lit warning lamps in the band (``lit_level`` >= ``min_level``, by default
        ``lit_min``)? True without a model: the colour tests then decide alone."""
        level = self.lit_level(now_s)
        return level is None or level >= (self.config.lit_min if min_level is None else min_level)

    @property
    def body_score(self) -> float | None:
        """Mean of the last ``body_window`` EV-body scores; None before any."""
        if not self.body_scores:
            return None
        recent = list(self.body_scores)[-self.config.body_window:]
        return float(sum(recent) / len(recent))

    @property
    def body_confident(self) -> bool:
        """The mean of the last ``body_window`` scores reaches ``body_threshold`` over at least ``body_min_scores``
        scores, or the last ``body_sure_min_scores`` each reach ``body_sure_threshold``; and they score this track's
        own box (``body_current``)."""
        cfg = self.config
        b = self.body_score
        if not self.body_current or b is None:
            return False
        n = len(self.body_scores)
        sure = n >= cfg.body_sure_min_scores and min(
            list(self.body_scores)[-cfg.body_sure_min_scores:]) >= cfg.body_sure_threshold
        return sure or (n >= cfg.body_min_scores and b >= cfg.body_threshold)

    def handed_over(self) -> None:
        """This evidence now belongs to a new track id, matched by position alone (``TrackEvClassifier._hand_over``).
        The lamp history and a confirmed state carry over; the body scores count again only once the new box has
        been scored too (a black truck that entered the view just behind an ambulance took over the ambulance's
        lost track, and with it the ambulance's body scores: ev_bench seed 16790, ``rellis_ev_yield``, rsu4)."""
        if self.state != EvState.CONFIRMED:
            self.body_current = False

    def update(self, now_s: float, lamps: LampMeasurement, crop_score: float | None = None,
               body_score: float | None = None, bar: LampMeasurement | None = None,
               lamps_alone: bool = True, lit_p: float | None = None) -> EvState:
        """One frame: ``lamps`` measured with the lamp-bright colours, ``bar`` with the light-bar colours
        (:mod:`rsu.classify.lamps`; default: ``lamps``), the optional crop score and EV-body score.
        ``lamps_alone`` False: the lamps may be another vehicle's (a confirmed EV just ahead, whose flashes light
        this vehicle's roof), so a flash pattern does not confirm alone now; with a confident body it does. ``lit_p``: the
        lamp-state model's p(lit) of the band (:mod:`rsu.classify.lamp_state`), None without one."""
        cfg = self.config
        bar = lamps if bar is None else bar
        self._t.append(now_s)
        for kind, m in (("bright", lamps), ("bar", bar)):
            for c in COLOURS[kind]:
                self._signals[f"{kind}_{c}"].append(getattr(m, c))
                self._signals[f"{kind}_{c}_centre"].append(getattr(m, f"{c}_centre"))
        for c in ("red", "blue"):
            self._signals[f"bar_{c}_core"].append(getattr(bar, f"{c}_core"))
            self._signals[f"bar_{c}_peak"].append(getattr(bar, f"{c}_peak"))
        self._signals["lit_p"].append(math.nan if lit_p is None else float(lit_p))
        while len(self._t) > cfg.max_history or (self._t and self._t[0] < now_s - 2 * cfg.flash_window_s):
            self._t.popleft()
            for d in self._signals.values():
                d.popleft()
        self._arrays.clear()  # the history changed: its arrays are made again on first use
        self.frames += 1
        if body_score is not None:
            self.body_scores.append(float(np.clip(body_score, 0.0, 1.0)))
            self.body_current = True
        flash = self._flash_cue(now_s, "bright")
        if flash is not None:
            self.last_flash_s = now_s
        flash_cue = flash or self._flash_cue(now_s, "bar")
        if flash_cue is not None:
            self.last_flash_cue_s = now_s
        lamp_cue = flash_cue or (EvCue.STEADY_BAR if self._steady_bar(now_s) else None)
        if lamp_cue is not None:
            self.last_lamp_cue_s = now_s
        if lamps.coloured >= cfg.lamp_on_fraction or bar.coloured >= cfg.bar_on_fraction:  # red/blue: white may be sky
            self.last_lamp_on_s = now_s
        step = cfg.flash_gain if flash is not None else -cfg.decay
        if crop_score is not None:
            self.score_sum += crop_score
            step += _logit(crop_score) - _logit(cfg.prior) if crop_score > cfg.prior else 0.0
        self.level = min(max(self.level + step, cfg.level_min), cfg.level_max)
        body = (EvCue.EV_BODY,) if self.body_confident else ()

        if self.state in (EvState.NONE, EvState.CLEARED, EvState.CANDIDATE):
            if self.level >= cfg.confirm_level and flash is not None and (lamps_alone or body) and (
                    flash == EvCue.ALTERNATION or self.looks_lit(now_s, cfg.lit_flash_min)):
                self.state, self.confirmed_at_s, self.cues = EvState.CONFIRMED, now_s, (flash, *body)
            elif lamps_alone and lamp_cue is not None and self._strong_bar_flash(now_s) and (body or self.looks_lit(now_s)):
                self.state, self.confirmed_at_s, self.cues = EvState.CONFIRMED, now_s, (EvCue.FLASH, *body)
            elif body and lamp_cue is not None and (flash is not None or flash_cue is None or self.looks_lit(now_s)):
                self.state, self.confirmed_at_s, self.cues = EvState.CONFIRMED, now_s, (lamp_cue, *body)
            elif self.level > cfg.candidate_level or lamp_cue is not None:
                self.state = EvState.CANDIDATE
            elif self.state == EvState.CANDIDATE:
                self.state = EvState.NONE
        elif self.state == EvState.CONFIRMED:
            if self.last_lamp_on_s is None or now_s - self.last_lamp_on_s >= cfg.clear_after_s:
                self.state = EvState.CLEARED
                self.level = min(self.level, 0.0)
            elif lamp_cue is not None:
                self.cues = (lamp_cue, *body)
        return self.state

    def _within_clear(self, t_s: float | None) -> bool:
        """Is ``t_s`` (a last-cue time) within ``clear_after_s`` of the last sample?"""
        return t_s is not None and bool(self._t) and self._t[-1] - t_s < self.config.clear_after_s

    @property
    def flashed_recently(self) -> bool:
        """Did the band give a flash or alternation cue (not a steady bar) within ``clear_after_s``?"""
        return self._within_clear(self.last_flash_cue_s)

    @property
    def light_state(self) -> LightState:
        if self.frames == 0:
            return LightState.UNKNOWN
        if self._within_clear(self.last_flash_s):
            return LightState.FLASHING
        if self._within_clear(self.last_lamp_cue_s):
            return LightState.STEADY
        return LightState.OFF

    @property
    def ev_score(self) -> float:
        """A probability-like summary of the evidence level for ``DetectedObject.ev_score``; with a confident
        EV body and a lamp cue, at least the body score."""
        s = 1.0 / (1.0 + math.exp(-(self.level - self.config.candidate_level)))
        if self.state == EvState.CONFIRMED and EvCue.EV_BODY in self.cues and self.body_score is not None:
            s = max(s, self.body_score)
        return s

    @property
    def mean_crop_score(self) -> float:
        return self.score_sum / self.frames if self.frames else 0.0
