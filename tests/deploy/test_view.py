"""`iea view`: the picture it builds from the corridor's messages, and the page in a real headless
browser drawing a live lockstep run (the EV, the AV and the EV alert, read from the page itself)."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
import urllib.request
import uuid
from pathlib import Path

import pytest

from deploy.procs import stop_process_group
from deploy.view_model import CorridorPicture, corridor_plan
from protocol.corridor import load_corridor
from protocol.examples import example_messages

pytestmark = pytest.mark.serial  # processes, Zenoh or its own timing: make test runs it alone


ROOT = Path(__file__).resolve().parents[2]


def test_plan_follows_the_corridor_file():
    c = load_corridor()
    plan = corridor_plan(c)
    assert len(plan["edges"]) == c.road.lanes + 2 and len(plan["lane_centres"]) == c.road.lanes
    assert [r["id"] for r in plan["rsus"]] == [r.rsu_id for r in c.rsus]  # any number of RSUs
    for r, cfg in zip(plan["rsus"], c.rsus, strict=True):
        assert 0.1 < r["hfov_rad"] < 3.0 and r["x_m"] == pytest.approx(cfg.camera.x_m, abs=0.01)
    x0, y0 = plan["edges"][1][0]
    assert (x0, y0) == pytest.approx(c.road.pose_at(0.0, 0.0)[:2], abs=0.01)


def test_picture_from_the_corridor_messages():
    pic = CorridorPicture("rellis")
    msgs = example_messages("rellis", stamp=5.0, seq=1)
    for key, msg in msgs:
        pic.on_message(key, msg, now_s=100.0)
    pic.on_presence("iea/rellis/alive/ddm/ddm", True)
    snap = pic.snapshot(100.5)
    json.dumps(snap)  # what the page receives
    assert {"EvAlert", "VehicleState", "PathSwitchCommand", "CommandAck"} <= {m.KIND for _, m in msgs}
    assert snap["alerts"] and snap["alerts"][0]["cues"] is not None
    assert any(e["kind"] == "alert" for e in snap["timeline"])
    assert pic.snapshot(100.0 + 10.0)["alerts"] == []  # an alert not repeated for 3 s is not drawn
    (vid, v), = snap["vehicles"].items()
    assert v["mode"] and v["cmd"] is not None and v["cmd"]["path"]
    assert any(e["kind"] == "command" for e in snap["timeline"])
    assert snap["objects"] and all(o["id"] is not None for objs in snap["objects"].values() for o in objs)
    assert snap["health"]["ddm"]["link"] == "up"
    pic.on_presence("iea/rellis/alive/ddm/ddm", False)
    assert pic.snapshot(100.5)["health"]["ddm"]["link"] == "lost"
    assert pic.snapshot(100.0 + 10.0)["objects"] == {}  # object lists older than 2 s are not drawn


def _get_json(url: str) -> dict:
    with urllib.request.urlopen(url, timeout=2.0) as r:
        return json.loads(r.read())


def chromium() -> str | None:
    return shutil.which("chromium") or shutil.which("chromium-browser")


@pytest.mark.slow
@pytest.mark.timeout(120)
def test_page_draws_a_live_lockstep_run_in_headless_chromium(tmp_path):
    browser = chromium()
    if browser is None:
        pytest.skip("Debian's chromium is not installed (apt-get install chromium): the page is not checked")
    from deploy.up import free_port
    from protocol import keys
    from protocol.zenoh_transport import ZenohTransport
    from scenario.lockstep import CorridorLockstep, LockstepConfig

    port = free_port()
    env = dict(os.environ, PYTHONPATH=str(ROOT), PYTHONUNBUFFERED="1")
    runner = CorridorLockstep(LockstepConfig(seed=1, duration_s=4.8, detector="motion"))
    cid = f"view-{uuid.uuid4().hex[:6]}"  # the lockstep's messages go out on Zenoh under a corridor of their own
    view = subprocess.Popen([sys.executable, "-m", "deploy", "view", "--port", str(port), "--corridor-id", cid],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env, cwd=ROOT,
                            start_new_session=True)
    browser_proc = None
    zenoh = ZenohTransport()
    try:
        assert "[view]" in view.stdout.readline()
        url = f"http://127.0.0.1:{port}/"
        browser_proc = subprocess.Popen(
            [browser, "--headless=new", "--no-sandbox", "--disable-gpu", "--no-first-run",
             f"--user-data-dir={tmp_path / 'chromium'}", "--window-size=1500,900", url],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
        time.sleep(1.0)
        bridge = lambda k, p: zenoh.publish_bytes(k.replace(f"/{runner.corridor_id}/", f"/{cid}/", 1), p)  # noqa: E731
        runner.bus.subscribe_bytes(keys.corridor_expr(runner.corridor_id), bridge)
        runner.run()  # the EV's lights come on at 4 s: alert (4.33 s), command and ack before 4.8 s
        seen: dict = {}
        deadline = time.monotonic() + 15.0
        while time.monotonic() < deadline:
            seen = _get_json(url + "api/seen")
            if seen.get("ev_drawn") and "av1" in seen.get("av_drawn", []) and seen.get("alert_text"):
                break
            time.sleep(0.5)
        assert seen, "the page never reported what it drew (did it load?)"
        assert seen["ev_drawn"] >= 1, seen
        assert "av1" in seen["av_drawn"], seen
        assert seen["alert_text"].startswith("EV ALERT"), seen
        assert seen["tracks_drawn"] >= 1 and seen["rate_hz"] >= 10.0, seen  # live at >= 10 Hz
    finally:
        zenoh.close()
        for p in (browser_proc, view):
            if p is not None:
                stop_process_group(p, signal.SIGTERM)
