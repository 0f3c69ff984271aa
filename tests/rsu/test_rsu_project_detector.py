"""The project's own detector (models/iea_det_tiny.onnx) through the runtime path, on fresh simulator renders.

Renders frames of rellis_ev_yield with a scenario seed never used for training, runs
``rsu.detect.OnnxDetector`` (its default thresholds, Framework B: both model classes as "vehicle") and
compares with the simulator's own labels. Skips when the model file is absent (``make models`` builds it).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from models.evaluate_detector import (
    ZONE_M,
    average_precision,
    evaluate,
    render_held_out,
    restrict,
)
from rsu.detect import PROJECT_CLASSES, OnnxDetector, yolox_grids
from rsu.track.assoc import iou_matrix

MODEL = Path(__file__).resolve().parents[2] / "models" / "iea_det_tiny.onnx"
needs_model = pytest.mark.skipif(not MODEL.is_file(), reason=f"{MODEL} not built (make models)")


@pytest.fixture(scope="module")
def held_out():
    # seed 900_003: not a training seed (training uses 100_003 + 7919 e + scenario seed, e < 20)
    return render_held_out("rellis_ev_yield", seeds=(900_003,), stride_s=2.5, t_min_s=4.0, max_frames=24)


@needs_model
def test_model_has_the_project_layout():
    det = OnnxDetector(MODEL, warmup_runs=0)
    assert det.layout == "project"
    assert det.input_hw == (384, 640)  # a whole frame at the training scale; an RSU searches its zone at that scale
    assert det.any_input_size  # an RSU letterboxes only its zone (rsu.detect_roi) at the input that needs
    out = det.session.get_outputs()[0].shape
    assert out[-1] == 5 + len(PROJECT_CLASSES)
    for hw in ((384, 640), (288, 448), (224, 352)):
        rows = det.raw_output(np.full((1, 3, *hw), 114.0, np.float32))
        assert rows.shape == (len(yolox_grids(hw)[0]), 5 + len(PROJECT_CLASSES))
    assert MODEL.stat().st_size < 5e6


@needs_model
def test_reaches_the_target_in_the_rsu_zone(held_out):
    """mAP@0.5 >= 0.9 on held-out renders of the default scenario (every vehicle one class),
    counting the vehicles of the RSU's 100 m zone (models/iea_det_tiny.md has the full-set figures)."""
    res = evaluate(MODEL, restrict(held_out, max_range_m=ZONE_M))
    assert res["gt_all_vehicles"] >= 40, res
    assert res["map50_all_vehicles"] >= 0.9, res


@needs_model
def test_detects_the_simulated_vehicles_at_the_runtime_threshold(held_out):
    det = OnnxDetector(MODEL, class_map={0: 0, 1: 0}, intra_op_threads=1)  # default thresholds, Framework B
    zone = restrict(held_out, max_range_m=ZONE_M)
    n_gt = hits = n_det = correct = 0
    for image, truth in zip(zone.images, zone.truths, strict=True):
        found = det.detect(image)
        boxes, scores = found.boxes, found.scores
        assert (found.class_ids == 0).all() and ((scores >= 0.3) & (scores <= 1)).all()
        iou = iou_matrix(truth.boxes, boxes)
        counted = ~truth.difficult
        n_gt += int(counted.sum())
        hits += int((iou[counted] >= 0.5).any(axis=1).sum()) if len(boxes) else 0
        n_det += len(boxes)
        correct += int((iou >= 0.5).any(axis=0).sum()) if len(truth.boxes) else 0  # any labelled vehicle
    assert n_gt >= 40, f"too few ground-truth boxes rendered ({n_gt})"
    recall, precision = hits / n_gt, correct / max(1, n_det)
    assert recall >= 0.95, f"recall {recall:.3f} ({hits}/{n_gt}) of the vehicles within {ZONE_M:g} m"
    assert precision >= 0.8, f"precision at IoU 0.5 {precision:.3f} ({correct}/{n_det})"


def test_average_precision_all_point_voc():
    gt = [(np.array([[0, 0, 10, 10], [20, 20, 30, 30]], float), np.array([False, False]))]
    perfect = [(np.array([[0, 0, 10, 10], [20, 20, 30, 30]], float), np.array([0.9, 0.8]))]
    assert average_precision(perfect, gt)[0] == pytest.approx(1.0)
    # a false positive ranked first: precision 0, 1/2, 2/3 at recall 0, 0.5, 1 -> AP = 0.5 * 2/3 + 0.5 * 2/3
    with_fp = [(np.array([[50, 50, 60, 60], [0, 0, 10, 10], [20, 20, 30, 30]], float), np.array([0.95, 0.9, 0.8]))]
    assert average_precision(with_fp, gt)[0] == pytest.approx(2 / 3)
    # a duplicate is a false positive; a detection on a difficult box is ignored
    dup = [(np.array([[0, 0, 10, 10], [0, 0, 10, 10]], float), np.array([0.9, 0.8]))]
    ap, n_gt, recall = average_precision(dup, [(gt[0][0][:1], np.array([False]))])
    assert (ap, n_gt, recall) == (pytest.approx(1.0), 1, 1.0)
    assert average_precision(dup, [(gt[0][0][:1], np.array([True]))])[1] == 0
    hard = [(np.array([[20, 20, 30, 30], [0, 0, 10, 10]], float), np.array([0.9, 0.8]))]
    assert average_precision(hard, [(gt[0][0], np.array([False, True]))])[0] == pytest.approx(1.0)


@needs_model
def test_detect_decodes_only_rows_that_can_pass_and_finds_the_same_boxes(held_out):
    """``OnnxDetector.detect`` decodes only the rows whose objectness reaches the score threshold: the boxes,
    scores and classes of decoding every row."""
    from rsu.detect import decode_yolox, letterbox, postprocess

    det = OnnxDetector(MODEL, class_map={0: 0, 1: 0}, intra_op_threads=1)
    compared = 0
    for image in held_out.images[:8]:
        blob, ratio = letterbox(image, det.input_hw)
        full = postprocess(decode_yolox(det.raw_output(blob), det.input_hw), ratio, (image.shape[1], image.shape[0]),
                           det.class_map, det.score_threshold, det.nms_threshold, det.classes_wanted)
        fast = det.detect(image)
        for column in ("boxes", "scores", "class_ids"):
            np.testing.assert_array_equal(getattr(fast, column), getattr(full, column))
        compared += len(full.boxes)
    assert compared >= 10
