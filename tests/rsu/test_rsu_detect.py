"""Detectors: YOLOX decoding from a hand-made tensor, the real COCO model on real video, MOG2 motion."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from rsu.detect import (
    COCO_TO_PROJECT,
    EV,
    PAD_VALUE,
    PROJECT_TO_PROJECT,
    VEHICLE,
    Detections,
    Detector,
    MotionDetector,
    OnnxDetector,
    decode_yolox,
    letterbox,
    postprocess,
    yolox_grids,
)
from rsu.track.assoc import iou_matrix

REAL = Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "real"
YOLOX = REAL / "yolox_nano" / "yolox_nano.onnx"
VIDEO3 = REAL / "traffic_videos" / "ambdet_video_3.mp4"
INPUT = (416, 416)


def _anchor_index(stride: int, gx: int, gy: int) -> int:
    offset = 0
    for s in (8, 16, 32):
        if s == stride:
            return offset + gy * (INPUT[1] // s) + gx
        offset += (INPUT[0] // s) * (INPUT[1] // s)
    raise ValueError(stride)


def _put(raw, stride, gx, gy, box_lb, obj, cls_col, cls_p):
    """Write a grid-relative YOLOX row for a box (cx, cy, w, h) given in letterbox pixels."""
    i = _anchor_index(stride, gx, gy)
    cx, cy, w, h = box_lb
    raw[i, 0] = cx / stride - gx
    raw[i, 1] = cy / stride - gy
    raw[i, 2] = np.log(w / stride)
    raw[i, 3] = np.log(h / stride)
    raw[i, 4] = obj
    raw[i, 5 + cls_col] = cls_p


def test_grid_layout_matches_yolox():
    grids, strides = yolox_grids(INPUT)
    assert len(grids) == 52 * 52 + 26 * 26 + 13 * 13 == 3549
    assert grids[1].tolist() == [1, 0] and grids[52].tolist() == [0, 1]  # x varies fastest
    assert strides[0, 0] == 8 and strides[52 * 52, 0] == 16 and strides[-1, 0] == 32


def test_decode_hand_made_yolox_coco_output():
    raw = np.zeros((3549, 85), np.float32)
    raw[:, 2:4] = -5.0  # tiny boxes everywhere, zero scores
    # car at stride 8 cell (10, 5): centre (84, 42), 40 x 24 letterbox pixels
    _put(raw, 8, 10, 5, (84.0, 42.0, 40.0, 24.0), 0.9, 2, 0.8)
    # a weaker duplicate of it, to be removed by NMS
    _put(raw, 8, 11, 5, (86.0, 43.0, 40.0, 24.0), 0.8, 2, 0.7)
    # truck at stride 32 cell (6, 7): centre (208, 240), 120 x 60
    _put(raw, 32, 6, 7, (208.0, 240.0, 120.0, 60.0), 0.95, 7, 0.9)
    # person (COCO 0) scoring high: not a vehicle
    _put(raw, 16, 20, 20, (328.0, 328.0, 30.0, 60.0), 0.99, 0, 0.99)
    # motorcycle below the score threshold: 0.5 * 0.5 = 0.25 < 0.3
    _put(raw, 16, 3, 3, (56.0, 56.0, 20.0, 20.0), 0.5, 3, 0.5)
    image_wh = (832, 624)  # letterbox ratio 416 / 832 = 0.5
    ratio = min(INPUT[0] / image_wh[1], INPUT[1] / image_wh[0])
    det = postprocess(decode_yolox(raw, INPUT), ratio, image_wh, COCO_TO_PROJECT, 0.3, 0.45)
    assert len(det) == 2
    order = np.argsort(det.boxes[:, 0])
    np.testing.assert_allclose(det.boxes[order[0]], [(84 - 20) * 2, (42 - 12) * 2, (84 + 20) * 2, (42 + 12) * 2],
                               atol=1e-3)
    np.testing.assert_allclose(det.boxes[order[1]], [(208 - 60) * 2, (240 - 30) * 2, (208 + 60) * 2, (240 + 30) * 2],
                               atol=1e-3)
    np.testing.assert_allclose(det.scores[order], [0.72, 0.855], atol=1e-6)
    assert det.classes.tolist() == [VEHICLE, VEHICLE]
    assert det.boxes.dtype == np.float32 and det.classes.dtype == np.int64
    boxes, scores, classes = det  # unpacks as (boxes, scores, classes)
    assert boxes is det.boxes


def test_decode_project_layout_two_classes_and_class_filter():
    raw = np.zeros((3549, 7), np.float32)
    raw[:, 2:4] = -5.0
    _put(raw, 8, 10, 10, (84.0, 84.0, 40.0, 30.0), 0.9, 0, 0.9)  # vehicle
    _put(raw, 16, 15, 10, (248.0, 168.0, 64.0, 48.0), 0.9, 1, 0.8)  # EV
    rows = decode_yolox(raw, INPUT)
    det = postprocess(rows, 1.0, (416, 416), PROJECT_TO_PROJECT, 0.3, 0.45)
    assert sorted(det.classes.tolist()) == [VEHICLE, EV]
    ev = det.boxes[det.classes == EV][0]
    np.testing.assert_allclose(ev, [216, 144, 280, 192], atol=1e-3)
    only_vehicles = postprocess(rows, 1.0, (416, 416), PROJECT_TO_PROJECT, 0.3, 0.45, classes_wanted=[VEHICLE])
    assert only_vehicles.classes.tolist() == [VEHICLE]


def test_nms_is_class_aware():
    raw = np.zeros((3549, 7), np.float32)
    raw[:, 2:4] = -5.0
    _put(raw, 8, 10, 10, (84.0, 84.0, 40.0, 30.0), 0.9, 0, 0.9)
    _put(raw, 8, 11, 10, (85.0, 84.0, 40.0, 30.0), 0.9, 1, 0.8)  # same place, other class: kept
    det = postprocess(decode_yolox(raw, INPUT), 1.0, (416, 416), PROJECT_TO_PROJECT, 0.3, 0.45)
    assert len(det) == 2


def test_letterbox_top_left_with_pad_114():
    image = np.full((300, 600, 3), 7, np.uint8)
    blob, ratio = letterbox(image, INPUT)
    assert ratio == pytest.approx(416 / 600)
    assert blob.shape == (1, 3, 416, 416) and blob.dtype == np.float32
    assert blob[0, :, 0, 0].tolist() == [7, 7, 7]
    assert blob[0, :, 207, 0].tolist() == [7, 7, 7] and blob[0, :, 209, 0].tolist() == [PAD_VALUE] * 3


def test_decode_rejects_wrong_anchor_count():
    with pytest.raises(ValueError, match="anchor points"):
        decode_yolox(np.zeros((100, 85), np.float32), INPUT)


@pytest.fixture(scope="module")
def yolox():
    if not YOLOX.is_file():
        pytest.skip(f"{YOLOX} absent (../shared/data/real not beside the repository)")
    return OnnxDetector(YOLOX, intra_op_threads=1)


def _video_frame(path: Path, number: int) -> np.ndarray:
    if not path.is_file():
        pytest.skip(f"{path} absent (../shared/data/real not beside the repository)")
    cap = cv2.VideoCapture(str(path))
    cap.set(cv2.CAP_PROP_POS_FRAMES, number)
    ok, image = cap.read()
    cap.release()
    assert ok
    return image


def test_yolox_model_detects_real_cars(yolox):
    assert yolox.layout == "yolox-coco" and yolox.input_hw == (416, 416)
    assert isinstance(yolox, Detector)
    image = _video_frame(VIDEO3, 30)
    det = yolox.detect(image)
    assert len(det) >= 5, "frame 30 of ambdet_video_3 shows at least 6 cars"
    assert (det.classes == VEHICLE).all() and (det.scores >= 0.3).all()
    h, w = image.shape[:2]
    assert (det.boxes[:, [0, 2]] <= w).all() and (det.boxes[:, [1, 3]] <= h).all() and (det.boxes >= 0).all()
    # the dark car left of centre (checked by eye on an annotated frame)
    assert iou_matrix(np.array([[159.0, 165.0, 209.0, 224.0]]), det.boxes.astype(float)).max() > 0.7


def test_onnx_detector_validates_arguments(tmp_path):
    with pytest.raises(FileNotFoundError):
        OnnxDetector(tmp_path / "missing.onnx")
    if YOLOX.is_file():
        with pytest.raises(ValueError, match="providers"):
            OnnxDetector(YOLOX, providers=["NoSuchExecutionProvider"])
    with pytest.raises(ValueError):
        MotionDetector(scale=2.0)


def test_detect_rejects_non_images(yolox):
    with pytest.raises(ValueError, match="uint8"):
        yolox.detect(np.zeros((10, 10), np.float32))


def test_motion_detector_finds_a_moving_box():
    rng = np.random.default_rng(0)
    background = rng.integers(60, 90, size=(240, 320, 3), dtype=np.uint8)
    md = MotionDetector(min_area_px=100, scale=1.0)
    assert isinstance(md, Detector)
    det = Detections.empty()
    for k in range(40):
        image = background.copy()
        image += rng.integers(0, 3, size=image.shape, dtype=np.uint8)
        x = 20 + 5 * k
        cv2.rectangle(image, (x, 100), (x + 40, 130), (20, 200, 240), -1)
        det = md.detect(image)
    assert len(det) == 1
    assert iou_matrix(np.array([[x, 100, x + 41, 131]], float), det.boxes.astype(float))[0, 0] > 0.7
    assert det.classes.tolist() == [VEHICLE]


def test_motion_detector_ignores_a_whole_frame_change():
    md = MotionDetector(scale=1.0)
    for _ in range(10):
        md.detect(np.full((120, 160, 3), 50, np.uint8))
    assert len(md.detect(np.full((120, 160, 3), 250, np.uint8))) == 0


def test_motion_detector_on_real_video():
    if not VIDEO3.is_file():
        pytest.skip(f"{VIDEO3} absent")
    cap = cv2.VideoCapture(str(VIDEO3))
    md = MotionDetector(min_area_px=150)
    counts = []
    for _ in range(40):
        ok, image = cap.read()
        assert ok
        counts.append(len(md.detect(image)))
    cap.release()
    assert max(counts[20:]) >= 3  # several moving cars once the background model has settled
