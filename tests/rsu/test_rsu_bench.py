"""Smoke run of bench/rsu_bench.py --quick --json (renders a few seconds of simulator frames)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def test_rsu_bench_quick_json():
    proc = subprocess.run([sys.executable, str(ROOT / "bench" / "rsu_bench.py"), "--quick", "--json"],
                          capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr
    figures = json.loads(proc.stdout.strip().splitlines()[-1])
    assert figures["tracker_speedup_vs_reference"] > 1.0
    # the densities an RSU sees as well as the stress case, with the same tracks as the reference
    assert figures["tracker_speedup_min"] == min(figures[f"tracker_{n}_targets"]["speedup"] for n in (5, 10, 20, 100))
    assert figures["tracker_same_tracks"] is True
    assert 0.0 < figures["mota"] <= 1.0 and 0.0 < figures["idf1"] <= 1.0
    # fps and MOTA/IDF1 on simulator renders, for the project's detector (when built) and MotionDetector
    detectors = {"motion"} | ({"project"} if (ROOT / "models" / "iea_det_tiny.onnx").is_file() else set())
    assert set(figures["fps_end_to_end"]) >= detectors
    assert all(v > 0 for v in figures["fps_end_to_end"].values())
    assert set(figures["mot_by_detector"]) >= detectors
    assert figures["mot_by_detector"]["motion"]["gt"] > 0
    loc = figures["localisation_label_boxes"]
    assert loc["loc_err_60m_n"] > 0 and loc["loc_err_60m_median_m_transform"] < 0.5
