"""EV recognition on real footage, scored per vehicle against labels, and on photos: the held-out split, cost per crop.

    python bench/ev_real_bench.py [--json] [--quick] [--clips-only] [--split tune|held_out|all] [--clips A,B]
                                  [--scans DIR [--rescore]] [--detections DIR]
                                  [--max-s S] [--ev-body default|none|PATH] [--score-threshold T]

Needs ``../shared/data/real`` (skips with a message, exit 0, when it is absent). Four measurements:

- **clips**: every clip of ``ev_videos`` and ``traffic_videos`` through :func:`rsu.scan.scan_video`, as an
  RSU runs it (COCO YOLOX-Nano, SORT, per-track lamp evidence with the lamp-state and EV-body models,
  ``EvAlertManager``), scored per vehicle against its label file ``bench/labels/<clip>.json``
  (:mod:`rsu.scan_labels`): ``ev_recall`` (labelled EVs lit and >= 40 px wide for >= 1 s that an alerted
  track overlapping them, IoU >= 0.3, found while lit), ``alert_delay_median_s`` / ``alert_delay_max_s`` (from
  the first such frame to that alert), ``wrong_vehicle_alerts`` (alerted tracks on no EV, EV clips),
  ``traffic_false_alerts`` and ``traffic_false_alerts_per_hour`` (alerted tracks on the clips with no EV, over
  ``traffic_video_s``), each also per viewpoint under ``by_viewpoint``, and per clip;
  ``real_ev_clips_alerted`` (EV clips with any alert) as before;
- **photos**: the 105 whole-scene photos of ``ev_images``: YOLOX, the largest vehicle box grown upwards by
  the body model's ``above_fraction`` (0.25), classified by the body model at its own ``threshold``; a
  photo with no vehicle is predicted non-EV. Accuracy, precision, recall, F-measure (thesis App. A);
- **split**: the held-out ``test`` split of ``ev_train`` (``split_by_group``, by source photo: the
  training never saw it), crops as the RSU takes them (``crop_of(s, body.above_fraction)``), same metrics:
  ``split_*`` with the label review of ``models/ev_train_review.csv`` applied (wrong labels fixed, unusable
  photos out, the reviewed Open Images Car/Truck boxes in: harder negatives), ``split_published_*`` on the
  data as published;
- **crop_ms**: one crop through the body model on one core, median of ``--crop-calls`` single-crop calls.

The clips are split once into those that may tune the recogniser (:data:`TUNE_CLIPS`) and those held out
(:data:`HELD_OUT_CLIPS`); ``--split`` scores one side (``tune_*`` / ``held_out_*`` figures are reported
either way with ``--split all``). Clips of the same scene are on the same side. ``--quick``: two short
clips (one EV, one traffic) and no photos: a CI smoke test of the whole path, in about 20 s.

With ``--json`` the last line is one JSON object: ``ev_recall``, ``alert_delay_median_s``,
``alert_delay_max_s``, ``wrong_vehicle_alerts``, ``traffic_false_alerts``, ``traffic_video_s``,
``by_viewpoint``, ``alert_confidence_ece`` (``tune_`` / ``held_out_``), ``photo_precision``, ``photo_recall``, ``split_*``, ``crop_ms``, ``per_clip``, ... (photo,
split and crop figures are null with ``--clips-only``, ``--quick`` or ``--ev-body none``).

The clips are scanned with an image-only localiser (``rsu.scan``): the corridor localiser of ``rsu1`` drops what it
cannot place in its zone (most of the track-frames of a clip filmed elsewhere), so these figures count every track,
not only the ones another camera's geometry would report.
"""

from __future__ import annotations

from bench._setup import REAL, ROOT  # noqa: F401  first: one thread per numeric library, before numpy loads

# isort: split
import argparse  # noqa: E402
import dataclasses  # noqa: E402
import json  # noqa: E402
import pickle  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from rsu.build import PipelineConfig, build_detector  # noqa: E402
from rsu.classify.body import load_body_classifier  # noqa: E402
from rsu.classify.confidence import expected_calibration_error  # noqa: E402
from rsu.classify.evaluation import load_scene_crops, metrics, ms_per_crop  # noqa: E402
from rsu.classify.real_data import REVIEW_CSV, crop_of, load_ev_train, split_by_group  # noqa: E402
from rsu.detect import Detector  # noqa: E402
from rsu.scan import scan_video  # noqa: E402
from rsu.scan_labels import TUNING_TRAFFIC_CLIPS, LabelError, load_labels, score_clip, summarize  # noqa: E402

