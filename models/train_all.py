"""Rebuild the project's models (``make models``): export the simulator's detection set, train the tiny
detector, export ``models/iea_det_tiny.onnx`` and evaluate it on held-out renders (figures for the card
``models/iea_det_tiny.md``); then train the EV crop classifiers on the same export's crops
(``cls/``): ``models/ev_cnn.onnx`` (card ``models/ev_cnn.md``) and ``models/ev_hsv8_gb.onnx``. Needs the
``train`` extra (torch, onnx, scikit-learn, skl2onnx). Seeded; about 30 minutes on 1 CPU core.
"""

from __future__ import annotations

import argparse
import sys

from models import evaluate_detector, train_detector, train_ev_cnn, train_ev_features

DATA_DIR = "datasets/det_train"
EXPORT_ARGS = ["--frames", "2000", "--seed", "1", "--stride-s", "1.05"]
"""All five scenarios, lighting cycled per pass, 18 episodes x 4 cameras; ``val`` episodes are not used."""
TRAIN_ARGS = ["--iterations", "4000", "--batch", "12", "--seed", "0"]


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description="Export data, train and evaluate the project's detector.")
    p.add_argument("--data", default=DATA_DIR)
    p.add_argument("--out", default="models/iea_det_tiny.onnx")
    p.add_argument("--skip-eval", action="store_true")
    p.add_argument("--only", choices=["all", "detector", "ev"], default="all", help="which models to train")
    a = p.parse_args(argv)
    from sim.cli import main as sim_main

    rc = sim_main(["export-dataset", "--out", a.data, *EXPORT_ARGS, "--quiet"])  # resumes if already there
    if rc:
        return rc
    if a.only in ("all", "ev"):
        rc = train_ev_cnn.main(["--data", f"{a.data}/cls", "--out", "models/ev_cnn.onnx", "--seed", "0"]) or \
            train_ev_features.main(["--data", f"{a.data}/cls", "--out", "models/ev_hsv8_gb.onnx", "--seed", "0"])
        if rc or a.only == "ev":
            return rc
    rc = train_detector.main(["--data", a.data, "--out", a.out, *TRAIN_ARGS])
    if rc or a.skip_eval:
        return rc
    return evaluate_detector.main([a.out, "--json"])


if __name__ == "__main__":
    sys.exit(main())
