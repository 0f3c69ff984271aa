"""TrackEvClassifier (per-track lamp evidence on box crops) and EvAlertManager (alert life cycle)."""

from __future__ import annotations

import numpy as np
import pytest

from protocol.enums import AlertState, EvState, LightState
from rsu.classify.alerts import EvAlertManager
from rsu.classify.ev import TrackEvClassifier, clip_box, extrapolate_box, match_lost_tracks
from rsu.frames import Frame
from rsu.perception import Detections, object_column
from rsu.track.sort import no_tracks

FPS = 15.0
BOX_A = (100.0, 100.0, 180.0, 160.0)  # the EV
BOX_B = (300.0, 100.0, 380.0, 160.0)  # a red car


def tracks(entries):
    """The table of tracks of (track_id, box) pairs."""
    if not entries:
        return no_tracks()
    ids = np.array([e[0] for e in entries], np.int64)
    n = len(entries)
    z = np.zeros(n, np.int64)
    return Detections(np.array([e[1] for e in entries], float), np.ones(n), z, track_ids=ids, det_indices=z,
                      hits=z + 5, age_frames=z + 5, velocity_px=np.zeros((n, 2)))


class Verdict:
    """One track's EV columns, read by track id."""

    def __init__(self, table, k):
        self.ev_score, self.light_state = float(table.ev_scores[k]), table.light_states[k]
        self.ev_state, self.track = table.ev_states[k], table.evidence[k]


def by_id(table):
    """The classifier's EV columns by track id."""
    return {int(tid): Verdict(table, k) for k, tid in enumerate(table.track_ids)}


def scene(t, lights_on_at=0.5, freq=2.0):
    img = np.full((240, 480, 3), 90, np.uint8)
    img[100:160, 100:180] = (230, 230, 230)            # white ambulance body
    img[130:150, 110:170] = (40, 40, 200)              # red stripe (paint, not lamp-bright)
    img[100:160, 300:380] = (30, 30, 190)              # red car
    if t >= lights_on_at:
        red_phase = ((t - lights_on_at) * freq) % 1.0 < 0.5
        img[102:110, 110:135 if red_phase else 110] = (0, 0, 255)
        if not red_phase:
            img[102:110, 145:170] = (255, 60, 0)
    return img


def run(n_frames, entries_of=lambda k: [(1, BOX_A), (2, BOX_B)], clf=None, **scene_kw):
    clf = clf or TrackEvClassifier()
    states = []
    for k in range(n_frames):
        t = k / FPS
        out = by_id(clf(Frame(scene(t, **scene_kw), t, k, "cam"), tracks(entries_of(k))))
        states.append((t, out))
    return clf, states


def test_clip_box_to_image():
    assert clip_box((-10, -5, 50, 40), 100, 80) == (0, 0, 50, 40)
    assert clip_box((90.2, 70.5, 150, 120), 100, 80) == (90, 70, 100, 80)
    assert clip_box((200, 10, 250, 40), 100, 80) is None
    assert clip_box((np.nan, 0, 10, 10), 100, 80) is None


def test_flashing_light_bar_confirms_fast_and_the_red_car_never():
    _, states = run(int(6 * FPS))
    first = next(t for t, out in states if 1 in out and out[1].ev_state == EvState.CONFIRMED)
    assert 0.5 < first <= 0.5 + 0.6
    assert all(out[2].ev_state != EvState.CONFIRMED for _, out in states)
    v = states[-1][1][1]
    score, light, state = v.ev_score, v.light_state, v.ev_state
    assert state == EvState.CONFIRMED and light == LightState.FLASHING and score > 0.9
    assert states[-1][1][2].light_state == LightState.OFF


def test_no_lights_no_confirmation():
    _, states = run(int(5 * FPS), lights_on_at=1e9)
    assert all(s.ev_state != EvState.CONFIRMED for _, out in states for s in out.values())


