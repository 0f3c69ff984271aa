"""Vehicle detectors behind one interface (thesis 2.3, Framework B: every vehicle as one class).

``detect(image) -> Detections`` (``rsu.perception``: boxes (N, 4) float32 xyxy pixels, scores (N,) float32,
class_ids (N,) int64)
in the project's class space: ``0`` vehicle, ``1`` emergency vehicle (EV; Framework A only).

``OnnxDetector`` runs an ONNX model with onnxruntime (CPU by default, any installed provider on
request) and understands two output layouts, both the YOLOX head (Ge et al. 2021):

- ``"yolox-coco"``: the COCO-pretrained YOLOX models (e.g. ``../shared/data/real/yolox_nano``):
  input ``[1, 3, S, S]`` float32, BGR, raw 0-255, letterboxed to the top-left with pad value 114;
  output ``[1, A, 85]``: A anchor points over strides 8/16/32 (A = sum (S/stride)^2), each row
  ``cx, cy, w, h`` grid-relative (``xy = (xy + grid) * stride``, ``wh = exp(wh) * stride``),
  objectness, 80 class scores. COCO car 2, motorcycle 3, bus 5, truck 7 map to vehicle.
- ``"project"``: the project's own detector (``models/``): the same input and the same YOLOX head
  with ``5 + 2`` columns per anchor point: ``cx, cy, w, h, objectness, p(vehicle), p(ev)``
  (Framework A's two classes; Framework B uses vehicle only or the max of both). Output name and
  input size are read from the model; an output already decoded to pixels (YOLOX exported with
  ``decode_in_inference``) is declared with ``decoded=True``.

The layout is chosen from the number of output columns (85 -> COCO, 7 -> project) unless given.
Per anchor the score of a project class is ``objectness * max(class scores mapped to it)``; boxes
below ``score_threshold`` go, then class-aware NMS (``cv2.dnn.NMSBoxesBatched``).

``MotionDetector`` needs no model: MOG2 background subtraction (Zivkovic 2004) for a fixed camera,
shadow removal, morphological clean-up, connected components -> boxes above a minimum area.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Protocol, runtime_checkable

import cv2
import numpy as np

from rsu.perception import Detections

VEHICLE, EV = 0, 1
PROJECT_CLASSES = ("vehicle", "ev")
COCO_TO_PROJECT: dict[int, int] = {2: VEHICLE, 3: VEHICLE, 5: VEHICLE, 7: VEHICLE}
"""COCO car, motorcycle, bus, truck -> vehicle."""
PROJECT_TO_PROJECT: dict[int, int] = {0: VEHICLE, 1: EV}
ONE_VEHICLE_CLASS: dict[int, int] = {0: VEHICLE, 1: VEHICLE}
"""Framework B with the project's model: score = obj x max(p(vehicle), p(ev)), one box per vehicle."""
PROJECT_MODEL = Path(__file__).resolve().parent.parent / "models" / "iea_det_tiny.onnx"
"""The project's own detector (``make models``; model card models/iea_det_tiny.md)."""
LAYOUTS = ("yolox-coco", "project")
YOLOX_STRIDES = (8, 16, 32)
PAD_VALUE = 114


@runtime_checkable
class Detector(Protocol):
    name: str

    def detect(self, image: np.ndarray) -> Detections: ...


def _image_of(frame) -> np.ndarray:
    image = getattr(frame, "image", frame)
    if not isinstance(image, np.ndarray) or image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8:
        raise ValueError("detect() needs an H x W x 3 uint8 BGR image (or a Frame holding one), got "
                         f"{type(image).__name__} {getattr(image, 'shape', '')} {getattr(image, 'dtype', '')}")
    return image


