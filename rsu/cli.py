"""``iea-rsu``: run one roadside unit on a video file, camera, stream, image folder or the simulator's camera."""

from __future__ import annotations

import argparse
import sys

import cv2

from protocol import metrics
from protocol.corridor import CorridorError
from protocol.logsetup import add_log_level_argument, configure_logging
from protocol.zenoh_transport import ZenohSettings
from rsu.build import PipelineConfig, ServiceOptions, run_rsu
from rsu.classify.evaluation import CLASSIFIERS
from rsu.frames import SourceError, SourceStalled
from rsu.localize import INTERPOLATIONS
from rsu.uplink import validate_uplink_bit_s


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="iea-rsu",
        description="Roadside unit: detect and track every vehicle (SORT), localise it on the corridor and "
                    "publish ObjectList every frame and Health at 1 Hz over Zenoh.",
        epilog="EV classifier comparison (thesis Table 2.2): iea-rsu eval-classifier DATASET (see its --help). "
               "Check a camera's EV recognition on a recorded clip: iea-rsu scan VIDEO (see its --help). "
               "example: iea-rsu --rsu rsu1 --source ../shared/data/real/traffic_videos/ambdet_video_3.mp4 "
               "--detector onnx --model ../shared/data/real/yolox_nano/yolox_nano.onnx --annotate out.mp4")
    ap.add_argument("--corridor", default=None, help="corridor TOML file (default deploy/corridors/rellis.toml)")
    ap.add_argument("--corridor-id", default=None, help="override the corridor id used in key expressions")
    ap.add_argument("--rsu", required=True, help="RSU id in the corridor file (its camera and calibration are used)")
    ap.add_argument("--source", required=True,
                    help="video file, camera index, rtsp://... or http://... URL, a folder of images, or 'sim': "
                         "this RSU's view rendered from the simulator's WorldSnapshot (iea-sim run)")
    ap.add_argument("--sim-seed", type=int, default=0, help="--source sim: seed of the camera noise")
    ap.add_argument("--fps", type=float, default=None, help="frame rate of an image folder (default: the camera's)")
    ap.add_argument("--realtime", action="store_true", help="play a video file at its own rate, dropping late frames")
    ap.add_argument("--read-timeout-s", type=float, default=5.0, help="a source silent this long is reported stalled")
    ap.add_argument("--max-stall-s", type=float, default=None, help="exit (code 3) after a stall this long")
    ap.add_argument("--queue-size", type=int, default=2, help="frames buffered from a live source (older dropped)")
    ap.add_argument("--max-frames", type=int, default=None, help="stop after this many frames")
    ap.add_argument("--detector", choices=["onnx", "project", "motion"], default="motion",
                    help="onnx: YOLOX-layout model (--model); project: the project's detector "
                         "(models/iea_det_tiny.onnx); motion: MOG2 background subtraction")
    ap.add_argument("--model", default=None, help="ONNX model for --detector onnx")
    ap.add_argument("--score-threshold", type=float, default=0.3)
    ap.add_argument("--providers", default=None,
                    help="onnxruntime providers, comma-separated, or 'auto' (default CPUExecutionProvider)")
    ap.add_argument("--threads", type=int, default=None,
                    help="CPU threads for the detector (onnxruntime intra-op) and OpenCV (default: all cores; the EV "
                         "classifiers: one); "
                         "use 1 when several RSUs share one machine (iea demo / iea up do)")
    ap.add_argument("--framework", choices=["A", "B"], default="B",
                    help="B: one class, track every vehicle (thesis 2.3); A: a tracker per class (thesis 2.2)")
    ap.add_argument("--max-age", type=int, default=1)
    ap.add_argument("--min-hits", type=int, default=3)
    ap.add_argument("--iou-threshold", type=float, default=0.3)
    ap.add_argument("--localization", choices=["transform", "reference"], default="transform",
                    help="transform: ray-plane back-projection; reference: interpolate the calibration pairs")
    ap.add_argument("--interpolation", choices=INTERPOLATIONS, default="homography+rbf")
    ap.add_argument("--ev-classifier", choices=["lamps", "none"], default="lamps",
                    help="lamps: per-track flashing light bar evidence (rsu.classify.ev), publishes EvAlert; "
                         "none: no EV classification")
    ap.add_argument("--hazards", choices=["static", "none"], default="static",
                    help="static: report static objects that appear in a lane (rsu.hazard, dual background) as "
                         "HazardAlert; none: no hazard detection")
    ap.add_argument("--hazard-background", metavar="IMAGE", default=None,
                    help="a frame of the empty road from this camera: the hazard detector starts from it instead of "
                         "learning the road over its first seconds (debris already there at start is then found)")
    ap.add_argument("--ev-crop-classifier", default="none",
                    help="per-crop EV probability fused into each track's evidence: none, cnn "
                         "(models/ev_cnn.onnx), hsv8-gb (models/ev_hsv8_gb.onnx) or PATH.onnx[:FEATURE]")
    ap.add_argument("--ev-body", default="default",
                    help="EV-body classifier trained on real vehicles: default (models/ev_body.onnx), "
                         "none, or PATH.onnx. It scores a track only while its lamps are lit, a few times a second; "
                         "a steady lit roof bar raises an alert only with a confident EV body")
    ap.add_argument("--whole-frame", action="store_true",
                    help="search the whole frame for vehicles; by default a detector of any input size (the "
                         "project's) letterboxes only the part of the frame where this RSU's zone of responsibility "
                         "lies (max_range_m + 15 m of road, from the corridor file's calibration; rsu.detect_roi)")
    ap.add_argument("--ev-box-gate", action="store_true",
                    help="no lamp measurement on boxes wider than one vehicle at their range (needs a calibrated "
                         "camera in the corridor file; rsu.classify.box_gate.SingleVehicleGate)")
    ap.add_argument("--annotate", metavar="OUT.mp4", default=None,
                    help="write the video with boxes, ids and labels over the corridor drawn through the camera "
                         "(lanes, road edges, coverage limit, 10 m grid: lines off the painted lanes mean the "
                         "camera moved; recommission with `iea calibrate`)")
    ap.add_argument("--camera-hz", type=float, default=None, metavar="HZ",
                    help="publish the annotated frame HZ times a second as JPEG on iea/<c>/rsu/<rsu>/camera/jpeg "
                         "for Foxglove and recordings (default: 2 from a simulated camera, 0 = off from a real one)")
    ap.add_argument("--uplink-kbit-s", type=float, default=None, metavar="KBIT_S",
                    help="the RSU's uplink (backhaul) rate: object lists and camera frames are thinned to half of it "
                         "so that EV and hazard alerts always find the link free (default: no budget; set it on "
                         "a cellular or radio backhaul of under 1 Mbit/s)")
    ap.add_argument("--key", metavar="PEM", default=None,
                    help="Ed25519 private key (from `iea keys new --role rsu`) that signs this RSU's EV and hazard alerts")
    ap.add_argument("--key-id", metavar="ID", default=None,
                    help="key id of --key (default: the corridor trust entry holding its public key)")
    add_log_level_argument(ap)
    ZenohSettings.add_arguments(ap)
    metrics.add_arguments(ap)
    return ap


