"""Signatures across real processes: an ``iea-vehicle`` whose corridor file trusts one DDM key refuses
forged and unsigned commands over Zenoh and follows the signed one; the CLIs refuse bad key files."""

from __future__ import annotations

import threading
import time
from pathlib import Path

import pytest
from sec_helpers import key, resume

from deploy.procs import stop_process
from protocol.corridor import DEFAULT_CORRIDOR
from protocol.enums import AckStatus
from protocol.keys import vehicle_key
from protocol.zenoh_transport import ZenohSettings, ZenohTransport

pytestmark = pytest.mark.serial  # processes, Zenoh or its own timing: make test runs it alone


ROOT = Path(__file__).resolve().parents[2]


def _corridor_file(tmp_path: Path, public: str) -> Path:
    p = tmp_path / "corridor.toml"
    p.write_text(DEFAULT_CORRIDOR.read_text() + f'\n[[trust]]\nkey_id = "ddm-1"\nrole = "ddm"\nvehicles = ["av1"]\n'
                                                f'public_key = "{public}"\n')
    return p


@pytest.mark.slow
@pytest.mark.timeout(90)
def test_vehicle_process_refuses_forged_and_unsigned_commands(tmp_path, corridor_id, spawn):
    ddm, public = key("ddm-1")
    rogue, _ = key("ddm-1")
    proc = spawn("-m", "vehicle", "run", "--corridor", str(_corridor_file(tmp_path, public)), "--corridor-id",
                 corridor_id, "--duration", "40")
    transport = ZenohTransport(ZenohSettings())
    states, acks, health = [], [], []
    got_ack = threading.Event()
    cmd_key = vehicle_key(corridor_id, "av1", "cmd")
    try:
        transport.subscribe(vehicle_key(corridor_id, "av1", "state"), lambda k, m: states.append(m))
        transport.subscribe(vehicle_key(corridor_id, "av1", "health"), lambda k, m: health.append(m))
        transport.subscribe(vehicle_key(corridor_id, "av1", "ack"), lambda k, m: (acks.append(m), got_ack.set()))
        deadline = time.monotonic() + 20.0
        while len(states) < 5 and time.monotonic() < deadline:
            assert proc.poll() is None, proc.stderr.read()
            time.sleep(0.05)
        assert len(states) >= 5, "no VehicleState from the vehicle process"
        now = time.time()
        forged = rogue.sign_message(cmd_key, resume(now, command_id="forged", seq=5, valid_s=30.0))
        unsigned = resume(now, command_id="unsigned", seq=6, valid_s=30.0)
        for _ in range(3):
            transport.publish(cmd_key, forged)
            transport.publish(cmd_key, unsigned)
            time.sleep(0.2)
        assert acks == []  # unauthenticated senders get no answer
        signed = ddm.sign_message(cmd_key, resume(time.time(), command_id="signed", seq=7, valid_s=30.0))
        deadline = time.monotonic() + 5.0
        while not got_ack.is_set() and time.monotonic() < deadline:  # resend until acknowledged
            transport.publish(cmd_key, signed)
            got_ack.wait(0.3)
        assert acks and acks[0].command_id == "signed" and acks[0].status == AckStatus.ACCEPTED
        n = len(health)
        deadline = time.monotonic() + 3.0
        while len(health) == n and time.monotonic() < deadline:
            time.sleep(0.05)
        rejected = health[-1].rejected
        assert rejected.get("auth_bad_signature") == 3 and rejected.get("auth_unsigned") == 3, rejected
        assert all(s.mode.value == "driving" for s in states)  # the car kept cruising throughout
    finally:
        transport.close()
        stop_process(proc)


def test_cli_key_errors(tmp_path, spawn):
    ddm, public = key("ddm-1")
    corridor = _corridor_file(tmp_path, public)
    missing = spawn("-m", "ddm", "run", "--corridor", str(corridor), "--key", str(tmp_path / "nope.pem"))
    _, err = missing.communicate(timeout=60)
    assert missing.returncode == 2 and "not found" in err
    from protocol.security import new_key_pair

    pem, _ = new_key_pair()
    stranger = tmp_path / "stranger.pem"
    stranger.write_bytes(pem)
    p = spawn("-m", "ddm", "run", "--corridor", str(corridor), "--key", str(stranger))
    _, err = p.communicate(timeout=60)
    assert p.returncode == 2 and "trust list" in err
    v = spawn("-m", "vehicle", "run", "--require-signed", "--duration", "1")  # default corridor: no trust entries
    _, err = v.communicate(timeout=60)
    assert v.returncode == 2 and "trust" in err
