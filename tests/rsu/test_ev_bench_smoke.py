"""bench/ev_bench.py --quick runs and its last line is the JSON of the bench's figures."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.timeout(90)
def test_ev_bench_quick_json():
    r = subprocess.run([sys.executable, "bench/ev_bench.py", "--quick", "--json"], cwd=ROOT, capture_output=True,
                       text=True, timeout=80)
    assert r.returncode == 0, r.stderr[-2000:]
    figures = json.loads(r.stdout.strip().splitlines()[-1])
    assert {"track_recall", "false_alerts", "lights_on_to_alert_median_s", "decoy_lamp_vehicles",
            "false_alerts_on_decoy_lamps", "false_alerts_on_ev_box"} <= set(figures)
    kinds = {"hazard", "turn_signal", "beacon", "led_strip", "brake_lights"}
    assert set(figures["decoy_lamp_modes"]) == set(figures["false_alerts_on_decoy_modes"]) == kinds
    assert figures["track_recall"] is not None and figures["track_recall"] > 0
    assert figures["lights_on_to_alert_median_s"] is not None and figures["lights_on_to_alert_median_s"] < 2.0
