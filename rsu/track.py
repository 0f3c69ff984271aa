"""SORT multi-object tracker (Bewley et al. 2016; thesis 2.2; SPEC.md "Perception"), vectorised.

Same algorithm as the reference ``sort.py`` (github.com/abewley/sort), re-implemented so that the
Kalman predict/update runs as batched numpy over all tracks instead of one filterpy object per track:

- state ``x = [u, v, s, r, u', v', s']``: box centre, area, aspect ratio (w/h), constant velocity of
  u, v, s (r is constant); measurement ``z = [u, v, s, r]``;
- ``F`` = constant velocity with dt = 1 frame, ``H`` = first four states;
- noise as the reference sets it on filterpy's identity defaults: ``R[2:,2:] *= 10``,
  ``P[4:,4:] *= 1000; P *= 10``, ``Q[-1,-1] *= 0.01; Q[4:,4:] *= 0.01``;
- before each predict, a track whose predicted area would become non-positive (``s + s' <= 0``)
  has its area velocity zeroed; a track whose predicted box is NaN is dropped;
- covariance update: filterpy's Joseph form ``(I-KH) P (I-KH)' + K R K'``, computed in its
  algebraically equal short form ``(I-KH) P`` (exact for the optimal gain; agrees to rounding);
- vectorisation: F, H, Q, R and P0 are block-diagonal over (u, u'), (v, v'), (s, s'), (r), so P
  stays so and every track's filter is a few 2x2 blocks; predict and update are element-wise array
  arithmetic (one matrix product for the predict) over all tracks at once, with no per-track loop;
- association: IoU matrix detections x predicted boxes; if every row and every column has at most
  one IoU above the threshold those pairs are taken directly, otherwise Hungarian assignment on
  ``-IoU`` (``scipy.optimize.linear_sum_assignment``); matched pairs below the threshold are undone;
- unmatched detections start tracks (in the reference's order, so ids are the same); a track is
  reported on a frame when it was updated on that frame and has ``hit_streak >= min_hits`` (or the
  tracker is still in its first ``min_hits`` frames); it is dropped after ``max_age`` frames unseen;
- ids count from 1 in the output (the reference reports ``id + 1``), per tracker instance (the
  reference shares a class-level counter between instances and wraps it at 10000; this does not).

``frameworks``: ``"B"`` (thesis 2.3, deployed) tracks every vehicle in one tracker whatever its
class; ``"A"`` (thesis 2.2) runs one tracker per detector class with a shared id counter, so a
detection whose class flips starts a new track, as in the thesis.

Pure core: no I/O, no clock, deterministic.
"""

from __future__ import annotations

import itertools
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

DIM_X = 7
DIM_Z = 4

F = np.eye(DIM_X)
F[0, 4] = F[1, 5] = F[2, 6] = 1.0
"""Constant-velocity transition, dt = 1 frame."""

R = np.diag([1.0, 1.0, 10.0, 10.0])
"""Measurement noise: filterpy's identity with ``R[2:,2:] *= 10``."""

P0 = np.diag([10.0, 10.0, 10.0, 10.0, 10000.0, 10000.0, 10000.0])
"""Initial covariance: identity, ``P[4:,4:] *= 1000``, then ``P *= 10``."""

Q = np.diag([1.0, 1.0, 1.0, 1.0, 0.01, 0.01, 0.0001])
"""Process noise: identity, ``Q[-1,-1] *= 0.01``, then ``Q[4:,4:] *= 0.01``."""

