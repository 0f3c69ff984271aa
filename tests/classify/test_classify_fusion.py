"""Per-track fusion of EV body and lamp evidence: a steady bar counts only with a confident body,
corner lamps never count, and a strong flash pattern still confirms alone."""

from __future__ import annotations

import numpy as np

from protocol.enums import EvCue, EvState, LightState
from rsu.classify.evidence_config import EvidenceConfig, lamp_activity
from rsu.classify.lamps import LampMeasurement, measure_lamps
from rsu.classify.temporal import TrackEvidence

FPS = 25.0
BAR = 0.04  # a lit bar covers ~4 % of the band


def run(signal, body=None, duration_s=3.0, every_s=0.25):
    """signal(t) -> LampMeasurement; body: the EV-body score fed every ``every_s`` (None: no classifier)."""
    ev = TrackEvidence()
    states, last = [], None
    for i in range(int(duration_s * FPS)):
        t = i / FPS
        b = None
        if body is not None and (last is None or t - last >= every_s - 1e-9):
            b, last = body, t
        states.append((t, ev.update(t, signal(t), body_score=b)))
    return ev, states


def first(states, state=EvState.CONFIRMED):
    return next((t for t, s in states if s == state), None)


def steady(t):
    return LampMeasurement(BAR, 0.0)


def dipping(t):  # an LED bar at ~80 % duty under motion blur: dark for one frame in five
    return LampMeasurement(0.0 if int(round(t * FPS)) % 5 == 4 else BAR, 0.0)


def test_steady_bar_with_a_confident_body_confirms_within_a_second():
    for signal in (steady, dipping):
        ev, states = run(signal, body=0.95)
        t = first(states)
        assert t is not None and t <= 1.0
        assert ev.cues == (EvCue.STEADY_BAR, EvCue.EV_BODY)
        assert ev.light_state == LightState.STEADY


def test_steady_bar_alone_or_with_an_unsure_body_never_confirms():
    for body in (None, 0.2):
        _, states = run(steady, body=body)
        assert first(states) is None


def test_body_alone_without_lamps_never_confirms():
    _, states = run(lambda t: LampMeasurement(0.0, 0.0), body=0.99)
    assert first(states) is None


def test_paint_sized_red_is_no_steady_bar():
    _, states = run(lambda t: LampMeasurement(0.6, 0.0), body=0.99)  # a red fire engine with its lights off
    assert first(states) is None


def test_corner_lamps_never_confirm_even_flashing_with_an_ev_body():
    def turn_signal(t):  # 1.5 Hz, lit at one corner of the band
        lit = (t * 1.5) % 1.0 < 0.5
        return LampMeasurement(BAR if lit else 0.0, 0.0, red_centre=0.0)

    def hazards(t):  # both corners together
        lit = (t * 1.5) % 1.0 < 0.5
        return LampMeasurement(2 * BAR if lit else 0.0, 0.0, red_centre=0.1)

    for signal in (turn_signal, hazards):
        for body in (None, 0.99):
            _, states = run(signal, body=body, duration_s=5.0)
            assert first(states) is None


def test_strong_flash_pattern_confirms_alone_and_names_its_cue():
    def alternating(t):
        red = (t * 2.0) % 1.0 < 0.5
        return LampMeasurement(BAR if red else 0.0, 0.0 if red else BAR)

    ev, states = run(alternating)
    assert first(states) is not None and first(states) <= 0.6  # one period of a 2 Hz bar, plus a frame
    assert ev.cues in ((EvCue.ALTERNATION,), (EvCue.FLASH,))  # no body classifier: no ev_body cue


def test_measure_lamps_centre_share_tells_a_roof_bar_from_corner_lamps():
    crop = np.full((60, 80, 3), 90, np.uint8)
    crop[2:8, 30:50] = (0, 0, 255)  # roof bar in the middle
    m = measure_lamps(crop, top_fraction=0.4)
    assert m.red > 0 and m.red_centre == 1.0
    crop = np.full((60, 80, 3), 90, np.uint8)
    crop[15:20, 0:8] = (0, 0, 255)  # two corner lamps
    crop[15:20, 72:80] = (0, 0, 255)
    m = measure_lamps(crop, top_fraction=0.4)
    assert m.red > 0 and m.red_centre == 0.0