def test_crop_score_is_called_on_the_clipped_crop_and_alone_cannot_confirm():
    seen = []

    def scorer(crop):
        seen.append(crop.shape)
        return 0.99

    clf = TrackEvClassifier(crop_score=scorer)
    _, states = run(int(3 * FPS), entries_of=lambda k: [(7, (100.0, 100.0, 180.0, 280.0))], clf=clf,
                    lights_on_at=1e9)
    assert seen and seen[0] == (185, 80, 3)  # the box grown 25 % (45 px) upwards, clipped at the bottom (y 240)
    assert all(out[7].ev_state != EvState.CONFIRMED for _, out in states)


def test_tracks_are_forgotten_when_gone():
    clf = TrackEvClassifier(forget_after_s=0.5)
    run(10, clf=clf)
    assert set(clf.tracks) == {1, 2}
    run(20, entries_of=lambda k: [(3, BOX_B)], clf=TrackEvClassifier())  # independent instance untouched
    for k in range(10, 30):
        clf(Frame(scene(k / FPS), k / FPS, k, "cam"), tracks([(3, BOX_B)]))
    assert set(clf.tracks) == {3}
    capped = TrackEvClassifier(max_tracks=4, handover_after_s=0.0)  # new ids on one box: no hand-over here
    for k in range(10):
        capped(Frame(scene(k / FPS), k / FPS, k, "cam"), tracks([(100 + k, BOX_B)]))
    assert len(capped.tracks) == 4 and max(capped.tracks) == 109


def obj(tid, state, x=10.0):
    """One localised track with its verdict and no evidence record."""
    one = np.ones(1)
    return Detections(np.array([[0.0, 0.0, 10.0, 10.0]]), one, np.zeros(1, np.int64), track_ids=np.array([tid]),
                      ev_scores=np.array([0.9 if state == EvState.CONFIRMED else 0.1]),
                      ev_states=object_column([state]), localized=np.ones(1, bool), positions_m=np.array([[x, 2.0]]),
                      lanes=object_column([1]))


def objs_of(rows):
    return Detections.concatenate(rows) if rows else obj(0, EvState.NONE)[[]]


def test_alert_life_cycle_active_refresh_2hz_and_cleared_when_gone():
    m = EvAlertManager()
    events = []
    for k in range(60):  # 4 s at 15 fps: candidate, then confirmed from frame 5, gone from frame 40
        t = k / FPS
        objs = objs_of([] if k >= 40 else [obj(4, EvState.CONFIRMED if k >= 5 else EvState.CANDIDATE, x=k)])
        events += [(t, e) for e in m.update(t, objs)]
    active = [(t, e) for t, e in events if e.state == AlertState.ACTIVE]
    cleared = [(t, e) for t, e in events if e.state == AlertState.CLEARED]
    assert active[0][0] == pytest.approx(5 / FPS)
    gaps = np.diff([t for t, _ in active])
    assert np.all(gaps >= 0.5 - 1e-6) and np.all(gaps <= 0.5 + 1 / FPS + 1e-6)
    assert len(cleared) == 1 and cleared[0][0] == pytest.approx(39 / FPS + 1.0, abs=1 / FPS + 1e-6)
    assert cleared[0][1].row.positions_m[0, 0] == 39  # last known position
    assert not m.active


def test_alert_cleared_when_the_evidence_clears():
    m = EvAlertManager()
    ev1 = m.update(0.0, obj(4, EvState.CONFIRMED))
    ev2 = m.update(0.1, obj(4, EvState.CLEARED))
    assert [e.state for e in ev1] == [AlertState.ACTIVE] and [e.state for e in ev2] == [AlertState.CLEARED]


def test_above_fraction_sees_a_light_bar_just_above_the_box():
    img = np.full((240, 480, 3), 90, np.uint8)
    img[95:100, 110:170] = (0, 0, 255)  # lamp on the roof, above a detector box that starts at y = 100
    assert TrackEvClassifier(above_fraction=0.0).measure(img, BOX_A)[0].red == 0.0
    assert TrackEvClassifier(above_fraction=0.2).measure(img, BOX_A)[0].red > 0.05
    assert TrackEvClassifier().measure(img, BOX_A)[0].red > 0.05  # the default grows the box 25 % upwards