YOLOX = REAL / "yolox_nano" / "yolox_nano.onnx"
VIDEO_SUFFIXES = (".mp4", ".avi", ".mov", ".mkv")
LABELS = ROOT / "bench" / "labels"
TUNE_CLIPS = (
    "closeup_police_lightbar_cycle", "elevated_police_nyc_redbars", "handheld_ambulance_florence_blue",
    "handheld_night_fire_engines", "incar_night_ambulance_ahead_blue", "india_ambulance_police_escort",
    "news_ambulances_australia_redblue", "street_ambulance_japan_red",
    "night_ambulance_india_blue", "roadside_night_ambulance_india_redblue", "elevated_day_ambulance_japan_red",
    *TUNING_TRAFFIC_CLIPS,
)
"""Clips a threshold of the recogniser may be set on: the escort, Japanese street, NYC and Florence clips set the
light-bar colour test and the strong-flash rule; the Indian night scene (two clips of one scene) set how far a
confirmed EV's lamps light the vehicles beside it (``TrackEvClassifier.glow_reach_share``); the footbridge clip
of the Japanese ambulance turned down a rule that read a track's flashes only on the frames after its lamps may
have been another vehicle's (its ambulance, held back beside a wrongly confirmed van, was then never found); the
alerts of all of them fit ``EvAlert.confidence`` (``bench/fit_alert_confidence.py``, :data:`rsu.classify.confidence.DEFAULT_MODEL`)."""
HELD_OUT_CLIPS = (
    "handheld_day_ambulance_blue", "roadside_ambulance_yellow",
    "ambdet_video_4", "embankment_day_dual_carriageway", "haarcascades_video2", "overpass_day_highway",
)
"""Clips nothing is set on: they measure. ambdet_video_4 and haarcascades_video2 are one motorway camera: the pair is
on one side."""
QUICK_CLIPS = ("elevated_day_ambulance_japan_red", "ambdet_video_4")


def clip_figures(path: Path, kind: str, body: str, max_s: float | None, scans: Path | None = None,
                 rescore: bool = False, detections: Path | None = None,
                 score_threshold: float | None = None) -> tuple[dict, object]:
    """One clip's scan and, where it has a label file, its per-vehicle score (None without one). ``scans``: a
    folder where each clip's scan is kept (``<stem>.pkl``; ``<stem>-score<T>.pkl`` at another detector threshold);
    ``rescore``: read it from there instead of scanning (scores again against the labels as they are now); ``detections``: a folder where each clip's detector output is
    kept and replayed (``rsu.scan.scan_video``'s ``detections_dir``): the recogniser runs again, the detector not;
    ``score_threshold``: the detector's (default: the RSU's)."""
    tag = "" if score_threshold is None else f"-score{score_threshold:g}"
    kept = None if scans is None else scans / f"{path.stem}{tag}.pkl"
    if rescore:
        if kept is None or not kept.is_file():
            raise FileNotFoundError(f"--rescore: no kept scan {kept} (run once with --scans {scans} first)")
        r = pickle.loads(kept.read_bytes())
    else:
        r = scan_video(path, detector_model=YOLOX, body=body, max_s=max_s, threads=1, record_boxes=True,
                       detections_dir=detections, score_threshold=score_threshold)
        if kept is not None:
            kept.parent.mkdir(parents=True, exist_ok=True)
            kept.write_bytes(pickle.dumps(r))
    ev = r.ev_tracks
    cues = sorted({c for t in ev for c in t.cues})
    out = dict(clip=path.name, kind=kind, duration_s=round(r.duration_s, 2), frames=r.frames,
               alerts=sum(a.state == "active" for a in r.alerts), first_alert_s=r.first_alert_s,
               tracks_alerted=[t.track_id for t in ev], cues=cues,
               tracks=[dict(track_id=t.track_id, first_seen_s=round(t.first_seen_s, 2),
                            alert_s=round(t.confirmed_s, 2), cues=list(t.cues),
                            body_score=None if t.body_score is None else round(t.body_score, 3)) for t in ev],
               candidate_tracks=len(r.tracks) - len(ev), ms_per_frame=round(1000 * r.wall_s / max(r.frames, 1), 2))
    score = None
    label_file = LABELS / f"{path.stem}.json"
    if label_file.is_file():
        labels = load_labels(label_file)
        if max_s is not None:
            labels = dataclasses.replace(labels, duration_s=min(labels.duration_s, r.duration_s))
        score = score_clip(labels, r.track_boxes)
        out["score"] = score.to_json()
        out["alert_rows"] = alert_rows(r, score)
    found = "-" if score is None else " ".join(
        f"{e.name}:{'-' if not e.scorable else (f'MISS(tracked {e.tracked_share:.0%})' if e.found_s is None else f'{e.delay_s:.1f}s')}"
        for e in score.evs) or "no EV"
    wrong = "-" if score is None else len(score.wrong_tracks)
    first = "-" if r.first_alert_s is None else f"{r.first_alert_s:.2f} s"
    print(f"  {kind:7s} {path.name:42s} {r.duration_s:5.1f} s  alerts {out['alerts']:2d}  first {first:>7s}  "
          f"found {found}  wrong {wrong}  cues {'+'.join(cues) or '-'}  {out['ms_per_frame']:.1f} ms/frame",
          flush=True)
    return out, score


