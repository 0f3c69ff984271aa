"""Rebuild the project's models (``make models``): export the simulator's detection sets, train the tiny
detector, export ``models/iea_det_tiny.onnx`` and evaluate it on held-out renders (figures for the card
``models/iea_det_tiny.md``); then train the EV crop classifiers on the mixed export's crops
(``cls/``): ``models/ev_cnn.onnx`` (card ``models/ev_cnn.md``) and ``models/ev_hsv8_gb.onnx``. Needs the
``train`` extra (torch, onnx, scikit-learn, skl2onnx). Seeded; about 70 minutes on 1 CPU core.
"""

from __future__ import annotations

import argparse
import sys

from models import evaluate_detector, train_detector, train_ev_cnn, train_ev_features

EXPORTS = {
    "datasets/det_rellis_day": ["--frames", "3000", "--scenario", "rellis_ev_yield", "--no-vary-lighting",
                                "--seed", "3", "--stride-s", "0.7"],
    "datasets/det_train": ["--frames", "2000", "--seed", "1", "--stride-s", "1.05"],
}
"""The default scenario in its own (day) lighting, 18 episodes x 4 cameras (episode seeds 300009 + 7919 e + 11,
never a held-out seed), and all five scenarios with the lighting cycled per pass (18 episodes x 4 cameras).
Every 5th episode of each is ``val`` (not used)."""
TRAIN_ARGS = ["--iterations", "2500", "--batch", "12", "--seed", "0"]


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description="Export data, train and evaluate the project's detector.")
    p.add_argument("--out", default="models/iea_det_tiny.onnx")
    p.add_argument("--skip-eval", action="store_true")
    p.add_argument("--only", choices=["all", "detector", "ev"], default="all", help="which models to train")
    a = p.parse_args(argv)
    from sim.cli import main as sim_main

    for folder, args in EXPORTS.items():
        rc = sim_main(["export-dataset", "--out", folder, *args, "--quiet"])  # resumes if already there
        if rc:
            return rc
    crops = "datasets/det_train/cls"  # every scenario and lighting
    if a.only in ("all", "ev"):
        rc = train_ev_cnn.main(["--data", crops, "--out", "models/ev_cnn.onnx", "--seed", "0"]) or \
            train_ev_features.main(["--data", crops, "--out", "models/ev_hsv8_gb.onnx", "--seed", "0"])
        if rc or a.only == "ev":
            return rc
    rc = train_detector.main(["--data", *EXPORTS, "--out", a.out, *TRAIN_ARGS])
    if rc or a.skip_eval:
        return rc
    return evaluate_detector.main([a.out, "--json"])


if __name__ == "__main__":
    sys.exit(main())
