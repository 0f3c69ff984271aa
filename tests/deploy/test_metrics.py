"""Prometheus metrics: off by default; a running RSU's endpoint shows its per-stage latency
histogram moving, its published messages by kind and the rates of its Health."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
import urllib.request
import uuid
from pathlib import Path

import numpy as np
import pytest

from deploy.procs import stop_process_group
from protocol import metrics
from protocol.corridor import load_corridor
from protocol.examples import example_messages
from protocol.local_bus import LocalBus

pytestmark = pytest.mark.serial  # processes, Zenoh or its own timing: make test runs it alone


ROOT = Path(__file__).resolve().parents[2]


def _scrape(port: int) -> str:
    with urllib.request.urlopen(f"http://127.0.0.1:{port}/metrics", timeout=2.0) as r:
        return r.read().decode()


def _value(text: str, metric: str, **labels: str) -> float | None:
    want = ",".join(f'{k}="{v}"' for k, v in labels.items())
    pat = re.compile(rf"^{re.escape(metric)}(?:\{{([^}}]*)\}})? (\S+)$", re.M)
    for m in pat.finditer(text):
        got = m.group(1) or ""
        if all(f'{k}="{v}"' in got for k, v in labels.items()) or (not want and not got):
            return float(m.group(2))
    return None


def test_hooks_are_off_until_served_then_count_every_transport():
    assert metrics.active() is None
    bus = LocalBus()
    bus.subscribe("iea/rellis/**", lambda k, m: None)
    for key, msg in example_messages("rellis"):
        bus.publish(key, msg)  # no endpoint: nothing to report to, nothing fails
    m = metrics.serve("ddm", "ddm", 0, "127.0.0.1")
    try:
        port = m.server.server_address[1]
        for key, msg in example_messages("rellis"):
            bus.publish(key, msg)
        bus.publish_bytes("iea/rellis/vehicle/av1/state", b"\x01garbage")
        metrics.observe_stages({"decision": 0.003})
        text = _scrape(port)
        assert _value(text, "iea_messages_published_total", kind="PathSwitchCommand") == 1.0
        assert _value(text, "iea_messages_received_total", kind="EvAlert") == 1.0
        assert _value(text, "iea_messages_dropped_total", kind="state", reason="format") == 1.0
        assert _value(text, "iea_commands_total", state="issued") == 1.0
        assert _value(text, "iea_stage_latency_seconds_count", stage="decision") == 1.0
        assert _value(text, "iea_link_up", peer="ddm") == 1.0  # the example Health's publisher
        assert _value(text, "iea_service_info", role="ddm", node="ddm") == 1.0
    finally:
        metrics.stop()
        bus.close()
    assert metrics.active() is None


def _video(path: Path, width: int, height: int, frames: int, fps: float) -> None:
    import cv2

    out = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, (width, height))
    rng = np.random.default_rng(0)
    base = rng.integers(60, 120, (height, width, 3), dtype=np.uint8)
    for i in range(frames):  # a grey road with a bright box crossing it
        img = base.copy()
        x = int(i * (width - 120) / frames)
        img[height // 2: height // 2 + 60, x: x + 120] = 230
        out.write(img)
    out.release()


@pytest.mark.timeout(60)
def test_a_running_rsu_serves_its_stage_histogram_moving(tmp_path):
    from deploy.up import free_port

    cam = load_corridor().rsu("rsu1").camera
    video = tmp_path / "road.mp4"
    _video(video, cam.width_px, cam.height_px, frames=200, fps=10.0)
    port = free_port()
    env = dict(os.environ, PYTHONPATH=str(ROOT), PYTHONUNBUFFERED="1")
    proc = subprocess.Popen([sys.executable, "-m", "rsu", "--rsu", "rsu1", "--source", str(video), "--realtime",
                             "--detector", "motion", "--threads", "1", "--hazards", "none",
                             "--corridor-id", f"m-{uuid.uuid4().hex[:6]}", "--metrics-port", str(port),
                             "--metrics-host", "127.0.0.1"],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env, cwd=ROOT,
                            start_new_session=True)
    try:
        first = None
        deadline = time.monotonic() + 30.0
        while time.monotonic() < deadline and proc.poll() is None:
            try:
                first = _value(_scrape(port), "iea_stage_latency_seconds_count", stage="detect")
            except OSError:
                first = None
            if first:
                break
            time.sleep(0.3)
        assert first, f"no detect observations on :{port}/metrics\n{proc.stdout.read() if proc.poll() else ''}"
        time.sleep(2.0)
        text = _scrape(port)
        later = _value(text, "iea_stage_latency_seconds_count", stage="detect")
        assert later > first  # the histogram moves with the frames
        assert _value(text, "iea_stage_latency_seconds_sum", stage="detect") > 0
        assert _value(text, "iea_stage_latency_seconds_bucket", stage="track", le="+Inf") > 0
        assert _value(text, "iea_messages_published_total", kind="ObjectList") >= later - 1
        assert _value(text, "iea_processed_fps", name="frames") is not None  # from its 1 Hz Health
        assert _value(text, "iea_health_status") is not None
    finally:
        stop_process_group(proc, signal.SIGINT)
