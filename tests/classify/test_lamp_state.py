"""The lamp-state model (rsu.classify.lamp_state) and what the recogniser does with it: a light-bar flash pattern confirms
without a confident body only where the model sees lit lamps; a box inside a nearer confirmed EV's crop sees that
EV's lamps, not its own."""

from __future__ import annotations

import numpy as np

from protocol.enums import EvState
from rsu.classify.ev import TrackEvClassifier, TrackInfo, crop_share_within
from rsu.classify.lamp_state import INPUT_HW, LampStateModel, band_input
from rsu.classify.lamps import LampMeasurement
from rsu.classify.temporal import TrackEvidence

FPS = 15.0


def _band(lit: bool) -> np.ndarray:
    """A dark roof band (60 x 32 px, a CCTV vehicle's) with a small beacon in the middle, lit or not (BGR)."""
    band = np.full((32, 60, 3), 60, np.uint8)
    band[12:22, :] = (90, 90, 95)  # the roof
    if lit:
        band[8:13, 26:32] = (255, 120, 40)  # blue glow
        band[9:12, 27:31] = (255, 235, 225)  # its clipped core
    else:
        band[8:13, 26:32] = (110, 70, 60)  # a dark blue dome
    return band


def test_band_input_is_the_models_size_and_fills_other_vehicles_pixels_with_the_bands_colour():
    band = _band(True)
    x = band_input(band)
    assert x.shape == (3, *INPUT_HW) and x.dtype == np.float32 and 0.0 <= x.min() and x.max() <= 1.0
    ignore = np.zeros(band.shape[:2], bool)
    ignore[:, :30] = True  # the left half (with half the beacon) is a nearer vehicle's
    hidden = band_input(band, ignore)
    assert hidden[:, :, : INPUT_HW[1] // 2 - 1].std() < x[:, :, : INPUT_HW[1] // 2 - 1].std()


def test_the_shipped_model_sees_a_small_lit_beacon_and_not_a_dark_one():
    model = LampStateModel()
    assert 0.0 < model.threshold < 1.0
    assert model(_band(True)) > model(_band(False))


def _flashing(lit_p: float | None, body: float | None = None) -> list[EvState]:
    """Two-colour bar flashing at 2 Hz from 1 s, measured with the light-bar colours only (no lamp-bright pixels)."""
    ev = TrackEvidence()
    out = []
    for i in range(int(4 * FPS)):
        t = i / FPS
        lit = t >= 1.0 and ((t - 1.0) * 2.0) % 1.0 < 0.5
        bar = LampMeasurement(0.02 if lit else 0.0, 0.0, red_peak=1.0, red_core=0.6)
        bright = LampMeasurement(0.0, 0.0)
        out.append(ev.update(t, bright, None, body, bar, lit_p=lit_p))
    return out


def test_a_light_bar_flash_pattern_confirms_alone_only_where_the_lamp_state_model_sees_lit_lamps():
    assert EvState.CONFIRMED in _flashing(None)  # no model: the colour tests decide
    assert EvState.CONFIRMED in _flashing(0.95)
    assert EvState.CONFIRMED not in _flashing(0.2)  # tail lights flickering at dusk, a blue fringe on a white van


def test_a_box_inside_a_nearer_confirmed_evs_crop_does_not_own_its_lamps():
    clf = TrackEvClassifier()
    boxes = np.array([[100.0, 100.0, 220.0, 200.0],   # the EV, nearer the camera
                      [120.0, 80.0, 200.0, 110.0]])   # a second box on its roof, where the beacons are
    bounds = [clf.crop_bounds(b, 400, 300) for b in boxes]
    assert crop_share_within(bounds[1], bounds[0]) > 0.9
    ev = TrackInfo(TrackEvidence(), 0.0, 1.0, box=boxes[0].copy())
    ev.evidence.state = EvState.CONFIRMED
    clf.tracks = {1: ev}
    assert clf._ev_ahead(1, [1, 2], boxes, bounds)
    ev.evidence.state = EvState.CANDIDATE  # not confirmed: the roof box's lamps are judged as its own
    assert not clf._ev_ahead(1, [1, 2], boxes, bounds)
    apart = np.array([boxes[0], [300.0, 20.0, 380.0, 60.0]])  # away from its roof, and not beside it
    ev.evidence.state = EvState.CONFIRMED
    assert not clf._ev_ahead(1, [1, 2], apart, [clf.crop_bounds(b, 400, 300) for b in apart])


def test_a_white_flicker_on_a_dark_bar_does_not_confirm_with_a_confident_body_where_the_model_sees_no_lit_lamp():
    """An ambulance whose lights are off: a white glint flickering on its dark bar is a light-bar flash pattern, and
    its body is confident; only the lamp-state model tells the bar is dark."""
    def run(lit_p):
        ev = TrackEvidence()
        states = []
        for i in range(int(4 * FPS)):
            t = i / FPS
            lit = t >= 1.0 and ((t - 1.0) * 2.0) % 1.0 < 0.5
            bar = LampMeasurement(0.0, 0.0, white=0.02 if lit else 0.0)
            states.append(ev.update(t, LampMeasurement(0.0, 0.0), None, 0.9, bar, lit_p=lit_p))
        return states

    assert EvState.CONFIRMED in run(None)
    assert EvState.CONFIRMED in run(0.95)
    assert EvState.CONFIRMED not in run(0.05)


def test_a_one_colour_lamp_bright_flash_confirms_alone_only_where_the_lamp_state_model_sees_lit_lamps():
    """One red lamp blinking at 2 Hz in the middle of the band, lamp-bright: a beacon, or a turn signal or hazard
    flasher whose lamp the band holds. Without a confident body only the lamp-state model tells them apart; red/blue
    alternation, which no ordinary vehicle's lamps show, confirms whatever the model says."""
    def run(lit_p, body=None, alternate=False):
        ev = TrackEvidence()
        states = []
        for i in range(int(4 * FPS)):
            t = i / FPS
            on = t >= 1.0
            red = ((t - 1.0) * 2.0) % 1.0 < 0.5
            bright = LampMeasurement(0.03 if on and red else 0.0, 0.03 if on and alternate and not red else 0.0)
            states.append(ev.update(t, bright, None, body, lit_p=lit_p))
        return states

    assert EvState.CONFIRMED in run(None)  # no model: the colour tests decide
    assert EvState.CONFIRMED in run(0.99)
    assert EvState.CONFIRMED not in run(0.01)  # a decoy's blinking lamp
    assert EvState.CONFIRMED in run(0.01, body=0.95)  # a confident body with the flash still confirms
    assert EvState.CONFIRMED in run(0.01, alternate=True)
