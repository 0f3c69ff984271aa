"""Evaluate an exported detector through the runtime path (``rsu.detect.OnnxDetector``) on fresh renders.

Held-out set: renders of a scenario (default ``rellis_ev_yield``, its own lighting) with scenario seeds
never used for training (the training exports use ``seed * 100003 + episode * 7919 + scenario seed``
with seed 1 or 3 and episodes < 20; the held-out seeds here are ``HELD_OUT_SEEDS``), every ``stride_s``
of sim time, all the corridor's cameras. Ground truth = the simulator's labels (``Renderer.labels``:
visible part of each vehicle as rendered). "Difficult" boxes (PASCAL VOC: not counted as ground truth,
and a detection matching one is neither a true nor a false positive): vehicles less than
``MIN_VISIBLE_FRACTION`` visible, vehicles farther than ``max_range_m`` from the camera (the RSU's zone
of responsibility, ``ZONE_M``; figures are also given for 150 m and for every labelled vehicle), and
optionally boxes whose shorter side is below ``min_box_px``.

``average_precision``: VOC all-point interpolated AP at IoU 0.5 (Everingham et al. 2010; VOC2010+).
Needs no torch (numpy, OpenCV, onnxruntime only).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from rsu.detect import OnnxDetector
from rsu.track.assoc import iou_matrix

HELD_OUT_SEEDS = (900_001, 900_002)
ZONE_M = 100.0
"""The RSU's zone of responsibility: about 100 m of road from its camera (docs/architecture.md §Coordinates,
deploy/corridors/rellis.toml: 4 RSUs 50 m apart, each covering about 100 m). A vehicle
farther away is the next RSU's (it is 50 m from it), so here it is 'difficult': neither counted nor penalised."""
WORLD_DT_S = 0.05


@dataclass
class FrameTruth:
    boxes: np.ndarray  # (n, 4) xyxy
    classes: np.ndarray  # (n,)
    difficult: np.ndarray  # (n,) bool
    range_m: np.ndarray | None = None  # (n,) horizontal distance camera -> vehicle centre


@dataclass
class HeldOutSet:
    images: list[np.ndarray] = field(default_factory=list)
    truths: list[FrameTruth] = field(default_factory=list)
    names: list[str] = field(default_factory=list)


def average_precision(detections: list[tuple[np.ndarray, np.ndarray]], truths: list[tuple[np.ndarray, np.ndarray]],
                      iou_threshold: float = 0.5) -> tuple[float, int, float]:
    """VOC all-point AP for one class.

    ``detections[i] = (boxes (n, 4), scores (n,))`` and ``truths[i] = (boxes (m, 4), difficult (m,) bool)``
    per image. Each detection, best score first, matches the unmatched-or-not ground truth box of highest
    IoU (VOC rule): >= threshold and not yet matched -> TP; already matched -> FP; difficult -> ignored.
    -> (AP, number of non-difficult ground-truth boxes, recall at the lowest score).
    """
    n_gt = int(sum((~d).sum() for _, d in truths))
    recs = []
    for img, ((dboxes, dscores), _truth) in enumerate(zip(detections, truths, strict=True)):
        for k in range(len(dboxes)):
            recs.append((float(dscores[k]), img, k))
    recs.sort(key=lambda r: -r[0])
    matched = [np.zeros(len(g), bool) for g, _ in truths]
    tp = np.zeros(len(recs))
    fp = np.zeros(len(recs))
    ious = [np.nan_to_num(iou_matrix(np.asarray(d, float).reshape(-1, 4), np.asarray(g, float).reshape(-1, 4)))
            for (d, _), (g, _) in zip(detections, truths, strict=True)]
    for j, (_, img, k) in enumerate(recs):
        gboxes, difficult = truths[img]
        if len(gboxes) == 0:
            fp[j] = 1
            continue
        row = ious[img][k]
        best = int(row.argmax())
        if row[best] >= iou_threshold:
            if difficult[best]:
                continue
            if not matched[img][best]:
                matched[img][best] = True
                tp[j] = 1
            else:
                fp[j] = 1
        else:
            fp[j] = 1
    if n_gt == 0:
        return float("nan"), 0, float("nan")
    ctp, cfp = np.cumsum(tp), np.cumsum(fp)
    recall = ctp / n_gt
    precision = ctp / np.maximum(ctp + cfp, 1e-9)
    mrec = np.concatenate([[0.0], recall, [1.0]])
    mpre = np.concatenate([[0.0], precision, [0.0]])
    mpre = np.maximum.accumulate(mpre[::-1])[::-1]
    idx = np.flatnonzero(mrec[1:] != mrec[:-1])
    ap = float(np.sum((mrec[idx + 1] - mrec[idx]) * mpre[idx + 1]))
    return ap, n_gt, float(recall[-1]) if len(recall) else 0.0


