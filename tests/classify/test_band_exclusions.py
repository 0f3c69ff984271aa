"""A lamp is counted for one vehicle only (rsu.classify.ev.band_exclusions): a car beside an EV must not take
in the EV's roof bar, which its own upward-grown crop reaches."""

from __future__ import annotations

import numpy as np

from rsu.classify.ev import TrackEvClassifier
from rsu.classify.ownership import band_exclusions


def _scene():
    image = np.zeros((240, 400, 3), np.uint8)
    boxes = np.array([[100.0, 100.0, 180.0, 160.0],   # the EV
                      [140.0, 100.0, 220.0, 160.0]])  # a car beside it, the same distance from the camera
    image[88:96, 120:160] = (255, 60, 0)  # the EV's lit blue roof bar, above its box (BGR)
    return image, boxes


def test_car_beside_an_ev_does_not_measure_the_evs_bar():
    image, boxes = _scene()
    clf = TrackEvClassifier()
    bounds = [clf.crop_bounds(b, image.shape[1], image.shape[0]) for b in boxes]
    assert bounds[1][0] < 160 and bounds[1][1] < 96  # the car's crop does reach the bar ...
    _, bar_shared, _, _ = clf._measure(image, bounds[1])
    _, bar_car, _, _ = clf._measure(image, bounds[1], band_exclusions(1, boxes, bounds))
    _, bar_ev, _, _ = clf._measure(image, bounds[0], band_exclusions(0, boxes, bounds))
    assert bar_shared.coloured > 0.0  # ... and without the split it counts it
    assert bar_car.coloured == 0.0
    assert bar_ev.coloured > 0.0  # the EV keeps its own bar


def test_a_nearer_vehicle_hides_its_box_and_its_crop_outside_this_box_and_a_far_one_only_its_side():
    boxes = np.array([[100.0, 50.0, 180.0, 100.0], [90.0, 80.0, 200.0, 160.0], [150.0, 40.0, 230.0, 95.0]])
    bounds = [(100, 38, 180, 100), (90, 60, 200, 160), (150, 27, 230, 95)]
    out = band_exclusions(0, boxes, bounds)
    assert (90, 80, 200, 160) in out  # box 1 is nearer (bottom 160 > 100): all of its box
    # and its crop above its box (rows 60-80), except box 0's rows nearer box 0's top (50) than box 1's top (80):
    # columns 100-180 above the midpoint, row 65
    assert {(90, 65, 200, 80), (90, 60, 100, 65), (180, 60, 200, 65)} <= set(out)
    assert not any(x1 < 180 and x2 > 100 and y1 < 65 and y2 > 60 for x1, y1, x2, y2 in out if x1 >= 90 and x2 <= 200)
    assert (165, 27, 230, 95) in out  # box 2 is farther, to the right: from the midpoint 165 of the centres 140, 190
    assert band_exclusions(1, boxes, bounds)[0] == (100, 38, 142, 100)  # box 1 (centre 145) gives up box 0's side (centre 140)


def test_a_truck_behind_a_car_does_not_measure_the_cars_tail_lights():
    """A farther vehicle seen above a nearer one's roof (sim tuning seeds 31372/91468: a truck or bus behind a car,
    or behind the EV itself, took in the tail lights or the light bar of the vehicle ahead through its upward-grown
    band): its own box above the nearer box's top is left out; the nearer vehicle keeps its own roof."""
    image = np.zeros((240, 400, 3), np.uint8)
    boxes = np.array([[100.0, 100.0, 180.0, 180.0],   # the truck, nearer
                      [120.0, 70.0, 160.0, 104.0]])   # the car ahead, its rear seen above the truck's roof
    image[92:97, 124:130] = (40, 40, 255)  # the car's lit tail lights (BGR red)
    image[92:97, 150:156] = (40, 40, 255)
    clf = TrackEvClassifier()
    bounds = [clf.crop_bounds(b, image.shape[1], image.shape[0]) for b in boxes]
    _, bar_shared, _, _ = clf._measure(image, bounds[0])
    assert bar_shared.red > 0.0  # without the exclusion the truck counts the car's tail lights
    _, bar_truck, _, _ = clf._measure(image, bounds[0], band_exclusions(0, boxes, bounds))
    assert bar_truck.red == 0.0
    image[98:103, 130:150] = (40, 40, 255)  # a red bar on the truck's own roof, at its box's top edge
    _, bar_truck, _, _ = clf._measure(image, bounds[0], band_exclusions(0, boxes, bounds))
    assert bar_truck.red > 0.0


