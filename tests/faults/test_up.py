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

pytestmark = pytest.mark.serial  # processes, Zenoh or its own timing: make test runs it alone



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
    assert "router ddm rsu1" in lines[-1] and "vehicle" in lines[-1]
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


def test_wait_for_log_reads_only_what_the_service_wrote_since_its_last_start(tmp_path):
    """A run folder reused by a later run keeps the old log: its "router ready" must not count."""
    g = ServiceGroup(tmp_path)
    g.log_path("router").write_text("router ready: tcp/127.0.0.1:1 (an earlier run)\n")
    try:
        g.start("router", ["-c", "import time; time.sleep(0.8); print('router ready', flush=True); time.sleep(5)"])
        assert not g.wait_for_log("router", "router ready", 0.3)
        assert g.wait_for_log("router", "router ready", 10.0)
    finally:
        g.stop_all(timeout_s=5)


@pytest.mark.timeout(90)
def test_up_services_started_before_the_router_wait_for_it(tmp_path, corridor_id):
    """A client whose router is not up yet waits for it (connect/timeout_ms -1) instead of exiting."""
    from deploy.process_faults import Recorder
    from deploy.up import Up
    from protocol.keys import corridor_expr
    from protocol.zenoh_transport import ZenohSettings, ZenohTransport

    up = Up(corridor_id=corridor_id, port=0, run_dir=tmp_path / "up", rsu_ids=[], with_sim=False, restart="no")
    rec = Recorder()
    transport = None
    try:
        for spec in up.specs:  # vehicle and DDM first, with no router to join
            up.group.start(spec.name, spec.args, spec.restart)
        time.sleep(4.0)
        assert up.group.exited() == {}, "a service gave up while the router was down"
        up._start_router()
        transport = ZenohTransport(ZenohSettings(mode="client", connect=[up.endpoint]))
        transport.subscribe(corridor_expr(corridor_id), rec.on_message)
        deadline = time.monotonic() + 40
        while time.monotonic() < deadline and not {"vehicle", "ddm"} <= set(rec.heard):
            time.sleep(0.2)
        assert {"vehicle", "ddm"} <= set(rec.heard), rec.heard.keys()
    finally:
        if transport is not None:
            transport.close()
        up.stop()
    assert all(code in (0, -signal.SIGINT) for code in up.group.exited().values()), up.group.exited()
