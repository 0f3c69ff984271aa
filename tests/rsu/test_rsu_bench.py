"""Smoke run of bench/rsu_bench.py --quick --json (a few seconds)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def test_rsu_bench_quick_json():
    proc = subprocess.run([sys.executable, str(ROOT / "bench" / "rsu_bench.py"), "--quick", "--json"],
                          capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr
    figures = json.loads(proc.stdout.strip().splitlines()[-1])
    assert figures["tracker_speedup_vs_reference"] > 1.0
    assert 0.0 < figures["mota"] <= 1.0 and 0.0 < figures["idf1"] <= 1.0
    if "fps_end_to_end" in figures:  # needs ../shared
        assert set(figures["fps_end_to_end"]) >= {"motion"}
        assert all(v > 0 for v in figures["fps_end_to_end"].values())