def build_eval_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="iea-rsu eval-classifier",
        description="Thesis Table 2.2 rerun: fit every feature x classifier pair on DATASET/train and print "
                    "accuracy, precision, recall, F-measure (App. A) and ms per crop on DATASET/val; the shipped "
                    "ONNX classifiers (models/ev_cnn.onnx, models/ev_hsv8_gb.onnx) are scored too.",
        epilog="build a dataset from simulator renders: iea-sim export-dataset --out DIR --frames 2000 --seed 1 "
               "--stride-s 1.05, then: iea-rsu eval-classifier DIR/cls. Fitting needs the 'train' extra. Most pairs "
               "fit in seconds; gradient_boosting, hist_gb and adaboost on the 49,152-element pixel array take "
               "about 35, 11 and 6 min on one core (1,761 train crops; the whole table 63 min): "
               "leave them out with --features or --classifiers for a quick look.")
    ap.add_argument("dataset", help="RAVEV-layout folder: DATASET/{train,val}/{ev,non_ev}/*.png")
    ap.add_argument("--features", nargs="+", default=["hog", "colour_hist", "pixels", "hsv8", "hsv8_top"],
                    help="feature descriptors (rsu.classify.features.FEATURES)")
    ap.add_argument("--classifiers", nargs="+", default=list(CLASSIFIERS), choices=CLASSIFIERS)
    ap.add_argument("--max-train-per-class", type=int, default=1500,
                    help="seeded subset of each train class (bounds the fitting time); 0: all")
    ap.add_argument("--no-fit", action="store_true", help="score the shipped ONNX classifiers only")
    ap.add_argument("--json", action="store_true", help="last line: one JSON object with every score")
    return ap


