"""Shared test fixtures: paths, ../shared detection, unique corridor ids, process cleanup."""

from __future__ import annotations

import os
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
