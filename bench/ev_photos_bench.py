"""EV classification on real whole-scene photos: detect the vehicles first, then classify.

    python bench/ev_photos_bench.py [--folder ../shared/data/real/ev_images] [--json] [--quick]

Each photo of ``emergency_vehicle/`` (52 police cars, many with the light bar on) and
``non_emergency/`` (53 civilian cars) goes through the COCO YOLOX-Nano detector
(``../shared/data/real/yolox_nano``; car, motorcycle, bus, truck); the largest vehicle box, grown 10 %
upwards for a roof light bar, is classified by each shipped classifier (``models/ev_cnn.onnx``,
``models/ev_hsv8_gb.onnx``, both trained on simulator renders only) and by the single-frame lamp rule of
the RSU (a bright saturated red or blue lamp in the top band of the box, ``measure_lamps``). A photo
with no detected vehicle is predicted non-EV. Prints accuracy, precision, recall, F-measure (thesis
App. A) and ms per crop; with ``--json`` the last line is one JSON object of the figures.
"""

from __future__ import annotations

from bench._setup import REAL, ROOT  # noqa: F401  first: one thread per numeric library, before numpy loads

# isort: split
import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from rsu.build import PipelineConfig, build_detector  # noqa: E402
from rsu.classify.classifiers import load_classifier  # noqa: E402
from rsu.classify.evaluation import SCENE_CLASSES, evaluate_scenes, load_scene_crops  # noqa: E402
from rsu.classify.evidence_config import EvidenceConfig  # noqa: E402
from rsu.classify.lamps import measure_lamps  # noqa: E402
from rsu.classify.ravev import IMAGE_SUFFIXES  # noqa: E402

QUICK_PER_CLASS = 8
"""Photos of each class in a ``--quick`` run."""


class LampRule:
    """The RSU's single-frame lamp cue as a classifier: 1 when the top band holds a lit red or blue lamp."""

    name = "lamp-rule"
    feature = "lamps"

    def __init__(self, on_fraction: float = EvidenceConfig().lamp_on_fraction) -> None:
        self.on_fraction = on_fraction

    def predict(self, crops):
        return np.array([float(max(m.red, m.blue) >= self.on_fraction) for m in map(measure_lamps, crops)])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--folder", default=str(REAL / "ev_images"))
    ap.add_argument("--detector", default=str(REAL / "yolox_nano" / "yolox_nano.onnx"))
    ap.add_argument("--score-threshold", type=float, default=0.3)
    ap.add_argument("--cv", action="store_true",
                    help="also 5-fold cross-validate feature x classifier pairs fitted on the real crops (train extra)")
    ap.add_argument("--quick", action="store_true",
                    help=f"the first {QUICK_PER_CLASS} photos of each class only (a smoke run)")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    if not Path(args.folder).is_dir() or not Path(args.detector).is_file():
        print(f"ev_photos_bench: {args.folder} or {args.detector} absent", file=sys.stderr)
        return 2
    if not args.quick:
        return measure(args, Path(args.folder))
    with tempfile.TemporaryDirectory(prefix="ev_photos-") as tmp:
        return measure(args, first_photos(Path(args.folder), QUICK_PER_CLASS, Path(tmp)))


def first_photos(folder: Path, per_class: int, out: Path) -> Path:
    """A folder under ``out`` with the first ``per_class`` photos (by name) of each class folder of ``folder``
    (symbolic links): the same layout, fewer photos."""
    for d in sorted(p for p in folder.iterdir() if p.is_dir() and p.name in SCENE_CLASSES):
        (out / d.name).mkdir()
        for f in sorted(p for p in d.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)[:per_class]:
            (out / d.name / f.name).symlink_to(f.resolve())
    return out


def measure(args: argparse.Namespace, folder: Path) -> int:
    """The figures of the photos of ``folder`` (module docstring)."""
    t0 = time.perf_counter()
    det = build_detector(PipelineConfig(detector=str(args.detector), score_threshold=args.score_threshold))
    models = [load_classifier("cnn"), load_classifier("hsv8-gb"), LampRule()]
    scene_crops = load_scene_crops(folder, det)
    scores, counts = evaluate_scenes(folder, det, models, scene_crops=scene_crops)
    best = max(scores, key=lambda s: s.f_measure)
    cv = []
    if args.cv:
        from rsu.classify.evaluation import cross_validate_scenes

        cv = cross_validate_scenes(*scene_crops, ["hsv8_top", "colour_hist", "hog"],
                                   ["svm", "random_forest", "hist_gb", "logistic"])
    figures = dict(**counts, best=best.classifier, accuracy=best.accuracy, precision=best.precision,
                   recall=best.recall, f_measure=best.f_measure,
                   scores={s.classifier: dict(accuracy=s.accuracy, precision=s.precision, recall=s.recall,
                                              f_measure=s.f_measure, ms_per_crop=s.ms_per_crop) for s in scores},
                   cross_validated={f"{s.feature}+{s.classifier}": dict(accuracy=s.accuracy, precision=s.precision,
                                                                      recall=s.recall, f_measure=s.f_measure)
                                    for s in cv},
                   runtime_s=time.perf_counter() - t0)
    print(f"{counts['images']} photos ({counts['ev_images']} EV), a vehicle found in {counts['with_vehicle']}; "
          f"best by F-measure: {best.classifier} (accuracy {best.accuracy:.3f}, precision {best.precision:.3f}, "
          f"recall {best.recall:.3f})")
    if args.json:
        print(json.dumps(figures))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
