"""Rebuild the project's models (``make models``): export the simulator's detection set, train the tiny
detector, export ``models/iea_det_tiny.onnx`` and evaluate it on held-out renders (figures for the card
``models/iea_det_tiny.md``). Needs the ``train`` extra (torch, onnx). Seeded; about 20 minutes on 1 CPU core.
"""

from __future__ import annotations

import argparse
import sys

from models import evaluate_detector, train_detector

DATA_DIR = "datasets/det_train"
EXPORT_ARGS = ["--frames", "2000", "--seed", "1", "--stride-s", "1.05"]
"""All five scenarios, lighting cycled per pass, 18 episodes x 4 cameras; ``val`` episodes are not used."""
TRAIN_ARGS = ["--iterations", "4000", "--batch", "12", "--seed", "0"]


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description="Export data, train and evaluate the project's detector.")
    p.add_argument("--data", default=DATA_DIR)
    p.add_argument("--out", default="models/iea_det_tiny.onnx")
    p.add_argument("--skip-eval", action="store_true")
    a = p.parse_args(argv)
    from sim.cli import main as sim_main

    rc = sim_main(["export-dataset", "--out", a.data, *EXPORT_ARGS, "--quiet"])  # resumes if already there
    if rc:
        return rc
    rc = train_detector.main(["--data", a.data, "--out", a.out, *TRAIN_ARGS])
    if rc or a.skip_eval:
        return rc
    return evaluate_detector.main([a.out, "--json"])


if __name__ == "__main__":
    sys.exit(main())
