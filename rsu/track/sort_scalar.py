"""SORT's frame step on Python floats, for the densities an RSU sees.

``rsu.track.sort.SortTracker`` keeps one row of ``rsu.track.sort``'s table layout per track; at 5-20 targets a frame of its
vectorised step is a few dozen numpy calls of ~0.5 us each on arrays of a few rows, so the calls, not the
arithmetic, set its cost. This module runs the same step on those rows as Python lists of floats: the reference's
algorithm (``bench/sort_reference.py``) with the same model as ``rsu.track.sort`` (per component (u, v, s, r) a 2x2
covariance block: predict p00 += 2 p01 + p11 + q0, p01 += p11, p11 += q1; update with gain k = [p00, p01] /
(p00 + r_c): x += k y, p11 -= k1 p01, p00 = r_c k0, p01 = r_c k1), the reference's association (its shortcut when
the pairs above the threshold are unambiguous, else Hungarian on -IoU), new tracks in its order and its output
order. The IoU is computed here on up to ``NUMPY_IOU_PAIRS`` pairs (with early rejection), by ``rsu.track.sort``'s
array IoU above that. Results equal the vectorised step's to rounding (tested against the reference).

Only finite detections with positive width and height are taken (``valid_detections``); the caller runs the
vectorised step otherwise, so numpy's inf / NaN semantics for degenerate boxes stay its business. Pure, no I/O.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator

import numpy as np
from scipy.optimize import linear_sum_assignment

# rsu.track.sort's row layout (checked there at import): state 0:7, p00 7:11, p01 11:14, p11 14:17, constant 1.0 at 17,
# then age, time since update, hits, hit streak, id, class, detection index, score
AGE, TSU, HITS, STREAK, ID, CLASS, DET, SCORE = range(18, 26)
NCOL = 26
NUMPY_IOU_PAIRS = 150
"""Detections x tracks from which the IoU is one array operation (below it, Python with early rejection is faster:
5.5 x 5 pairs cost 16 us of CPU by array operations and 8 us in Python, measured by ``bench/rsu_bench.py``'s
streams)."""


def valid_detections(dets: list[list[float]]) -> bool:
    """Every box finite with x2 > x1 and y2 > y1 (a NaN fails the comparisons)."""
    return all(0.0 < x2 - x1 < math.inf and 0.0 < y2 - y1 < math.inf for x1, y1, x2, y2 in dets)


def _predict(rows: list[list[float]]) -> list[tuple[float, float, float, float]] | None:
    """Advance every row one frame in place (the reference's guard: s' = 0 where s + s' <= 0); the predicted
    boxes, or None when a box is not finite (the caller's array step then drops or keeps it as numpy does)."""
    boxes = []
    finite = True
    for row in rows:
        u, v, s, r, du, dv, ds, a0, a1, a2, a3, b0, b1, b2, c0, c1, c2, one, age, tsu = row[:20]
        if s + ds <= 0.0:
            ds = 0.0
        s += ds
        u += du
        v += dv
        row[:20] = (u, v, s, r, du, dv, ds, a0 + 2.0 * b0 + c0 + 1.0, a1 + 2.0 * b1 + c1 + 1.0,
                    a2 + 2.0 * b2 + c2 + 1.0, a3 + 1.0, b0 + c0, b1 + c1, b2 + c2, c0 + 0.01, c1 + 0.01,
                    c2 + 0.0001, one, age + 1.0, tsu + 1.0)
        sr = s * r
        if not 0.0 < sr < math.inf:
            finite = False
            continue
        w = math.sqrt(sr)
        h = 0.5 * (s / w)
        w *= 0.5
        boxes.append((u - w, v - h, u + w, v + h))
    return boxes if finite else None


def _iou_pairs(dets: list[list[float]], boxes: list[tuple], thr: float, iou_fn: Callable
               ) -> tuple[list[tuple[int, int]], Callable[[], np.ndarray]]:
    """Pairs (detection, track) with IoU > thr in row order, and a function giving the full IoU matrix."""
    n, m = len(dets), len(boxes)
    if n * m >= NUMPY_IOU_PAIRS:
        iou = iou_fn(np.array(dets), np.array(boxes))
        rows, cols = (iou > thr).nonzero()
        return list(zip(rows.tolist(), cols.tolist(), strict=True)), lambda: iou
    above = []
    table = []
    areas = [(x2 - x1) * (y2 - y1) for x1, y1, x2, y2 in boxes]
    for i, (x1, y1, x2, y2) in enumerate(dets):
        area = (x2 - x1) * (y2 - y1)
        row = [0.0] * m
        for j, (bx1, by1, bx2, by2) in enumerate(boxes):
            iw = (x2 if x2 < bx2 else bx2) - (x1 if x1 > bx1 else bx1)
            if iw <= 0.0:
                continue
            ih = (y2 if y2 < by2 else by2) - (y1 if y1 > by1 else by1)
            if ih <= 0.0:
                continue
            inter = iw * ih
            q = row[j] = inter / (area + areas[j] - inter)
            if q > thr:
                above.append((i, j))
        table.append(row)
    return above, lambda: np.array(table).reshape(n, m)


def _associate(dets: list[list[float]], boxes: list[tuple], thr: float, iou_fn: Callable
               ) -> tuple[list[tuple[int, int]], list[int]]:
    """(matched (detection, track) pairs, unmatched detections in the reference's order)."""
    n = len(dets)
    if not n or not boxes:
        return [], list(range(n))
    above, matrix = _iou_pairs(dets, boxes, thr, iou_fn)
    k = len(above)
    if k and len({d for d, _ in above}) == k and len({t for _, t in above}) == k:
        taken = {d for d, _ in above}
        return above, [d for d in range(n) if d not in taken]
    iou = matrix()
    rows, cols = linear_sum_assignment(-iou)
    taken = set(rows.tolist())
    unmatched = [d for d in range(n) if d not in taken]
    pairs = []
    for d, t in zip(rows.tolist(), cols.tolist(), strict=True):
        if iou[d, t] >= thr:
            pairs.append((d, t))
        else:
            unmatched.append(d)
    return pairs, unmatched


def _update(row: list[float], z: tuple[float, float, float, float]) -> None:
    """Kalman update of one row with measurement z = (u, v, s, r); R = diag(1, 1, 10, 10)."""
    u, v, s, r, du, dv, ds, a0, a1, a2, a3, b0, b1, b2, c0, c1, c2 = row[:17]
    g = a0 + 1.0
    k0, k1 = a0 / g, b0 / g
    y = z[0] - u
    u, du, c0, a0, b0 = u + k0 * y, du + k1 * y, c0 - k1 * b0, k0, k1
    g = a1 + 1.0
    k0, k1 = a1 / g, b1 / g
    y = z[1] - v
    v, dv, c1, a1, b1 = v + k0 * y, dv + k1 * y, c1 - k1 * b1, k0, k1
    g = a2 + 10.0
    k0, k1 = a2 / g, b2 / g
    y = z[2] - s
    s, ds, c2, a2, b2 = s + k0 * y, ds + k1 * y, c2 - k1 * b2, 10.0 * k0, 10.0 * k1
    k0 = a3 / (a3 + 10.0)
    r, a3 = r + k0 * (z[3] - r), 10.0 * k0
    row[:17] = (u, v, s, r, du, dv, ds, a0, a1, a2, a3, b0, b1, b2, c0, c1, c2)


def step(rows: list[list[float]], dets: list[list[float]], scores: list[float] | None, class_ids: list | None,
         ids: Iterator[int], iou_threshold: float, report_all: bool, min_hits: int, max_age: int,
         iou_fn: Callable) -> tuple[list[list[float]], list[tuple]] | None:
    """One SORT frame on ``rows`` (valid ``dets``, see ``valid_detections``): (the live rows, per reported track
    (x1, y1, x2, y2, u', v', score, id, class, detection, hits, age)), or None with ``rows`` predicted when a
    predicted box is not finite (the caller finishes the frame with arrays)."""
    boxes = _predict(rows)
    if boxes is None:
        return None
    pairs, unmatched = _associate(dets, boxes, iou_threshold, iou_fn)
    for d, t in pairs:
        row = rows[t]
        x1, y1, x2, y2 = dets[d]
        w, h = x2 - x1, y2 - y1
        _update(row, (x1 + w / 2.0, y1 + h / 2.0, w * h, w / h))
        row[TSU:DET + 1] = (0.0, row[HITS] + 1.0, (0.0 if row[TSU] >= 2.0 else row[STREAK]) + 1.0, row[ID],
                            row[CLASS] if class_ids is None else float(class_ids[d]), float(d))
        row[SCORE] = 1.0 if scores is None else scores[d]
    for d in unmatched:
        x1, y1, x2, y2 = dets[d]
        w, h = x2 - x1, y2 - y1
        rows.append([x1 + w / 2.0, y1 + h / 2.0, w * h, w / h, 0.0, 0.0, 0.0, 10.0, 10.0, 10.0, 10.0, 0.0, 0.0, 0.0,
                     10000.0, 10000.0, 10000.0, 1.0, 0.0, 0.0, 0.0, 0.0, float(next(ids)),
                     0.0 if class_ids is None else float(class_ids[d]), float(d),
                     1.0 if scores is None else scores[d]])
    out = []
    for row in reversed(rows):  # the reference walks its track list backwards
        if row[TSU] < 1.0 and (report_all or row[STREAK] >= min_hits):
            u, v, s, r = row[:4]
            w = math.sqrt(s * r)
            h = 0.5 * (s / w)
            w *= 0.5
            out.append((u - w, v - h, u + w, v + h, row[4], row[5], row[SCORE], row[ID], row[CLASS], row[DET],
                        row[HITS], row[AGE]))
    if any(row[TSU] > max_age for row in rows):
        rows = [row for row in rows if row[TSU] <= max_age]
    return rows, out
