"""SortTracker: equality with the reference SORT, id behaviour, frameworks A/B."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from scipy.optimize import linear_sum_assignment

from bench.sort_reference import HAVE_FILTERPY, ReferenceSort, _associate
from rsu.evaluate import mot_result_lines, read_mot_detections, synthetic_scene
from rsu.perception import Detections
from rsu.track.assoc import associate, iou_matrix
from rsu.track.frameworks import FrameworkTracker
from rsu.track.sort import SortTracker, as_mot


def dets(boxes, scores=None, class_ids=None):
    """The detector's table of a frame (scores 1 and class 0 where not given)."""
    boxes = np.asarray(boxes, float).reshape(-1, 4)
    n = len(boxes)
    return Detections(boxes, np.ones(n) if scores is None else np.asarray(scores, float),
                      np.zeros(n, np.int64) if class_ids is None else np.asarray(class_ids, np.int64))


def _run_both(frames, max_age, min_hits, iou_threshold, use_filterpy=False):
    ours = SortTracker(max_age, min_hits, iou_threshold)
    ref = ReferenceSort(max_age, min_hits, iou_threshold, use_filterpy=use_filterpy)
    n_reported = 0
    for k, f in enumerate(frames):
        dets = np.hstack([f.det_boxes, f.det_scores[:, None]])
        a = as_mot(ours.update(f.det_boxes, f.det_scores))
        b = ref.update(dets)
        assert a.shape == b.shape, f"frame {k}: {len(a)} tracks vs reference {len(b)}"
        np.testing.assert_array_equal(a[:, 4], b[:, 4], err_msg=f"frame {k}: ids differ")
        np.testing.assert_allclose(a[:, :4], b[:, :4], rtol=0, atol=1e-6, err_msg=f"frame {k}")
        n_reported += len(a)
        # the live (also unreported) tracks agree in state and full 7x7 covariance
        assert len(ours) == len(ref.trackers)
        if len(ours):
            np.testing.assert_allclose(ours.x, np.hstack([t.kf.x for t in ref.trackers]).T, rtol=1e-9, atol=1e-9)
            np.testing.assert_allclose(ours.covariance, np.stack([t.kf.P for t in ref.trackers]),
                                       rtol=1e-9, atol=1e-9)
    return n_reported


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("max_age,min_hits,iou_threshold", [(1, 3, 0.3), (3, 1, 0.3), (5, 3, 0.5), (2, 0, 0.1)])
def test_same_tracks_as_reference(seed, max_age, min_hits, iou_threshold):
    # misses, false positives, births, deaths and crossing targets
    frames = synthetic_scene(n_frames=120, n_targets=15, seed=seed, miss_prob=0.15, false_pos_per_frame=1.0,
                             mean_life_frames=40.0)
    assert _run_both(frames, max_age, min_hits, iou_threshold) > 500


@pytest.mark.parametrize("scalar_max_rows", [0, 12, 10**6])
@pytest.mark.parametrize("seed", [3, 4])
def test_scalar_and_array_steps_give_the_reference_tracks(monkeypatch, seed, scalar_max_rows):
    """Every frame on arrays (0), on Python floats (10**6), or switching between them as the density crosses 12
    live tracks + detections (the scalar step for the densities an RSU sees)."""
    import rsu.track.sort as track

    monkeypatch.setattr(track, "SCALAR_MAX_ROWS", scalar_max_rows)
    frames = synthetic_scene(n_frames=150, n_targets=8, seed=seed, miss_prob=0.15, false_pos_per_frame=1.0,
                             mean_life_frames=30.0)
    assert _run_both(frames, 1, 3, 0.3) > 300
    assert _run_both(frames, 3, 1, 0.5) > 300


def test_degenerate_detections_and_boxes_take_the_array_step(monkeypatch):
    """A zero-height detection (numpy's inf ratio) runs the frame with arrays, as before, and the tracker goes on."""
    boxes = [np.array([[10.0, 10.0, 50.0, 40.0], [100.0, 100.0, 140.0, 100.0]])] * 3 + [
        np.array([[12.0, 10.0, 52.0, 40.0]])] * 3
    frames = [SimpleNamespace(det_boxes=b, det_scores=np.ones(len(b))) for b in boxes]
    with np.errstate(invalid="ignore", divide="ignore"):
        ours, ref = SortTracker(1, 1, 0.3), ReferenceSort(1, 1, 0.3)
        for f in frames:
            a = as_mot(ours.update(f.det_boxes, f.det_scores))
            b = ref.update(np.hstack([f.det_boxes, f.det_scores[:, None]]))
            np.testing.assert_array_equal(a[:, 4], b[:, 4])
            np.testing.assert_allclose(a[:, :4], b[:, :4], rtol=0, atol=1e-6)


