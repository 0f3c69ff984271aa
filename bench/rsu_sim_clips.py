"""Simulator clips for ``bench/rsu_bench.py``: renders of one camera with their ground truth (``Renderer.labels``,
for evaluation only, never seen by the pipeline), and the RSU's tracking and localisation scored on them."""

from __future__ import annotations

from bench._setup import REAL  # noqa: F401  first: one thread per numeric library, before numpy loads

# isort: split
from dataclasses import dataclass, replace

import numpy as np

from models.evaluate_detector import ZONE_M
from rsu.build import MOTION, PROJECT, PipelineConfig, build_detector, build_tracker
from rsu.detect import PROJECT_MODEL
from rsu.evaluate import MotEvaluator
from rsu.localize import GroundProjector, Localizer
from rsu.track.assoc import iou_matrix
from sim.camera_source import Frame, SimCamera
from sim.render.labels import MIN_VISIBLE_FRACTION
from sim.scenario import load_scenario
from sim.world import World

YOLOX = REAL / "yolox_nano" / "yolox_nano.onnx"
WORLD_DT_S = 0.05
WARMUP_S = 2.0
"""Frames in the first 2 s of a clip run through the pipeline but are not scored (MOG2 learns its
background in them; a fixed camera runs continuously)."""


@dataclass
class SimTruth:
    """Ground truth of one camera frame from ``Renderer.labels``: counted boxes (visible >= 30 %, vehicle
    centre within the RSU's zone) with integer ids, ignore boxes (the other labelled vehicles), and per
    counted box the vehicle centre (x, y), its distance from the camera and its visible fraction."""

    ids: np.ndarray
    boxes: np.ndarray
    ignore_boxes: np.ndarray
    centres_xy: np.ndarray
    range_m: np.ndarray
    visible: np.ndarray


@dataclass
class SimClip:
    name: str
    rsu_id: str
    frames: list[Frame]
    truths: list[SimTruth]


def render_sim_clip(scenario: str, rsu_id: str, seed: int, duration_s: float, zone_m: float = ZONE_M) -> SimClip:
    """One camera's frames at its own rate (every snapshot that starts a new camera frame, as
    ``SimCamera.read`` does) over ``duration_s`` of the scenario, with ground truth."""
    sc = load_scenario(scenario).with_overrides(seed=seed)
    world = World(sc)
    camera = SimCamera(sc.corridor, rsu_id, seed=seed)
    centre = camera.rsu.camera.centre_world
    frames, truths, last, id_of = [], [], -1, {}
    for _ in range(int(round(duration_s / WORLD_DT_S))):
        world.step(WORLD_DT_S)
        snap = world.snapshot()
        n = camera.frame_index(snap.sim_time_s)
        if n == last:
            continue
        last = n
        frames.append(camera.render(snap))
        pos = {a.actor_id: (a.pos_x_m, a.pos_y_m) for a in snap.actors}
        labels = [lb for lb in camera.renderer.labels(snap, include_dropped=True) if lb.visible_fraction > 0]
        xy = np.array([pos[lb.actor_id] for lb in labels], float).reshape(-1, 2)
        rng_m = np.hypot(xy[:, 0] - centre[0], xy[:, 1] - centre[1])
        vis = np.array([lb.visible_fraction for lb in labels], float)
        boxes = np.array([lb.bbox_px for lb in labels], float).reshape(-1, 4)
        counted = (vis >= MIN_VISIBLE_FRACTION) & (rng_m <= zone_m)
        ids = np.array([id_of.setdefault(lb.actor_id, len(id_of) + 1) for lb in labels], np.int64)
        truths.append(SimTruth(ids[counted], boxes[counted], boxes[~counted], xy[counted], rng_m[counted],
                               vis[counted]))
    return SimClip(f"{scenario}/s{seed}/{rsu_id}", rsu_id, frames, truths)


def sim_detectors() -> dict[str, PipelineConfig]:
    """The RSU pipelines measured on simulator renders (no EV classifier), one per detector that is here."""
    configs: dict[str, PipelineConfig] = {}
    if PROJECT_MODEL.is_file():
        configs["project"] = PipelineConfig(detector=PROJECT, ev_classifier=False)
    configs["motion"] = PipelineConfig(detector=MOTION, ev_classifier=False)
    if YOLOX.is_file():
        configs["yolox_nano"] = PipelineConfig(detector=str(YOLOX), ev_classifier=False)
    return configs


def beyond_zone(hyp_boxes: np.ndarray, counted_boxes: np.ndarray, camera, margin_m: float = 10.0) -> np.ndarray:
    """Hypotheses outside the evaluated region: matching no counted vehicle (IoU < 0.5) and standing
    (bottom-centre of the box back-projected to the road with the true camera) more than ``ZONE_M +
    margin_m`` from the camera, where no counted vehicle can be (a counted vehicle's centre is within
    ``ZONE_M``, its near edge nearer still). Tracks of far vehicles, which no RSU evaluates here."""
    if not len(hyp_boxes):
        return np.zeros(0, bool)
    uv = np.column_stack([(hyp_boxes[:, 0] + hyp_boxes[:, 2]) / 2, hyp_boxes[:, 3]])
    xy, valid = GroundProjector(camera).to_ground(uv)
    c = camera.centre_world
    with np.errstate(invalid="ignore"):
        far = ~valid | (np.hypot(xy[:, 0] - c[0], xy[:, 1] - c[1]) > ZONE_M + margin_m)
    if len(counted_boxes):
        far &= np.nan_to_num(iou_matrix(hyp_boxes, counted_boxes)).max(axis=1) < 0.5
    return far


