"""SORT multi-object tracker (Bewley et al. 2016; thesis 2.2; docs/architecture.md §Tracking), vectorised.

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
  stays so and every track's filter is a few 2x2 blocks; all of a track's state (filter and
  bookkeeping) is one float64 row of one array (structure of arrays), the predict of all tracks is
  one matrix product, the update a few element-wise operations, with no per-track loop; tuned for
  the per-call overhead that dominates at ~20 targets (``bench/rsu_bench.py``): few numpy calls,
  ``take``/``compress`` rather than fancy indexing, coordinate-major boxes for the IoU;
- association: IoU matrix detections x predicted boxes; if every row and every column has at most
  one IoU above the threshold those pairs are taken directly, otherwise Hungarian assignment on
  ``-IoU`` (``scipy.optimize.linear_sum_assignment``); matched pairs below the threshold are undone;
- unmatched detections start tracks (in the reference's order, so ids are the same); a track is
  reported on a frame when it was updated on that frame and has ``hit_streak >= min_hits`` (or the
  tracker is still in its first ``min_hits`` frames); it is dropped after ``max_age`` frames unseen;
- ids count from 1 in the output (the reference reports ``id + 1``), per tracker instance (the
  reference shares a class-level counter between instances and wraps it at 10000; this does not).

Two code paths give the same tracks: up to ``SCALAR_MAX_ROWS`` live tracks + detections a frame runs on Python floats
(``rsu.track.sort_scalar``), above it on the table with array operations. At the densities an RSU sees (5-20
targets) numpy's per-call cost, not the arithmetic, sets the array step's price (~75 us at 20 targets against ~60 us
on floats), and the array step alone would fall under ten times the reference's speed at 20 targets; at 100 targets
the array step is the cheaper (~205 against ~375 us). Both are measured by ``bench/rsu_bench.py --tracker-only``
and tested equal to the reference and to each other.

A frame's answer is the table of its reported tracks (``rsu.perception.Detections`` with the tracker's columns).
The thesis's two ways of running it over classes are ``rsu.track.frameworks.FrameworkTracker``.

Pure core: no I/O, no clock, deterministic.
"""

from __future__ import annotations

import itertools
from collections.abc import Iterator

import numpy as np

from rsu.perception import Detections
from rsu.track import sort_scalar
from rsu.track.assoc import _associate, iou_matrix

DIM_X = 7

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
# P are exact zeros throughout) and S = H P H' + R is diagonal. A track's covariance is therefore,
# per measured component c in (u, v, s, r), the symmetric 2x2 block [p00, p01, p11] of (c, c')
# (r has no velocity: only p00), and predict/update become element-wise array arithmetic over all
# tracks. (u and v have the same P0, Q and R and are always updated together, so their blocks are
# equal; they are kept as separate columns so that every operation is a plain slice.)
_R4 = np.array([R[0, 0], R[1, 1], R[2, 2], R[3, 3]])
_Z_OF_STATE = np.array([0, 1, 2, 3, 0, 1, 2])
"""Measured component (u, v, s, r) that drives each state [u, v, s, r, u', v', s']."""
_R7 = _R4[_Z_OF_STATE]


def block_to_full_covariance(p00: np.ndarray, p01: np.ndarray, p11: np.ndarray) -> np.ndarray:
    """(T, 4) p00 of (u, v, s, r) and (T, 3) p01, p11 of (u, v, s) -> (T, 7, 7) full SORT covariance."""
    full = np.zeros((len(p00), DIM_X, DIM_X))
    for c in range(4):
        full[:, c, c] = p00[:, c]
    for c in range(3):
        full[:, c, c + 4] = full[:, c + 4, c] = p01[:, c]
        full[:, c + 4, c + 4] = p11[:, c]
    return full


def _boxes_to_z_cm(boxes_cm: np.ndarray) -> np.ndarray:
    """(4, N) coordinate-major xyxy boxes -> (4, N) measurements [u, v, s, r] (s = w h: also the box area)."""
    z = np.empty_like(boxes_cm)
    wh = boxes_cm[2:4] - boxes_cm[0:2]
    np.divide(wh, 2.0, out=z[0:2])
    z[0:2] += boxes_cm[0:2]
    np.multiply(wh[0], wh[1], out=z[2])
    np.divide(wh[0], wh[1], out=z[3])
    return z


def _x_to_boxes_cm(x: np.ndarray) -> np.ndarray:
    """(N, >=4) states -> (4, N) coordinate-major xyxy boxes (same arithmetic as ``x_to_boxes``)."""
    out = np.empty((4, len(x)))
    half = out[2:4]
    w = out[2]
    np.multiply(x[:, 2], x[:, 3], out=w)
    np.sqrt(w, out=w)
    np.divide(x[:, 2], w, out=out[3])
    half *= 0.5
    xy = x[:, 0:2].T
    np.subtract(xy, half, out=out[0:2])
    half += xy
    return out