def test_boxes_too_small_to_resolve_a_light_bar_are_not_measured():
    small = (110.0, 100.0, 140.0, 125.0)  # 30 x 25 px, on the flashing bar
    clf, states = run(int(3 * FPS), entries_of=lambda k: [(5, small)])
    assert all((out[5].ev_score, out[5].light_state, out[5].ev_state) == (clf.tracks[5].evidence.ev_score,
                                                                         LightState.UNKNOWN, EvState.NONE)
               for _, out in states)
    assert clf.tracks[5].evidence.frames == 0
    _, states = run(int(3 * FPS), entries_of=lambda k: [(5, small)], clf=TrackEvClassifier(min_box_px=20))
    assert states[-1][1][5].ev_state == EvState.CONFIRMED


def moving_ev_scene(t, x0=40.0, speed_pxps=75.0, flash_frames=2, period_frames=7):
    """A white EV body moving right whose red-only bar strobes ``flash_frames`` out of every
    ``period_frames`` frames (about 2 Hz), and a steady red car parked at BOX_B."""
    img = np.full((240, 640, 3), 90, np.uint8)
    x = int(round(x0 + speed_pxps * t))
    img[100:160, x:x + 80] = (230, 230, 230)
    img[100:160, 300 + 200:380 + 200] = (30, 30, 190)
    if int(round(t * FPS)) % period_frames < flash_frames:
        img[102:110, x + 10:x + 70] = (0, 0, 255)
    return img, (float(x), 100.0, float(x + 80), 160.0)


def run_fragmented(clf, n_frames=int(4 * FPS), visible=9, hidden=3, other_at=None):
    """The EV's track is reported for ``visible`` frames, then not at all for ``hidden`` frames (SORT lost
    it and its successor is not yet confirmed), then under a new id, and so on; ``other_at``: from that
    frame a new id also appears on the parked red car."""
    confirmed = []
    for k in range(n_frames):
        t = k / FPS
        img, box = moving_ev_scene(t)
        seg, pos = divmod(k, visible + hidden)
        entries = [(100 + seg, box)] if pos < visible else []
        if other_at is not None and k >= other_at:
            entries.append((7, (500.0, 100.0, 580.0, 160.0)))
        out = by_id(clf(Frame(img, t, k, "cam"), tracks(entries)))
        confirmed += [(t, tid) for tid, v in out.items() if v.ev_state == EvState.CONFIRMED]
    return confirmed


def test_evidence_survives_track_id_switches():
    # each id sees at most one complete flash of one colour: alone, no id can confirm
    assert run_fragmented(TrackEvClassifier(handover_after_s=0.0)) == []
    clf = TrackEvClassifier()
    confirmed = run_fragmented(clf, other_at=20)
    assert confirmed and confirmed[0][0] < 2.0
    assert {tid for _, tid in confirmed} <= {100, 101, 102, 103, 104}  # never the red car
    last = max(tid for _, tid in confirmed)
    assert clf.tracks[last].handed_over_from[:2] == (100, 101)


def test_a_new_track_elsewhere_does_not_take_over_the_evidence():
    clf = TrackEvClassifier()
    img, box = moving_ev_scene(0.0)
    clf(Frame(img, 0.0, 0, "cam"), tracks([(1, box)]))
    clf(Frame(img, 1 / FPS, 1, "cam"), tracks([(2, (500.0, 100.0, 580.0, 160.0))]))
    assert 1 in clf.tracks and clf.tracks[2].handed_over_from == ()
    # too old to hand over
    clf(Frame(img, 2.0, 2, "cam"), tracks([(3, box)]))
    assert clf.tracks[3].handed_over_from == ()


def test_lost_track_boxes_are_moved_on_before_matching():
    box = np.array([0.0, 0.0, 40.0, 30.0])
    v = np.array([100.0, 0.0])  # centre moving 100 px/s to the right
    new = np.array([[30.0, 0.0, 70.0, 30.0], [200.0, 0.0, 240.0, 30.0]])
    assert match_lost_tracks(new, box[None], 0.3) == []  # IoU 0.14 where it was last seen
    assert match_lost_tracks(new, extrapolate_box(box, v, 0.3)[None], 0.3) == [(0, 0)]
    two = np.array([[0.0, 0.0, 40.0, 30.0], [5.0, 0.0, 45.0, 30.0]])
    assert match_lost_tracks(two, two[::-1], 0.3) == [(0, 1), (1, 0)]  # one each, the best overall assignment


