"""`iea up`: the router and the services as local processes; Ctrl-C stops them all cleanly."""

from __future__ import annotations

import ast
import re
import signal
import subprocess
import time

import pytest

from deploy.cli import main as iea_main
from deploy.procs import ServiceGroup


def test_up_help(capsys):
    with pytest.raises(SystemExit) as exc:
        iea_main(["up", "--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    assert "router" in out and "--port" in out and "Ctrl-C" in out


@pytest.mark.timeout(90)
def test_up_ctrl_c_stops_every_service_and_the_router(spawn, tmp_path, corridor_id):
    p = spawn("-m", "deploy", "up", "--port", "0", "--no-sim", "--rsus", "1", "--status-every-s", "0",
              "--corridor-id", corridor_id, "--runs", str(tmp_path), stdout=subprocess.PIPE,
              stderr=subprocess.STDOUT, start_new_session=True)
    deadline = time.monotonic() + 45
    lines = []
    while time.monotonic() < deadline:
        line = p.stdout.readline()
        if not line:
            break
        lines.append(line)
        if "Ctrl-C to stop" in line:
            break
    assert any("Ctrl-C to stop" in x for x in lines), "".join(lines)
    assert "router vehicle ddm rsu1" in lines[-1]
    time.sleep(3.0)
    p.send_signal(signal.SIGINT)  # what the terminal sends
    out, _ = p.communicate(timeout=40)
    assert p.returncode == 0, out
    m = re.search(r"exit codes (\{.*?\})", out)
    assert m, out
    codes = ast.literal_eval(m.group(1))
    assert set(codes) == {"router", "vehicle", "ddm", "rsu1"}
    # each one stopped on SIGINT (0 once its handler is installed, -SIGINT while still importing),
    # none had to be SIGKILLed after the grace period
    assert all(c in (0, -signal.SIGINT) for c in codes.values()), codes
    assert codes["router"] == 0
    logs = next(tmp_path.glob("up-*")) / "logs"
    assert {f.stem for f in logs.glob("*.log")} == {"router", "vehicle", "ddm", "rsu1"}
    assert "router ready" in (logs / "router.log").read_text()


def test_service_group_restarts_on_failure_only(tmp_path):
    g = ServiceGroup(tmp_path)
    try:
        g.start("crash", ["-c", "import sys; sys.exit(3)"], restart="on-failure")
        g.start("ok", ["-c", "print('done')"], restart="on-failure")
        g.start("once", ["-c", "import sys; sys.exit(4)"])
        for p in list(g.procs.values()):
            p.wait(timeout=20)
        assert g.supervise() == ["crash"]
        assert g.restarts == {"crash": 1}
        g.procs["crash"].wait(timeout=20)
        assert "done" in g.log_path("ok").read_text()
        assert g.exited()["once"] == 4
    finally:
        g.stop_all(timeout_s=5)
