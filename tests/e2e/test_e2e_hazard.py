"""End to end, lockstep: hazard_in_lane on sim renders -> RSU hazard detection -> HazardAlert ->
DDM hazard policy -> PathSwitchCommand -> vehicle controller on the plant; the AV passes the debris with
>= 1 m lateral clearance (or stops before it). Runs bench/hazard_bench.py's lockstep, one RSU, 10 s."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def _bench():
    spec = importlib.util.spec_from_file_location("hazard_bench", ROOT / "bench" / "hazard_bench.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod  # dataclasses look their module up
    spec.loader.exec_module(mod)
    return mod


@pytest.mark.timeout(180)
def test_hazard_in_lane_end_to_end_clearance():
    r = _bench().run_one("hazard_in_lane", 102, end_to_end=True, duration_s=10.0, rsu_ids=["rsu3"],
                         min_visible_s=2.0, match_m=2.5)
    # perception: rsu3 finds both objects (box, rock) in lane 1 and reports nothing else
    assert r["instances"] == 2 and r["found"] == 2, r["missed"]
    assert r["false_alarms"] == 0, r["false_detail"]
    # decision + control: a lane change around them, then back to cruise
    manoeuvres = [m for _cid, m in r["commands"]]
    assert "lane_change" in manoeuvres and manoeuvres[-1] == "resume", manoeuvres
    # outcome: passed both with the clearance asked, no contact, and drove on
    assert r["collisions"] == 0
    assert r["passed"] == 2 and r["min_clearance_m"] >= 1.0, r
    assert r["av_final_x_m"] > 130.0 and r["av_final_speed_mps"] > 8.0