def render_held_out(scenario: str = "rellis_ev_yield", seeds=HELD_OUT_SEEDS, stride_s: float = 0.7,
                    lighting: str | None = None, min_box_px: float = 0.0, max_frames: int | None = None,
                    t_min_s: float = 0.0) -> HeldOutSet:
    """Render the held-out frames and their ground truth (see the module docstring)."""
    from sim.render.labels import MIN_VISIBLE_FRACTION
    from sim.render.renderer import Renderer
    from sim.scenario import load_scenario
    from sim.world import World

    out = HeldOutSet()
    base = load_scenario(scenario)
    stride_steps = max(1, int(round(stride_s / WORLD_DT_S)))
    for seed in seeds:
        sc = base.with_overrides(seed=seed, lighting=lighting)
        world = World(sc)
        renderers = {r.rsu_id: (r, Renderer(r.camera, sc.corridor.road, seed=sc.seed)) for r in sc.corridor.rsus}
        for step in range(1, int(sc.duration_s / WORLD_DT_S) + 1):
            world.step(WORLD_DT_S)
            if step % stride_steps or step * WORLD_DT_S < t_min_s:
                continue
            snap = world.snapshot()
            for rsu_id, (rsu, rend) in renderers.items():
                labels = rend.labels(snap, MIN_VISIBLE_FRACTION, include_dropped=True)
                labels = [lb for lb in labels if lb.visible_fraction > 0]
                boxes = np.array([lb.bbox_px for lb in labels], np.float64).reshape(-1, 4)
                classes = np.array([lb.class_id for lb in labels], np.int64)
                small = np.minimum(boxes[:, 2] - boxes[:, 0], boxes[:, 3] - boxes[:, 1]) < min_box_px
                difficult = np.array([lb.visible_fraction < MIN_VISIBLE_FRACTION for lb in labels], bool) | small
                out.images.append(rend.render(snap, frame_index=int(round(snap.sim_time_s * rsu.camera.fps))))
                pos = {a.actor_id: (a.pos_x_m, a.pos_y_m) for a in snap.actors}
                cam = rsu.camera.centre_world
                rng_m = np.array([math.hypot(pos[lb.actor_id][0] - cam[0], pos[lb.actor_id][1] - cam[1])
                                  for lb in labels], np.float64)
                out.truths.append(FrameTruth(boxes, classes, difficult.reshape(-1), rng_m))
                out.names.append(f"{sc.name}_s{seed}_{rsu_id}_t{snap.sim_time_s:.2f}")
                if max_frames and len(out.images) >= max_frames:
                    return out
    return out


def detect_all(model_path: str | Path, images: list[np.ndarray], score_threshold: float = 0.01):
    """Runtime detections of every image: (Framework A outputs, Framework B outputs)."""
    det_a = OnnxDetector(model_path, score_threshold=score_threshold)
    det_b = OnnxDetector(model_path, score_threshold=score_threshold, class_map={0: 0, 1: 0})
    return [det_a.detect(im) for im in images], [det_b.detect(im) for im in images]


def evaluate(model_path: str | Path, data: HeldOutSet, score_threshold: float = 0.01, outputs=None) -> dict:
    """mAP@0.5 per class (Framework A: vehicle, ev) and of one 'vehicle' class (Framework B: every vehicle,
    score = objectness * max(p(vehicle), p(ev)), via ``class_map={0: 0, 1: 0}``). ``outputs``: the
    result of ``detect_all`` on ``data.images`` when already at hand."""
    res: dict = {"frames": len(data.images)}
    outs_a, outs_b = outputs if outputs is not None else detect_all(model_path, data.images, score_threshold)
    for cls, name in ((0, "vehicle"), (1, "ev")):
        dets = [(o.boxes[o.class_ids == cls], o.scores[o.class_ids == cls]) for o in outs_a]
        # a box of the other class is not ground truth for this one, but a detection on it is not penalised
        # twice in Framework A either: keep VOC's rule (other classes are simply absent)
        tr = [(t.boxes[t.classes == cls], t.difficult[t.classes == cls]) for t in data.truths]
        ap, n, rec = average_precision(dets, tr)
        res[f"ap50_{name}"], res[f"gt_{name}"], res[f"recall_{name}"] = ap, n, rec
    res["map50_framework_a"] = float(np.nanmean([res["ap50_vehicle"], res["ap50_ev"]]))
    ap, n, rec = average_precision([(o.boxes, o.scores) for o in outs_b],
                                   [(t.boxes, t.difficult) for t in data.truths])
    res["map50_all_vehicles"], res["gt_all_vehicles"], res["recall_all_vehicles"] = ap, n, rec
    return res