# ----------------------------------------------------------------------------- YOLOX pre/post-processing
def letterbox(image: np.ndarray, size: tuple[int, int]) -> tuple[np.ndarray, float]:
    """Resize keeping the aspect ratio into a (h, w) canvas at the top-left, pad 114; -> (1,3,h,w) float32, ratio."""
    h_in, w_in = size
    ratio = min(h_in / image.shape[0], w_in / image.shape[1])
    new_w, new_h = int(image.shape[1] * ratio), int(image.shape[0] * ratio)
    canvas = np.full((h_in, w_in, 3), PAD_VALUE, dtype=np.uint8)
    canvas[:new_h, :new_w] = cv2.resize(image, (new_w, new_h), interpolation=cv2.INTER_LINEAR)
    blob = np.ascontiguousarray(canvas.transpose(2, 0, 1)[None], dtype=np.float32)
    return blob, ratio


def yolox_grids(input_hw: tuple[int, int], strides: Sequence[int] = YOLOX_STRIDES) -> tuple[np.ndarray, np.ndarray]:
    """Anchor-point grid (A, 2) [x, y] in cells and the stride (A, 1) of each, in YOLOX order (read-only arrays,
    made once per input size)."""
    return _yolox_grids(tuple(int(v) for v in input_hw), tuple(int(v) for v in strides))


@functools.lru_cache(maxsize=16)
def _yolox_grids(input_hw: tuple[int, int], strides: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray]:
    grids, expanded = [], []
    for stride in strides:
        hs, ws = input_hw[0] // stride, input_hw[1] // stride
        xv, yv = np.meshgrid(np.arange(ws), np.arange(hs))
        grids.append(np.stack([xv, yv], axis=2).reshape(-1, 2))
        expanded.append(np.full((hs * ws, 1), stride))
    out = np.concatenate(grids).astype(np.float32), np.concatenate(expanded).astype(np.float32)
    for a in out:
        a.flags.writeable = False
    return out


def decode_yolox(raw: np.ndarray, input_hw: tuple[int, int], strides: Sequence[int] = YOLOX_STRIDES,
                 anchors: np.ndarray | None = None) -> np.ndarray:
    """Grid-relative YOLOX rows (A, 5+C) -> rows with cx, cy, w, h in input pixels (YOLOX ``demo_postprocess``).
    ``anchors``: indices of the rows to decode and return, in order (default: all)."""
    grids, stride = yolox_grids(input_hw, strides)
    if raw.shape[0] != len(grids):
        raise ValueError(f"YOLOX output has {raw.shape[0]} anchor points, input {input_hw} with strides "
                         f"{tuple(strides)} gives {len(grids)}")
    if anchors is not None:
        raw, grids, stride = raw[anchors], grids[anchors], stride[anchors]
    out = raw.astype(np.float32, copy=True)
    out[:, :2] = (out[:, :2] + grids) * stride
    out[:, 2:4] = np.exp(out[:, 2:4]) * stride
    return out


def class_scores(rows: np.ndarray, class_map: Mapping[int, int], n_project_classes: int = 2) -> np.ndarray:
    """(A, n_project_classes) objectness * max of the model's class scores mapped to each project class."""
    out = np.zeros((len(rows), n_project_classes), dtype=np.float32)
    for project_class in range(n_project_classes):
        cols = [5 + c for c, p in class_map.items() if p == project_class]
        if cols:
            out[:, project_class] = rows[:, 4] * rows[:, cols].max(axis=1)
    return out


def nms(boxes: np.ndarray, scores: np.ndarray, classes: np.ndarray, iou_threshold: float,
        score_threshold: float = 0.0) -> np.ndarray:
    """Class-aware non-maximum suppression; indices kept, best score first."""
    if len(boxes) == 0:
        return np.zeros(0, dtype=np.int64)
    xywh = np.column_stack([boxes[:, :2], boxes[:, 2:] - boxes[:, :2]]).astype(np.float32)
    keep = cv2.dnn.NMSBoxesBatched(xywh.tolist(), scores.astype(float).tolist(), classes.astype(int).tolist(),
                                   float(score_threshold), float(iou_threshold))
    keep = np.asarray(keep, dtype=np.int64).reshape(-1)
    return keep[np.argsort(-scores[keep], kind="stable")]