def eval_main(argv: list[str]) -> int:
    import json

    from rsu.classify.evaluation import evaluate_table, format_table, scores_json

    args = build_eval_parser().parse_args(argv)
    try:
        scores = evaluate_table(args.dataset, args.features, args.classifiers, fit=not args.no_fit,
                                max_train_per_class=args.max_train_per_class or None,
                                warn=lambda text: print(f"iea-rsu eval-classifier: {text}", file=sys.stderr))
    except (FileNotFoundError, ValueError, RuntimeError) as exc:
        print(f"iea-rsu eval-classifier: {exc}", file=sys.stderr)
        return 2
    print(format_table(scores))
    if args.json:
        print(json.dumps({"scores": scores_json(scores)}))
    return 0


def build_scan_parser() -> argparse.ArgumentParser:
    from rsu.scan import DEFAULT_DETECTOR

    ap = argparse.ArgumentParser(
        prog="iea-rsu scan",
        description="Check a camera: run a recorded clip through the RSU's EV recognition (detector, SORT, "
                    "per-track lamp evidence and the EV-body classifier, EV alerts; nothing is published) and "
                    "report which vehicles were recognised as EVs, when, and on which cues (flash, alternation, "
                    "steady_bar, ev_body).",
        epilog="Prints a progress line every 2 s of video to stderr, then one line per EV track and a summary; "
               "--json: one JSON object per line (type track, alert, summary). Exit code 2 on a missing or "
               "unreadable video or model. example: iea-rsu scan "
               "../shared/data/real/ev_videos/street_ambulance_japan_red.mp4 --annotate out.mp4")
    ap.add_argument("video", help="recorded clip (any format OpenCV reads)")
    ap.add_argument("--json", action="store_true",
                    help="one JSON line per track that was ever candidate or confirmed, per alert (active / "
                         "cleared), then a summary line")
    ap.add_argument("--annotate", metavar="OUT.mp4", default=None,
                    help="write the clip with every track box (green vehicle, red EV), the lamp band where "
                         "lamps are measured (yellow) and labels: id, state, cues, body score")
    ap.add_argument("--model", default=str(DEFAULT_DETECTOR),
                    help="YOLOX-layout ONNX vehicle detector (default: the COCO YOLOX-Nano in "
                         "../shared/data/real/yolox_nano), or 'motion': background subtraction, for a fixed "
                         "camera without a model")
    ap.add_argument("--ev-body", default="default",
                    help="EV-body classifier: default (models/ev_body.onnx), none (lamps only), or PATH.onnx")
    ap.add_argument("--max-s", type=float, default=None, help="scan only the first S seconds of the clip")
    ap.add_argument("--score-threshold", type=float, default=None,
                    help="the detector's score threshold, in (0, 1) (default: the RSU's, 0.3); lower finds more of "
                         "a camera's vehicles, at the price of more false boxes")
    ap.add_argument("--threads", type=int, default=1, help="CPU threads for the detector and classifiers")
    ap.add_argument("--labels", metavar="LABELS.json", default=None,
                    help="score the alerts per vehicle against this clip's labels (format: rsu.scan_labels; "
                         "e.g. bench/labels/<clip>.json): EVs found, alert delays, wrong-vehicle alerts; "
                         "--json adds a line of type score before the summary")
    return ap