def x_to_boxes(x: np.ndarray) -> np.ndarray:
    """(N, >=4) states -> (N, 4) xyxy boxes (NaN where s * r < 0; call under ``np.errstate``)."""
    out = np.empty((len(x), 4))
    half = out[:, 2:4]  # w / 2, h / 2 with w = sqrt(s r), h = s / w
    w = half[:, 0]
    np.multiply(x[:, 2], x[:, 3], out=w)
    np.sqrt(w, out=w)
    np.divide(x[:, 2], w, out=half[:, 1])
    half *= 0.5
    np.subtract(x[:, 0:2], half, out=out[:, 0:2])
    half += x[:, 0:2]
    return out


def no_tracks() -> Detections:
    """A tracker's answer with no track: zero rows, every tracker column filled."""
    e = np.empty(0, dtype=np.int64)
    return Detections(np.empty((0, 4)), np.empty(0), e, track_ids=e, det_indices=e, hits=e, age_frames=e,
                      velocity_px=np.empty((0, 2)))


def as_mot(tracks: Detections) -> np.ndarray:
    """(M, 5) rows [x1, y1, x2, y2, id] as the reference ``Sort.update`` returns."""
    return np.hstack([tracks.boxes, tracks.column("track_ids")[:, None].astype(float)])


# Structure of arrays: one float64 row per track (small integers are exact in float64), so that
# gathering, scattering, adding and dropping tracks is one array operation each.
_X = slice(0, 7)  # state [u, v, s, r, u', v', s']
_P00, _P01, _P11 = slice(7, 11), slice(11, 14), slice(14, 17)  # covariance of (u, v, s, r), see above
_ONE = 17  # constant 1.0 (lets the predict's affine map be one matrix product)
_AGE, _TSU, _HITS, _STREAK, _ID, _CLASS, _DET = range(18, 25)  # integers; _AGE.._DET contiguous
_SCORE = 25
_NCOL = 26
_PREDICT_MAP = np.eye(_NCOL)
"""Right-multiplied, affine through the ``_ONE`` column: x = F x, per block P = F P F' + Q with
F = [[1, 1], [0, 1]], age += 1, tsu += 1; the other columns are kept (multiplied by 1, plus exact
zeros). A row with a non-finite entry becomes all NaN (0 * inf) and is then dropped as NaN."""
_PREDICT_MAP[4:7, 0:3] += np.eye(3)  # u += u', v += v', s += s'
for _c in range(3):  # p00 += 2 p01 + p11; p01 += p11
    _PREDICT_MAP[_P01.start + _c, _P00.start + _c] = 2.0
    _PREDICT_MAP[_P11.start + _c, _P00.start + _c] = 1.0
    _PREDICT_MAP[_P11.start + _c, _P01.start + _c] = 1.0
_PREDICT_MAP[_ONE, _P00] = np.diag(Q)[0:4]
_PREDICT_MAP[_ONE, _P11] = np.diag(Q)[4:7]
_PREDICT_MAP[_ONE, _AGE] = _PREDICT_MAP[_ONE, _TSU] = 1.0
_NEW_ROW = np.zeros((1, _NCOL))
_NEW_ROW[0, _P00] = np.diag(P0)[0:4]
_NEW_ROW[0, _P11] = np.diag(P0)[4:7]
_NEW_ROW[0, _ONE] = 1.0
assert (_AGE, _TSU, _HITS, _STREAK, _ID, _CLASS, _DET, _SCORE, _NCOL) == (
    sort_scalar.AGE, sort_scalar.TSU, sort_scalar.HITS, sort_scalar.STREAK, sort_scalar.ID,
    sort_scalar.CLASS, sort_scalar.DET, sort_scalar.SCORE, sort_scalar.NCOL), "rsu.track.sort_scalar's row layout"
SCALAR_MAX_ROWS = 48
"""Live tracks + detections up to which a frame runs on Python floats (``rsu.track.sort_scalar``: the densities an RSU
sees, where numpy's per-call cost dominates); above it, on the table with array operations. Measured with
``bench/rsu_bench.py``'s streams: at 20 targets the scalar step costs ~60 us of CPU, the array step ~75 us; at 100,
~375 and ~205 us."""


def _rows_tracks(r: np.ndarray) -> Detections:
    """The tracked rows of table rows (K, _NCOL), in their order: the filtered state's box and velocity, the row's
    bookkeeping."""
    ints = r[:, _AGE:_DET + 1].astype(np.int64)
    return Detections(x_to_boxes(r), r[:, _SCORE], ints[:, _CLASS - _AGE], track_ids=ints[:, _ID - _AGE],
                      det_indices=ints[:, _DET - _AGE], hits=ints[:, _HITS - _AGE], age_frames=ints[:, 0],
                      velocity_px=r[:, 4:6])