def test_lamp_activity_gates_the_body_classifier_to_bar_like_light():
    """The EV-body classifier runs only on bands that could hold a light bar: a thin central bar or bright
    central lamps, not paint that fills the band, nor corner lamps (tail, brake, turn, hazard)."""
    cfg = EvidenceConfig()
    dark = LampMeasurement(0.0, 0.0)
    assert lamp_activity(dark, LampMeasurement(0.02, 0.0, 0.9, 1.0), cfg)  # a thin red bar in the middle
    assert lamp_activity(LampMeasurement(0.0, 0.03, 1.0, 0.8), dark, cfg)  # bright blue lamps in the middle
    assert not lamp_activity(dark, LampMeasurement(0.35, 0.0, 0.9, 1.0), cfg)  # red paint over the band
    assert not lamp_activity(LampMeasurement(0.05, 0.0, 0.1, 1.0), LampMeasurement(0.05, 0.0, 0.1, 1.0), cfg)
    assert not lamp_activity(dark, dark, cfg)


def _white_run(white, body, duration_s=3.0):
    ev, states, last = TrackEvidence(), [], None
    for i in range(int(duration_s * FPS)):
        t = i / FPS
        b = None
        if body is not None and (last is None or t - last >= 0.25 - 1e-9):
            b, last = body, t
        bar = LampMeasurement(0.0, 0.0, white=white(t))
        states.append((t, ev.update(t, LampMeasurement(0.0, 0.0), body_score=b, bar=bar)))
    return ev, states


def test_white_strobe_confirms_only_with_a_confident_body_and_steady_white_never():
    strobe = lambda t: BAR if (t * 2.0) % 1.0 < 0.4 else 0.0  # noqa: E731  (2 Hz, 40 % duty)
    ev, states = _white_run(strobe, body=0.95)
    assert first(states) is not None and first(states) <= 1.5
    assert EvCue.FLASH in ev.cues and EvCue.EV_BODY in ev.cues
    assert first(_white_run(strobe, body=None)[1]) is None  # a white flash alone: headlight glints, reflections
    assert first(_white_run(lambda t: BAR, body=0.95)[1]) is None  # steady white: sky, a white roof


def test_bar_definition_measures_a_central_white_lamp():
    from rsu.classify.lamps import BAR_COLOURED, measure_band

    crop = np.full((100, 100, 3), 90, np.uint8)
    crop[5:12, 40:60] = 255  # a lit white strobe in the middle of the roof
    crop[60:70, 0:10] = 255  # a headlight at the corner, below the band
    bar, = measure_band(crop, 0.4, (BAR_COLOURED,))
    assert 0.03 < bar.white < 0.04 and bar.white_centre == 1.0 and bar.red == bar.blue == 0.0


def test_bar_definition_reads_red_lamps_as_red_and_an_amber_beacon_as_no_colour():
    from rsu.classify.lamps import BAR_COLOURED, measure_band

    def red_of(bgr):
        crop = np.full((100, 100, 3), 40, np.uint8)
        crop[5:15, 40:60] = bgr
        return measure_band(crop, 0.4, (BAR_COLOURED,))[0].red

    assert red_of((40, 40, 255)) > 0.04  # a red lamp
    assert red_of((120, 101, 233)) > 0.04  # a pink-red LED point (hue ~350 degrees)
    assert red_of((40, 90, 255)) > 0.04  # a red lamp blooming towards orange (hue ~14 degrees)
    assert red_of((0, 140, 255)) == 0.0 and red_of((30, 180, 250)) == 0.0  # amber beacons (hue 33-40 degrees)


def _bar_run(bar_signal, duration_s=3.0):
    ev, states = TrackEvidence(), []
    for i in range(int(duration_s * FPS)):
        t = i / FPS
        states.append((t, ev.update(t, LampMeasurement(0.0, 0.0), bar=bar_signal(t))))
    return ev, states


def test_strong_regular_bar_flashing_confirms_without_a_body_score():
    """A far EV whose body the classifier cannot judge yet: its blue bar flashing at 3 Hz confirms alone."""
    blue = lambda t: LampMeasurement(0.0, BAR if (t * 3.0) % 1.0 < 0.4 else 0.0)  # noqa: E731
    ev, states = _bar_run(blue)
    assert first(states) is not None and first(states) <= 1.5 and ev.cues == (EvCue.FLASH,)
    # ... but not a lamp's glow flashing over a third of the band (a car lit by the EV at night), nor blue paint
    # flickering with the box (its brightest pixel does not clip), nor a corner lamp
    glow = lambda t: LampMeasurement(0.0, 0.35 if (t * 3.0) % 1.0 < 0.4 else 0.0)  # noqa: E731
    paint = lambda t: LampMeasurement(0.0, BAR if (t * 3.0) % 1.0 < 0.4 else 0.0, blue_peak=0.8)  # noqa: E731
    corner = lambda t: LampMeasurement(0.0, BAR if (t * 3.0) % 1.0 < 0.4 else 0.0, 1.0, 0.1)  # noqa: E731
    assert first(_bar_run(glow)[1]) is None and first(_bar_run(paint)[1]) is None
    assert first(_bar_run(corner)[1]) is None
    # ... nor two flashes alone (the strong pattern needs three)
    two = lambda t: LampMeasurement(0.0, BAR if t < 0.7 and (t * 3.0) % 1.0 < 0.4 else 0.0)  # noqa: E731
    assert first(_bar_run(two)[1]) is None