def cpu_latency(model_path: str | Path, images: list[np.ndarray], threads: int = 1, repeats: int = 1) -> dict:
    """Per-frame time of ``OnnxDetector.detect`` (letterbox + inference + decode + NMS), ``threads`` CPU
    threads: wall-clock, and this process's CPU time (the cost on one core when the machine is shared)."""
    det = OnnxDetector(model_path, intra_op_threads=threads, warmup_runs=3)
    times, cpu = [], []
    for _ in range(repeats):
        for im in images:
            t0, c0 = time.perf_counter(), time.process_time()
            det.detect(im)
            times.append(time.perf_counter() - t0)
            cpu.append(time.process_time() - c0)
    t = np.array(times) * 1e3
    return {"latency_ms_median": float(np.median(t)), "latency_ms_p90": float(np.percentile(t, 90)),
            "cpu_ms_mean": float(np.mean(cpu) * 1e3), "latency_frames": len(t), "threads": threads}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description="mAP@0.5 and CPU latency of a project-layout ONNX detector on "
                                            "held-out simulator renders, through rsu.detect.OnnxDetector.")
    p.add_argument("model", nargs="?", default="models/iea_det_tiny.onnx")
    p.add_argument("--scenario", default="rellis_ev_yield")
    p.add_argument("--seeds", type=int, nargs="+", default=list(HELD_OUT_SEEDS))
    p.add_argument("--stride-s", type=float, default=0.7)
    p.add_argument("--lighting", default=None, help="override the scenario's lighting (day, dusk, night)")
    p.add_argument("--max-range-m", type=float, nargs="+", default=[ZONE_M, 150.0, math.inf],
                   help="report with vehicles farther than this from the camera as difficult (default: the "
                        f"RSU's {ZONE_M:g} m zone, 150 m and every labelled vehicle)")
    p.add_argument("--min-box-px", type=float, nargs="+", default=[0.0],
                   help="also report with boxes whose shorter side (full-res px) is below this as difficult")
    p.add_argument("--json", action="store_true", help="last line: one JSON object of the figures")
    a = p.parse_args(argv)
    t0 = time.perf_counter()
    data = render_held_out(a.scenario, a.seeds, a.stride_s, a.lighting)
    print(f"rendered {len(data.images)} held-out frames of {a.scenario} seeds {a.seeds} "
          f"({time.perf_counter() - t0:.0f} s)", flush=True)
    figures: dict = {"model": str(a.model), "scenario": a.scenario, "seeds": a.seeds, "lighting": a.lighting}
    outputs = detect_all(a.model, data.images)
    for r in a.max_range_m:
        for m in a.min_box_px:
            res = evaluate(a.model, restrict(data, min_box_px=m, max_range_m=r), outputs=outputs)
            key = f"range_{r:g}_m" + (f"_min_box_px_{m:g}" if m > 0 else "")
            figures[key] = res
            print(f"{key}: " + ", ".join(f"{k} {v:.3f}" if isinstance(v, float) else f"{k} {v}"
                                         for k, v in res.items()), flush=True)
    lat = cpu_latency(a.model, data.images[:60])
    figures.update(lat)
    print(f"CPU latency (1 thread, OnnxDetector.detect): median {lat['latency_ms_median']:.1f} ms, "
          f"p90 {lat['latency_ms_p90']:.1f} ms wall-clock, {lat['cpu_ms_mean']:.1f} ms CPU time per frame "
          f"over {lat['latency_frames']} frames")
    if a.json:
        print(json.dumps(figures))
    return 0


def restrict(data: HeldOutSet, min_box_px: float = 0.0, max_range_m: float = math.inf) -> HeldOutSet:
    """The same frames with boxes whose shorter side is below ``min_box_px`` or whose vehicle is farther
    than ``max_range_m`` (horizontal, camera to vehicle centre) also marked difficult."""
    out = HeldOutSet(images=data.images, names=data.names)
    for t in data.truths:
        sides = np.minimum(t.boxes[:, 2] - t.boxes[:, 0], t.boxes[:, 3] - t.boxes[:, 1])
        far = t.range_m > max_range_m if t.range_m is not None else np.zeros(len(t.boxes), bool)
        out.truths.append(FrameTruth(t.boxes, t.classes, t.difficult | (sides < min_box_px) | far, t.range_m))
    return out


if __name__ == "__main__":
    sys.exit(main())