def _bus_behind_ev():
    """A bus near the camera and, just ahead of it in the image, the EV (farther: bottom edge higher)."""
    boxes = np.array([[100.0, 120.0, 200.0, 260.0],   # the bus
                      [130.0, 90.0, 175.0, 125.0]])   # the EV, rising above the bus roof, 35 px tall
    clf = TrackEvClassifier()
    bounds = [clf.crop_bounds(b, 400, 300) for b in boxes]
    return clf, boxes, bounds


def test_a_vehicle_just_ahead_too_small_to_measure_may_own_the_lamps_on_the_bus_roof():
    """Its flashes may be what the bus's band sees (sim tuning seed 44077): the bus then needs a confident body."""
    clf, boxes, bounds = _bus_behind_ev()
    assert clf._ev_ahead(0, [1, 2], boxes, bounds)
    big = boxes.copy()
    big[1] = (120.0, 60.0, 190.0, 125.0)  # measured (65 px tall) and not confirmed: its lamps are judged as its own
    assert not clf._ev_ahead(0, [1, 2], big, [clf.crop_bounds(b, 400, 300) for b in big])
    assert not clf._ev_ahead(1, [1, 2], boxes, bounds)  # the bus is nearer the camera than the EV, not ahead of it


def test_a_confirmed_ev_lost_for_a_frame_still_counts_as_just_ahead():
    """SORT drops a track after one missed detection: the EV's confirmed track, lost in this frame, is still just
    ahead of the bus, so the bus's flashes do not confirm alone in that frame (sim tuning seed 44077)."""
    from protocol.enums import EvState
    from rsu.classify.ev import TrackInfo
    from rsu.classify.temporal import TrackEvidence

    clf, boxes, _ = _bus_behind_ev()
    ev = TrackInfo(TrackEvidence(), 0.0, 1.0, box=np.array([120.0, 60.0, 190.0, 125.0]))
    ev.evidence.state = EvState.CONFIRMED
    clf.tracks = {7: ev}
    bus = boxes[:1]
    bounds = [clf.crop_bounds(bus[0], 400, 300)]
    assert clf._ev_ahead(0, [1], bus, bounds, clf._lost_evs(1.2, [1]))
    assert not clf._ev_ahead(0, [1], bus, bounds, clf._lost_evs(1.0 + clf.handover_after_s + 0.1, [1]))
    ev.evidence.state = EvState.CANDIDATE
    assert not clf._ev_ahead(0, [1], bus, bounds, clf._lost_evs(1.2, [1]))


def test_a_flashing_ev_lost_behind_the_nearer_truck_owns_its_flashes_while_hidden():
    """An EV that drives on behind a truck nearer the camera, its lower body hidden (the detector loses it) and its
    light bar above the truck's roof, still owns those flashes for ``occluded_hold_s`` while its moved-on box's
    bottom edge is behind the truck's box; the truck's band does not confirm on them alone (tuning seed 52609,
    ``ev_two_lanes_dense``, rsu4: a false alert on the truck 0.67 s after the EV's track was lost). Out from behind
    the truck, the claim ends with the hand-over time as before."""
    from protocol.enums import EvState
    from rsu.classify.ev import TrackInfo

    clf, boxes, _ = _bus_behind_ev()
    ev = TrackInfo(_flashing_evidence(1.0), 0.0, 1.0, box=boxes[1].copy(), centre_velocity_pxps=np.zeros(2))
    assert ev.evidence.state != EvState.CONFIRMED and ev.evidence.flashed_recently
    clf.tracks = {7: ev}
    truck = boxes[:1]
    bounds = [clf.crop_bounds(truck[0], 400, 300)]
    late_s = 1.0 + clf.handover_after_s + 0.3
    assert late_s - 1.0 < clf.occluded_hold_s
    assert clf._ev_ahead(0, [1], truck, bounds, clf._lost_evs(late_s, [1], truck))
    assert not clf._ev_ahead(0, [1], truck, bounds, clf._lost_evs(1.0 + clf.occluded_hold_s + 0.1, [1], truck))
    beside = np.array([[260.0, 120.0, 360.0, 260.0]])  # the truck in the next lane: the EV's bottom edge in sight
    assert clf._lost_evs(late_s, [1], beside).boxes.shape == (0, 4)
    assert clf._lost_evs(1.2, [1], beside).boxes.shape == (1, 4)  # within the hand-over time, wherever it is
    itself = np.array([[128.0, 88.0, 178.0, 130.0]])  # a box over the lost one, lower: the EV seen again, hiding nothing
    assert clf._lost_evs(late_s, [1], itself).boxes.shape == (0, 4)