# The model decouples into independent blocks, (u, u'), (v, v'), (s, s') and (r): F, H, Q, R and P0
# are all block-diagonal over them, so P stays block-diagonal (the off-block entries of filterpy's 7x7
# P are exact zeros throughout) and S = H P H' + R is diagonal. (u, u') and (v, v') have the same
# P0, Q and R and are always updated together, so their 2x2 blocks are equal. A track's covariance is
# therefore three symmetric 2x2 blocks [p00, p01, p11] for b in (u|v, s, r) (the r block has no
# velocity: p01 = p11 = 0), and predict/update become element-wise array arithmetic over all tracks.
_BLOCK_OF_Z = np.array([0, 0, 1, 2])
"""Covariance block of each measured component u, v, s, r."""
_GAIN_OF_STATE = np.array([0, 0, 1, 2, 3, 3, 4])
"""Column of the gains [k0(u|v), k0(s), k0(r), k1(u|v), k1(s), k1(r)] that updates each state."""
_Z_OF_STATE = np.array([0, 1, 2, 3, 0, 1, 2])
"""Innovation component that updates each state (u' from u, v' from v, s' from s)."""
_Q0 = np.array([Q[0, 0], Q[2, 2], Q[3, 3]])
_Q1 = np.array([Q[4, 4], Q[6, 6], 0.0])
_R_BLOCK = np.array([R[0, 0], R[2, 2], R[3, 3]])
_P0_00 = np.array([P0[0, 0], P0[2, 2], P0[3, 3]])
_P0_11 = np.array([P0[4, 4], P0[6, 6], 0.0])


def block_to_full_covariance(p00: np.ndarray, p01: np.ndarray, p11: np.ndarray) -> np.ndarray:
    """(T, 3) block entries -> (T, 7, 7) full SORT covariance (for inspection and tests)."""
    full = np.zeros((len(p00), DIM_X, DIM_X))
    for i, b in enumerate(_BLOCK_OF_Z):
        full[:, i, i] = p00[:, b]
    for pos, vel, b in ((0, 4, 0), (1, 5, 0), (2, 6, 1)):
        full[:, pos, vel] = full[:, vel, pos] = p01[:, b]
        full[:, vel, vel] = p11[:, b]
    return full


def boxes_to_z(boxes: np.ndarray) -> np.ndarray:
    """(N, 4) xyxy boxes -> (N, 4) measurements [u, v, s, r]."""
    wh = boxes[:, 2:4] - boxes[:, 0:2]
    z = np.empty((len(boxes), 4))
    z[:, 0:2] = boxes[:, 0:2] + wh / 2.0
    z[:, 2] = wh[:, 0] * wh[:, 1]
    z[:, 3] = wh[:, 0] / wh[:, 1]
    return z


def x_to_boxes(x: np.ndarray) -> np.ndarray:
    """(N, >=4) states -> (N, 4) xyxy boxes (NaN where s * r < 0; call under ``np.errstate``)."""
    half = np.empty((len(x), 2))
    half[:, 0] = np.sqrt(x[:, 2] * x[:, 3])
    half[:, 1] = x[:, 2] / half[:, 0]
    half /= 2.0
    return np.concatenate([x[:, 0:2] - half, x[:, 0:2] + half], axis=1)


def iou_matrix(boxes_a: np.ndarray, boxes_b: np.ndarray) -> np.ndarray:
    """IoU of every box in ``boxes_a`` (N, 4) with every box in ``boxes_b`` (M, 4): (N, M)."""
    with np.errstate(invalid="ignore", divide="ignore"):
        return _iou(boxes_a, boxes_b)


def _iou(boxes_a: np.ndarray, boxes_b: np.ndarray) -> np.ndarray:
    ax1, ay1, ax2, ay2 = boxes_a.T[:, :, None]
    bx1, by1, bx2, by2 = boxes_b.T[:, None, :]
    inter = np.minimum(ax2, bx2) - np.maximum(ax1, bx1)
    np.maximum(inter, 0.0, out=inter)
    ih = np.minimum(ay2, by2) - np.maximum(ay1, by1)
    np.maximum(ih, 0.0, out=ih)
    inter *= ih
    union = (ax2 - ax1) * (ay2 - ay1) + (bx2 - bx1) * (by2 - by1) - inter
    return inter / union


_EMPTY_INDEX = np.empty(0, dtype=np.intp)


