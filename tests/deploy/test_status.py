"""`iea status` over a running `iea up`: one query per kind lists every service as one table."""

from __future__ import annotations

import re
import signal
import subprocess
import time

import pytest

from deploy.cli import main as iea_main

pytestmark = pytest.mark.serial  # processes, Zenoh or its own timing: make test runs it alone



def test_status_help(capsys):
    with pytest.raises(SystemExit) as exc:
        iea_main(["status", "--help"])
    assert exc.value.code == 0
    assert "--corridor-id" in capsys.readouterr().out


@pytest.mark.timeout(120)
def test_status_lists_every_service_of_iea_up(spawn, tmp_path, corridor_id):
    up = spawn("-m", "deploy", "up", "--port", "0", "--no-sim", "--rsus", "1", "--status-every-s", "0",
               "--corridor-id", corridor_id, "--runs", str(tmp_path), stdout=subprocess.PIPE,
               stderr=subprocess.STDOUT, start_new_session=True)
    endpoint, deadline = None, time.monotonic() + 60
    while time.monotonic() < deadline:
        line = up.stdout.readline()
        if not line:
            break
        m = re.search(r"router (tcp/127\.0\.0\.1:\d+)", line)
        endpoint = endpoint or (m.group(1) if m else None)
        if "Ctrl-C to stop" in line:
            break
    assert endpoint, "iea up did not print its router endpoint"
    rows: dict[str, list[str]] = {}
    try:
        for _ in range(40):  # the services import and declare themselves within seconds of `iea up` starting
            p = spawn("-m", "deploy", "status", "--corridor-id", corridor_id, "--connect", endpoint)
            text, _ = p.communicate(timeout=30)
            rows = {ln.split()[0]: ln.split() for ln in text.splitlines()[2:] if ln.strip()}
            if all(rows.get(s, [None, None])[1] == "yes" for s in ("ddm", "rsu/rsu1", "vehicle/av1")):
                break
            time.sleep(1.0)
        assert rows["ddm"][1] == "yes" and rows["rsu/rsu1"][1] == "yes" and rows["vehicle/av1"][1] == "yes", rows
        assert rows["rsu/rsu2"][1] == "missing"  # in the corridor file, not started (--rsus 1)
        assert "tracks" in " ".join(rows["ddm"]) and "command" in " ".join(rows["vehicle/av1"])
    finally:
        up.send_signal(signal.SIGINT)
        up.communicate(timeout=40)