def postprocess(rows: np.ndarray, ratio: float, image_wh: tuple[int, int], class_map: Mapping[int, int],
                score_threshold: float, nms_threshold: float, classes_wanted: Sequence[int] | None = None,
                min_box_px: float = 2.0) -> Detections:
    """Decoded rows (A, 5+C) in letterbox pixels -> Detections in image pixels."""
    per_class = class_scores(rows, class_map)
    if classes_wanted is not None:
        mask = np.zeros(per_class.shape[1], dtype=bool)
        mask[list(classes_wanted)] = True
        per_class[:, ~mask] = 0.0
    classes = per_class.argmax(axis=1)
    scores = per_class[np.arange(len(rows)), classes]
    sel = scores >= score_threshold
    if not sel.any():
        return Detections.empty()
    r = rows[sel]
    boxes = np.column_stack([r[:, 0] - r[:, 2] / 2, r[:, 1] - r[:, 3] / 2,
                             r[:, 0] + r[:, 2] / 2, r[:, 1] + r[:, 3] / 2]) / ratio
    w, h = image_wh
    boxes[:, [0, 2]] = boxes[:, [0, 2]].clip(0, w)
    boxes[:, [1, 3]] = boxes[:, [1, 3]].clip(0, h)
    scores, classes = scores[sel], classes[sel]
    big = ((boxes[:, 2] - boxes[:, 0]) >= min_box_px) & ((boxes[:, 3] - boxes[:, 1]) >= min_box_px)
    boxes, scores, classes = boxes[big], scores[big], classes[big]
    keep = nms(boxes, scores, classes, nms_threshold)
    return Detections(boxes[keep].astype(np.float32), scores[keep].astype(np.float32), classes[keep].astype(np.int64))


