"""EV identification on real footage and photos: clips, photos, the held-out split, cost per crop.

    python bench/ev_real_bench.py [--json] [--clips-only] [--max-s S] [--ev-body default|none|PATH]

Needs ``../shared/data/real`` (skips with a message, exit 0, when it is absent). Four measurements:

- **clips**: every clip of ``ev_videos`` (6 real EV clips) and ``traffic_videos`` (4 clips with no EV)
  through :func:`rsu.scan.scan_video`, as an RSU runs it: COCO YOLOX-Nano, SORT, per-track lamp evidence
  with the EV-body classifier, ``EvAlertManager``. Per clip: alerts (active onsets), first alert time,
  the tracks alerted and their cues. ``real_ev_clips_alerted``: EV clips with at least one alert (whether
  the alert is on the EV is for the annotated video to show: ``iea-rsu scan CLIP --annotate OUT.mp4``);
  ``real_traffic_false_alerts``: alerted tracks on the traffic clips (every one is false; a vehicle whose
  track is re-identified under a new id and alerted again counts twice);
- **photos**: the 105 whole-scene photos of ``ev_images``: YOLOX, the largest vehicle box grown upwards by
  the body model's ``above_fraction`` (0.25), classified by the body model at its own ``threshold``; a
  photo with no vehicle is predicted non-EV. Accuracy, precision, recall, F-measure (thesis App. A);
- **split**: the held-out ``test`` split of ``ev_train`` (``split_by_group``, by source photo: the
  training never saw it), crops as the RSU takes them (``crop_of(s, body.above_fraction)``), same metrics:
  ``split_*`` with the label review of ``models/ev_train_review.csv`` applied (wrong labels fixed, unusable
  photos out, the reviewed Open Images Car/Truck boxes in: harder negatives), ``split_published_*`` on the
  data as published;
- **crop_ms**: one crop through the body model on one core, median of ``--crop-calls`` single-crop calls.

With ``--json`` the last line is one JSON object: ``real_ev_clips_alerted``, ``real_ev_clips``,
``real_traffic_false_alerts``, ``photo_*``, ``split_*``, ``crop_ms``, ``per_clip``, ... (photo, split and
crop figures are null with ``--clips-only`` or ``--ev-body none``).

The clips are scanned with an image-only localiser (``rsu.scan``): the corridor localiser of ``rsu1`` drops what it
cannot place in its zone (most of the track-frames of a clip filmed elsewhere), so these figures count every track,
not only the ones another camera's geometry would report.
"""

from __future__ import annotations

from bench._setup import REAL, ROOT  # noqa: F401  first: one thread per numeric library, before numpy loads

# isort: split
import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from rsu.build import PipelineConfig, build_detector  # noqa: E402
from rsu.classify.body import load_body_classifier  # noqa: E402
from rsu.classify.evaluation import load_scene_crops, metrics, ms_per_crop  # noqa: E402
from rsu.classify.real_data import REVIEW_CSV, crop_of, load_ev_train, split_by_group  # noqa: E402
from rsu.detect import Detector  # noqa: E402
from rsu.scan import scan_video  # noqa: E402

YOLOX = REAL / "yolox_nano" / "yolox_nano.onnx"
VIDEO_SUFFIXES = (".mp4", ".avi", ".mov", ".mkv")


def clip_figures(path: Path, kind: str, body: str, max_s: float | None) -> dict:
    r = scan_video(path, detector_model=YOLOX, body=body, max_s=max_s, threads=1)
    ev = r.ev_tracks
    cues = sorted({c for t in ev for c in t.cues})
    out = dict(clip=path.name, kind=kind, duration_s=round(r.duration_s, 2), frames=r.frames,
               alerts=sum(a.state == "active" for a in r.alerts), first_alert_s=r.first_alert_s,
               tracks_alerted=[t.track_id for t in ev], cues=cues,
               tracks=[dict(track_id=t.track_id, first_seen_s=round(t.first_seen_s, 2),
                            alert_s=round(t.confirmed_s, 2), cues=list(t.cues),
                            body_score=None if t.body_score is None else round(t.body_score, 3)) for t in ev],
               candidate_tracks=len(r.tracks) - len(ev), ms_per_frame=round(1000 * r.wall_s / max(r.frames, 1), 2))
    first = "-" if r.first_alert_s is None else f"{r.first_alert_s:.2f} s"
    print(f"  {kind:7s} {path.name:40s} {r.duration_s:5.1f} s  alerts {out['alerts']:2d}  first {first:>7s}  "
          f"tracks {out['tracks_alerted']}  cues {'+'.join(cues) or '-'}  {out['ms_per_frame']:.1f} ms/frame",
          flush=True)
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


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--ev-body", default="default", help="default (models/ev_body.onnx), none, or PATH.onnx")
    ap.add_argument("--clips-only", action="store_true", help="only the clips (no photo, split or cost figures)")
    ap.add_argument("--max-s", type=float, default=None, help="scan only the first S seconds of each clip")
    ap.add_argument("--crop-calls", type=int, default=300, help="single-crop calls timed for crop_ms")
    ap.add_argument("--json", action="store_true", help="last line: one JSON object of the figures")
    args = ap.parse_args(argv)
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
    per_clip = []
    print(f"clips (YOLOX-Nano, EV body {args.ev_body}{'' if args.max_s is None else f', first {args.max_s} s'}):")
    for kind, folder in (("ev", REAL / "ev_videos"), ("traffic", REAL / "traffic_videos")):
        for path in sorted(p for p in folder.iterdir() if p.suffix.lower() in VIDEO_SUFFIXES):
            per_clip.append(clip_figures(path, kind, args.ev_body, args.max_s))
    ev_clips = [c for c in per_clip if c["kind"] == "ev"]
    figures = dict(real_ev_clips_alerted=sum(c["alerts"] > 0 for c in ev_clips), real_ev_clips=len(ev_clips),
                   real_traffic_false_alerts=sum(len(c["tracks_alerted"]) for c in per_clip if c["kind"] == "traffic"),
                   real_traffic_clips=len(per_clip) - len(ev_clips), ev_body=args.ev_body, max_s=args.max_s)
    print(f"EV clips alerted {figures['real_ev_clips_alerted']}/{figures['real_ev_clips']}, false alert tracks on "
          f"{figures['real_traffic_clips']} traffic clips: {figures['real_traffic_false_alerts']}")
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
