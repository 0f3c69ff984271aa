"""Association of SORT (Bewley et al. 2016): the IoU of boxes and the reference's matching of detections to predicted
track boxes (its unambiguous-pairs shortcut, else Hungarian on -IoU). Used by ``rsu.track.sort`` and ``rsu.classify``. Pure, no I/O."""

from __future__ import annotations

import numpy as np
from scipy.optimize import linear_sum_assignment


def iou_matrix(boxes_a: np.ndarray, boxes_b: np.ndarray) -> np.ndarray:
    """IoU of every box in ``boxes_a`` (N, 4) with every box in ``boxes_b`` (M, 4): (N, M)."""
    a, b = np.asarray(boxes_a, dtype=np.float64).T.copy(), np.asarray(boxes_b, dtype=np.float64).T.copy()
    with np.errstate(invalid="ignore", divide="ignore"):
        return _iou(a, _areas(a), b, _areas(b))


def _areas(boxes_cm: np.ndarray) -> np.ndarray:
    """Areas (x2 - x1) (y2 - y1) of (4, N) coordinate-major boxes."""
    wh = boxes_cm[2:4] - boxes_cm[0:2]
    return wh[0] * wh[1]


def _iou(boxes_a: np.ndarray, areas_a: np.ndarray, boxes_b: np.ndarray, areas_b: np.ndarray) -> np.ndarray:
    """IoU (N, M) of coordinate-major boxes (4, N), (4, M) with their areas (x2 - x1) (y2 - y1); the
    reference's arithmetic: max(0, min(x2) - max(x1)) max(0, min(y2) - max(y1)) / (a + b - inter).

    Coordinate-major (contiguous rows): the (2, N, M) operations run long unit-stride inner loops,
    several times faster than broadcasting (N, 4) views."""
    a, b = boxes_a[:, :, None], boxes_b[:, None, :]
    wh = np.minimum(a[2:4], b[2:4])
    wh -= np.maximum(a[0:2], b[0:2])
    np.maximum(wh, 0.0, out=wh)
    inter = wh[0] * wh[1]
    union = areas_a[:, None] + areas_b
    union -= inter
    inter /= union
    return inter


_EMPTY_INDEX = np.empty(0, dtype=np.intp)


def associate(det_boxes: np.ndarray, trk_boxes: np.ndarray, iou_threshold: float
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Match detections to predicted track boxes (reference ``associate_detections_to_trackers``).

    Returns (matched detection indices, matched track indices, unmatched detection indices), the
    unmatched detections in the reference's order (never assigned first, then assigned with an IoU
    below the threshold), which fixes the order in which new tracks, and so their ids, are created.

    Shortcut, the reference's own: when every detection and every track has at most one IoU above
    the threshold and there is at least one such pair (the reference's test ``above.sum(1).max() == 1
    and above.sum(0).max() == 1``; here: the above pairs' rows are distinct and their columns are
    distinct, which is the same condition), those pairs are the matches, no Hungarian step. This is
    part of the published algorithm, not an optimisation that Hungarian would reproduce: with IoU
    d0-t1 0.318, d0-t0 0.238, d1-t1 0.267 and threshold 0.3 the shortcut matches d0-t1, whereas the
    optimal assignment {d0-t0, d1-t1} (0.505 > 0.318) is filtered to no match at all. Taking it under
    exactly the reference's condition gives exactly the reference's matches and unmatched order (the
    pairs come from ``nonzero`` in row order, as the reference's ``np.where``). Otherwise: Hungarian on
    -IoU, pairs with IoU < threshold undone (tests: ``test_associate_*``).
    """
    a = np.asarray(det_boxes, dtype=np.float64).T.copy()
    b = np.asarray(trk_boxes, dtype=np.float64).T.copy()
    with np.errstate(invalid="ignore", divide="ignore"):
        return _associate(a, _areas(a), b, iou_threshold)


def _associate(det_cm: np.ndarray, det_areas: np.ndarray, trk_cm: np.ndarray, iou_threshold: float
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``associate`` on (4, N) and (4, M) coordinate-major boxes; callers hold np.errstate."""
    n_det, n_trk = det_cm.shape[1], trk_cm.shape[1]
    if n_trk == 0 or n_det == 0:
        return _EMPTY_INDEX, _EMPTY_INDEX, np.arange(n_det)
    iou = _iou(det_cm, det_areas, trk_cm, _areas(trk_cm))
    rows, cols = (iou > iou_threshold).nonzero()
    k = len(rows)
    free = np.ones(n_det, dtype=bool)
    if k and len(set(rows.tolist())) == k and len(set(cols.tolist())) == k:
        free[rows] = False  # unambiguous: every pair is above the threshold
        return rows, cols, np.flatnonzero(free)
    rows, cols = linear_sum_assignment(-iou)
    keep = iou[rows, cols] >= iou_threshold
    free[rows] = False
    if keep.all():
        return rows, cols, np.flatnonzero(free)
    low_rows = rows.compress(~keep)
    return rows.compress(keep), cols.compress(keep), np.concatenate([np.flatnonzero(free), low_rows])
