"""Temporal EV evidence on synthetic lamp signals at 15 fps: flashing confirms fast, lookalikes never do."""

from __future__ import annotations

import numpy as np
import pytest

from protocol.enums import EvState, LightState
from rsu.classify.lamps import LampMeasurement, blink_transitions, measure_lamps
from rsu.classify.temporal import TrackEvidence

FPS = 15.0
ON = 0.03  # a lit lamp covers ~3% of the top band


def run(signal, duration_s=8.0, crop_score=None):
    """signal(t) -> (red, blue); returns the evidence and the list of (t, state)."""
    ev = TrackEvidence()
    states = []
    for i in range(int(duration_s * FPS)):
        t = i / FPS
        red, blue = signal(t)
        states.append((t, ev.update(t, LampMeasurement(red, blue), crop_score)))
    return ev, states


def first_time(states, state):
    return next((t for t, s in states if s == state), None)


def alternating(freq_hz, on_at=1.0, off_at=None):
    def sig(t):
        if t < on_at or (off_at is not None and t >= off_at):
            return 0.0, 0.0
        phase = ((t - on_at) * freq_hz) % 1.0
        return (ON, 0.0) if phase < 0.5 else (0.0, ON)
    return sig


def strobe(freq_hz, on_at=1.0):
    def sig(t):
        if t < on_at:
            return 0.0, 0.0
        lit = ((t - on_at) * freq_hz) % 1.0 < 0.5
        return (ON, ON) if lit else (0.0, 0.0)
    return sig


@pytest.mark.parametrize("freq", [1.0, 1.5, 2.0, 3.0, 4.0])
def test_alternating_light_bar_confirms_within_a_fraction_of_a_second(freq):
    ev, states = run(alternating(freq))
    t = first_time(states, EvState.CONFIRMED)
    assert t is not None and t >= 1.0
    # a blink is seen after half a period; confirmation takes one more frame (+ one of sampling)
    assert t - 1.0 <= 1.0 / (2 * freq) + 2.0 / FPS + 1e-6
    assert states[-1][1] == EvState.CONFIRMED and ev.light_state == LightState.FLASHING


@pytest.mark.parametrize("freq", [1.0, 2.5, 4.0])
def test_strobe_confirms(freq):
    _, states = run(strobe(freq))
    t = first_time(states, EvState.CONFIRMED)
    assert t is not None and t - 1.0 <= 0.7


def test_lights_already_on_when_the_track_appears():
    _, states = run(alternating(2.0, on_at=0.0))
    assert first_time(states, EvState.CONFIRMED) <= 0.6


@pytest.mark.parametrize("name,signal", [
    ("brake light on and held", lambda t: (ON if t >= 1.0 else 0.0, 0.0)),
    ("red car paint", lambda t: (0.05, 0.0)),
    ("blue car paint", lambda t: (0.0, 0.06)),
    ("stop-and-go brake pumping every 3 s", lambda t: (ON if (t % 6.0) < 3.0 else 0.0, 0.0)),
    ("dark", lambda t: (0.0, 0.0)),
    ("one glitch frame", lambda t: (ON, ON) if abs(t - 2.0) < 0.03 else (0.0, 0.0)),
    # a steady tail light that drops out of the measured band for a frame now and then (the box jitters)
    ("tail light in a jittering box", lambda t: (0.0 if int(t * FPS) % 11 in (0, 5) else ON, 0.0)),
    ("brake pumping every 2 s (1 s on, 1 s off)", lambda t: (ON if (t % 2.0) < 1.0 else 0.0, 0.0)),
    ("blue paint glint every 0.7 s", lambda t: (0.0, ON) if int(t * FPS) % 10 == 0 else (0.0, 0.0)),
])
def test_lookalikes_never_confirm(name, signal):
    _, states = run(signal, duration_s=12.0)
    assert first_time(states, EvState.CONFIRMED) is None, name


def test_a_red_flash_handing_over_to_blue_is_enough_evidence():
    """Alternation is seen after one red flash: confirmation about half a period after lights-on."""
    _, states = run(alternating(2.0, on_at=1.0))
    t = first_time(states, EvState.CONFIRMED)
    assert t is not None and t - 1.0 <= 0.25 + 2.0 / FPS + 1e-6


def test_a_slow_flasher_confirms_on_its_second_flash():
    # one colour lit 0.5 s in every 1.33 s: the first flash's dark stretch starts before the 2 s window
    def sig(t):
        return (0.0, ON if t >= 1.0 and ((t - 1.0) % (4 / 3)) < 0.5 else 0.0)
    _, states = run(sig)
    t = first_time(states, EvState.CONFIRMED)
    assert t is not None and t <= 1.0 + 4 / 3 + 0.5 + 3 / FPS


