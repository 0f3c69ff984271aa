"""Every bench runs in its quick mode (``bench/suite.py``): it exits 0 and the last line of its output is one JSON
object holding the bench's key figures. Each run is a process of its own (and starts its own services), so the
tests are ``serial``; the benches that start a corridor of services are ``slow`` too."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys

import pytest
from conftest import ROOT, node_harness, require_shared

from bench.suite import BENCHES, Bench, bench_scripts

pytestmark = pytest.mark.serial

RUN_TIMEOUT_S = 600.0
"""The most a quick run may take: the slowest, e2e_bench's, takes a few minutes on a 2-core machine shared with other
jobs."""


def run_quick(bench: Bench) -> subprocess.CompletedProcess:
    """``python bench/<name>.py <quick args> --json`` in its own process group, killed whole when it ends or times
    out (a bench's services must not outlive it)."""
    proc = subprocess.Popen([sys.executable, *bench.command(quick=True)], cwd=ROOT, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True,
                            env=dict(os.environ, PYTHONPATH=str(ROOT), PYTHONUNBUFFERED="1"))
    try:
        out, err = proc.communicate(timeout=RUN_TIMEOUT_S)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        out, err = proc.communicate()
        pytest.fail(f"{bench.name} --quick ran over {RUN_TIMEOUT_S:.0f} s\n{out[-2000:]}\n{err[-3000:]}")
    finally:
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
    return subprocess.CompletedProcess(proc.args, proc.returncode, out, err)


def test_every_bench_script_has_a_row_in_the_suite():
    assert bench_scripts() == sorted(b.name for b in BENCHES), "add the bench to bench/suite.py's BENCHES"


def test_a_bench_left_to_its_own_test_is_run_there():
    for b in BENCHES:
        if b.tested_by is not None:
            assert b.name in (ROOT / b.tested_by).read_text(), f"{b.tested_by} does not run {b.name}"


@pytest.mark.timeout(RUN_TIMEOUT_S + 30)
@pytest.mark.parametrize("bench", [pytest.param(b, id=b.name, marks=[pytest.mark.slow] if b.processes else [])
                                   for b in BENCHES if b.tested_by is None])
def test_quick_run_ends_with_its_figures_as_json(bench: Bench):
    if bench.needs_shared:
        require_shared("data", "real")
    if bench.needs_tool and shutil.which(bench.needs_tool) is None:
        pytest.skip(f"{bench.name} needs {bench.needs_tool} on PATH (Debian: apt-get install {bench.needs_tool})")
    if bench.needs_tool == "node":
        node_harness()
    r = run_quick(bench)
    assert r.returncode == 0, f"{bench.name} exited {r.returncode}\n{r.stdout[-2000:]}\n{r.stderr[-3000:]}"
    lines = r.stdout.strip().splitlines()
    assert lines, f"{bench.name} printed nothing\n{r.stderr[-3000:]}"
    figures = json.loads(lines[-1])
    assert isinstance(figures, dict), f"{bench.name}: the last line is not a JSON object: {lines[-1][:200]}"
    missing = [k for k in bench.figures if figures.get(k) is None]
    assert not missing, f"{bench.name}: key figures missing or null: {missing}; it reported {sorted(figures)}"
