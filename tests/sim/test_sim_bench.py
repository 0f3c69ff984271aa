import json
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def test_sim_bench_quick_prints_json_figures_last():
    r = subprocess.run([sys.executable, str(REPO / "bench" / "sim_bench.py"), "--quick", "--json"],
                       capture_output=True, text=True, timeout=120, cwd=REPO)
    assert r.returncode == 0, r.stderr
    figures = json.loads(r.stdout.strip().splitlines()[-1])
    assert figures["render_fps_1280x720"] > 0 and figures["world_steps_per_s"] > 0
    assert figures["vehicles_in_view"] == 20
    assert 0 < figures["render_ms"] < figures["render_ms_reference"]  # the cached path is the cheaper one
    assert figures["render_ms_max"] == max(figures["render_ms"], figures["render_ms_dusk"], figures["render_ms_night"])