# ----------------------------------------------------------------------------- ONNX detector
class OnnxDetector:
    """YOLOX-layout ONNX detector (see the module docstring for the two layouts)."""

    def __init__(self, model_path: str | Path, *, layout: str | None = None,
                 class_map: Mapping[int, int] | None = None, classes_wanted: Sequence[int] | None = None,
                 score_threshold: float = 0.3, nms_threshold: float = 0.45, decoded: bool = False,
                 providers: Sequence[str] | str | None = None, intra_op_threads: int | None = None,
                 input_size: tuple[int, int] | None = None, warmup_runs: int = 1, name: str | None = None) -> None:
        import onnxruntime as ort

        path = Path(model_path)
        if not path.is_file():
            raise FileNotFoundError(f"ONNX model {str(path)!r} not found")
        if not 0.0 <= score_threshold <= 1.0 or not 0.0 < nms_threshold <= 1.0:
            raise ValueError(f"thresholds must be in [0, 1]: score {score_threshold}, nms {nms_threshold}")
        if providers is None:
            providers = ["CPUExecutionProvider"]
        elif providers == "auto":
            providers = ort.get_available_providers()
        elif isinstance(providers, str):
            providers = [providers]
        missing = [p for p in providers if p not in ort.get_available_providers()]
        if missing:
            raise ValueError(f"onnxruntime providers {missing} are not installed; available: "
                             f"{ort.get_available_providers()}")
        options = ort.SessionOptions()
        if intra_op_threads:
            options.intra_op_num_threads = int(intra_op_threads)
            options.inter_op_num_threads = 1
        self.session = ort.InferenceSession(str(path), sess_options=options, providers=list(providers))
        inp = self.session.get_inputs()[0]
        out = self.session.get_outputs()[0]
        self.input_name, self.output_name = inp.name, out.name
        shape = inp.shape
        declared = self.session.get_modelmeta().custom_metadata_map.get("input_hw")
        if input_size is not None:
            self.input_hw = tuple(input_size)
        elif len(shape) == 4 and all(isinstance(d, int) for d in shape[2:]):
            self.input_hw = (int(shape[2]), int(shape[3]))
        elif declared:  # a model of any input size (models.resize_detector.any_size_model) names its default
            self.input_hw = tuple(int(v) for v in declared.split(","))
        else:
            self.input_hw = (416, 416)
        self.roi: tuple[int, int, int, int] | None = None
        """The part of the frame that is letterboxed and searched (x1, y1, x2, y2 pixels; None: all of it): an RSU
        searches only where its zone of responsibility lies in the image (``search_window``, ``rsu.detect_roi``)."""
        columns = out.shape[-1] if out.shape and isinstance(out.shape[-1], int) else None
        if layout is None:
            layout = {85: "yolox-coco", 7: "project"}.get(columns or 0)
            if layout is None:
                raise ValueError(f"{path.name}: cannot tell the output layout from {out.shape}; give layout= "
                                 f"one of {LAYOUTS}")
        if layout not in LAYOUTS:
            raise ValueError(f"layout must be one of {LAYOUTS}, got {layout!r}")
        self.layout = layout
        self.class_map = dict(class_map) if class_map is not None else (
            COCO_TO_PROJECT if layout == "yolox-coco" else PROJECT_TO_PROJECT)
        self.classes_wanted = classes_wanted
        self.score_threshold, self.nms_threshold = score_threshold, nms_threshold
        self.decoded = decoded
        self.providers = self.session.get_providers()
        self.name = name or f"onnx:{path.stem}"
        for _ in range(max(0, warmup_runs)):
            self.session.run([self.output_name], {self.input_name: np.full((1, 3, *self.input_hw), PAD_VALUE,
                                                                            np.float32)})

    @property
    def any_input_size(self) -> bool:
        """Does the model take any input size (symbolic height and width), so that ``input_hw`` and ``roi`` may be
        changed after loading?"""
        return not all(isinstance(d, int) for d in self.session.get_inputs()[0].shape[2:])

    def search_window(self, roi: tuple[int, int, int, int], input_hw: tuple[int, int]) -> None:
        """Letterbox only ``roi`` (x1, y1, x2, y2 pixels) of each frame, at the model input ``input_hw``; needs a model
        of any input size."""
        if not self.any_input_size:
            raise ValueError(f"{self.name}: the model has a fixed input {self.input_hw}; a search window needs a model "
                             "of any input size (models.resize_detector.any_size_model)")
        if len(roi) != 4 or roi[2] <= roi[0] or roi[3] <= roi[1] or min(roi) < 0:
            raise ValueError(f"roi must be x1, y1, x2, y2 pixels with x2 > x1 >= 0 and y2 > y1 >= 0, got {roi}")
        self.roi, self.input_hw = tuple(int(v) for v in roi), tuple(int(v) for v in input_hw)

    def raw_output(self, blob: np.ndarray) -> np.ndarray:
        """Model output (A, 5+C) for one letterboxed blob (batch of one)."""
        out = self.session.run([self.output_name], {self.input_name: blob})[0]
        return np.asarray(out).reshape(-1, out.shape[-1])

    def detect(self, image: np.ndarray) -> Detections:
        image = _image_of(image)
        x0 = y0 = 0
        if self.roi is not None:  # the ROI (cut to the image) is letterboxed; boxes go back to frame pixels
            x0, y0 = min(self.roi[0], image.shape[1] - 1), min(self.roi[1], image.shape[0] - 1)
            image = image[y0:self.roi[3], x0:self.roi[2]]
        blob, ratio = letterbox(image, self.input_hw)
        rows = self.raw_output(blob)
        if not self.decoded:  # a box scores objectness x class probability (both sigmoids): at most its objectness,
            # so only rows whose objectness reaches the threshold can pass postprocess (same boxes, a tenth of the work)
            rows = decode_yolox(rows, self.input_hw, anchors=np.flatnonzero(rows[:, 4] >= self.score_threshold))
        found = postprocess(rows, ratio, (image.shape[1], image.shape[0]), self.class_map, self.score_threshold,
                            self.nms_threshold, self.classes_wanted)
        if (x0 or y0) and len(found):
            found = Detections(found.boxes + np.array([x0, y0, x0, y0], np.float32), found.scores, found.class_ids)
        return found