def test_boxes_cut_by_the_left_right_or_top_border_are_not_measured():
    seen = []
    clf = TrackEvClassifier(crop_score=lambda crop: seen.append(crop.shape) or 0.5)
    run(10, entries_of=lambda k: [(7, (-20.0, 100.0, 60.0, 160.0)), (8, (440.0, 100.0, 481.0, 160.0)),
                                  (9, (200.0, 5.0, 260.0, 60.0))], clf=clf)
    assert not seen and all(clf.tracks[t].evidence.frames == 0 for t in (7, 8, 9))


def test_a_box_cut_by_the_border_that_fills_the_view_is_measured():
    # a vehicle so near that its box spans the image's height: the part in view is measured, and its bar confirms
    clf, states = run(int(3 * FPS), entries_of=lambda k: [(7, (100.0, -4.0, 180.0, 236.0))])
    assert clf.tracks[7].evidence.frames == int(3 * FPS)
    assert states[-1][1][7].ev_state == EvState.CONFIRMED
    with pytest.raises(ValueError, match="fill_view_fraction"):
        TrackEvClassifier(fill_view_fraction=0.0)


def test_a_confirmed_ev_is_not_body_scored_again():
    """The body classifier runs on lamp-active tracks until they confirm, not on a confirmed EV (scoring one on
    four RSUs at once would halve their processed fps while an EV is in view)."""
    calls = []
    clf = TrackEvClassifier(body=lambda crop: calls.append(crop.shape) or 0.95)
    per_frame = []
    for k in range(int(4 * FPS)):
        t = k / FPS
        out = by_id(clf(Frame(scene(t), t, k, "cam"), tracks([(1, BOX_A)])))
        per_frame.append((out[1].ev_state, len(calls)))
    first = next(k for k, (state, _n) in enumerate(per_frame) if state == EvState.CONFIRMED)
    assert per_frame[first][1] >= 1  # scored while a candidate
    assert all(state == EvState.CONFIRMED for state, _n in per_frame[first:])
    assert per_frame[-1][1] == per_frame[first][1]  # ~3 s confirmed (12 scores at 4 Hz before): none since


def test_a_box_that_merges_the_lost_ev_with_a_nearer_vehicle_does_not_take_over_its_evidence():
    """A detector box over the EV and the top of the truck just behind it (nearer the camera) overlaps the EV's lost
    track, but it holds most of the truck's box: two vehicles merged, not the EV seen again, so it must not carry
    the EV's alert to the truck's place (ev_bench seed 51100, ``night_ev``, rsu1). The EV's own box seen again does."""
    from rsu.classify.ownership import holds_nearer_vehicle

    ev_box, truck = (100.0, 100.0, 140.0, 140.0), (105.0, 125.0, 150.0, 180.0)
    merged = (100.0, 98.0, 150.0, 165.0)
    boxes = np.array([merged, truck])
    assert holds_nearer_vehicle(0, boxes) and not holds_nearer_vehicle(1, boxes)
    assert not holds_nearer_vehicle(0, np.array([ev_box, truck]))  # the EV alone holds a sliver of the truck
    for new_box, takes_over in ((merged, False), (ev_box, True)):
        clf = TrackEvClassifier()
        img = np.full((240, 320, 3), 90, np.uint8)
        clf(Frame(img, 0.0, 0, "cam"), tracks([(1, ev_box), (2, truck)]))
        clf(Frame(img, 1 / FPS, 1, "cam"), tracks([(3, new_box), (2, truck)]))
        assert (clf.tracks[3].handed_over_from == (1,)) == takes_over