@pytest.mark.skipif(not HAVE_FILTERPY, reason="filterpy not installed: reference with filterpy's KalmanFilter skipped")
def test_same_tracks_as_reference_with_filterpy():
    frames = synthetic_scene(n_frames=100, n_targets=20, seed=7, miss_prob=0.1, false_pos_per_frame=0.5)
    assert _run_both(frames, 1, 3, 0.3, use_filterpy=True) > 500
    assert _run_both(frames, 4, 2, 0.3, use_filterpy=True) > 500


def test_area_velocity_guard_matches_the_reference():
    # a box shrinking fast, then missed: the predicted area s + s' goes <= 0 and both zero s'
    boxes = [np.array([_box(200, 200, 120 - 12 * k, 120 - 12 * k)]) if k < 8 else np.empty((0, 4))
             for k in range(16)]
    frames = [SimpleNamespace(det_boxes=b, det_scores=np.ones(len(b))) for b in boxes]
    assert _run_both(frames, 6, 1, 0.1) == 8
    ours = SortTracker(6, 1, 0.1)
    fired = []
    for k, b in enumerate(boxes):
        if len(ours) and ours.x[0, 2] + ours.x[0, 6] <= 0:
            fired.append(k)  # this frame's predict applies the guard
        ours.update(b)
    assert fired == [7]


def test_associate_matches_the_reference_including_its_unique_pairs_shortcut():
    rng = np.random.default_rng(5)
    n_shortcut = n_hungarian = 0
    for _ in range(400):
        n_det, n_trk = rng.integers(1, 7, size=2)
        centres = rng.uniform(0, 120, size=(n_det + n_trk, 2))
        sizes = rng.uniform(20, 60, size=(n_det + n_trk, 2))
        boxes = np.hstack([centres - sizes / 2, centres + sizes / 2])
        det, trk = boxes[:n_det], boxes[n_det:]
        rows, cols, unmatched = associate(det, trk, 0.3)
        ref_matches, ref_unmatched, _ = _associate(det, trk, 0.3)
        np.testing.assert_array_equal(np.stack([rows, cols], axis=1).reshape(-1, 2), ref_matches.reshape(-1, 2))
        np.testing.assert_array_equal(unmatched, ref_unmatched)
        above = iou_matrix(det, trk) > 0.3
        if above.any() and above.sum(0).max() == 1 and above.sum(1).max() == 1:
            n_shortcut += 1
        else:
            n_hungarian += 1
    assert n_shortcut > 50 and n_hungarian > 50  # both paths exercised


def test_associate_shortcut_is_the_references_not_hungarians():
    # only d0-t1 is above 0.3 (0.318): the shortcut matches it, as the reference does; the optimal
    # assignment d0-t0 + d1-t1 (0.238 + 0.267 = 0.505 > 0.318) would be filtered to no match at all
    det = np.array([[14.0, 0.0, 30.0, 10.0], [28.0, 0.0, 53.0, 10.0]])
    trk = np.array([[9.0, 0.0, 19.0, 10.0], [23.0, 0.0, 36.0, 10.0]])
    iou = iou_matrix(det, trk)
    r, c = linear_sum_assignment(-iou)
    assert not (iou[r, c] >= 0.3).any()
    rows, cols, unmatched = associate(det, trk, 0.3)
    assert rows.tolist() == [0] and cols.tolist() == [1] and unmatched.tolist() == [1]
    ref_matches, ref_unmatched, _ = _associate(det, trk, 0.3)
    assert ref_matches.tolist() == [[0, 1]] and ref_unmatched.tolist() == [1]


