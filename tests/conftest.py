"""Shared test fixtures: paths, ../shared detection, unique corridor ids, process cleanup."""

from __future__ import annotations

import fcntl
import json
import os
import shutil
import subprocess
import sys
import uuid
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
SHARED = ROOT.parent / "shared"
REAL_DATA = SHARED / "data" / "real"


def require_shared(*parts: str) -> Path:
    """Path under ../shared, or skip the test with a clear message when it is absent."""
    path = SHARED.joinpath(*parts)
    if not path.exists():
        pytest.skip(f"needs {path} (the project's ../shared folder beside the repository); not found")
    return path


@pytest.fixture
def corridor_id() -> str:
    """A corridor id no other test run uses, so parallel Zenoh runs never cross-talk."""
    return f"t{uuid.uuid4().hex[:10]}"


@pytest.fixture
def spawn(request):
    """Start ``python -m ...`` processes with the repository on PYTHONPATH; all are killed at teardown. Only for tests
    marked ``serial`` (``make test`` runs those one at a time: processes beside a parallel test would share its
    two cores and miss their deadlines)."""
    if request.node.get_closest_marker("serial") is None:
        pytest.fail(f"{request.node.nodeid} starts processes: mark it `serial` (pytestmark = pytest.mark.serial)")
    procs: list[subprocess.Popen] = []
    env = dict(os.environ, PYTHONPATH=str(ROOT), PYTHONUNBUFFERED="1")

    def _spawn(*args: str, **kwargs) -> subprocess.Popen:
        kwargs.setdefault("stdout", subprocess.PIPE)
        kwargs.setdefault("stderr", subprocess.PIPE)
        kwargs.setdefault("text", True)
        p = subprocess.Popen([sys.executable, *args], cwd=ROOT, env=env, **kwargs)
        procs.append(p)
        return p

    yield _spawn
    for p in procs:
        if p.poll() is None:
            p.kill()
        try:
            p.communicate(timeout=5)
        except Exception:
            pass


# ------------------------------------------------------------------ the Node readers (tests/node)
NODE_DIR = ROOT / "tests" / "node"
NEEDED = ("@mcap/core", "@mcap/support", "@foxglove/ws-protocol", "@foxglove/schemas", "ajv", "ws")


def node_harness() -> str:
    """The node executable, with tests/node's packages installed (``npm ci`` once); skips when impossible."""
    node, npm = shutil.which("node"), shutil.which("npm")
    if node is None or npm is None:
        pytest.skip("needs Node.js and npm on PATH (apt-get install nodejs npm) for the outside readers")
    modules = NODE_DIR / "node_modules"
    with open(NODE_DIR / ".install.lock", "w") as lock:  # one install even with parallel test workers
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not all((modules / name / "package.json").is_file() for name in NEEDED):
            try:
                r = subprocess.run([npm, "ci", "--no-audit", "--no-fund"], cwd=NODE_DIR, capture_output=True,
                                   text=True, timeout=240)
            except subprocess.TimeoutExpired:
                pytest.skip("npm ci in tests/node took over 240 s (registry unreachable?)")
            if r.returncode != 0:
                pytest.skip(f"npm ci in tests/node failed (registry unreachable?): {r.stderr.strip()[-400:]}")
    return node


def run_node(node: str, script: str, *args: str, timeout_s: float = 120.0) -> tuple[int, dict]:
    r = subprocess.run([node, script, *args], cwd=NODE_DIR, capture_output=True, text=True, timeout=timeout_s)
    lines = [ln for ln in r.stdout.splitlines() if ln.startswith("{")]
    assert lines, f"{script} printed no result: {r.stdout[-1000:]} {r.stderr[-2000:]}"
    return r.returncode, json.loads(lines[-1])
