"""Evaluation only (never used to perceive): CLEAR-MOT (MOTA, MOTP) and IDF1, and a synthetic scene.

- CLEAR-MOT (Bernardin & Stiefelhagen 2008): per frame, ground-truth/hypothesis pairs with IoU >= 0.5
  may match; a pair matched on the previous frame is kept while still valid, the rest are assigned
  by Hungarian on IoU; MOTA = 1 - (FN + FP + IDSW) / GT, MOTP = mean IoU of matches.
- IDF1 (Ristani et al. 2016): one-to-one assignment of ground-truth ids to hypothesis ids maximising
  the number of frames where the pair overlaps with IoU >= 0.5 (IDTP); IDF1 = 2 IDTP / (GT + HYP).
- ``synthetic_scene``: boxes moving at constant velocity through an image with births, deaths,
  crossings, pixel noise, missed detections and false positives; ground truth plus detections in the
  project's detector output form. Used by the tracker tests and the benchmark.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import linear_sum_assignment

from rsu.track.assoc import iou_matrix


@dataclass
class MotMetrics:
    num_frames: int = 0
    num_gt: int = 0
    num_hyp: int = 0
    true_positives: int = 0
    false_negatives: int = 0
    false_positives: int = 0
    id_switches: int = 0
    iou_sum: float = 0.0
    idtp: int = 0
    num_gt_ids: int = 0
    num_hyp_ids: int = 0

    @property
    def mota(self) -> float:
        if self.num_gt == 0:
            return float("nan")
        return 1.0 - (self.false_negatives + self.false_positives + self.id_switches) / self.num_gt

    @property
    def motp_iou(self) -> float:
        return self.iou_sum / self.true_positives if self.true_positives else float("nan")

    @property
    def idf1(self) -> float:
        denom = self.num_gt + self.num_hyp
        return 2.0 * self.idtp / denom if denom else float("nan")

    def as_dict(self) -> dict[str, float | int]:
        return {"mota": self.mota, "idf1": self.idf1, "motp_iou": self.motp_iou,
                "frames": self.num_frames, "gt": self.num_gt, "fn": self.false_negatives,
                "fp": self.false_positives, "idsw": self.id_switches,
                "gt_ids": self.num_gt_ids, "hyp_ids": self.num_hyp_ids}


def _inside_fraction(boxes: np.ndarray, regions: np.ndarray) -> np.ndarray:
    """(N, M): the fraction of each box's area (xyxy) that lies inside each region."""
    lt = np.maximum(boxes[:, None, :2], regions[None, :, :2])
    rb = np.minimum(boxes[:, None, 2:], regions[None, :, 2:])
    inter = np.clip(rb - lt, 0, None).prod(-1)
    area = np.clip(boxes[:, 2:] - boxes[:, :2], 0, None).prod(-1)
    return inter / np.maximum(area, 1e-9)[:, None]