def scan_main(argv: list[str]) -> int:
    import json

    from rsu.scan import scan_video

    args = build_scan_parser().parse_args(argv)
    if args.threads < 1:
        print(f"iea-rsu scan: --threads must be >= 1, got {args.threads}", file=sys.stderr)
        return 2
    if args.score_threshold is not None and not 0.0 < args.score_threshold < 1.0:
        print(f"iea-rsu scan: --score-threshold must lie in (0, 1), got {args.score_threshold}", file=sys.stderr)
        return 2
    cv2.setNumThreads(args.threads)

    def progress(t_s: float, frames: int, ev_tracks: int) -> None:
        print(f"iea-rsu scan: {t_s:6.1f} s of video, {frames} frames, {ev_tracks} EV tracks", file=sys.stderr,
              flush=True)

    labels = None
    if args.labels is not None:
        from rsu.scan_labels import load_labels

        try:
            labels = load_labels(args.labels)
        except (FileNotFoundError, ValueError) as exc:
            print(f"iea-rsu scan: --labels: {exc}", file=sys.stderr)
            return 2
    try:
        result = scan_video(args.video, detector_model=args.model, body=args.ev_body, max_s=args.max_s,
                            annotate_path=args.annotate, threads=args.threads, progress=progress,
                            record_boxes=labels is not None, score_threshold=args.score_threshold)
    except (FileNotFoundError, ValueError, SourceError, SourceStalled) as exc:
        hint = " (--ev-body none scans on the lamps alone)" if "ev_body" in str(exc) else ""
        print(f"iea-rsu scan: {exc}{hint}", file=sys.stderr)
        return 2
    score_row = None
    if labels is not None:
        from dataclasses import replace

        from rsu.scan_labels import score_clip, summarize

        if args.max_s is not None:  # a partial scan is scored on the part scanned
            labels = replace(labels, duration_s=min(labels.duration_s, result.duration_s))

        score = score_clip(labels, result.track_boxes)
        figures = {k: v for k, v in summarize([score]).items() if k != "by_viewpoint"}
        score_row = dict(type="score", video=result.video, **figures, **score.to_json())
    if args.json:
        lines = result.json_lines()
        if score_row is not None:
            lines.insert(len(lines) - 1, json.dumps(score_row))
        print("\n".join(lines))
        return 0
    for t in result.ev_tracks:
        body = "-" if t.body_score is None else f"{t.body_score:.2f}"
        box = ",".join(f"{v:.0f}" for v in t.last_box)
        print(f"EV track {t.track_id}: seen {t.first_seen_s:.2f} s, alert {t.confirmed_s:.2f} s, cues "
              f"{'+'.join(t.cues) or '-'}, body {body}, last seen {t.last_seen_s:.2f} s at [{box}]")
    if score_row is not None:
        found = ", ".join(f"{e['name']} {_ev_outcome(e)}" for e in score_row["evs"]) or "no EV labelled"
        print(f"labels {args.labels}: {found}; wrong-vehicle alerts {len(score_row['wrong_tracks'])} "
              f"(tracks {score_row['wrong_tracks']})")
    s = result.summary()
    first = "-" if s["first_alert_s"] is None else f"{s['first_alert_s']:.2f} s"
    print(f"{result.video}: {s['duration_s']:.1f} s, {s['frames']} frames in {s['wall_s']:.1f} s; "
          f"{s['ev_tracks']} EV tracks (first alert {first}), {s['candidate_tracks']} candidates never confirmed; "
          f"detector {s['detector']}, EV body {s['body'] or 'none'}")
    return 0


def _ev_outcome(e: dict) -> str:
    if not e["scorable"]:
        return "not scorable"
    return "missed" if e["found_s"] is None else f"found {e['delay_s']:.2f} s after it could be"


def pipeline_config(args: argparse.Namespace) -> PipelineConfig:
    """The pipeline the options ask for (ValueError naming the option that is wrong)."""
    if args.detector == "onnx" and not args.model:
        raise ValueError("--detector onnx needs --model PATH")
    if args.threads is not None and args.threads < 1:
        raise ValueError(f"--threads must be >= 1, got {args.threads}")
    providers = args.providers if args.providers in (None, "auto") else tuple(args.providers.split(","))
    return PipelineConfig(
        detector=args.model if args.detector == "onnx" else args.detector, score_threshold=args.score_threshold,
        providers=providers, threads=args.threads, framework=args.framework, max_age=args.max_age,
        min_hits=args.min_hits, iou_threshold=args.iou_threshold, localization=args.localization,
        interpolation=args.interpolation, ev_classifier=args.ev_classifier == "lamps", ev_body=args.ev_body,
        ev_crop_classifier=args.ev_crop_classifier, ev_box_gate=args.ev_box_gate, detect_roi=not args.whole_frame,
        hazards=args.hazards == "static", hazard_background=args.hazard_background)


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    if argv and argv[0] == "eval-classifier":
        return eval_main(argv[1:])
    if argv and argv[0] == "scan":
        return scan_main(argv[1:])
    parser = build_parser()
    args = parser.parse_args(argv)
    configure_logging(parser, args)
    try:
        options = ServiceOptions(
            rsu_id=args.rsu, source=args.source, corridor_file=args.corridor, corridor_id=args.corridor_id,
            sim_seed=args.sim_seed, fps=args.fps, realtime=args.realtime, read_timeout_s=args.read_timeout_s,
            max_stall_s=args.max_stall_s, queue_size=args.queue_size, max_frames=args.max_frames,
            annotate=args.annotate, key=args.key, key_id=args.key_id, zenoh=ZenohSettings.from_args(args),
            camera_hz=args.camera_hz,
            uplink_bit_s=None if args.uplink_kbit_s is None else validate_uplink_bit_s(1000.0 * args.uplink_kbit_s))
        metrics.serve_from_args(args, "rsu", args.rsu)
        return run_rsu(options, pipeline_config(args))
    except (CorridorError, KeyError, ValueError, FileNotFoundError, SourceError, SourceStalled) as exc:
        print(f"iea-rsu: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    raise SystemExit(main())
