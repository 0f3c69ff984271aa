"""Foxglove's own tools read the corridor, from another language: a short lockstep run is recorded (the
recorder of `iea demo` / `iea up`) and served live by the Foxglove bridge (`iea foxglove`) at once.
Node reads the recording with the reference MCAP reader (@mcap/core): every channel's encoding is one
Foxglove decodes, every message parses as JSON and validates against its channel's schema (Ajv), the
Foxglove schemas are @foxglove/schemas' own, and the scene, map and image channels are present and well
formed. Node's @foxglove/ws-protocol client subscribes to the scene, the map and the EV alert channels of
the live bridge during the run and decodes what arrives.

The Node harness is tests/node (package.json, package-lock.json); `npm ci` runs once when its
node_modules is missing. Skips, saying why, without node/npm, the registry or foxglove-sdk."""

from __future__ import annotations

import json
import subprocess
import time
from pathlib import Path

import pytest
from conftest import NODE_DIR, node_harness, run_node

from protocol.codec import encode

pytestmark = [pytest.mark.serial, pytest.mark.slow]

ROOT = Path(__file__).resolve().parents[2]
@pytest.fixture(scope="module")
def live_run(tmp_path_factory):
    """A 5 s lockstep run (the EV's lights come on at 4 s: an alert, a command, an ack) recorded to MCAP and
    served by the bridge while Node's Foxglove client is subscribed."""
    node = node_harness()
    pytest.importorskip("foxglove", reason="needs the foxglove-sdk package (extra foxglove)")
    from deploy.foxglove_bridge import FoxgloveBridge, corridor_channels
    from deploy.record import scene_recorder
    from protocol.corridor import load_corridor
    from scenario.lockstep import CorridorLockstep, LockstepConfig

    path = tmp_path_factory.mktemp("fox") / "run.mcap"
    runner = CorridorLockstep(LockstepConfig(seed=1, duration_s=5.0, detector="motion"),
                              recorder=scene_recorder(path, load_corridor()))
    bridge = FoxgloveBridge(runner.corridor, port=0, scene_hz=10.0)
    client = None
    try:
        bridge.attach(runner.bus, poll_ddm=False)
        patterns = [r"^/scene/objects$", r"^/scene/road$", r"^/map/av1$", r"/rsu/[^/]+/ev$", r"^/log$",
                    r"/rsu/rsu1/camera/jpeg$"]
        client = subprocess.Popen([node, "ws_client.mjs", bridge.url, "150", *patterns], cwd=NODE_DIR,
                                  stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        deadline = time.monotonic() + 30.0
        while sum(bridge.subscribed.values()) < len(patterns) + 3 and time.monotonic() < deadline:
            assert client.poll() is None, client.communicate()
            time.sleep(0.1)
        subscribed = dict(bridge.subscribed)
        metrics = runner.run()
        out, err = client.communicate(timeout=60)
        lines = [ln for ln in out.splitlines() if ln.startswith("{")]
        assert lines, f"the ws client printed no result: {out[-1000:]} {err[-2000:]}"
        yield {"node": node, "path": path, "ws": json.loads(lines[-1]), "ws_rc": client.returncode,
               "subscribed": subscribed, "metrics": metrics, "sent": bridge.sent,
               "channels": len(corridor_channels(runner.corridor, runner.corridor_id))}
    finally:
        if client is not None and client.poll() is None:
            client.kill()
            client.wait(timeout=10)
        bridge.close()


def test_foxglove_ws_client_receives_the_scene_map_and_alerts_live(live_run):
    ws = live_run["ws"]
    assert live_run["ws_rc"] == 0 and ws["problems"] == [], ws
    assert ws["opened"] and ws["server"].startswith("iea-corridor rellis")
    # every key of the corridor (4 RSUs, 1 AV, DDM, simulator), the cameras and the derived channels, at start
    assert ws["advertised"] == live_run["channels"] >= 4 * 5 + 4 + 3 + 6
    assert all(n > 0 for n in ws["got"].values()), ws["got"]  # scene, road, AV fix, an EV alert, log, camera
    assert any(t.endswith("/ev") for t in ws["perTopic"]) and ws["perTopic"]["/scene/objects"] >= 1


def test_mcap_core_reads_every_channel_of_the_recording(live_run):
    rc, rep = run_node(live_run["node"], "read_mcap.mjs", str(live_run["path"]))
    assert rc == 0 and rep["problemCount"] == 0, rep["problems"]
    assert rep["encodings"] == {"json": rep["channels"]} and rep["profile"] == "iea-corridor"
    assert all(rep["foxgloveSchemasMatch"].values()) and len(rep["foxgloveSchemasMatch"]) == 5
    schemas = rep["perSchema"]
    for kind in ("ObjectList", "EvAlert", "PathSwitchCommand", "CommandAck", "VehicleState", "WorldSnapshot",
                 "Health", "foxglove.SceneUpdate", "foxglove.FrameTransforms", "foxglove.LocationFix",
                 "foxglove.CompressedImage", "foxglove.Log"):
        assert schemas.get(kind, 0) > 0, (kind, schemas)
    topics = rep["perTopic"]
    assert topics["/scene/road"] >= 1 and topics["/scene/objects"] >= 40 and topics["/map/av1"] >= 40
    assert sum(n for t, n in topics.items() if t.endswith("/camera/jpeg")) >= 4 * 8  # 4 RSUs at 2 Hz for ~5 s


def test_mcap_core_reader_catches_a_message_off_its_schema_and_a_schema_foxglove_cannot_read(tmp_path, live_run):
    """The checks have teeth: a CommandAck missing its fields fails its schema, and the committed wire schema
    (positional records, $ref, anyOf) is refused as one Foxglove's JSON Schema reader cannot read."""
    from mcap.writer import Writer

    from protocol.examples import example_messages
    from protocol.json_view import to_json as wire_json
    from protocol.record_view import record_view_schema
    from protocol.schema_export import SCHEMA_DIR

    path = tmp_path / "bad.mcap"
    with open(path, "wb") as f:
        w = Writer(f)
        w.start(profile="iea-corridor")
        sid = w.register_schema("CommandAck", "jsonschema", json.dumps(record_view_schema("CommandAck")).encode())
        cid = w.register_channel("iea/rellis/vehicle/av1/ack", "json", sid)
        w.add_message(cid, log_time=1, publish_time=1, data=json.dumps({"kind": "CommandAck", "v": 1}).encode())
        wire_sid = w.register_schema("EvAlert", "jsonschema", (SCHEMA_DIR / "EvAlert.json").read_bytes())
        wire_cid = w.register_channel("iea/rellis/rsu/rsu1/ev", "json", wire_sid)
        key, alert = example_messages("rellis")[1]
        w.add_message(wire_cid, log_time=2, publish_time=2, data=wire_json(encode(alert)))
        w.finish()
    rc, rep = run_node(live_run["node"], "read_mcap.mjs", str(path))
    assert rc == 1 and rep["problemCount"] == 2, rep["problems"]
    assert any("fails CommandAck" in p for p in rep["problems"])
    assert any(p.startswith("iea/rellis/rsu/rsu1/ev: schema EvAlert not readable by Foxglove") for p in rep["problems"])