@dataclass
class MotEvaluator:
    """Feed ``update(gt_ids, gt_boxes, hyp_ids, hyp_boxes)`` per frame, then read ``result()``."""

    iou_threshold: float = 0.5
    _m: MotMetrics = field(default_factory=MotMetrics)
    _last_match: dict[int, int] = field(default_factory=dict)
    _pair_counts: dict[tuple[int, int], int] = field(default_factory=dict)
    _gt_ids: set[int] = field(default_factory=set)
    _hyp_ids: set[int] = field(default_factory=set)

    def update(self, gt_ids, gt_boxes, hyp_ids, hyp_boxes, ignore_boxes=None) -> None:
        """One frame. ``ignore_boxes`` (optional, (k, 4)): ground truth that is not counted (distractors:
        barely visible or out of the evaluated zone). A hypothesis that overlaps no counted box with IoU >=
        ``iou_threshold`` but lies at least half inside one ignore box (intersection / its own area >= 0.5,
        KITTI's "DontCare" rule, Geiger et al. 2012) is removed: neither a true nor a false positive."""
        gt_ids = [int(g) for g in np.asarray(gt_ids).reshape(-1)]
        hyp_ids = [int(h) for h in np.asarray(hyp_ids).reshape(-1)]
        gt_boxes = np.asarray(gt_boxes, dtype=float).reshape(-1, 4)
        hyp_boxes = np.asarray(hyp_boxes, dtype=float).reshape(-1, 4)
        if ignore_boxes is not None and len(hyp_ids):
            ignore_boxes = np.asarray(ignore_boxes, dtype=float).reshape(-1, 4)
            if len(ignore_boxes):
                on_ignored = _inside_fraction(hyp_boxes, ignore_boxes).max(axis=1) >= 0.5
                if len(gt_ids):
                    on_ignored &= np.nan_to_num(iou_matrix(hyp_boxes, gt_boxes)).max(axis=1) < self.iou_threshold
                hyp_boxes = hyp_boxes[~on_ignored]
                hyp_ids = [h for h, drop in zip(hyp_ids, on_ignored, strict=True) if not drop]
        if len(set(hyp_ids)) != len(hyp_ids) or len(set(gt_ids)) != len(gt_ids):
            raise ValueError("ids must be unique within a frame")
        m = self._m
        m.num_frames += 1
        m.num_gt += len(gt_ids)
        m.num_hyp += len(hyp_ids)
        self._gt_ids.update(gt_ids)
        self._hyp_ids.update(hyp_ids)
        iou = iou_matrix(gt_boxes, hyp_boxes) if len(gt_ids) and len(hyp_ids) else np.zeros((len(gt_ids), len(hyp_ids)))
        iou = np.nan_to_num(iou)
        valid = iou >= self.iou_threshold
        # IDF1 co-occurrence counts
        for gi, hj in zip(*np.nonzero(valid), strict=True):
            key = (gt_ids[gi], hyp_ids[hj])
            self._pair_counts[key] = self._pair_counts.get(key, 0) + 1
        # CLEAR-MOT: keep still-valid previous correspondences, Hungarian for the rest
        matches: list[tuple[int, int]] = []
        gt_free = np.ones(len(gt_ids), dtype=bool)
        hyp_free = np.ones(len(hyp_ids), dtype=bool)
        hyp_index = {h: j for j, h in enumerate(hyp_ids)}
        for gi, g in enumerate(gt_ids):
            h = self._last_match.get(g)
            j = hyp_index.get(h) if h is not None else None
            if j is not None and valid[gi, j] and hyp_free[j]:
                matches.append((gi, j))
                gt_free[gi] = hyp_free[j] = False
        gi_free, hj_free = np.flatnonzero(gt_free), np.flatnonzero(hyp_free)
        if len(gi_free) and len(hj_free):
            sub = np.where(valid[np.ix_(gi_free, hj_free)], iou[np.ix_(gi_free, hj_free)], 0.0)
            rows, cols = linear_sum_assignment(-sub)
            for r, c in zip(rows, cols, strict=True):
                if sub[r, c] >= self.iou_threshold:
                    gi, j = int(gi_free[r]), int(hj_free[c])
                    matches.append((gi, j))
                    g, h = gt_ids[gi], hyp_ids[j]
                    if g in self._last_match and self._last_match[g] != h:
                        m.id_switches += 1
        for gi, j in matches:
            self._last_match[gt_ids[gi]] = hyp_ids[j]
            m.iou_sum += float(iou[gi, j])
        m.true_positives += len(matches)
        m.false_negatives += len(gt_ids) - len(matches)
        m.false_positives += len(hyp_ids) - len(matches)

    def result(self) -> MotMetrics:
        m = self._m
        m.num_gt_ids, m.num_hyp_ids = len(self._gt_ids), len(self._hyp_ids)
        if self._pair_counts:
            g_index = {g: i for i, g in enumerate(sorted(self._gt_ids))}
            h_index = {h: j for j, h in enumerate(sorted(self._hyp_ids))}
            counts = np.zeros((len(g_index), len(h_index)))
            for (g, h), c in self._pair_counts.items():
                counts[g_index[g], h_index[h]] = c
            rows, cols = linear_sum_assignment(-counts)
            m.idtp = int(counts[rows, cols].sum())
        return m


@dataclass(frozen=True)
class SyntheticFrame:
    gt_ids: np.ndarray
    gt_boxes: np.ndarray
    det_boxes: np.ndarray
    det_scores: np.ndarray
    det_classes: np.ndarray


