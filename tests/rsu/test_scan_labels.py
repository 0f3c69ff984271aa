"""Per-vehicle scoring of EV alerts against clip labels (rsu.scan_labels): synthetic tracks and labels."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from rsu.scan_labels import (
    ClipLabels,
    LabelError,
    LabelledVehicle,
    labels_from_json,
    labels_to_json,
    load_labels,
    score_clip,
    summarize,
    write_labels,
)

FPS = 10.0
LABELS_DIR = Path(__file__).resolve().parents[2] / "bench" / "labels"


def vehicle(name, boxes, lit=True, role="ev", t0=0.0, step_s=0.5):
    """A vehicle labelled every ``step_s`` from ``t0``; ``lit``: one bool for all or a list per frame."""
    lits = lit if isinstance(lit, list) else [lit] * len(boxes)
    return LabelledVehicle(name, role, "ambulance" if role == "ev" else "hazard",
                           tuple((t0 + k * step_s, *b, lits[k]) for k, b in enumerate(boxes)))


def clip(*vehicles, viewpoint="elevated", duration_s=5.0, name="c.mp4"):
    return ClipLabels(name, "ev_videos", viewpoint, 640, 360, FPS, duration_s, tuple(vehicles))


def track(box, t0, t1, alert_from=None, alert_to=None, shift_px_s=0.0):
    """Rows of one track holding ``box`` (moving right at ``shift_px_s``) from t0 to t1, alerted in a range."""
    rows, k = [], 0
    while t0 + k / FPS <= t1 + 1e-9:
        t = round(t0 + k / FPS, 3)
        dx = shift_px_s * t
        alerted = alert_from is not None and alert_from <= t <= (alert_to if alert_to is not None else 1e9)
        rows.append((t, box[0] + dx, box[1], box[2] + dx, box[3], alerted))
        k += 1
    return rows


BOX = (100.0, 100.0, 180.0, 160.0)  # 80 px wide


def test_interpolation_between_frames_and_gap_means_out_of_view():
    v = vehicle("a", [(0, 0, 100, 50), (100, 0, 200, 50)])
    box, lit = v.at(0.25)
    assert box.tolist() == [50, 0, 150, 50] and lit
    far = LabelledVehicle("b", "ev", "x", ((0.0, 0, 0, 10, 10, True), (3.0, 0, 0, 10, 10, True)))
    assert far.at(1.5) is None          # 3 s apart: out of view between
    assert far.at(0.2) is not None      # the edge half-step still stands
    assert v.at(-1.0) is None and v.at(2.0) is None


def test_found_on_its_own_track_with_delay_from_first_scorable_frame():
    ev = vehicle("amb", [BOX] * 9)  # 0..4 s, lit, 80 px
    s = score_clip(clip(ev), {7: track(BOX, 0.0, 4.0, alert_from=1.5)})
    (e,) = s.evs
    assert e.scorable and e.scorable_from_s == 0.0
    assert e.found_s == 1.5 and e.found_track == 7 and e.delay_s == pytest.approx(1.5)
    assert s.on_ev_tracks == [7] and s.wrong_tracks == []
    f = summarize([s])
    assert f["ev_recall"] == 1.0 and f["alert_delay_median_s"] == 1.5 and f["alert_delay_max_s"] == 1.5
    assert f["wrong_vehicle_alerts"] == 0 and f["by_viewpoint"]["elevated"]["ev_recall"] == 1.0


def test_alert_on_a_neighbour_is_a_wrong_vehicle_and_the_ev_is_missed():
    ev = vehicle("amb", [BOX] * 9)
    neighbour = (200.0, 100.0, 280.0, 160.0)  # no overlap with the EV
    s = score_clip(clip(ev), {1: track(BOX, 0.0, 4.0), 2: track(neighbour, 0.0, 4.0, alert_from=1.0)})
    assert s.evs[0].found_s is None and s.wrong_tracks == [2]
    f = summarize([s])
    assert f["ev_recall"] == 0.0 and f["wrong_vehicle_alerts"] == 1 and f["alert_delay_median_s"] is None


def test_a_nearer_car_that_brushes_the_ev_does_not_find_it():
    ev = vehicle("amb", [BOX] * 9)
    car = (150.0, 110.0, 230.0, 170.0)  # beside the EV: IoU 0.25 with it
    rows = track(car, 0.0, 4.0, alert_from=1.0)
    rows = [(t, *BOX, a) if 1.0 <= t <= 1.4 else (t, *r[1:5], a) for t, *_, a in rows for r in [(t, *car, a)]]
    s = score_clip(clip(ev), {2: rows})  # on the EV's box for 0.5 of its 3 alerted seconds
    assert s.wrong_tracks == [2] and s.evs[0].found_s is None


def test_alert_while_lights_are_off_does_not_find_the_ev():
    lit = [False] * 4 + [True] * 5  # lit from 2.0 s
    ev = vehicle("amb", [BOX] * 9, lit=lit)
    s = score_clip(clip(ev), {3: track(BOX, 0.0, 1.5, alert_from=0.5)})  # alerted only while dark
    assert s.evs[0].scorable and s.evs[0].scorable_from_s == pytest.approx(2.0, abs=0.26)
    assert s.evs[0].found_s is None
    assert s.on_ev_tracks == [3]  # on the EV all the same: not a wrong-vehicle alert


def test_small_or_brief_evs_are_not_scorable():
    small = vehicle("far", [(100.0, 100.0, 130.0, 120.0)] * 9)   # 30 px wide
    brief = vehicle("brief", [BOX, BOX], t0=1.0)                 # in view 0.75-1.75 s: under 1 s
    longer = vehicle("longer", [BOX] * 3, t0=1.0)                # 0.75-2.25 s
    s = score_clip(clip(small, brief, longer, duration_s=4.0), {})
    assert [e.scorable for e in s.evs] == [False, False, True]
    very_brief = LabelledVehicle("vb", "ev", "x", ((1.0, *BOX, True),))  # one frame: 0.5 s in view
    s2 = score_clip(clip(very_brief), {})
    assert not s2.evs[0].scorable
    assert summarize([s2])["ev_recall"] is None


def test_traffic_clip_false_alerts_and_rate_per_hour():
    traffic = ClipLabels("t.mp4", "traffic_videos", "elevated", 640, 360, FPS, 36.0, ())
    s = score_clip(traffic, {4: track(BOX, 0.0, 2.0, alert_from=1.0), 5: track(BOX, 0.0, 2.0)})
    assert not s.has_ev and s.wrong_tracks == [4]
    f = summarize([s])
    assert f["traffic_false_alerts"] == 1 and f["traffic_video_s"] == 36.0
    assert f["traffic_false_alerts_per_hour"] == 100.0 and f["wrong_vehicle_alerts"] == 0


def test_flasher_alert_is_wrong_and_counted_as_flasher():
    ev = vehicle("amb", [BOX] * 9)
    hz_box = (300.0, 100.0, 380.0, 160.0)
    hz = vehicle("hz", [hz_box] * 9, role="flasher")
    s = score_clip(clip(ev, hz), {9: track(hz_box, 0.0, 4.0, alert_from=0.5)})
    assert s.wrong_tracks == [9] and s.flasher_tracks == [9]
    assert summarize([s])["flasher_alerts"] == 1


def test_per_viewpoint_figures_split_the_clips():
    a = score_clip(clip(vehicle("a", [BOX] * 9), viewpoint="elevated", name="a.mp4"),
                   {1: track(BOX, 0.0, 4.0, alert_from=0.0)})
    b = score_clip(clip(vehicle("b", [BOX] * 9), viewpoint="in-car", name="b.mp4"), {})
    f = summarize([a, b])
    assert f["ev_recall"] == 0.5
    assert f["by_viewpoint"]["elevated"]["ev_recall"] == 1.0 and f["by_viewpoint"]["in-car"]["ev_recall"] == 0.0
    assert "roadside" not in f["by_viewpoint"]


def test_moving_ev_is_followed_by_interpolation():
    boxes = [(100.0 + 20 * k, 100.0, 180.0 + 20 * k, 160.0) for k in range(9)]  # 40 px/s
    s = score_clip(clip(vehicle("amb", boxes)), {1: track(BOX, 0.0, 4.0, alert_from=3.0, shift_px_s=40.0)})
    assert s.evs[0].found_s == 3.0


def test_label_file_round_trip_and_validation(tmp_path):
    c = clip(vehicle("amb", [BOX] * 3), vehicle("hz", [BOX] * 2, role="flasher"))
    p = write_labels(c, tmp_path / "c.json")
    assert load_labels(p) == c
    d = labels_to_json(c)
    with pytest.raises(LabelError, match="viewpoint"):
        labels_from_json(dict(d, viewpoint="drone"), "x.json")
    bad = json.loads(json.dumps(d))
    bad["vehicles"][0]["frames"][1][0] = 0.0
    with pytest.raises(LabelError, match="increasing"):
        labels_from_json(bad, "x.json")
    bad = json.loads(json.dumps(d))
    bad["vehicles"][0]["frames"][0][3] = 0.0
    with pytest.raises(LabelError, match="x2 <= x1"):
        labels_from_json(bad, "x.json")
    bad = json.loads(json.dumps(d))
    bad["vehicles"][1]["role"] = "bus"
    with pytest.raises(LabelError, match="role"):
        labels_from_json(bad, "x.json")


def test_the_repository_label_files_are_valid():
    files = sorted(LABELS_DIR.glob("*.json"))
    assert files, f"no label files in {LABELS_DIR}"
    for f in files:
        labels = load_labels(f)
        assert f.stem == Path(labels.clip).stem
        assert labels.folder in ("ev_videos", "traffic_videos")
        assert labels.has_ev == (labels.folder == "ev_videos"), f"{f.name}: EV clip without EV, or the reverse"


def test_tracked_share_tells_a_detector_miss_from_a_recogniser_miss():
    ev = vehicle("amb", [BOX] * 9)  # lit and in view 0-4 s
    neighbour = (300.0, 100.0, 380.0, 160.0)
    half = score_clip(clip(ev), {1: track(BOX, 0.0, 2.0), 2: track(neighbour, 0.0, 4.0)})
    assert half.evs[0].found_s is None
    assert half.evs[0].tracked_share == pytest.approx(0.5, abs=0.05)  # in a track's box for 2 of its 4 s
    whole = score_clip(clip(ev), {1: track(BOX, 0.0, 4.5)})
    assert whole.evs[0].tracked_share == pytest.approx(1.0)
    never = score_clip(clip(ev), {2: track(neighbour, 0.0, 4.0)})
    assert never.evs[0].tracked_share == 0.0
    assert never.to_json()["evs"][0]["tracked_share"] == 0.0
    dark = score_clip(clip(vehicle("amb", [BOX] * 9, lit=False)), {1: track(BOX, 0.0, 4.0)})
    assert not dark.evs[0].scorable and dark.evs[0].tracked_share is None
