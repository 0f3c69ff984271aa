"""The vehicle as a real process over Zenoh: command in, accepted ack and VehicleState out."""

import os
import subprocess
import sys
import threading
import time
from pathlib import Path
from uuid import uuid4

import pytest
from vehicle_helpers import make_command

from deploy.procs import stop_process
from protocol.corridor import load_corridor
from protocol.enums import AckStatus
from protocol.keys import vehicle_key
from protocol.zenoh_transport import ZenohSettings, ZenohTransport

pytestmark = pytest.mark.serial  # processes, Zenoh or its own timing: make test runs it alone


ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.slow
@pytest.mark.timeout(60)
def test_vehicle_process_over_zenoh(tmp_path):
    cid = f"t{uuid4().hex[:8]}"
    record = tmp_path / "run"
    proc = subprocess.Popen(
        [sys.executable, "-m", "vehicle.cli", "run", "--corridor-id", cid, "--vehicle", "av1", "--duration", "25",
         "--record", str(record)],
        cwd=ROOT, env={**os.environ, "PYTHONPATH": str(ROOT)}, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    transport = ZenohTransport(ZenohSettings())
    states, acks = [], []
    got_ack = threading.Event()

    def on_ack(key, msg):
        acks.append(msg)
        got_ack.set()

    try:
        transport.subscribe(vehicle_key(cid, "av1", "state"), lambda k, m: states.append(m))
        transport.subscribe(vehicle_key(cid, "av1", "ack"), on_ack)
        deadline = time.monotonic() + 15.0
        while len(states) < 5 and time.monotonic() < deadline:
            assert proc.poll() is None, proc.stdout.read().decode(errors="replace")
            time.sleep(0.05)
        assert len(states) >= 5, "no VehicleState from the vehicle process"
        road = load_corridor().road
        st = states[-1]
        s_car, _ = road.to_frenet(st.pos_x_m, st.pos_y_m)
        cmd = make_command(road, s_car + st.speed_mps * 0.3, command_id="zenoh-1", seq=1, now=time.time(),
                           stop_ahead_m=80.0)
        deadline = time.monotonic() + 5.0
        while not got_ack.is_set() and time.monotonic() < deadline:  # resend until acknowledged
            transport.publish(vehicle_key(cid, "av1", "cmd"), cmd)
            got_ack.wait(0.3)
        assert acks, "no ack from the vehicle process"
        assert acks[0].command_id == "zenoh-1" and acks[0].status == AckStatus.ACCEPTED, acks[0]
        n = len(states)
        time.sleep(1.0)
        assert len(states) - n >= 12  # ~20 Hz
        assert states[-1].active_command_id == "zenoh-1" and states[-1].mode.value == "manoeuvre"
    finally:
        transport.close()
        stop_process(proc)
    assert (record / "run.npz").is_file()  # SIGTERM ends it cleanly and the run is written
