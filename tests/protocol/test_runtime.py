"""Process-level settings of the services (protocol.runtime)."""

from __future__ import annotations

import signal
import subprocess
import sys
import time

import pytest

from protocol.runtime import freeze_startup_heap

pytestmark = pytest.mark.serial  # processes, Zenoh or its own timing: make test runs it alone


SLEEPER = ("import sys, time\n"
           "if sys.argv[1] == 'fix':\n"
           "    from protocol.runtime import stop_on_ctrl_c; stop_on_ctrl_c()\n"
           "print('ready', flush=True)\n"
           "time.sleep(30)\n")


def _started_with_sigint_ignored(mode: str) -> subprocess.Popen:
    """A Python process started as a background job of a non-interactive shell starts: SIGINT ignored."""
    p = subprocess.Popen([sys.executable, "-c", SLEEPER, mode], stdout=subprocess.PIPE, text=True,
                         preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN))
    assert p.stdout.readline().strip() == "ready"
    return p


@pytest.mark.timeout(60)
def test_sigint_stops_a_cli_started_with_sigint_ignored():
    """``iea up`` stops its services with SIGINT; a service that inherited SIGINT ignored (make test run as a
    background job) stops too, and so does ``iea up`` itself on the test's Ctrl-C."""
    fixed = _started_with_sigint_ignored("fix")
    plain = _started_with_sigint_ignored("plain")
    try:
        for p in (fixed, plain):
            p.send_signal(signal.SIGINT)
        assert fixed.wait(timeout=10) != 0  # KeyboardInterrupt
        time.sleep(1.0)
        assert plain.poll() is None  # the condition the fix is for: SIGINT is dropped without it
    finally:
        for p in (fixed, plain):
            p.kill()
            p.wait(timeout=10)


def test_freeze_startup_heap_freezes_what_is_alive():
    import gc

    try:
        assert freeze_startup_heap() > 1000
    finally:
        gc.unfreeze()