def alert_rows(r, score) -> list[dict]:
    """Each alert onset with what it rested on (cues, body score, box width), the confidence the RSU gave it and
    whether it was right (its track on a labelled EV): the data of ``bench/fit_alert_confidence.py``."""
    rows = []
    for a in r.alerts:
        if a.state != "active":
            continue
        box = next((b for b in r.track_boxes.get(a.track_id, []) if abs(b[0] - a.t_s) < 1e-6), None)
        rows.append(dict(track_id=a.track_id, t_s=round(a.t_s, 3), cues=list(a.cues),
                         body_score=None if a.body_score is None else round(a.body_score, 3),
                         width_px=None if box is None else round(box[3] - box[1], 1),
                         confidence=None if a.confidence is None else round(a.confidence, 3),
                         right=a.track_id in score.on_ev_tracks))
    return rows


def clip_paths(split: str, names: list[str] | None, quick: bool) -> list[tuple[str, Path]]:
    """(kind, path) of the clips to scan, in folder then name order."""
    wanted = set(QUICK_CLIPS) if quick else set(names) if names else None
    if wanted is None and split != "all":
        wanted = set(TUNE_CLIPS if split == "tune" else HELD_OUT_CLIPS)
    out = []
    for kind, folder in (("ev", REAL / "ev_videos"), ("traffic", REAL / "traffic_videos")):
        for path in sorted(p for p in folder.iterdir() if p.suffix.lower() in VIDEO_SUFFIXES):
            if wanted is None or path.stem in wanted or path.name in wanted:
                out.append((kind, path))
    return out


def photo_figures(folder: Path, detector: Detector, body) -> dict:
    """Largest vehicle of each whole-scene photo, grown upwards as the RSU crops, through the body model."""
    crops, labels = load_scene_crops(folder, detector, above_fraction=body.above_fraction)
    probs = np.array([0.0 if c is None else float(body.predict([c])[0]) for c in crops])
    acc, p, r, f = metrics(labels, probs, body.threshold)
    return dict(photo_images=len(labels), photo_ev_images=int(labels.sum()),
                photo_with_vehicle=sum(c is not None for c in crops),
                photo_accuracy=acc, photo_precision=p, photo_recall=r, photo_f_measure=f)


def split_figures(root: Path, body, crop_calls: int) -> dict:
    """The held-out ``test`` split of ev_train through the body model, with the label review applied
    (``split_*``, :mod:`rsu.classify.real_data`) and as published (``split_published_*``), and the cost of one crop."""
    out = {}
    for prefix, review in (("split_published", None), ("split", REVIEW_CSV)):
        crops, labels = [], []
        for s in split_by_group(load_ev_train(root, review=review))["test"]:
            c = crop_of(s, body.above_fraction)
            if c is not None:
                crops.append(c)
                labels.append(s.label)
        prob = np.concatenate([body.predict(crops[i:i + 32]) for i in range(0, len(crops), 32)])
        acc, p, r, f = metrics(np.array(labels), prob, body.threshold)
        out.update({f"{prefix}_crops": len(crops), f"{prefix}_ev_crops": int(sum(labels)), f"{prefix}_accuracy": acc,
                    f"{prefix}_precision": p, f"{prefix}_recall": r, f"{prefix}_f_measure": f})
    return dict(out, crop_ms=ms_per_crop(body, crops, crop_calls), crop_calls=crop_calls)