def synthetic_scene(n_frames: int = 200, n_targets: int = 20, seed: int = 0, width: int = 1280,
                    height: int = 720, noise_px: float = 1.5, miss_prob: float = 0.05,
                    false_pos_per_frame: float = 0.2, mean_life_frames: float = 80.0) -> list[SyntheticFrame]:
    """Moving boxes (about ``n_targets`` alive at once) and noisy detections of them.

    Targets move at constant velocity (some left-right, some right-left, so they cross), die after a
    random life or when they leave the image and are replaced by new ones.
    """
    rng = np.random.default_rng(seed)
    next_id = 1
    alive: list[dict] = []

    def spawn() -> dict:
        nonlocal next_id
        w = rng.uniform(40, 120)
        h = w * rng.uniform(0.5, 0.9)
        t = {"id": next_id, "cx": rng.uniform(w, width - w), "cy": rng.uniform(h, height - h),
             "vx": rng.choice([-1, 1]) * rng.uniform(1.0, 8.0), "vy": rng.uniform(-1.5, 1.5),
             "w": w, "h": h, "life": rng.exponential(mean_life_frames) + 5}
        next_id += 1
        return t

    alive = [spawn() for _ in range(n_targets)]
    frames = []
    for _ in range(n_frames):
        ids, gtb = [], []
        for t in alive:
            ids.append(t["id"])
            gtb.append([t["cx"] - t["w"] / 2, t["cy"] - t["h"] / 2, t["cx"] + t["w"] / 2, t["cy"] + t["h"] / 2])
        gt = np.array(gtb).reshape(-1, 4)
        seen = rng.random(len(gt)) >= miss_prob
        det = gt[seen] + rng.normal(0, noise_px, size=(int(seen.sum()), 4))
        n_fp = rng.poisson(false_pos_per_frame)
        if n_fp:
            xy = rng.uniform([0, 0], [width - 60, height - 40], size=(n_fp, 2))
            wh = rng.uniform([20, 15], [60, 40], size=(n_fp, 2))
            det = np.vstack([det, np.hstack([xy, xy + wh])])
        order = rng.permutation(len(det))
        det = det[order]
        frames.append(SyntheticFrame(np.array(ids, dtype=np.int64), gt, det,
                                     rng.uniform(0.5, 1.0, len(det)), np.zeros(len(det), dtype=np.int64)))
        nxt = []
        for t in alive:
            t["cx"] += t["vx"]
            t["cy"] += t["vy"]
            t["life"] -= 1
            if t["life"] > 0 and -t["w"] / 2 < t["cx"] < width + t["w"] / 2 and 0 < t["cy"] < height:
                nxt.append(t)
        while len(nxt) < n_targets:
            nxt.append(spawn())
        alive = nxt
    return frames


def read_mot_detections(source) -> dict[int, np.ndarray]:
    """MOTChallenge ``det.txt`` rows ``frame, id, x, y, w, h, score, ...`` (a path or an (N, >=7) array)
    -> {frame: (K, 5) [x1, y1, x2, y2, score]} for frames 1..max (empty arrays where none)."""
    rows = np.loadtxt(source, delimiter=",", ndmin=2) if isinstance(source, str) else np.asarray(source, float)
    if rows.ndim != 2 or rows.shape[1] < 7:
        raise ValueError(f"MOT detections need >= 7 columns (frame,id,x,y,w,h,score), got shape {rows.shape}")
    out: dict[int, np.ndarray] = {}
    last = int(rows[:, 0].max()) if len(rows) else 0
    for frame in range(1, last + 1):
        d = rows[rows[:, 0] == frame, 2:7].copy()
        d[:, 2:4] += d[:, 0:2]
        out[frame] = d
    return out


def mot_result_lines(frame: int, tracks_xyxy_id: np.ndarray) -> list[str]:
    """MOTChallenge result lines ``frame,id,x,y,w,h,1,-1,-1,-1`` as the reference ``sort.py`` writes them."""
    return [f"{frame:d},{int(d[4]):d},{d[0]:.2f},{d[1]:.2f},{d[2] - d[0]:.2f},{d[3] - d[1]:.2f},1,-1,-1,-1"
            for d in tracks_xyxy_id]