def _flashing_evidence(until_s: float):
    """Evidence of a track whose own band flashed red and blue (an EV's bar) until ``until_s``: not confirmed yet."""
    from rsu.classify.lamps import LampMeasurement
    from rsu.classify.temporal import TrackEvidence

    ev = TrackEvidence()
    for i in range(int(until_s * 15) + 1):
        t = i / 15
        red = (t * 2.0) % 1.0 < 0.5
        ev.update(t, LampMeasurement(0.04 if red else 0.0, 0.0 if red else 0.04), lamps_alone=False)
    return ev


def test_a_flashing_track_just_ahead_may_own_the_flashes_before_it_is_confirmed():
    """An EV whose track SORT started again (it had passed a truck) builds its evidence anew; until it is confirmed
    its flashes, seen in the band of the truck just behind it, must not confirm the truck alone (ev_bench seed 51100,
    ``night_ev``, rsu2), in the frame where it is tracked and in one where SORT lost it."""
    from protocol.enums import EvState, LightState
    from rsu.classify.ev import TrackInfo
    from rsu.classify.lamps import LampMeasurement

    clf, boxes, bounds = _bus_behind_ev()
    big = boxes.copy()
    big[1] = (120.0, 60.0, 190.0, 125.0)  # measured (65 px tall): without lamp cues its lamps are judged as its own
    big_bounds = [clf.crop_bounds(b, 400, 300) for b in big]
    ev = TrackInfo(_flashing_evidence(1.0), 0.0, 1.0, box=big[1].copy())
    assert ev.evidence.state != EvState.CONFIRMED and ev.evidence.light_state != LightState.OFF
    clf.tracks = {2: ev}
    assert clf._ev_ahead(0, [1, 2], big, big_bounds)
    assert clf._lost_evs(1.2, [1]).boxes.shape == (1, 4)  # lost for a frame: still just ahead
    assert clf._ev_ahead(0, [1], big[:1], big_bounds[:1], clf._lost_evs(1.2, [1]))
    quiet = TrackInfo(_flashing_evidence(1.0), 0.0, 1.0, box=big[1].copy())
    quiet.evidence.update(4.0, LampMeasurement(0.0, 0.0))
    assert quiet.evidence.light_state == LightState.OFF  # no lamp cue for clear_after_s: its lamps are out
    clf.tracks = {2: quiet}
    assert not clf._ev_ahead(0, [1, 2], big, big_bounds)


def test_an_ev_just_ahead_of_a_bus_keeps_its_bar_inside_the_bus_crop():
    """The bus is nearer (bottom edge lower) and its crop, grown above its box for a roof bar, reaches over the police
    car just ahead of it: the car's bar, inside the car's own box, is the car's (ev_bench tuning seed 21376,
    ``ev_two_lanes_dense``, rsu1: the car's band lost every flash to the bus's crop and it was never confirmed);
    above the bus's box and outside the car's box the bus's crop stays the bus's."""
    image = np.zeros((300, 400, 3), np.uint8)
    boxes = np.array([[100.0, 120.0, 300.0, 280.0],   # the bus, nearer: its crop reaches 40 px above its box
                      [170.0, 85.0, 240.0, 130.0]])   # the police car just ahead, its roof inside the bus's crop
    image[86:92, 190:220] = (255, 60, 0)  # the car's lit blue bar, at its box's top (BGR)
    clf = TrackEvClassifier()
    bounds = [clf.crop_bounds(b, image.shape[1], image.shape[0]) for b in boxes]
    assert bounds[0][1] < 86  # the bus's crop takes in the bar
    _, bar_car, _, _ = clf._measure(image, bounds[1], band_exclusions(1, boxes, bounds))
    assert bar_car.blue > 0.0
    image[86:92, 190:220] = 0
    image[80:84, 190:220] = (255, 60, 0)  # a blue light above the car's box, in both crops: the bus's crop keeps it
    _, bar_car, _, _ = clf._measure(image, bounds[1], band_exclusions(1, boxes, bounds))
    assert bar_car.blue == 0.0


