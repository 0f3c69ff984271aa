"""Scalar SORT as the reference ``sort.py`` does it (github.com/abewley/sort), for checks and speed baselines.

One Kalman filter object per track, predicted and updated one at a time in Python loops, association
as the reference (shortcut when the above-threshold IoU pairs are unambiguous, else Hungarian on
-IoU), new tracks in the reference's order, output walked backwards over the track list. This is an
independent re-implementation of the published algorithm (not a copy of the GPL file) used as the
oracle in ``tests/rsu/test_rsu_track.py`` and as the baseline in ``bench/rsu_bench.py``.

The Kalman filter is filterpy's ``KalmanFilter`` (what the reference uses) when filterpy is
installed, otherwise ``NumpyKalman`` below, which performs the same operations (filterpy's predict
and Joseph-form update, ``np.linalg.inv`` of S).
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import linear_sum_assignment

try:  # the reference's own Kalman filter, when available
    from filterpy.kalman import KalmanFilter as _FilterpyKalman
except ImportError:  # pragma: no cover - depends on the environment
    _FilterpyKalman = None

HAVE_FILTERPY = _FilterpyKalman is not None


class NumpyKalman:
    """The subset of filterpy.kalman.KalmanFilter that SORT uses, same arithmetic."""

    def __init__(self, dim_x: int, dim_z: int) -> None:
        self.x = np.zeros((dim_x, 1))
        self.P = np.eye(dim_x)
        self.Q = np.eye(dim_x)
        self.R = np.eye(dim_z)
        self.F = np.eye(dim_x)
        self.H = np.zeros((dim_z, dim_x))
        self._I = np.eye(dim_x)

    def predict(self) -> None:
        self.x = self.F @ self.x
        self.P = self.F @ self.P @ self.F.T + self.Q

    def update(self, z: np.ndarray) -> None:
        y = z - self.H @ self.x
        pht = self.P @ self.H.T
        s = self.H @ pht + self.R
        k = pht @ np.linalg.inv(s)
        self.x = self.x + k @ y
        i_kh = self._I - k @ self.H
        self.P = i_kh @ self.P @ i_kh.T + k @ self.R @ k.T


def _z(b: np.ndarray) -> np.ndarray:
    w, h = b[2] - b[0], b[3] - b[1]
    return np.array([b[0] + w / 2.0, b[1] + h / 2.0, w * h, w / float(h)]).reshape((4, 1))


def _box(x: np.ndarray) -> np.ndarray:
    with np.errstate(invalid="ignore"):
        w = np.sqrt(x[2] * x[3])
        h = x[2] / w
    return np.array([x[0] - w / 2.0, x[1] - h / 2.0, x[0] + w / 2.0, x[1] + h / 2.0]).reshape((1, 4))


class _Track:
    def __init__(self, box: np.ndarray, track_id: int, use_filterpy: bool) -> None:
        kf = _FilterpyKalman(dim_x=7, dim_z=4) if use_filterpy else NumpyKalman(7, 4)
        kf.F = np.array([[1, 0, 0, 0, 1, 0, 0], [0, 1, 0, 0, 0, 1, 0], [0, 0, 1, 0, 0, 0, 1],
                         [0, 0, 0, 1, 0, 0, 0], [0, 0, 0, 0, 1, 0, 0], [0, 0, 0, 0, 0, 1, 0],
                         [0, 0, 0, 0, 0, 0, 1]], dtype=float)
        kf.H = np.array([[1, 0, 0, 0, 0, 0, 0], [0, 1, 0, 0, 0, 0, 0], [0, 0, 1, 0, 0, 0, 0],
                         [0, 0, 0, 1, 0, 0, 0]], dtype=float)
        kf.R[2:, 2:] *= 10.0
        kf.P[4:, 4:] *= 1000.0
        kf.P *= 10.0
        kf.Q[-1, -1] *= 0.01
        kf.Q[4:, 4:] *= 0.01
        kf.x[:4] = _z(box)
        self.kf = kf
        self.id = track_id
        self.time_since_update = 0
        self.hits = 0
        self.hit_streak = 0
        self.age = 0

    def update(self, box: np.ndarray) -> None:
        self.time_since_update = 0
        self.hits += 1
        self.hit_streak += 1
        self.kf.update(_z(box))

    def predict(self) -> np.ndarray:
        if self.kf.x[6] + self.kf.x[2] <= 0:
            self.kf.x[6] *= 0.0
        self.kf.predict()
        self.age += 1
        if self.time_since_update > 0:
            self.hit_streak = 0
        self.time_since_update += 1
        return _box(self.kf.x)


def _iou(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    b = np.expand_dims(b, 0)
    a = np.expand_dims(a, 1)
    xx1 = np.maximum(a[..., 0], b[..., 0])
    yy1 = np.maximum(a[..., 1], b[..., 1])
    xx2 = np.minimum(a[..., 2], b[..., 2])
    yy2 = np.minimum(a[..., 3], b[..., 3])
    wh = np.maximum(0.0, xx2 - xx1) * np.maximum(0.0, yy2 - yy1)
    return wh / ((a[..., 2] - a[..., 0]) * (a[..., 3] - a[..., 1])
                 + (b[..., 2] - b[..., 0]) * (b[..., 3] - b[..., 1]) - wh)


def _associate(dets: np.ndarray, trks: np.ndarray, thr: float):
    if len(trks) == 0:
        return np.empty((0, 2), dtype=int), np.arange(len(dets)), np.empty((0,), dtype=int)
    iou = _iou(dets, trks)
    if min(iou.shape) > 0:
        a = (iou > thr).astype(np.int32)
        if a.sum(1).max() == 1 and a.sum(0).max() == 1:
            matched = np.stack(np.where(a), axis=1)
        else:
            r, c = linear_sum_assignment(-iou)
            matched = np.array(list(zip(r, c, strict=True)))
    else:
        matched = np.empty(shape=(0, 2))
    um_d = [d for d in range(len(dets)) if d not in matched[:, 0]]
    um_t = [t for t in range(len(trks)) if t not in matched[:, 1]]
    matches = []
    for m in matched:
        if iou[m[0], m[1]] < thr:
            um_d.append(m[0])
            um_t.append(m[1])
        else:
            matches.append(m.reshape(1, 2))
    matches = np.empty((0, 2), dtype=int) if not matches else np.concatenate(matches, axis=0)
    return matches, np.array(um_d), np.array(um_t)


class ReferenceSort:
    """The reference tracker; ``update(dets (N, >=4))`` -> (M, 5) [x1, y1, x2, y2, id], ids from 1."""

    def __init__(self, max_age: int = 1, min_hits: int = 3, iou_threshold: float = 0.3,
                 use_filterpy: bool | None = None) -> None:
        self.max_age, self.min_hits, self.iou_threshold = max_age, min_hits, iou_threshold
        self.use_filterpy = HAVE_FILTERPY if use_filterpy is None else use_filterpy
        if self.use_filterpy and not HAVE_FILTERPY:
            raise RuntimeError("filterpy is not installed")
        self.trackers: list[_Track] = []
        self.frame_count = 0
        self._next_id = 0

    def update(self, dets: np.ndarray) -> np.ndarray:
        dets = np.asarray(dets, dtype=float).reshape(-1, np.shape(dets)[1] if np.size(dets) else 5)
        self.frame_count += 1
        trks = np.zeros((len(self.trackers), 5))
        to_del = []
        for t, trk in enumerate(trks):
            pos = self.trackers[t].predict()[0]
            trk[:] = [pos[0], pos[1], pos[2], pos[3], 0]
            if np.any(np.isnan(pos)):
                to_del.append(t)
        trks = np.ma.compress_rows(np.ma.masked_invalid(trks))
        for t in reversed(to_del):
            self.trackers.pop(t)
        matched, um_dets, _ = _associate(dets[:, :4], trks[:, :4], self.iou_threshold)
        for m in matched:
            self.trackers[m[1]].update(dets[m[0], :4])
        for i in um_dets:
            self.trackers.append(_Track(dets[i, :4], self._next_id, self.use_filterpy))
            self._next_id += 1
        ret = []
        i = len(self.trackers)
        for trk in reversed(self.trackers):
            d = _box(trk.kf.x)[0]
            if trk.time_since_update < 1 and (trk.hit_streak >= self.min_hits
                                              or self.frame_count <= self.min_hits):
                ret.append(np.concatenate((d, [trk.id + 1])).reshape(1, -1))
            i -= 1
            if trk.time_since_update > self.max_age:
                self.trackers.pop(i)
        return np.concatenate(ret) if ret else np.empty((0, 5))