def test_a_car_just_behind_a_flashing_ev_is_not_body_scored_with_the_ev_in_its_crop():
    """A car 11-13 m behind the EV (nearer the camera, the EV just above it in the image): its crop, grown above its
    box, holds the EV's bar and body, so the body classifier would score the EV there; with the EV's track flashing
    just ahead, the car takes no body score and does not confirm (ev_bench seeds 16790 and 36545). Alone in the
    same image, the car is scored: the EV's lamps do reach its band."""
    car = (95.0, 125.0, 185.0, 190.0)

    def tall_bar(t):  # the EV's flashes light the car's roof, in step (rows 126-132, inside the car's box)
        img = scene(t)
        img[126:133] = img[103:110]
        return img

    def run_on(clf, entries):
        out = []
        for k in range(int(4 * FPS)):
            t = k / FPS
            out.append(by_id(clf(Frame(tall_bar(t), t, k, "cam"), tracks(entries))))
        return out

    scored = []
    crop_rows = TrackEvClassifier().crop_bounds(car, 480, 240)
    car_rows = crop_rows[3] - crop_rows[1]
    clf = TrackEvClassifier(body=lambda crop: scored.append(crop.shape[0]) or 0.95)
    states = run_on(clf, [(1, BOX_A), (2, car)])
    assert any(out[1].ev_state == EvState.CONFIRMED for out in states)  # the EV alerts
    with_ev_ahead = scored.count(car_rows)  # once at most: before the EV's own flashes are seen
    assert all(out[2].ev_state != EvState.CONFIRMED for out in states)
    scored.clear()
    run_on(TrackEvClassifier(body=lambda crop: scored.append(crop.shape[0]) or 0.95), [(2, car)])
    assert with_ev_ahead <= 1 < scored.count(car_rows)


def test_the_body_classifier_does_not_see_a_farther_vehicle_in_the_crop():
    """The crop, grown above the box for the roof bar, takes in a farther vehicle seen above this one; the body
    classifier gets it with that vehicle's box blanked where it rises above this box's top, so that it scores this
    vehicle (ev_bench seed 16790: a black truck just behind an ambulance scored 0.68 with the ambulance in its crop,
    0.40 with the ambulance's box blanked above the truck's top)."""
    from rsu.classify.ownership import blank_rects

    far = (120.0, 55.0, 200.0, 100.0)  # a green van farther up the road, its bottom at the EV's roof

    def with_van(t):
        img = scene(t)
        img[55:100, 120:200] = (0, 200, 0)
        return img

    def greens_seen(entries):
        seen = []
        clf = TrackEvClassifier(body=lambda crop: seen.append(int((crop[..., 1] == 200).sum())) or 0.2)
        for k in range(int(2 * FPS)):
            t = k / FPS
            clf(Frame(with_van(t), t, k, "cam"), tracks(entries))
        assert seen  # the flashing EV was scored
        return seen

    assert all(n > 0 for n in greens_seen([(1, BOX_A)]))  # untracked, the van is in the crop
    assert all(n == 0 for n in greens_seen([(1, BOX_A), (2, far)]))  # tracked: blanked
    # a bus behind the EV, its box taking in the EV's upper body: only its part above the EV's top is blanked,
    # the EV's own box (which hides the bus there) is scored as it is
    bus = (90.0, 40.0, 200.0, 130.0)
    whites = []
    clf = TrackEvClassifier(body=lambda crop: whites.append(int((crop == 230).all(axis=2).sum())) or 0.2)
    for k in range(int(2 * FPS)):
        clf(Frame(with_van(k / FPS), k / FPS, k, "cam"), tracks([(1, BOX_A), (2, bus)]))
    body_px = 80 * 60 - 60 * 20 - 25 * 8  # the white body, less its red stripe and the lamps drawn over it
    assert whites and all(n >= body_px - 25 * 8 for n in whites)
    crop = np.zeros((4, 4, 3), np.uint8)
    crop[:2] = 7
    mask = np.zeros((4, 4), bool)
    mask[:1] = True
    assert (blank_rects(crop, mask)[0] == 0).all() and blank_rects(crop, None) is crop  # median of the rest
