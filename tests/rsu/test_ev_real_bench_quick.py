"""``bench/ev_real_bench.py --quick``: the per-vehicle scoring of real clips end to end, as CI runs it (two short
clips: an elevated EV clip and a motorway CCTV clip with no EV). Skips without ../shared/data/real."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from tests.conftest import ROOT, require_shared


@pytest.mark.shared
@pytest.mark.slow
def test_quick_mode_ends_with_the_per_vehicle_figures():
    require_shared("data", "real", "yolox_nano", "yolox_nano.onnx")
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    out = subprocess.run([sys.executable, str(ROOT / "bench" / "ev_real_bench.py"), "--quick", "--json"],
                         capture_output=True, text=True, timeout=240, cwd=ROOT, env=env)
    assert out.returncode == 0, out.stderr
    f = json.loads(out.stdout.strip().splitlines()[-1])
    from bench.suite import BENCHES

    (bench,) = [b for b in BENCHES if b.name == "ev_real_bench"]
    assert [k for k in bench.figures if f.get(k) is None] == []  # the suite's key figures, filled
    for key in ("photo_precision", "photo_recall", "crop_ms", "alert_confidence_ece"):
        assert key in f, key
    assert f["clips_scored"] == 2 and f["clips_unlabelled"] == []
    assert f["evs_scorable"] == 1 and f["traffic_clips"] == 1 and f["traffic_video_s"] > 9.0
    assert set(f["by_viewpoint"]) == {"elevated"}
    assert f["photo_precision"] is None  # no photos in quick mode