def test_mot_det_format_gives_the_reference_output(tmp_path):
    frames = synthetic_scene(n_frames=60, n_targets=10, seed=3, miss_prob=0.1)
    rows = []
    for k, f in enumerate(frames, start=1):
        for b, s in zip(f.det_boxes, f.det_scores, strict=True):
            rows.append(f"{k},-1,{b[0]:.3f},{b[1]:.3f},{b[2] - b[0]:.3f},{b[3] - b[1]:.3f},{s:.4f},-1,-1,-1")
    det_file = tmp_path / "det.txt"
    det_file.write_text("\n".join(rows) + "\n")
    per_frame = read_mot_detections(str(det_file))
    ours, ref = SortTracker(), ReferenceSort()
    out_ours, out_ref = [], []
    for frame, dets in per_frame.items():
        out_ours += mot_result_lines(frame, ours.update_mot(dets))
        out_ref += mot_result_lines(frame, ref.update(dets))
    assert len(out_ref) > 300
    assert out_ours == out_ref


def _box(cx, cy, w=40.0, h=30.0):
    return [cx - w / 2, cy - h / 2, cx + w / 2, cy + h / 2]


def test_constant_velocity_targets_keep_ids_through_a_missed_frame():
    trk = SortTracker(max_age=3, min_hits=3, iou_threshold=0.3)
    ids_seen = {0: set(), 1: set()}
    for k in range(40):
        boxes = [_box(100 + 6 * k, 100), _box(600 - 5 * k, 300)]
        keep = [0, 1]
        if k in (10, 25):
            keep = [1]  # target 0 missed for one frame
        if k == 18:
            keep = [0]  # target 1 missed for one frame
        out = trk.update(np.array([boxes[i] for i in keep]))
        for tid, di in zip(out.track_ids, out.det_indices, strict=True):
            ids_seen[keep[di]].add(int(tid))
    assert ids_seen == {0: {1}, 1: {2}}


def test_track_lost_for_longer_than_max_age_gets_a_new_id():
    trk = SortTracker(max_age=1, min_hits=1)
    ids = []
    for k in range(20):
        if 8 <= k < 11:  # three frames missing > max_age = 1
            trk.update(np.empty((0, 4)))
            continue
        out = trk.update(np.array([_box(100 + 3 * k, 100)]))
        ids += [int(t) for t in out.track_ids]
    assert set(ids) == {1, 2} and ids[0] == 1 and ids[-1] == 2


def test_crossing_targets_keep_their_ids():
    # two cars in adjacent lanes passing each other: their boxes overlap for several frames
    trk = SortTracker(max_age=2, min_hits=2)
    rng = np.random.default_rng(0)
    labels: dict[int, set[int]] = {0: set(), 1: set()}
    for k in range(60):
        gt = np.array([_box(100 + 8 * k, 200, 80, 50), _box(580 - 8 * k, 215, 80, 50)])
        det = gt + rng.normal(0, 1.0, gt.shape)
        order = rng.permutation(2)
        out = trk.update(det[order])
        for tid, di in zip(out.track_ids, out.det_indices, strict=True):
            labels[int(order[di])].add(int(tid))
    overlap = iou_matrix(np.array([_box(100 + 8 * 30, 200, 80, 50)]), np.array([_box(580 - 8 * 30, 215, 80, 50)]))
    assert overlap[0, 0] > 0.5  # they really cross
    assert labels == {0: {1}, 1: {2}} or labels == {0: {2}, 1: {1}}


def test_no_duplicate_ids_and_ids_never_reused():
    frames = synthetic_scene(n_frames=150, n_targets=20, seed=11, miss_prob=0.1, false_pos_per_frame=1.0)
    trk = SortTracker(max_age=3, min_hits=2)
    retired: set[int] = set()
    previous: set[int] = set()
    for f in frames:
        out = trk.update(f.det_boxes, f.det_scores)
        ids = [int(t) for t in out.track_ids]
        assert len(ids) == len(set(ids))
        assert not set(ids) & retired
        live = {int(t) for t in trk.track_ids}
        retired |= previous - live
        previous = live
    assert max(previous | retired) > 20


def test_outputs_carry_detection_index_score_and_class():
    trk = SortTracker(min_hits=0)
    boxes = np.array([_box(100, 100), _box(300, 100)])
    out = trk.update(boxes, np.array([0.9, 0.6]), np.array([0, 1]))
    by_det = {int(d): i for i, d in enumerate(out.det_indices)}
    assert set(by_det) == {0, 1}
    i = by_det[1]
    assert out.scores[i] == pytest.approx(0.6) and out.class_ids[i] == 1
    np.testing.assert_allclose(out.boxes[i], boxes[1])


