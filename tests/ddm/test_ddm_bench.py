"""Smoke test of bench/ddm_bench.py --quick (8 RSUs, 2 s of frames; a few seconds)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.timeout(60)
def test_bench_quick_prints_the_issue_keys_as_last_json_line():
    out = subprocess.run([sys.executable, str(ROOT / "bench" / "ddm_bench.py"), "--quick", "--json"], cwd=ROOT,
                         capture_output=True, text=True, timeout=60, check=True).stdout
    figures = json.loads(out.strip().splitlines()[-1])
    for key in ("updates_per_s", "decision_latency_p50_ms", "decision_latency_p99_ms", "updates_per_cpu_s",
                "alert_to_command_cpu_p50_ms", "alert_to_command_cpu_p99_ms"):
        assert figures[key] > 0
    assert figures["decisions"] > 0