def confidence_figures(per_clip: list[dict]) -> dict:
    """Expected calibration error of ``EvAlert.confidence`` over the alerts of the clips scanned (all, tuning,
    held-out): the model of :mod:`rsu.classify.confidence` was fitted on the tuning clips' alerts."""
    out = {}
    for prefix, names in (("", None), ("tune_", TUNE_CLIPS), ("held_out_", HELD_OUT_CLIPS)):
        rows = [a for c in per_clip if names is None or Path(c["clip"]).stem in names for a in c.get("alert_rows", [])
                if a["confidence"] is not None]
        ece = expected_calibration_error([a["confidence"] for a in rows], [int(a["right"]) for a in rows])
        out[f"{prefix}alert_confidence_ece"] = None if ece is None else round(ece, 3)
        out[f"{prefix}alerts_scored"] = len(rows)
    return out


def print_scores(f: dict) -> None:
    def line(name: str, g: dict) -> str:
        rec = "-" if g["ev_recall"] is None else f"{g['ev_recall']:.2f}"
        med = "-" if g["alert_delay_median_s"] is None else f"{g['alert_delay_median_s']:.2f}"
        mx = "-" if g["alert_delay_max_s"] is None else f"{g['alert_delay_max_s']:.2f}"
        return (f"  {name:10s} EVs {g['evs_found']}/{g['evs_scorable']} (recall {rec}), delay median {med} s "
                f"max {mx} s, wrong-vehicle alerts {g['wrong_vehicle_alerts']}, traffic false alerts "
                f"{g['traffic_false_alerts']} in {g['traffic_video_s']:.0f} s")
    print("per-vehicle scores:")
    print(line("all", f))
    for vp, g in f["by_viewpoint"].items():
        print(line(vp, g))
    print(f"  EvAlert.confidence ECE {f['alert_confidence_ece']} over {f['alerts_scored']} alerts (tuning "
          f"{f['tune_alert_confidence_ece']}, held-out {f['held_out_alert_confidence_ece']})")
    for side in ("tune", "held_out"):
        if f"{side}_ev_recall" in f:
            print(line(side, {k[len(side) + 1:]: v for k, v in f.items() if k.startswith(side + "_")}))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--ev-body", default="default", help="default (models/ev_body.onnx), none, or PATH.onnx")
    ap.add_argument("--clips-only", action="store_true", help="only the clips (no photo, split or cost figures)")
    ap.add_argument("--max-s", type=float, default=None, help="scan only the first S seconds of each clip")
    ap.add_argument("--quick", action="store_true",
                    help=f"smoke test: only {' and '.join(QUICK_CLIPS)}, no photos (implies --clips-only)")
    ap.add_argument("--split", choices=("all", "tune", "held_out"), default="all",
                    help="score the tuning clips, the held-out clips, or all (default)")
    ap.add_argument("--clips", default=None, help="comma-separated clip names (stems) to scan instead")
    ap.add_argument("--scans", type=Path, default=None, help="keep each clip's scan in this folder (a cache)")
    ap.add_argument("--detections", type=Path, default=None,
                    help="keep each clip's detector output in this folder and replay it (keyed by video, model and "
                         "detector code): recogniser changes re-run without the detector")
    ap.add_argument("--rescore", action="store_true",
                    help="score the scans kept in --scans against the labels as they are now, without scanning")
    ap.add_argument("--score-threshold", type=float, default=None,
                    help="the detector's score threshold on the clips, in (0, 1) (default: the RSU's, 0.3)")
    ap.add_argument("--crop-calls", type=int, default=300, help="single-crop calls timed for crop_ms")
    ap.add_argument("--json", action="store_true", help="last line: one JSON object of the figures")
    args = ap.parse_args(argv)
    if args.score_threshold is not None and not 0.0 < args.score_threshold < 1.0:
        ap.error(f"--score-threshold must lie in (0, 1), got {args.score_threshold}")
    if not REAL.is_dir() or not YOLOX.is_file():
        reason = f"{REAL} or {YOLOX} absent (../shared/data/real not beside the repository): nothing to measure"
        print(f"ev_real_bench: skipped: {reason}")
        if args.json:
            print(json.dumps({"skipped": reason}))
        return 0
    t0 = time.perf_counter()
    try:
        body = load_body_classifier(args.ev_body, threads=1)
    except (FileNotFoundError, ValueError) as exc:
        print(f"ev_real_bench: {exc} (--ev-body none measures the lamps alone)", file=sys.stderr)
        return 2
    per_clip, scores = [], []
    paths = clip_paths(args.split, args.clips.split(",") if args.clips else None, args.quick)
    if not paths:
        print(f"ev_real_bench: no clip matches --clips {args.clips}", file=sys.stderr)
        return 2
    print(f"clips (YOLOX-Nano, EV body {args.ev_body}{'' if args.max_s is None else f', first {args.max_s} s'}):")
    try:
        for kind, path in paths:
            out, score = clip_figures(path, kind, args.ev_body, args.max_s, args.scans, args.rescore,
                                       args.detections, args.score_threshold)
            per_clip.append(out)
            if score is not None:
                scores.append(score)
    except (LabelError, FileNotFoundError) as exc:
        print(f"ev_real_bench: {exc}", file=sys.stderr)
        return 2
    ev_clips = [c for c in per_clip if c["kind"] == "ev"]
    figures = dict(real_ev_clips_alerted=sum(c["alerts"] > 0 for c in ev_clips), real_ev_clips=len(ev_clips),
                   real_traffic_clips=len(per_clip) - len(ev_clips), ev_body=args.ev_body, max_s=args.max_s,
                   score_threshold=args.score_threshold or PipelineConfig().score_threshold,
                   split=args.split if not (args.quick or args.clips) else None,
                   clips_scored=len(scores), clips_unlabelled=[c["clip"] for c in per_clip if "score" not in c])
    figures.update(summarize(scores))
    if args.split == "all" and not (args.quick or args.clips):
        for side, names in (("tune", TUNE_CLIPS), ("held_out", HELD_OUT_CLIPS)):
            sub = summarize([s for s in scores if Path(s.clip).stem in names])
            figures.update({f"{side}_{k}": v for k, v in sub.items() if k != "by_viewpoint"})
    figures.update(confidence_figures(per_clip))
    print_scores(figures)
    if args.quick:
        args.clips_only = True
    for key in ("photo_precision", "photo_recall", "split_precision", "split_recall", "crop_ms"):
        figures[key] = None
    if body is not None and not args.clips_only:
        figures.update(threshold=body.threshold, above_fraction=body.above_fraction)
        det = build_detector(PipelineConfig(detector=str(YOLOX)))
        figures.update(photo_figures(REAL / "ev_images", det, body))
        print(f"photos: {figures['photo_images']} ({figures['photo_ev_images']} EV), a vehicle in "
              f"{figures['photo_with_vehicle']}: accuracy {figures['photo_accuracy']:.3f}, precision "
              f"{figures['photo_precision']:.3f}, recall {figures['photo_recall']:.3f}, F {figures['photo_f_measure']:.3f}")
        figures.update(split_figures(REAL / "ev_train", body, args.crop_calls))
        for prefix, what in (("split_published", "as published"), ("split", "label review applied")):
            print(f"held-out split, {what}: {figures[prefix + '_crops']} crops ({figures[prefix + '_ev_crops']} EV): "
                  f"accuracy {figures[prefix + '_accuracy']:.3f}, precision {figures[prefix + '_precision']:.3f}, "
                  f"recall {figures[prefix + '_recall']:.3f}, F {figures[prefix + '_f_measure']:.3f}")
        print(f"{figures['crop_ms']:.2f} ms per crop (one core, median of {args.crop_calls})")
    figures.update(per_clip=per_clip, runtime_s=round(time.perf_counter() - t0, 1))
    if args.json:
        print(json.dumps(figures))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