def test_empty_frames_and_bad_arguments():
    trk = SortTracker()
    assert len(trk.update(np.empty((0, 4)))) == 0
    assert len(trk.update_mot(np.empty((0, 5)))) == 0
    with pytest.raises(ValueError):
        SortTracker(iou_threshold=1.5)
    with pytest.raises(ValueError):
        SortTracker(max_age=-1)
    with pytest.raises(ValueError):
        FrameworkTracker("C")


def test_framework_a_resets_the_id_on_a_misclassified_frame_b_does_not():
    def run(framework):
        trk = FrameworkTracker(framework, max_age=3, min_hits=1)
        ids = []
        for k in range(20):
            cls = 1 if k == 10 else 0  # one frame classified EV
            out = trk.update(dets(np.array([_box(100 + 4 * k, 100)]), np.array([0.9]), np.array([cls])))
            ids += [int(t) for t in out.track_ids]
        return ids

    ids_b = run("B")
    assert set(ids_b) == {1}
    ids_a = run("A")
    assert len(set(ids_a)) >= 2  # the class flip started another track (thesis 2.2)
    assert ids_a[10] != ids_a[9]


def test_framework_a_ids_unique_across_classes():
    trk = FrameworkTracker("A", min_hits=0)
    out = trk.update(dets(np.array([_box(100, 100), _box(300, 100), _box(500, 100)]), None, np.array([0, 1, 0])))
    assert sorted(out.track_ids.tolist()) == [1, 2, 3]
    assert sorted(out.det_indices.tolist()) == [0, 1, 2]


def _tentative_run(frames, min_hits):
    trk = SortTracker(1, min_hits, 0.3)
    out = []
    for k, f in enumerate(frames):
        reported = trk.update(f.det_boxes, f.det_scores)
        held = trk.tentative()
        matched = set(trk.track_ids[trk.time_since_update == 0].tolist())
        r_ids, h_ids = set(reported.track_ids.tolist()), set(held.track_ids.tolist())
        assert not r_ids & h_ids, f"frame {k}: a track both reported and held back"
        assert r_ids | h_ids == matched, f"frame {k}: every track matched on the frame is one or the other"
        if k < min_hits:
            assert not h_ids  # the reference reports every matched track in its first min_hits frames
        born = held.hits == 0
        np.testing.assert_allclose(held.boxes[born], f.det_boxes[held.det_indices[born]], atol=1e-6)
        out.append((held.track_ids.tolist(), np.round(held.boxes, 6).tolist(), held.det_indices.tolist()))
    return out


@pytest.mark.parametrize("min_hits", [3, 1])
def test_tentative_tracks_are_the_matched_ones_sort_holds_back(monkeypatch, min_hits):
    """``SortTracker.tentative``: after a frame, the tracks it matched but did not report (born or re-found under
    min_hits frames ago), with their filtered boxes (a newborn's: its detection); the same on the array step."""
    import rsu.track.sort as track

    frames = synthetic_scene(n_frames=120, n_targets=10, seed=5, miss_prob=0.15, false_pos_per_frame=1.0,
                             mean_life_frames=30.0)
    scalar = _tentative_run(frames, min_hits)
    assert sum(len(ids) for ids, _b, _d in scalar) > 50  # births, false positives and re-found tracks
    monkeypatch.setattr(track, "SCALAR_MAX_ROWS", 0)
    assert _tentative_run(frames, min_hits) == scalar


def test_framework_a_tentative_tracks_index_the_whole_input():
    trk = FrameworkTracker("A", min_hits=3)
    for k in range(4):  # a car (class 0) and an EV (class 1), each tracker past its first min_hits frames
        trk.update(dets(np.array([_box(100 + 2 * k, 100), _box(400, 300)]), np.ones(2), np.array([0, 1])))
    boxes = np.array([_box(108, 100), _box(400, 300), _box(700, 300)])  # a new car, third in the input
    reported = trk.update(dets(boxes, np.ones(3), np.array([0, 1, 0])))
    held = trk.tentative()
    assert sorted(reported.det_indices.tolist()) == [0, 1]
    assert held.det_indices.tolist() == [2]  # class 0's second detection, the input's third
    np.testing.assert_allclose(held.boxes, boxes[2:])