def test_a_steady_bar_just_ahead_does_not_hold_back_the_vehicle_behind():
    """A farther track whose band gave only a steady-bar cue (a blue object on a van's roof line in the Japanese
    clip, body 0.08) does not own flashes: the ambulance just behind it keeps its body scores. One that flashed does."""
    from protocol.enums import LightState
    from rsu.classify.ev import TrackInfo, _may_own_flashes
    from rsu.classify.lamps import LampMeasurement
    from rsu.classify.temporal import TrackEvidence

    steady = TrackEvidence()
    for i in range(15):
        steady.update(i / 15, LampMeasurement(0.0, 0.0), bar=LampMeasurement(0.0, 0.03))
    assert steady.light_state == LightState.STEADY and steady.last_flash_cue_s is None
    clf, boxes, bounds = _bus_behind_ev()
    big = boxes.copy()
    big[1] = (120.0, 60.0, 190.0, 125.0)
    big_bounds = [clf.crop_bounds(b, 400, 300) for b in big]
    clf.tracks = {2: TrackInfo(steady, 0.0, 1.0, box=big[1].copy())}
    assert not _may_own_flashes(clf.tracks[2]) and not clf._ev_ahead(0, [1, 2], big, big_bounds)
    clf.tracks = {2: TrackInfo(_flashing_evidence(1.0), 0.0, 1.0, box=big[1].copy())}
    assert _may_own_flashes(clf.tracks[2]) and clf._ev_ahead(0, [1, 2], big, big_bounds)


def test_a_car_beside_a_confirmed_ev_is_lit_by_it():
    """At night a confirmed EV's beacon flashes on the car beside it (tuning clip roadside_night_ambulance_india_redblue):
    that car's flashes confirm only with a confident body while the EV is beside it, seen or lost for a moment; a car
    more than one EV width away, or not level with it, is judged on its own lamps."""
    from protocol.enums import EvState
    from rsu.classify.ev import TrackInfo, lit_beside
    from rsu.classify.temporal import TrackEvidence

    clf = TrackEvClassifier()
    boxes = np.array([[100.0, 100.0, 180.0, 200.0],   # the EV, 80 px wide
                      [230.0, 110.0, 290.0, 170.0],   # a car 50 px to its right, farther (bottom edge higher)
                      [300.0, 110.0, 360.0, 170.0]])  # a car 120 px to its right
    bounds = [clf.crop_bounds(b, 400, 300) for b in boxes]
    ev = TrackEvidence()
    ev.state = EvState.CONFIRMED
    clf.tracks = {1: TrackInfo(ev, 0.0, 1.0, box=boxes[0].copy())}
    assert clf._ev_ahead(1, [1, 2, 3], boxes, bounds)
    assert not clf._ev_ahead(2, [1, 2, 3], boxes, bounds)
    clf.tracks[1].evidence.state = EvState.CANDIDATE  # not confirmed: the car's flashes may be its own
    assert not clf._ev_ahead(1, [1, 2, 3], boxes, bounds)
    clf.tracks[1].evidence.state = EvState.CONFIRMED
    lost = clf._lost_evs(1.2, [2, 3], boxes[1:])  # the EV's detection missed for 0.2 s
    assert lost.boxes[lost.confirmed].shape == (1, 4)
    assert clf._ev_ahead(0, [2, 3], boxes[1:], bounds[1:], lost)
    assert not lit_beside((230, 0, 290, 90), boxes[0], 1.0)  # above the EV's box, not level with it