def test_sunlit_paint_without_a_lamp_core_is_no_steady_bar_even_with_a_confident_body():
    """The simulator's red truck cab: bar-sized, central, steady, but no pixel clips like a lit lamp."""
    paint = lambda t: LampMeasurement(BAR, 0.0, red_core=0.0)  # noqa: E731
    lit = lambda t: LampMeasurement(BAR, 0.0, red_core=0.5)  # noqa: E731
    ev, states = TrackEvidence(), {}
    for name, sig in (("paint", paint), ("lit", lit)):
        ev, last, out = TrackEvidence(), None, []
        for i in range(int(3.0 * FPS)):
            t = i / FPS
            b = None
            if last is None or t - last >= 0.25 - 1e-9:
                b, last = 0.95, t
            out.append((t, ev.update(t, LampMeasurement(0.0, 0.0), body_score=b, bar=sig(t))))
        states[name] = first(out)
    assert states["paint"] is None and states["lit"] is not None


def test_sunlit_paint_whose_brightest_pixel_does_not_clip_is_no_steady_bar():
    """The simulator's red truck cab in sunlight passes the core test (R >= 220 on 10-34 % of its pixels, ev_bench
    tuning seeds 31372/91468) but its brightest pixel stays at R 228-243; a lit lamp clips at 255."""
    paint = lambda t: LampMeasurement(BAR, 0.0, red_core=0.2, red_peak=240 / 255)  # noqa: E731
    lit = lambda t: LampMeasurement(BAR, 0.0, red_core=0.2, red_peak=1.0)  # noqa: E731
    states = {}
    for name, sig in (("paint", paint), ("lit", lit)):
        ev, last, out = TrackEvidence(), None, []
        for i in range(int(3.0 * FPS)):
            t = i / FPS
            b = None
            if last is None or t - last >= 0.25 - 1e-9:
                b, last = 0.95, t
            out.append((t, ev.update(t, LampMeasurement(0.0, 0.0), body_score=b, bar=sig(t))))
        states[name] = first(out)
    assert states["paint"] is None and states["lit"] is not None


def test_flashes_that_may_be_a_confirmed_ev_ahead_confirm_only_with_a_confident_body():
    """A bus just behind a confirmed EV: the EV's flashes light the bus roof in step (sim tuning seed 91468). With
    ``lamps_alone`` False the flash pattern does not confirm alone; a confident body still confirms."""
    def alternating(t):
        red = (t * 2.0) % 1.0 < 0.5
        return LampMeasurement(BAR if red else 0.0, 0.0 if red else BAR)

    for body, confirms in ((None, False), (0.95, True)):
        ev, last, out = TrackEvidence(), None, []
        for i in range(int(3.0 * FPS)):
            t = i / FPS
            b = None
            if body is not None and (last is None or t - last >= 0.25 - 1e-9):
                b, last = body, t
            out.append((t, ev.update(t, alternating(t), body_score=b, lamps_alone=False)))
        assert (first(out) is not None) == confirms


def test_a_bar_flash_needs_lamp_lit_runs_and_paint_hovering_at_the_level_does_not_flicker_into_flashes():
    """Red paint whose lit share wavers with the box (brightest channel 0.71-0.85, ev_bench tuning seed 50857) gives no
    flash cue even with a confident body, while the same pattern lamp-lit (clipped) does; paint hovering around the
    lamp level (0.84-0.88, seed 91468) with a steady share gives none either."""
    cfg = EvidenceConfig()

    def run_bar(share, peak):
        ev, last, out = TrackEvidence(cfg), None, []
        for i in range(int(3.0 * FPS)):
            t = i / FPS
            b = None
            if last is None or t - last >= 0.25 - 1e-9:
                b, last = 0.95, t
            out.append((t, ev.update(t, LampMeasurement(0.0, 0.0), body_score=b,
                                     bar=LampMeasurement(share(t), 0.0, red_core=0.0, red_peak=peak(t)))))
        return first(out)

    flashing = lambda t: 0.03 if (t * 2.0) % 1.0 < 0.3 else 0.002  # noqa: E731
    assert run_bar(flashing, lambda t: 1.0) is not None
    assert run_bar(flashing, lambda t: 0.8) is None
    hovering = lambda t: 0.84 + 0.04 * (int(round(t * FPS)) % 2)  # noqa: E731
    assert run_bar(lambda t: 0.03, hovering) is None
