"""Rebuild the project's models (``make models``): export the simulator's detection sets, train the tiny
detector, export ``models/iea_det_tiny.onnx`` and evaluate it on held-out renders (figures for the card
``models/iea_det_tiny.md``). Needs the ``train`` extra (torch, onnx). Seeded; about 40 minutes on 1 CPU core.
"""

from __future__ import annotations

import argparse
import sys

from models import evaluate_detector, train_detector

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
    a = p.parse_args(argv)
    from sim.cli import main as sim_main

    for folder, args in EXPORTS.items():
        rc = sim_main(["export-dataset", "--out", folder, *args, "--quiet"])  # resumes if already there
        if rc:
            return rc
    rc = train_detector.main(["--data", *EXPORTS, "--out", a.out, *TRAIN_ARGS])
    if rc or a.skip_eval:
        return rc
    return evaluate_detector.main([a.out, "--json"])


if __name__ == "__main__":
    sys.exit(main())
