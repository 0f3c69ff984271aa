"""The network lab on this machine (needs CAP_NET_ADMIN, ``ip``, ``iptables``, ``tc``; skips naming them
otherwise): it comes up with each role on its own host and messages cross its router; nothing it made is left
behind after a run, after a failing test, after SIGINT, or after its process was killed."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest

from deploy.netlab.net import leftovers, unavailable_reason

REASON = unavailable_reason()
pytestmark = [pytest.mark.serial, pytest.mark.slow, pytest.mark.timeout(120),
              pytest.mark.skipif(REASON is not None, reason=REASON or "")]
ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def _netns(pid: int) -> str:
    return os.readlink(f"/proc/{pid}/ns/net")


def test_lab_comes_up_each_role_on_its_own_host_and_messages_cross(tmp_path):
    from deploy.netlab.lab import Lab
    from deploy.process_faults import Recorder

    lab = Lab(run_dir=tmp_path / "run", with_sim=False, rsu_ids=[], restart="no", signed=False)
    rec = Recorder()
    try:
        lab.start(settle_s=0.5, extra_subscribers=[rec.on_message])
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline and not {"ddm", "vehicle"} <= set(rec.heard):
            time.sleep(0.1)
        assert {"ddm", "vehicle"} <= set(rec.heard), rec.heard  # crossed host -> router -> monitor
        spaces = {name: _netns(lab.group.procs[name].pid) for name in ("router", "ddm", "vehicle")}
        assert len(set(spaces.values())) == 3 and _netns(os.getpid()) not in spaces.values(), spaces
        before = lab.net.link_bytes("vehicle")
        time.sleep(1.5)
        assert lab.net.link_bytes("vehicle")[0] > before[0]  # the vehicle's state really goes over its veth
        prefix = lab.plan.prefix
        assert leftovers(prefix)["namespaces"]
    finally:
        lab.stop()
    assert leftovers(prefix) == {"namespaces": [], "links": [], "processes": []}


def test_nothing_left_after_a_failing_test_body(tmp_path):
    from deploy.netlab.lab import Lab

    lab = Lab(run_dir=tmp_path / "run", with_sim=False, rsu_ids=[], restart="no", signed=False)
    with pytest.raises(AssertionError, match="on purpose"):
        try:
            lab.start(settle_s=0.2, monitor=False)
            lab.net.drop("vehicle", 0.3)
            lab.net.cap("ddm", 256e3)
            raise AssertionError("a test failing on purpose inside the lab")
        finally:
            lab.stop()
    assert leftovers(lab.plan.prefix) == {"namespaces": [], "links": [], "processes": []}


def _start_cli(tmp_path) -> tuple[subprocess.Popen, str]:
    env = dict(os.environ, PYTHONPATH=ROOT, PYTHONUNBUFFERED="1")
    p = subprocess.Popen([sys.executable, "-m", "deploy.netlab", "up", "--no-sim", "--rsus", "0", "--runs",
                          str(tmp_path)], cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                         text=True, start_new_session=True)
    deadline = time.monotonic() + 60
    lines = []
    while time.monotonic() < deadline:
        line = p.stdout.readline()
        lines.append(line)
        if line.startswith("lab up: prefix "):
            return p, line.split()[3].rstrip(";")
        if not line and p.poll() is not None:
            break
    p.kill()
    raise AssertionError("the lab never came up:\n" + "".join(lines))


def test_nothing_left_after_sigint(tmp_path):
    p, prefix = _start_cli(tmp_path)
    try:
        found = leftovers(prefix)
        assert len(found["namespaces"]) == 3 and found["processes"], found  # router, ddm, vehicle
        p.send_signal(signal.SIGINT)
        out, _ = p.communicate(timeout=40)
    finally:
        if p.poll() is None:
            p.kill()
    assert p.returncode == 0 and f"lab down: prefix {prefix}" in out, out
    assert leftovers(prefix) == {"namespaces": [], "links": [], "processes": []}


def test_a_killed_run_is_cleaned_up_by_the_next(tmp_path):
    from deploy.netlab.net import cleanup_stale

    p, prefix = _start_cli(tmp_path)
    os.killpg(p.pid, signal.SIGKILL)  # no clean-up of its own: its namespaces outlive it
    p.wait(timeout=10)
    assert leftovers(prefix)["namespaces"]
    assert prefix in cleanup_stale()
    assert leftovers(prefix) == {"namespaces": [], "links": [], "processes": []}


def test_nothing_left_after_sigint_in_the_middle_of_a_bench_row(tmp_path):
    from deploy.netlab.plan import PREFIX_HEAD, base36

    env = dict(os.environ, PYTHONPATH=ROOT, PYTHONUNBUFFERED="1")
    p = subprocess.Popen([sys.executable, os.path.join(ROOT, "bench", "netfault_bench.py"), "--rows",
                          "vehicle link cut 1 s", "--no-scale", "--runs", str(tmp_path)], cwd=ROOT, env=env,
                         stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True)
    prefix = PREFIX_HEAD + base36(p.pid).rjust(5, "0")  # every lab the bench makes
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and len(leftovers(prefix)["processes"]) < 4:
            time.sleep(0.2)
        assert len(leftovers(prefix)["processes"]) >= 4, "the bench's lab never started its services"
        p.send_signal(signal.SIGINT)  # as Ctrl-C in its terminal
        out, _ = p.communicate(timeout=60)
    finally:
        if p.poll() is None:
            os.killpg(p.pid, signal.SIGKILL)
    assert p.returncode == 130, out
    assert leftovers(prefix) == {"namespaces": [], "links": [], "processes": []}