def sim_mot(clips: list[SimClip], config: PipelineConfig, corridor) -> dict[str, float]:
    """MOTA/IDF1 (``rsu.evaluate.MotEvaluator``, IoU 0.5, ignore boxes as distractors) of detector ->
    ``FrameworkTracker('B')`` (the RSU defaults: max_age 1, min_hits 3, IoU 0.3) over the clips, and
    the localisation error of what the pipeline publishes (``Localizer.update``, both methods: world
    position of each track) against the vehicle centres, for tracks whose box matches (IoU >= 0.5) a
    counted vehicle 55-65 m from the camera."""
    ev = MotEvaluator()
    loc_err: dict[str, list[float]] = {"transform": [], "reference": []}
    out_of_zone = 0
    for n_clip, clip in enumerate(clips):
        id_offset = 1_000_000 * n_clip  # one evaluator for all clips: ids of different clips must not meet
        detector, tracker = build_detector(config, corridor, clip.rsu_id), build_tracker(config)
        localizers = {m: Localizer(corridor, clip.rsu_id, method=m) for m in loc_err}
        camera = corridor.rsu(clip.rsu_id).camera
        for frame, truth in zip(clip.frames, clip.truths, strict=True):
            det = detector.detect(frame.image)
            tracks = tracker.update(det)
            placed = {m: loc.update(tracks, frame.timestamp_s, det.boxes) for m, loc in localizers.items()}
            if frame.timestamp_s < WARMUP_S:
                continue
            keep = ~beyond_zone(tracks.boxes, truth.boxes, camera)
            out_of_zone += int((~keep).sum())
            ev.update(truth.ids + id_offset, truth.boxes, tracks.track_ids[keep] + id_offset, tracks.boxes[keep],
                      truth.ignore_boxes)
            near60 = np.flatnonzero(np.abs(truth.range_m - 60.0) <= 5.0)
            for method, table in placed.items():
                objs = table[table.localized]
                if not len(near60) or not len(objs):
                    continue
                boxes = np.asarray(objs.boxes, float)
                xy = np.asarray(objs.positions_m, float)
                iou = iou_matrix(truth.boxes[near60], boxes)
                best = iou.argmax(axis=1)
                ok = iou[np.arange(len(near60)), best] >= 0.5
                loc_err[method].extend(np.hypot(*(xy[best[ok]] - truth.centres_xy[near60[ok]]).T).tolist())
    out: dict[str, float] = dict(ev.result().as_dict())
    out["hyp_beyond_zone_not_scored"] = out_of_zone
    for method, errs in loc_err.items():
        out[f"loc_err_60m_median_m_{method}"] = float(np.median(errs)) if errs else float("nan")
        out[f"loc_err_60m_n_{method}"] = len(errs)
    return out


def sim_localisation_truth_boxes(clips: list[SimClip], corridor, pitch_error_deg: float = 0.15) -> dict[str, float]:
    """Localisation error of the label boxes themselves (the rendered visible part of each vehicle at
    least 90 % visible, 55-65 m from the camera): the localiser's own error, without the detector's.
    Also ray-plane with the camera pitch mis-set by ``pitch_error_deg`` (a mounting-angle estimate
    error; reference interpolation needs only the surveyed pairs)."""
    errs: dict[str, list[float]] = {"transform": [], "reference": [], "transform_pose_error": []}
    for clip in clips:
        rsu = corridor.rsu(clip.rsu_id)
        bad = replace(rsu, camera=replace(rsu.camera, pitch_rad=rsu.camera.pitch_rad + np.radians(pitch_error_deg)))
        locs = {"transform": Localizer(corridor, rsu), "reference": Localizer(corridor, rsu, method="reference"),
                "transform_pose_error": Localizer(corridor, bad)}
        for truth in clip.truths:
            sel = (np.abs(truth.range_m - 60.0) <= 5.0) & (truth.visible >= 0.9)
            if sel.any():
                for method, loc in locs.items():
                    xy, _, valid = loc.localize_boxes(truth.boxes[sel])
                    errs[method].extend(np.hypot(*(xy - truth.centres_xy[sel]).T)[valid].tolist())
    out: dict[str, float] = {"loc_err_60m_n": len(errs["transform"]), "pitch_error_deg": pitch_error_deg}
    for m, e in errs.items():
        out[f"loc_err_60m_median_m_{m}"] = float(np.median(e)) if e else float("nan")
        out[f"loc_err_60m_p90_m_{m}"] = float(np.percentile(e, 90)) if e else float("nan")
    return out


