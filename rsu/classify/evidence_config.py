"""The thresholds of the per-track EV evidence (:class:`EvidenceConfig`, each with how it was set) and the per-frame
test of whether a track's lamp band is worth an EV-body score (:func:`lamp_activity`). The rule that reads them is
:class:`rsu.classify.temporal.TrackEvidence` (its module docstring)."""

from __future__ import annotations

from dataclasses import dataclass

from rsu.classify.lamps import LampMeasurement


@dataclass(frozen=True)
class EvidenceConfig:
    lamp_on_fraction: float = 0.015
    """A lamp colour counts as on above this fraction of the band's pixels. 0.015, not the 0.025 first tuned
    with the motion detector's loose boxes: in the project detector's tight box of an EV seen from the front
    at 30-60 m the bar's lit half fills 1.5-2.5 % of the band, and at 0.025 the EV confirmed only once it
    came closer (rellis_ev_yield seed 8: 1.60 s after lights on instead of 0.33 s). Held-out runs of
    ``bench/ev_bench.py`` keep recall 1.0 and 0 false alerts at 0.015."""
    lamp_off_ratio: float = 0.2
    """... and as off below this share of its recent peak."""
    flash_window_s: float = 2.0
    max_on_s: float = 0.6
    """A flash lasts at most this long (half a period at 1 Hz, with a frame of slack); a colour lit longer
    in the window is a steady lamp and gives no evidence."""
    max_dark_s: float = 1.0
    """Two flashes of one colour count when at most this far apart."""
    handover_s: float = 0.2
    """A flash of one colour hands over to the other when that one lights within this time of its end."""
    min_dark_ratio: float = 0.5
    """A flash must follow a dark stretch at least this share of its own length (duty cycle <= ~2/3)."""
    min_on_samples: int = 2
    """Lit samples a flash pattern needs (a colour's two flashes need one more): one glint is no flash."""
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
    bar_on_fraction: float = 0.005
    """A light-bar colour (the chroma test of :data:`rsu.classify.lamps.BAR_COLOURED`) counts as on above this
    share of the band: a roof bar seen by an elevated camera fills 0.7-3 % of it (measured on the tuning
    clips named in :mod:`rsu.classify.lamps`); the cues it gives count only with a confident EV body."""
    centre_min_share: float = 0.5
    """A lamp colour counts only when at least this share of its lit pixels lies in the central half of the
    band's width (median over its lit samples): a roof bar does, corner lamps (tail, turn, hazard) do not."""
    steady_window_s: float = 0.6
    steady_min_share: float = 0.6
    """A steady bar: lit on at least this share of the samples of the last ``steady_window_s`` (>= 3 samples)."""
    steady_min_core: float = 0.05
    """... and with at least this share of its pixels a lamp's core (the channel >= 220, median over its lit
    samples): a lit lamp clips the sensor somewhere, paint does not. Measured: real bars 0.45-0.7 (escort and
    Japanese-ambulance clips), 0.09-0.30 (the roadside ambulance's red bar at 20-40 m: it is a tuning clip
    for this threshold since); the simulator's sunlit red truck cab 0 (the brightest sim paint, R 185, peaks
    at 219 in sunlight), which the body classifier trained on real photos scored ~0.55 (ev_bench seeds
    301/302, tuning seeds since: 3 false alerts before this test, 0 after)."""
    steady_max_fraction: float = 0.12
    """... and covering at most this share of the band (median over its lit samples): a roof bar is a thin
    strip, while red or blue *paint* bright enough to pass the real-video colour test covers the body."""
    steady_min_peak: float = 250 / 255
    """... and with its brightest pixel's channel at least this share of 255 (median over its lit samples): a lit
    lamp clips the sensor at its brightest point. Sunlit red paint passes the core test (the simulator's red
    truck cab: R 228-243 at its brightest, core share 0.1-0.34; ev_bench tuning seeds 31372/91468: 3 false
    alerts on it) but stays below 250."""
    bar_flash_min_peak: float = 220 / 255
    """A light-bar red or blue lit run counts as a *flash* only when the median of its lit samples' brightest
    channel reaches this share of 255 (the lamp-core level of ``steady_min_core``): a lamp lighting clips the
    sensor somewhere, while red paint whose lit share wavers with the box does not. Set on ev_bench tuning seed
    50857 (a red car's paint, brightest channel 0.71-0.85, read as bar flashes: 1 false alert). A test per
    *run*, not per sample: masking samples under the level made paint hovering at it (0.84-0.88, seed 91468)
    flicker into flashes."""
    strong_bar_flashes: int = 3
    """A light-bar colour (red or blue) that flashes this many times in ``flash_window_s`` - complete flashes of
    lamp-lit runs (``bar_flash_min_peak``), each after a dark stretch, at most ``max_dark_s`` apart, central,
    bar-sized (at most ``steady_max_fraction`` of the band) - is a strong flash pattern that confirms alone, like a
    lamp-bright flash: a far EV whose body the classifier cannot yet judge still alerts. Paint does not flash, and
    corner lamps (turn signals, hazards) are excluded as for every cue. 0: never. The size bound stays: without it
    (measured on tuning seeds) a close EV driving away, its bar filling 13-40 % of the band, confirmed
    (``ev_two_lanes_dense`` 21674, rsu1: missed with it), but so did the EV's red and blue glow on a car beside it
    at night (11-33 % of the band, clipped, alternating: ``night_ev`` 31372, a false alert)."""
    lit_min: float = 0.6
    """A light-bar colour's flash pattern confirms (alone when strong, ``strong_bar_flashes``, else with a confident EV
    body) only when the lamp-state model (:mod:`rsu.classify.lamp_state`) sees lit lamps: the ``lit_quantile`` of its
    p(lit) over the last ``flash_window_s`` at least this (no model: no test). With a confident body too: a flicker of
    white on a dark bar (p(lit) 0-0.3) and an ambulance body confirmed an EV whose lights were never on (ev_bench
    ``ev_lights_never_on``, seed 99765). Set on the tuning clips of ``bench/ev_real_bench.py``:
    without it the tail lights of ``overpass_dusk_taillights`` and a blue object above a van's roof in
    ``street_ambulance_japan_red`` alert (1 traffic, 2 wrong-vehicle alerts); from 0.5 to 0.7 none does and no EV is
    lost or delayed, at 0.8 one alert comes 0.5 s later: 0.6, the middle. The lamp-bright flash has its own level
    (``lit_flash_min``)."""
    lit_flash_min: float = 0.4
    """A lamp-bright flash (a lamp that saturates the sensor) of one colour confirms without a confident body only
    when the ``lit_quantile`` of p(lit) over the last ``flash_window_s`` is at least this (no model: no test); red/blue
    alternation of lamp-bright colours needs no model. One colour flashing is also what a turn signal or hazard flasher
    shows when the band holds its lamp (``bench/ev_bench.py`` tuning seed 72567, ``ev_two_lanes_dense``, rsu1: a
    car's red rear turn signal on a 51 px box, its quantile 0.01, 1 false alert without the test); no ordinary
    vehicle's lamps alternate red and blue, and the simulator's night EVs, whose renders the model reads at 0.02-0.5,
    confirm on alternation. The EVs that confirm on a one-colour lamp-bright flash read 0.76 (the Florence ambulance
    of ``bench/ev_real_bench.py``'s tuning clips) to 0.999 (the simulator's day scenarios, tuning seeds 38238 and
    72567): 0.4, between the turn signal and the lowest EV."""
    lit_quantile: float = 0.75
    """... the quantile: a flashing lamp is dark about half the time, so the median would miss it."""
    body_threshold: float = 0.5
    """EV-body score that counts as confident (the body model's ``confident_threshold``, from its metadata)."""
    body_min_scores: int = 3
    """... over at least this many scores (about 0.75 s at the classifier's 4 Hz): one lucky crop is not a body."""
    body_sure_threshold: float = 0.76
    """An EV body is also confident after ``body_sure_min_scores`` scores that each reach this: the lowest score at
    which the body model takes no vehicle for an EV on the ``val`` split of ``ev_train``, so one score fewer suffices.
    The body model carries its own (``sure_threshold`` in its metadata, which replaces this default:
    :class:`rsu.classify.ev.TrackEvClassifier`); a model without one gets this value."""
    body_sure_min_scores: int = 2
    """... that many scores (half a second at the classifier's 4 Hz)."""
    body_window: int = 6


def lamp_activity(lamps: LampMeasurement, bar: LampMeasurement, config: EvidenceConfig) -> bool:
    """Does one frame's band show what a light bar could be, so that the EV-body classifier is worth running
    (only while it has lamp activity)? A lamp-bright colour lit in the middle of the band, or a
    light-bar colour lit in the middle and covering at most ``steady_max_fraction`` of it. Red or blue paint
    covers more of the band than a bar (and could give no lamp cue: a lamp lit that long or that wide is no
    flash and no steady bar), and corner lamps (tail, brake, turn, hazard) sit off the middle: neither earns
    a body score."""
    for c in ("red", "blue"):
        centre = getattr(lamps, f"{c}_centre")
        if getattr(lamps, c) >= config.lamp_on_fraction and centre >= config.centre_min_share:
            return True
        x, centre = getattr(bar, c), getattr(bar, f"{c}_centre")
        if config.bar_on_fraction <= x <= config.steady_max_fraction and centre >= config.centre_min_share:
            return True
    return False
