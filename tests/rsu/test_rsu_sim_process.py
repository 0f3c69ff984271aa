"""End to end over Zenoh: ``iea-sim run`` + ``iea-rsu --source sim`` raise an EvAlert for the EV."""

from __future__ import annotations

import subprocess
import sys
import time
import uuid
from pathlib import Path

import pytest

from deploy.procs import stop_process
from protocol.enums import AlertState
from protocol.keys import rsu_key
from protocol.messages import EvAlert
from protocol.zenoh_transport import ZenohTransport

pytestmark = pytest.mark.serial  # processes, Zenoh or its own timing: make test runs it alone


ROOT = Path(__file__).resolve().parents[2]


def _stop(proc: subprocess.Popen) -> str:
    stop_process(proc, timeout_s=5.0)
    return (proc.stderr.read() if proc.stderr else "")[-3000:]


@pytest.mark.slow
@pytest.mark.timeout(60)
def test_sim_and_rsu_processes_raise_an_ev_alert_over_zenoh():
    cid = f"t{uuid.uuid4().hex[:8]}"
    alerts: list[EvAlert] = []
    transport = ZenohTransport()
    transport.subscribe(rsu_key(cid, "rsu1", "ev"), lambda k, m: alerts.append(m))
    rsu = subprocess.Popen([sys.executable, "-m", "rsu", "--rsu", "rsu1", "--corridor-id", cid, "--source", "sim",
                            "--detector", "motion", "--read-timeout-s", "2", "--log-level", "WARNING"],
                           cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    sim = None
    try:
        time.sleep(2.0)  # the RSU subscribes before the world starts
        t_start = time.time()
        sim = subprocess.Popen([sys.executable, "-m", "sim", "run", "rellis_ev_yield", "--corridor-id", cid,
                                "--duration", "9", "--seed", "3"],
                               cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        deadline = time.monotonic() + 30.0  # lights on at 4 s sim time; the EV is in rsu1's view 2-7 s
        while time.monotonic() < deadline and not any(a.state == AlertState.ACTIVE for a in alerts):
            time.sleep(0.2)
    finally:
        sim_err = _stop(sim) if sim is not None else ""
        rsu_err = _stop(rsu)
        transport.close()
    active = [a for a in alerts if a.state == AlertState.ACTIVE]
    assert active, f"no active EvAlert; rsu stderr:\n{rsu_err}\nsim stderr:\n{sim_err}"
    a = active[0]
    assert a.rsu_id == "rsu1" and a.alert_id == f"rsu1-ev-{a.object_id}"
    # frames carry the simulator's capture stamp (wall clock), as a live camera's would
    assert t_start < a.first_seen <= time.time() and 0.0 < a.confidence <= 1.0 and a.evidence.frames > 0
    assert -30.0 < a.pos_x_m < 160.0  # on the corridor in front of rsu1
