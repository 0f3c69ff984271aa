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


def test_render_split_bench_prints_stages_and_the_geometry_free_bound():
    """bench/render_split_bench.py: per lighting, the frame's stages and the frame with its geometry's answers handed
    back (which draws the same frames, so it costs less than the full frame and more than nothing)."""
    r = subprocess.run([sys.executable, str(REPO / "bench" / "render_split_bench.py"), "--frames", "4", "--rounds", "1",
                        "--json"], capture_output=True, text=True, timeout=120, cwd=REPO)
    assert r.returncode == 0, r.stderr
    figures = json.loads(r.stdout.strip().splitlines()[-1])
    for lighting in ("day", "dusk", "night"):
        assert 0 < figures[f"without_geometry_ms_{lighting}"] < figures[f"render_ms_{lighting}"] * 1.5
        stages = figures[f"stage_ms_{lighting}"]
        assert {"pose_frame", "visible_polygons", "lamp_halos", "_expose_frame", "rest"} <= set(stages)
    assert "_draw_headlight_pool" in figures["stage_ms_night"] and "_draw_shadow" in figures["stage_ms_day"]