def test_runs_of_a_lamp_signal_with_hysteresis():
    from rsu.classify.lamps import lamp_runs

    t = np.arange(12) / FPS
    x = np.array([0, 1, 1, 0.5, 1, 0, 0, 1, 1, 0, 1, 1.0])
    runs = lamp_runs(t, x, on_level=0.8, off_level=0.2, frame_s=1 / FPS)
    assert [(r.samples, r.complete) for r in runs] == [(3, True), (2, True), (2, False)]
    assert runs[0].duration_s == pytest.approx(4 / FPS)


def test_a_crop_classifier_alone_cannot_confirm_without_flashing():
    _, states = run(lambda t: (0.05, 0.0), crop_score=0.99)
    assert first_time(states, EvState.CONFIRMED) is None
    assert first_time(states, EvState.CANDIDATE) is not None  # but it is watched


def test_lights_off_clears_after_the_hold_time_and_one_dropout_does_not():
    def sig(t):
        if abs(t - 3.0) < 0.03:
            return 0.0, 0.0  # one missed detection of the lamp
        return alternating(2.0, on_at=1.0, off_at=5.0)(t)

    _, states = run(sig, duration_s=10.0)
    confirmed = first_time(states, EvState.CONFIRMED)
    cleared = first_time(states, EvState.CLEARED)
    assert confirmed is not None and confirmed < 1.6
    assert all(s == EvState.CONFIRMED for t, s in states if confirmed <= t < 5.5)
    assert cleared is not None and 6.0 <= cleared <= 7.5  # 2 s without a lit lamp


def test_flash_rate_is_estimated():
    ev, _ = run(alternating(2.0), duration_s=5.0)
    assert ev.flash_hz == pytest.approx(2.0, rel=0.3)


def test_blink_transitions_with_hysteresis():
    x = np.array([0, 0, 1, 1, 0.5, 1, 0, 0, 1])
    assert blink_transitions(x, on_level=0.8, off_level=0.2) == 3


def test_measure_lamps_reads_the_top_band_only():
    crop = np.full((100, 80, 3), 60, np.uint8)
    crop[5:15, 10:30] = (0, 0, 255)  # red lamp on the roof
    crop[5:15, 50:70] = (255, 40, 0)  # blue lamp
    crop[80:90, 5:20] = (0, 0, 255)  # tail light low on the body
    m = measure_lamps(crop)
    assert m.red == pytest.approx(200 / (40 * 80)) and m.blue == pytest.approx(200 / (40 * 80))
    dull = np.full((100, 80, 3), 60, np.uint8)
    dull[:30] = (30, 30, 140)  # dark red paint: saturated but not lamp-bright
    assert measure_lamps(dull).red == 0.0


def test_median_of_is_numpys_median_on_short_windows():
    from rsu.classify.lamps import median_of

    rng = np.random.default_rng(0)
    for n in range(1, 40):
        for scale in (1.0, 1e-3, 1e6):
            x = rng.random(n) * scale
            assert median_of(x) == float(np.median(x))
            assert median_of(np.round(x, 1)) == float(np.median(np.round(x, 1)))  # ties
    assert median_of(np.array([3, 1, 2])) == 2.0 and median_of(np.array([4, 1, 2, 3])) == 2.5
    assert np.isnan(median_of(np.array([1.0, np.nan, 2.0])))


@pytest.mark.parametrize("scores, confident", [
    ((0.9,), False),             # one score is never a body
    ((0.9, 0.8), True),          # two sure scores are
    ((0.9, 0.6), False),         # one of them only confident: three are needed
    ((0.9, 0.6, 0.5), True),
    ((0.45, 0.45, 0.5), False),  # mean under the confident threshold
])
def test_two_sure_body_scores_or_three_confident_ones_make_a_body(scores, confident):
    ev = TrackEvidence()
    for i, b in enumerate(scores):
        ev.update(i / FPS, LampMeasurement(0.0, 0.0), body_score=b)
    assert ev.body_confident == confident


def test_body_scores_handed_to_a_new_track_count_only_after_its_own_box_is_scored():
    ev = TrackEvidence()
    for i in range(4):
        ev.update(i / FPS, LampMeasurement(0.0, 0.0), body_score=0.9)
    assert ev.body_confident and ev.state != EvState.CONFIRMED
    ev.handed_over()  # matched by position alone: the new box may be another vehicle
    assert not ev.body_confident
    ev.update(4 / FPS, LampMeasurement(0.0, 0.0))  # frames without a body score keep it out
    assert not ev.body_confident
    ev.update(5 / FPS, LampMeasurement(0.0, 0.0), body_score=0.9)  # the new box scored as an EV too
    assert ev.body_confident


def test_a_confirmed_ev_keeps_its_body_evidence_through_a_hand_over():
    ev, states = run(alternating(2.0), duration_s=3.0)
    assert states[-1][1] == EvState.CONFIRMED
    for t in np.arange(3.0, 3.5, 1 / FPS):
        ev.update(float(t), LampMeasurement(0.0, 0.0), body_score=0.9)
    ev.handed_over()
    assert ev.body_confident and ev.state == EvState.CONFIRMED