# ----------------------------------------------------------------------------- motion detector
def vehicle_detector(model_path: str | Path = PROJECT_MODEL, *, framework: str = "B", **kwargs) -> OnnxDetector:
    """An ONNX detector as an RSU runs it: in Framework B (one class, thesis 2.3) a model of the project's
    layout scores both of its classes as one vehicle class (``ONE_VEHICLE_CLASS``), so an EV gets one box,
    not a second one from class-aware NMS. ``kwargs`` go to ``OnnxDetector``."""
    det = OnnxDetector(model_path, **kwargs)
    if framework == "B" and det.layout == "project":
        det.class_map = dict(ONE_VEHICLE_CLASS)
    return det


class MotionDetector:
    """MOG2 background subtraction for a fixed camera: moving blobs -> vehicle boxes (no model).

    ``scale`` < 1 runs the subtractor on a smaller image (faster; boxes are scaled back). Shadows
    (MOG2 marks them 127) are removed; opening removes speckle, closing joins a vehicle's parts.
    A frame whose foreground exceeds ``max_foreground_fraction`` (lighting change, camera shake)
    gives no detections. Score = foreground fill of the box.
    """

    def __init__(self, *, min_area_px: float = 150.0, scale: float = 0.5, history: int = 300,
                 var_threshold: float = 25.0, detect_shadows: bool = True, open_px: int = 3, close_px: int = 9,
                 max_foreground_fraction: float = 0.5, learning_rate: float = -1.0, name: str = "motion") -> None:
        if not 0.05 <= scale <= 1.0:
            raise ValueError(f"scale must be in [0.05, 1], got {scale}")
        self.subtractor = cv2.createBackgroundSubtractorMOG2(history=history, varThreshold=var_threshold,
                                                             detectShadows=detect_shadows)
        self.min_area_px, self.scale = float(min_area_px), float(scale)
        self.open_kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (open_px, open_px)) if open_px > 1 else None
        self.close_kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (close_px, close_px)) if close_px > 1 else None
        self.max_foreground_fraction = max_foreground_fraction
        self.learning_rate = learning_rate
        self.frames_seen = 0
        self.name = name

    def foreground(self, image: np.ndarray) -> np.ndarray:
        """Cleaned binary foreground mask (uint8 0/255) at the working scale."""
        small = image if self.scale == 1.0 else cv2.resize(image, None, fx=self.scale, fy=self.scale,
                                                           interpolation=cv2.INTER_AREA)
        mask = self.subtractor.apply(small, learningRate=self.learning_rate)
        _, mask = cv2.threshold(mask, 200, 255, cv2.THRESH_BINARY)  # drop shadows (127)
        if self.open_kernel is not None:
            mask = cv2.morphologyEx(mask, cv2.MORPH_OPEN, self.open_kernel)
        if self.close_kernel is not None:
            mask = cv2.morphologyEx(mask, cv2.MORPH_CLOSE, self.close_kernel)
        return mask

    def detect(self, image: np.ndarray) -> Detections:
        image = _image_of(image)
        mask = self.foreground(image)
        self.frames_seen += 1
        if self.frames_seen == 1 or cv2.countNonZero(mask) > self.max_foreground_fraction * mask.size:
            return Detections.empty()
        n, _, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
        stats = stats[1:]
        min_area_small = self.min_area_px * self.scale * self.scale
        x, y, w, h, area = (stats[:, i] for i in range(5))
        keep = (w * h >= min_area_small) & (area > 0)
        if not keep.any():
            return Detections.empty()
        x, y, w, h, area = x[keep], y[keep], w[keep], h[keep], area[keep]
        boxes = np.column_stack([x, y, x + w, y + h]).astype(np.float32) / self.scale
        scores = np.clip(area / (w * h), 0.0, 1.0).astype(np.float32)
        return Detections(boxes, scores, np.zeros(len(boxes), dtype=np.int64))