def associate(det_boxes: np.ndarray, trk_boxes: np.ndarray, iou_threshold: float
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Match detections to predicted track boxes (reference ``associate_detections_to_trackers``).

    Returns (matched detection indices, matched track indices, unmatched detection indices), the
    unmatched detections in the reference's order (never assigned first, then assigned with an IoU
    below the threshold), which fixes the order in which new tracks, and so their ids, are created.
    """
    n_det, n_trk = len(det_boxes), len(trk_boxes)
    if n_trk == 0 or n_det == 0:
        return _EMPTY_INDEX, _EMPTY_INDEX, np.arange(n_det)
    iou = _iou(det_boxes, trk_boxes)  # callers hold np.errstate
    above = iou > iou_threshold
    if above.sum(1).max() == 1 and above.sum(0).max() == 1:
        rows, cols = above.nonzero()  # unambiguous: every pair is above the threshold
        low_rows = _EMPTY_INDEX
    else:
        rows, cols = linear_sum_assignment(-iou)
        keep = iou[rows, cols] >= iou_threshold
        low_rows = rows[~keep]
        rows, cols = rows[keep], cols[keep]
    free = np.ones(n_det, dtype=bool)
    free[rows] = False
    free[low_rows] = False
    return rows, cols, np.concatenate([np.flatnonzero(free), low_rows])


@dataclass(slots=True)
class TrackSet:
    """Tracks reported on one frame (arrays of equal length M, in the reference's output order)."""

    track_ids: np.ndarray
    """(M,) int64, from 1."""
    boxes: np.ndarray
    """(M, 4) float64 xyxy: the filtered state after the update."""
    class_ids: np.ndarray
    """(M,) int64: class of the detection matched on this frame."""
    scores: np.ndarray
    """(M,) float64: score of the detection matched on this frame."""
    det_indices: np.ndarray
    """(M,) int64: index of the matched detection in this frame's input."""
    hits: np.ndarray
    """(M,) int64: total updates of the track."""
    age_frames: np.ndarray
    """(M,) int64: predictions since the track was born."""
    velocity_px: np.ndarray
    """(M, 2) float64: filtered centre velocity (u', v') in pixels per frame."""

    def __len__(self) -> int:
        return len(self.track_ids)

    def as_mot(self) -> np.ndarray:
        """(M, 5) rows [x1, y1, x2, y2, id] as the reference ``Sort.update`` returns."""
        return np.hstack([self.boxes, self.track_ids[:, None].astype(float)])

    @staticmethod
    def empty() -> TrackSet:
        e = np.empty(0, dtype=np.int64)
        return TrackSet(e, np.empty((0, 4)), e, np.empty(0), e, e, e, np.empty((0, 2)))

    @staticmethod
    def concatenate(parts: list[TrackSet]) -> TrackSet:
        if not parts:
            return TrackSet.empty()
        return TrackSet(*(np.concatenate([getattr(p, f) for p in parts])
                          for f in TrackSet.__dataclass_fields__))


# Column layout of the per-track arrays (one float and one int array, so that dropping and adding
# tracks costs one operation each rather than one per attribute).
_X = slice(0, 7)  # state [u, v, s, r, u', v', s']
_P00, _P01, _P11 = slice(7, 10), slice(10, 13), slice(13, 16)  # covariance blocks (u|v, s, r)
_SCORE = 16
_NF = 17
_ID, _CLASS, _DET, _HITS, _STREAK, _AGE, _TSU = range(7)  # adjacent: _HITS, _STREAK; _AGE, _TSU
_NI = 7
_PREDICT_MAP = np.eye(_SCORE)
"""Right-multiplied map of the columns [x, p00, p01, p11] for one predict step."""
_PREDICT_MAP[4:7, 0:3] += np.eye(3)  # u += u', v += v', s += s'
for _b in range(3):  # p00 += 2 p01 + p11; p01 += p11
    _PREDICT_MAP[_P01.start + _b, _P00.start + _b] = 2.0
    _PREDICT_MAP[_P11.start + _b, _P00.start + _b] = 1.0
    _PREDICT_MAP[_P11.start + _b, _P01.start + _b] = 1.0
_PREDICT_Q = np.concatenate([_Q0, np.zeros(3), _Q1])
_F_NEW = np.zeros(_NF)
_F_NEW[_P00] = _P0_00
_F_NEW[_P11] = _P0_11


class SortTracker:
    """SORT with vectorised Kalman filtering; ``update`` once per frame, also with no detections."""

    def __init__(self, max_age: int = 1, min_hits: int = 3, iou_threshold: float = 0.3,
                 id_source: Iterator[int] | None = None) -> None:
        if max_age < 0 or min_hits < 0:
            raise ValueError(f"max_age and min_hits must be >= 0, got {max_age}, {min_hits}")
        if not 0.0 <= iou_threshold <= 1.0:
            raise ValueError(f"iou_threshold must be in [0, 1], got {iou_threshold}")
        self.max_age = int(max_age)
        self.min_hits = int(min_hits)
        self.iou_threshold = float(iou_threshold)
        self._ids = id_source if id_source is not None else itertools.count(1)
        self.frame_count = 0
        self._f = np.zeros((0, _NF))
        self._i = np.zeros((0, _NI), dtype=np.int64)

    def __len__(self) -> int:
        """Number of live tracks (reported or not)."""
        return len(self._i)

    @property
    def x(self) -> np.ndarray:
        """(T, 7) states of the live tracks."""
        return self._f[:, _X]

    @property
    def track_ids(self) -> np.ndarray:
        return self._i[:, _ID]

    @property
    def time_since_update(self) -> np.ndarray:
        return self._i[:, _TSU]

    @property
    def covariance(self) -> np.ndarray:
        """(T, 7, 7) state covariance of every live track (as filterpy would hold it)."""
        return block_to_full_covariance(self._f[:, _P00], self._f[:, _P01], self._f[:, _P11])

    def _predict(self) -> np.ndarray:
        """Advance every track one frame; drop tracks whose box became invalid. Returns (T, 4) boxes."""
        f, i = self._f, self._i
        x = f[:, _X]
        x[x[:, 6] + x[:, 2] <= 0, 6] = 0.0  # the reference's area-velocity guard
        # x = F x and, per block with F_block = [[1, 1], [0, 1]], P = F P F' + Q, both linear in the
        # columns (x, p00, p01, p11): one matrix product for all tracks
        f[:, :_SCORE] = f[:, :_SCORE] @ _PREDICT_MAP
        f[:, _P00.start:_SCORE] += _PREDICT_Q
        i[i[:, _TSU] > 0, _STREAK] = 0
        i[:, _AGE:_TSU + 1] += 1
        boxes = x_to_boxes(f)
        if np.isnan(boxes.sum()):  # the reference drops tracks whose predicted box is not a number
            bad = np.isnan(boxes).any(axis=1)
            self._f, self._i = f[~bad], i[~bad]
            boxes = boxes[~bad]
        return boxes

    @staticmethod
    def _kalman_update(f: np.ndarray, z: np.ndarray) -> None:
        """In-place Kalman update of track rows ``f`` (K, _NF) with measurements ``z`` (K, 4), per block.

        Per block with measured state 0 and noise r: S = p00 + r, K = [p00, p01] / S, x += K y.
        The covariance update is filterpy's Joseph form (I-KH) P (I-KH)' + K r K', which for this
        (optimal) gain equals (I-KH) P exactly in algebra: p00 = r k0, p01 = r k1, p11 -= k1 p01
        (the two agree to rounding; the tests compare with filterpy's result).
        """
        p01 = f[:, _P01]
        s = f[:, _P00] + _R_BLOCK
        gains = f[:, _P00.start:_P11.start].reshape(-1, 2, 3) / s[:, None, :]  # [k0; k1] per block
        f[:, 0:7] += gains.reshape(-1, 6)[:, _GAIN_OF_STATE] * (z - f[:, 0:4])[:, _Z_OF_STATE]
        f[:, _P11] -= gains[:, 1] * p01
        f[:, _P00.start:_P11.start] = (gains * _R_BLOCK).reshape(-1, 6)

    def update(self, boxes: np.ndarray, scores: np.ndarray | None = None,
               class_ids: np.ndarray | None = None) -> TrackSet:
        """Process one frame of detections (N, 4) xyxy; returns the tracks reported on this frame."""
        boxes = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
        n = len(boxes)
        self.frame_count += 1
        with np.errstate(invalid="ignore", divide="ignore"):
            predicted = self._predict()
            self._i[:, _DET] = -1
            det, trk, new = associate(boxes, predicted, self.iou_threshold)
            z = boxes_to_z(boxes)
            if len(det):
                i = self._i[trk]
                i[:, _TSU] = 0
                i[:, _HITS:_STREAK + 1] += 1
                i[:, _DET] = det
                if class_ids is not None:
                    i[:, _CLASS] = np.asarray(class_ids).reshape(n)[det]
                self._i[trk] = i
                f = self._f[trk]
                f[:, _SCORE] = 1.0 if scores is None else np.asarray(scores).reshape(n)[det]
                self._kalman_update(f, z[det])
                self._f[trk] = f
            if len(new):
                k = len(new)
                f_new = np.tile(_F_NEW, (k, 1))
                f_new[:, 0:4] = z[new]
                f_new[:, _SCORE] = 1.0 if scores is None else np.asarray(scores).reshape(n)[new]
                i_new = np.zeros((k, _NI), dtype=np.int64)
                i_new[:, _ID] = [next(self._ids) for _ in range(k)]
                i_new[:, _DET] = new
                if class_ids is not None:
                    i_new[:, _CLASS] = np.asarray(class_ids).reshape(n)[new]
                self._f = np.concatenate([self._f, f_new])
                self._i = np.concatenate([self._i, i_new])
            f, i = self._f, self._i
            report = i[:, _TSU] < 1
            if self.frame_count > self.min_hits:
                report &= i[:, _STREAK] >= self.min_hits
            sel = np.flatnonzero(report)[::-1]  # the reference walks its track list backwards
            fs, is_ = f[sel], i[sel]
            out = TrackSet(
                track_ids=is_[:, _ID], boxes=x_to_boxes(fs), class_ids=is_[:, _CLASS],
                scores=fs[:, _SCORE], det_indices=is_[:, _DET], hits=is_[:, _HITS],
                age_frames=is_[:, _AGE], velocity_px=fs[:, 4:6],
            )
            dead = i[:, _TSU] > self.max_age
            if dead.any():
                self._f, self._i = f[~dead], i[~dead]
        return out

    def update_mot(self, dets: np.ndarray) -> np.ndarray:
        """Reference-compatible call: dets (N, >=4) [x1, y1, x2, y2, (score)] -> (M, 5) [box, id]."""
        dets = np.asarray(dets, dtype=np.float64)
        dets = dets.reshape(0, 5) if dets.size == 0 else dets
        scores = dets[:, 4] if dets.shape[1] > 4 else None
        return self.update(dets[:, :4], scores).as_mot()


FRAMEWORKS = ("A", "B")


class FrameworkTracker:
    """Tracking per thesis framework: ``"B"`` one class-agnostic SORT; ``"A"`` one SORT per class.

    Ids are unique across the per-class trackers of framework A (one shared counter).
    """

    def __init__(self, framework: str = "B", max_age: int = 1, min_hits: int = 3,
                 iou_threshold: float = 0.3) -> None:
        if framework not in FRAMEWORKS:
            raise ValueError(f"framework must be one of {FRAMEWORKS}, got {framework!r}")
        self.framework = framework
        self._params = (max_age, min_hits, iou_threshold)
        self._ids = itertools.count(1)
        self.trackers: dict[int, SortTracker] = {}
        if framework == "B":
            self.trackers[-1] = SortTracker(*self._params, id_source=self._ids)

    def update(self, boxes: np.ndarray, scores: np.ndarray | None = None,
               class_ids: np.ndarray | None = None) -> TrackSet:
        boxes = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
        n = len(boxes)
        scores = np.ones(n) if scores is None else np.asarray(scores, dtype=np.float64).reshape(n)
        class_ids = (np.zeros(n, dtype=np.int64) if class_ids is None
                     else np.asarray(class_ids, dtype=np.int64).reshape(n))
        if self.framework == "B":
            return self.trackers[-1].update(boxes, scores, class_ids)
        for c in np.unique(class_ids):
            if int(c) not in self.trackers:
                self.trackers[int(c)] = SortTracker(*self._params, id_source=self._ids)
        parts = []
        for c, trk in sorted(self.trackers.items()):
            sel = np.flatnonzero(class_ids == c)
            ts = trk.update(boxes[sel], scores[sel], class_ids[sel])
            parts.append(TrackSet(ts.track_ids, ts.boxes, ts.class_ids, ts.scores,
                                  sel[ts.det_indices] if len(ts) else ts.det_indices,
                                  ts.hits, ts.age_frames, ts.velocity_px))
        return TrackSet.concatenate(parts)
