"""`iea health` (the containers' health check) against a real DDM process over Zenoh on loopback."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path
from uuid import uuid4

import pytest

from deploy.procs import stop_process

pytestmark = pytest.mark.serial  # processes, Zenoh or its own timing: make test runs it alone


ROOT = Path(__file__).resolve().parents[2]


def _health(*args: str, timeout_s: float = 8.0) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "deploy", "health", *args, "--timeout-s", str(timeout_s)],
                          capture_output=True, text=True, cwd=ROOT, timeout=60)


def test_health_reports_a_running_service_and_fails_for_a_silent_one():
    cid = f"t{uuid4().hex[:8]}"
    ddm = subprocess.Popen([sys.executable, "-m", "ddm", "run", "--corridor-id", cid, "--log-level", "WARNING"],
                           cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        ok = _health("ddm", "--corridor-id", cid)
        assert ok.returncode == 0, ok.stderr
        assert f"iea/{cid}/ddm/health" in ok.stdout and ("ok" in ok.stdout or "degraded" in ok.stdout)
        silent = _health("rsu", "rsu1", "--corridor-id", cid, timeout_s=2.0)  # no RSU runs
        assert silent.returncode == 1 and "no Health" in silent.stderr
    finally:
        stop_process(ddm)
    bad = subprocess.run([sys.executable, "-m", "deploy", "health", "rsu"], capture_output=True, text=True,
                         cwd=ROOT, timeout=60)
    assert bad.returncode == 2 and "needs its id" in bad.stderr


def test_health_key_names_each_services_health():
    import pytest

    from deploy.status import health_key

    assert health_key("c", "rsu", "rsu2") == "iea/c/rsu/rsu2/health"
    assert health_key("c", "vehicle", "av1") == "iea/c/vehicle/av1/health"
    assert (health_key("c", "ddm"), health_key("c", "sim")) == ("iea/c/ddm/health", "iea/c/sim/health")
    with pytest.raises(ValueError, match="needs its id"):
        health_key("c", "vehicle")