def _scalar_tracks(out: list[tuple]) -> Detections:
    """The tracked rows of ``rsu.track.sort_scalar.step``'s reported rows (x1, y1, x2, y2, u', v', score, id, class,
    detection, hits, age)."""
    if not out:
        return no_tracks()
    a = np.array(out)
    ints = a[:, 7:12].astype(np.int64)
    return Detections(a[:, 0:4], a[:, 6], ints[:, 1], track_ids=ints[:, 0], det_indices=ints[:, 2], hits=ints[:, 3],
                      age_frames=ints[:, 4], velocity_px=a[:, 4:6])


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
        self._t = np.zeros((0, _NCOL))
        self._rows: list[list[float]] | None = None
        """The same table as Python lists while frames run on ``rsu.track.sort_scalar`` (then ``_t`` is stale)."""

    def __len__(self) -> int:
        """Number of live tracks (reported or not)."""
        return len(self._rows) if self._rows is not None else len(self._t)

    def _table(self) -> np.ndarray:
        """(T, _NCOL) rows of the live tracks (a copy while they are held as lists)."""
        return self._t if self._rows is None else np.array(self._rows, dtype=np.float64).reshape(-1, _NCOL)

    def _to_arrays(self) -> None:
        if self._rows is not None:
            self._t, self._rows = self._table(), None

    @property
    def x(self) -> np.ndarray:
        """(T, 7) states of the live tracks."""
        return self._table()[:, _X]

    @property
    def track_ids(self) -> np.ndarray:
        return self._table()[:, _ID].astype(np.int64)

    @property
    def time_since_update(self) -> np.ndarray:
        return self._table()[:, _TSU].astype(np.int64)

    @property
    def covariance(self) -> np.ndarray:
        """(T, 7, 7) state covariance of every live track (as filterpy would hold it)."""
        t = self._table()
        return block_to_full_covariance(t[:, _P00], t[:, _P01], t[:, _P11])

    def _predict(self) -> np.ndarray:
        """Advance every track one frame; drop tracks whose box became invalid. Returns (4, T) boxes.

        The reference's ``if time_since_update > 0: hit_streak = 0`` is applied lazily, in
        ``update`` to the matched tracks (after this predict, time_since_update >= 2 exactly when it
        was > 0 before): the streak of an unmatched track is never read before it is matched again.
        """
        old = self._t
        t = self._t = old @ _PREDICT_MAP
        # the reference's guard: s' = 0 before the predict where s + s' <= 0, i.e. where the predicted
        # area t[:, 2] = s + s' is <= 0 (rare: fixed up after the product, same values)
        bad = t[:, 2] <= 0.0
        if bad.any():
            t[bad, 2] = old[bad, 2]
            t[bad, 6] = 0.0
        return self._predicted_boxes()

    def _predicted_boxes(self) -> np.ndarray:
        """(4, T) boxes of the predicted tracks; tracks whose box is not a number are dropped."""
        t = self._t
        boxes = _x_to_boxes_cm(t)
        if np.isnan(boxes.sum()):  # the reference drops tracks whose predicted box is not a number
            good = ~np.isnan(boxes).any(axis=0)
            self._t = t.compress(good, axis=0)
            boxes = boxes.compress(good, axis=1)
        return boxes

    @staticmethod
    def _kalman_update(t: np.ndarray, z: np.ndarray) -> None:
        """In-place Kalman update of track rows ``t`` (K, _NCOL) with measurements ``z`` (K, 4).

        Per component with noise r: S = p00 + r, K = [p00, p01] / S, x += K y.
        The covariance update is filterpy's Joseph form (I-KH) P (I-KH)' + K r K', which for this
        (optimal) gain equals (I-KH) P exactly in algebra: p00 = r k0, p01 = r k1, p11 -= k1 p01
        (the two agree to rounding; the tests compare with filterpy's result).
        """
        p = t[:, _P00.start:_P01.stop]  # [p00 of u, v, s, r; p01 of u, v, s], aligned with the states
        s = t[:, _P00] + _R4
        k = p / s.take(_Z_OF_STATE, axis=1)  # gains [k0 of u, v, s, r; k1 of u, v, s]
        y = (z - t[:, 0:4]).take(_Z_OF_STATE, axis=1)
        y *= k
        t[:, _X] += y
        t[:, _P11] -= k[:, 4:7] * t[:, _P01]
        np.multiply(k, _R7, out=p)

    def update(self, boxes: np.ndarray, scores: np.ndarray | None = None,
               class_ids: np.ndarray | None = None) -> Detections:
        """Process one frame of detections (N, 4) xyxy; returns the tracks reported on this frame.

        Up to ``SCALAR_MAX_ROWS`` live tracks + detections (and detections with a finite, positive size) the frame
        runs on Python floats (``rsu.track.sort_scalar``), otherwise with array operations; same tracks either way."""
        boxes = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
        n = len(boxes)
        if scores is not None:
            scores = np.asarray(scores, dtype=np.float64).reshape(n)
        if class_ids is not None:
            class_ids = np.asarray(class_ids).reshape(n)
        self.frame_count += 1
        if len(self) + n <= SCALAR_MAX_ROWS and sort_scalar.valid_detections(dets := boxes.tolist()):
            if self._rows is None:
                self._rows = self._t.tolist()
            res = sort_scalar.step(self._rows, dets, None if scores is None else scores.tolist(),
                                    None if class_ids is None else class_ids.tolist(), self._ids,
                                    self.iou_threshold, self.frame_count <= self.min_hits, self.min_hits,
                                    self.max_age, iou_matrix)
            if res is not None:
                self._rows = res[0]
                return _scalar_tracks(res[1])
            self._to_arrays()  # a predicted box is not finite: the frame goes on with arrays, predicted
            return self._update_arrays(boxes, scores, class_ids, predicted=True)
        self._to_arrays()
        return self._update_arrays(boxes, scores, class_ids, predicted=False)

    def _update_arrays(self, boxes: np.ndarray, scores: np.ndarray | None, class_ids: np.ndarray | None,
                       predicted: bool) -> Detections:
        """``update`` with array operations over the table (``predicted``: the tracks were advanced already)."""
        with np.errstate(invalid="ignore", divide="ignore"):
            predicted = self._predicted_boxes() if predicted else self._predict()
            boxes_cm = boxes.T.copy()
            z_cm = _boxes_to_z_cm(boxes_cm)  # z_cm[2] = w h is also the box area
            det, trk, new = _associate(boxes_cm, z_cm[2], predicted, self.iou_threshold)
            t = self._t
            if len(det):
                # (ndarray.take / .compress: same result as fancy / boolean indexing, several times
                # faster on arrays this small)
                m = t.take(trk, axis=0)
                m[:, _STREAK] *= m[:, _TSU] < 2  # lazy streak reset, see _predict
                m[:, _HITS:_STREAK + 1] += 1.0
                m[:, _TSU] = 0.0
                m[:, _DET] = det
                m[:, _SCORE] = 1.0 if scores is None else scores.take(det)
                if class_ids is not None:
                    m[:, _CLASS] = class_ids.take(det)
                self._kalman_update(m, z_cm.take(det, axis=1).T)
                t[trk] = m
            if len(new):
                k = len(new)
                b = _NEW_ROW.repeat(k, axis=0)
                b[:, 0:4] = z_cm.take(new, axis=1).T
                b[:, _ID] = list(itertools.islice(self._ids, k))
                b[:, _DET] = new
                b[:, _SCORE] = 1.0 if scores is None else scores.take(new)
                if class_ids is not None:
                    b[:, _CLASS] = class_ids.take(new)
                t = self._t = np.concatenate([t, b])
            report = t[:, _TSU] < 1.0
            if self.frame_count > self.min_hits:
                report &= t[:, _STREAK] >= self.min_hits
            # (the reference walks its track list backwards)
            out = _rows_tracks(t.take(np.flatnonzero(report)[::-1], axis=0))
            alive = t[:, _TSU] <= self.max_age
            if not alive.all():
                self._t = t.compress(alive, axis=0)
        return out

    def tentative(self) -> Detections:
        """The tracks matched to a detection on the last ``update`` that it did not report: born or re-found
        less than ``min_hits`` frames ago (SORT holds them back as possible false positives). Their boxes are
        measured like any track's, so what reads a vehicle's look over frames (the EV classifier) can start at
        the track's birth instead of when it is first reported. Same fields as ``update``'s result, oldest track
        first."""
        if self.frame_count <= self.min_hits:  # every matched track was reported
            return no_tracks()
        rows = self._rows if self._rows is not None else self._t
        held = [r for r in rows if r[_TSU] < 1.0 and r[_STREAK] < self.min_hits]
        if not held:
            return no_tracks()
        with np.errstate(invalid="ignore", divide="ignore"):
            return _rows_tracks(np.array(held, dtype=np.float64).reshape(-1, _NCOL))

    def update_mot(self, dets: np.ndarray) -> np.ndarray:
        """Reference-compatible call: dets (N, >=4) [x1, y1, x2, y2, (score)] -> (M, 5) [box, id]."""
        dets = np.asarray(dets, dtype=np.float64)
        dets = dets.reshape(0, 5) if dets.size == 0 else dets
        scores = dets[:, 4] if dets.shape[1] > 4 else None
        return as_mot(self.update(dets[:, :4], scores))
