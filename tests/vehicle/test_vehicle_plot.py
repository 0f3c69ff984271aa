"""Run folders, the report figures (PNG) and the command-line entry points."""

import json
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np

from vehicle.cli import main
from vehicle.lockstep import field_test_scenario, run_scenario
from vehicle.plot import plot_run
from vehicle.record import read_run, write_run

ROOT = Path(__file__).resolve().parents[2]


def test_run_folder_round_trip_and_figures(tmp_path):
    r = run_scenario(field_test_scenario(13.4))
    write_run(tmp_path, r.record)
    cols, paths, meta = read_run(tmp_path)
    assert len(cols["t_s"]) == len(r.record.rows) and len(paths) == 2
    assert meta["metrics"]["completed"] and meta["events"][0]["event"] == "command"
    header = (tmp_path / "run.csv").read_text().splitlines()[0]
    assert header.startswith("t_s,x_m,y_m")
    written = plot_run(tmp_path)
    assert {p.name for p in written} == {"path.png", "speed.png", "lateral_error.png", "yaw_error.png",
                                         "yaw_rate_error.png"}
    for p in written:
        img = cv2.imread(str(p))
        assert img is not None and img.shape == (560, 1000, 3)
        assert (img < 250).any(axis=2).mean() > 0.02  # something was drawn
    # the vehicle trace (blue-ish) appears on the path figure
    img = cv2.imread(str(tmp_path / "path.png")).astype(int)
    assert np.count_nonzero((img[:, :, 0] > 150) & (img[:, :, 2] < 100)) > 300


def test_cli_lockstep_and_plot(tmp_path, capsys):
    assert main(["lockstep", "--out", str(tmp_path / "r"), "--speed", "13.4"]) == 0
    metrics = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert metrics["completed"] and metrics["max_lateral_error_m"] < 0.25
    assert main(["plot", str(tmp_path / "r"), "--out", str(tmp_path / "png")]) == 0
    assert (tmp_path / "png" / "lateral_error.png").is_file()
    assert main(["plot", str(tmp_path / "nothing")]) == 2


def test_cli_help_and_bad_vehicle():
    out = subprocess.run([sys.executable, "-m", "vehicle", "run", "--help"], cwd=ROOT, capture_output=True,
                         text=True, timeout=30)
    assert out.returncode == 0 and "--corridor-id" in out.stdout and "--connect" in out.stdout
    assert main(["run", "--vehicle", "nobody"]) == 2


def test_bench_quick_json(tmp_path):
    out = subprocess.run([sys.executable, "bench/control_bench.py", "--quick", "--json"], cwd=ROOT,
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    figures = json.loads(out.stdout.strip().splitlines()[-1])
    for key in ("max_lateral_error_m", "settled_lateral_error_m", "max_yaw_error_rad", "stop_error_m",
                "controller_step_us"):
        assert isinstance(figures[key], float) and figures[key] >= 0
    assert figures["max_lateral_error_m"] <= 0.25 and figures["stop_error_m"] <= 1.0
