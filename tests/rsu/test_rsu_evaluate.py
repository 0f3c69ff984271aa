"""CLEAR-MOT / IDF1 evaluator on hand-checked cases."""

from __future__ import annotations

import numpy as np
import pytest

from rsu.evaluate import MotEvaluator, synthetic_scene

A = [0, 0, 10, 10]
B = [50, 0, 60, 10]


def test_perfect_tracking():
    ev = MotEvaluator()
    for k in range(10):
        boxes = np.array([A, B], float) + [k, 0, k, 0]
        ev.update([1, 2], boxes, [7, 8], boxes)
    m = ev.result()
    assert (m.mota, m.idf1, m.motp_iou) == (1.0, 1.0, 1.0)
    assert m.num_gt == 20 and m.id_switches == 0


def test_counts_misses_false_positives_and_switches():
    ev = MotEvaluator()
    ev.update([1, 2], [A, B], [7, 8], [A, B])
    ev.update([1, 2], [A, B], [7], [A])  # gt 2 missed
    ev.update([1, 2], [A, B], [7, 9, 5], [A, B, [200, 200, 220, 220]])  # gt 2 now id 9 (switch), one FP
    ev.update([1, 2], [A, B], [7, 9], [A, B])
    m = ev.result()
    assert (m.false_negatives, m.false_positives, m.id_switches, m.num_gt) == (1, 1, 1, 8)
    assert m.mota == pytest.approx(1 - 3 / 8)
    # IDF1: gt1<->7 on 4 frames, gt2<->9 on 2 frames (better than gt2<->8 on 1): IDTP 6, GT 8, HYP 8
    assert m.idtp == 6 and m.idf1 == pytest.approx(12 / 16)


def test_low_overlap_is_not_a_match():
    ev = MotEvaluator()
    ev.update([1], [A], [3], [[6, 6, 16, 16]])  # IoU 16/184 < 0.5
    m = ev.result()
    assert (m.false_negatives, m.false_positives) == (1, 1)


def test_duplicate_ids_rejected():
    with pytest.raises(ValueError):
        MotEvaluator().update([1, 1], [A, B], [], np.empty((0, 4)))


def test_synthetic_scene_is_deterministic_and_keeps_its_population():
    a = synthetic_scene(50, 12, seed=4)
    b = synthetic_scene(50, 12, seed=4)
    assert all(np.array_equal(x.det_boxes, y.det_boxes) for x, y in zip(a, b, strict=True))
    assert all(len(f.gt_ids) == 12 for f in a)
    assert len({int(i) for f in a for i in f.gt_ids}) > 12  # targets die and are replaced


def test_hypotheses_on_ignored_ground_truth_are_neither_true_nor_false_positives():
    far = [100, 100, 110, 108]  # e.g. a vehicle beyond the RSU's zone: ignored ground truth
    ev = MotEvaluator()
    loose = [103, 102, 112, 110]  # IoU 0.47 with it, but 7/9 of its area inside it: ignored too (KITTI)
    wide = [95, 95, 125, 120]  # mostly background around it: a false positive
    ev.update([1], [A], [7, 8, 9, 10, 11], [A, far, loose, wide, [300, 300, 320, 320]], ignore_boxes=[far])
    m = ev.result()
    assert (m.true_positives, m.false_positives, m.false_negatives, m.num_hyp) == (1, 2, 0, 3)
    # a hypothesis that matches a counted box stays a true positive even if it also overlaps an ignore box
    ev = MotEvaluator()
    ev.update([1], [A], [7], [A], ignore_boxes=[A])
    assert (ev.result().true_positives, ev.result().false_positives) == (1, 0)
    # without ignore boxes the same hypothesis is a false positive
    ev = MotEvaluator()
    ev.update([1], [A], [7, 8], [A, far])
    assert ev.result().false_positives == 1
