"""MCAP recording and replay: the file validates with the mcap reader, carries each message's
key, stamp, receive time and JSON Schema, and a lockstep run replayed into a fresh DDM makes the same
decisions; `iea record` and `iea replay` move the bytes over real Zenoh."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
import uuid
from pathlib import Path

import pytest

from deploy.procs import stop_process
from deploy.record import McapRecorder, check_recording, peek_header, read_recording
from deploy.replay import recorded_commands, rename_corridor, replay_into_ddm, schedule
from protocol.codec import encode
from protocol.examples import example_messages
from protocol.record_view import record_view_schema

pytestmark = pytest.mark.serial  # processes, Zenoh or its own timing: make test runs it alone


ROOT = Path(__file__).resolve().parents[2]


def _write_examples(path: Path, corridor: str = "rellis", n: int = 3) -> list[tuple[str, bytes, float]]:
    sent = []
    t = [100.0]
    with McapRecorder(path, clock=lambda: t[0], metadata={"corridor_id": corridor}) as rec:
        for i in range(n):
            for key, msg in example_messages(corridor, stamp=10.0 + i, seq=i):
                payload = encode(msg)
                rec.on_bytes(key, payload)
                sent.append((key, payload, t[0]))
                t[0] += 0.01
        rec.on_bytes(f"iea/{corridor}/rsu/rsu1/objects", b"\xc1 not msgpack")  # recorded as it came
    return sent


def test_recording_holds_key_stamp_receive_time_and_schema(tmp_path):
    path = tmp_path / "run.mcap"
    sent = _write_examples(path)
    info = check_recording(path)
    assert info["messages"] == len(sent) + 1 and info["profile"] == "iea-corridor"
    kinds = {m.kind for m in read_recording(path)} - {"unknown"}
    assert set(info["schemas"]) == kinds | {"iea.WirePayload"}
    import jsonschema
    from mcap.reader import make_reader

    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        views = {ch.topic: json.loads(m.data) for _s, ch, m in reader.iter_messages()}
    for ch in summary.channels.values():  # JSON, and the schema record is the committed JSON Schema of the kind
        sc = summary.schemas[ch.schema_id]
        assert sc.encoding == "jsonschema" and ch.message_encoding == "json"
        if ch.topic.startswith("_wire/"):  # the payload that is no message: its bytes, base64, under its key
            assert ch.metadata["key"] == "iea/rellis/rsu/rsu1/objects" and sc.name == "iea.WirePayload"
            continue
        # the record view of the committed JSON Schema of the kind: fields named, the form Foxglove reads
        schema = json.loads(sc.data)
        assert schema == record_view_schema(ch.metadata["kind"])
        assert f"protocol/schema/{ch.metadata['kind']}.json" in schema["$comment"]
        assert views[ch.topic]["kind"] == ch.metadata["kind"]  # a JSON object every JSON reader parses
        jsonschema.Draft202012Validator(schema).validate(views[ch.topic])
    cmd = views["iea/rellis/vehicle/av1/cmd"]
    assert cmd["reason"].startswith("EV approaching") and len(cmd["waypoints"]) == 40
    assert cmd["waypoints"][0] == {"x": 100.0, "y": 5.55} and "supersedes" not in cmd  # null: left out
    obj = views["iea/rellis/rsu/rsu1/objects"]["objects"][0]
    assert obj["pos_x_m"] == 20.0 and obj["obj_type"] == "vehicle" and len(obj["bbox_px"]) == 4
    got = list(read_recording(path))
    assert [(m.key, m.payload) for m in got[:-1]] == [(k, p) for k, p, _ in sent]  # the wire bytes back
    for m, (_, _, recv) in zip(got, sent, strict=False):
        assert m.receive_s == pytest.approx(recv, abs=1e-9)
        stamp, seq = peek_header(m.payload)
        assert m.stamp_s == pytest.approx(stamp) and m.seq == seq
    assert {m.stamp_s for m in got[:-1]} == {10.0, 11.0, 12.0}
    assert got[-1].payload == b"\xc1 not msgpack" and got[-1].stamp_s == pytest.approx(got[-1].receive_s)
    assert got[-1].key == "iea/rellis/rsu/rsu1/objects"
    only_rsu = list(read_recording(path, "iea/rellis/rsu/**"))
    assert only_rsu and all("/rsu/" in m.key for m in only_rsu)


def test_signed_messages_keep_their_signature_through_the_json_view(tmp_path):
    from cryptography.hazmat.primitives.serialization import load_pem_private_key

    from protocol.security import Signer, TrustList, Verifier, new_key_pair

    pem, public_b64 = new_key_pair()
    trust = TrustList.from_entries([{"key_id": "k1", "role": "rsu", "rsu_id": "rsu1", "public_key": public_b64}])
    key, alert = example_messages("rellis")[1]
    signed = Signer("k1", load_pem_private_key(pem, None)).sign_message(key, alert)
    assert signed.auth is not None
    payload = encode(signed)
    with McapRecorder(tmp_path / "run.mcap", clock=lambda: 5.0) as rec:
        rec.on_bytes(key, payload)
    (m,) = read_recording(tmp_path / "run.mcap")
    assert m.payload == payload
    from protocol.codec import decode

    Verifier(trust).check(key, decode(m.payload), now=alert.stamp)  # raises when the signature does not verify


def test_check_recording_refuses_a_truncated_file(tmp_path):
    path = tmp_path / "run.mcap"
    _write_examples(path)
    data = path.read_bytes()
    (tmp_path / "cut.mcap").write_bytes(data[: len(data) // 2])
    with pytest.raises(Exception):  # noqa: B017 (the mcap reader raises its own error kinds)
        check_recording(tmp_path / "cut.mcap")


def test_schedule_scales_by_speed_and_renames_the_corridor(tmp_path):
    path = tmp_path / "run.mcap"
    _write_examples(path, n=2)
    offsets = [o for o, _ in schedule(read_recording(path), 2.0)]
    assert offsets[0] == 0.0 and offsets[-1] == pytest.approx((len(offsets) - 1) * 0.01 / 2)
    assert all(o == 0.0 for o, _ in schedule(read_recording(path), 0.0))
    assert rename_corridor("iea/rellis/vehicle/av1/cmd", "other") == "iea/other/vehicle/av1/cmd"
    with pytest.raises(ValueError):
        list(schedule(read_recording(path), -1.0))


@pytest.mark.slow
def test_lockstep_replayed_into_a_fresh_ddm_makes_the_same_decisions(tmp_path):
    from scenario.lockstep import CorridorLockstep, LockstepConfig

    path = tmp_path / "run.mcap"
    # the EV's lights come on at 4 s: the run holds the alert, the command and its ack
    runner = CorridorLockstep(LockstepConfig(seed=1, duration_s=5.0, detector="motion"),
                              recorder=lambda now, meta: McapRecorder(path, clock=now, metadata=meta))
    runner.run()
    info = check_recording(path)
    assert {"ObjectList", "EvAlert", "PathSwitchCommand", "CommandAck", "VehicleState", "WorldSnapshot",
            "Health"} <= set(info["schemas"])
    recorded = recorded_commands(path)
    assert recorded and recorded[0].manoeuvre != "resume" and "EV" in recorded[0].reason
    replayed = replay_into_ddm(path, runner.corridor, runner.config.ddm_config, duration_s=5.0)
    assert replayed == recorded  # same vehicles, ids, manoeuvres, reasons and issue times
    # the inputs matter: without the EV alerts and object lists the fresh DDM decides nothing of the kind
    cut = tmp_path / "no_rsu.mcap"
    with McapRecorder(cut) as rec:
        for m in read_recording(path):
            if "/rsu/" not in m.key:
                rec.clock = lambda t=m.receive_s: t
                rec.on_bytes(m.key, m.payload)
    assert replay_into_ddm(cut, runner.corridor, runner.config.ddm_config, duration_s=5.0) != recorded


def _iea(*args: str) -> list[str]:
    return [sys.executable, "-m", "deploy", *args]


@pytest.mark.timeout(60)
def test_iea_record_and_iea_replay_over_zenoh(tmp_path):
    src = tmp_path / "src.mcap"
    sent = _write_examples(src, corridor="rec", n=3)
    cid = f"rr-{uuid.uuid4().hex[:6]}"
    out = tmp_path / "out.mcap"
    env = dict(os.environ, PYTHONPATH=str(ROOT), PYTHONUNBUFFERED="1")
    rec = subprocess.Popen(_iea("record", "--out", str(out), "--corridor-id", cid, "--duration-s", "25"),
                           stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env, cwd=ROOT)
    try:
        line = rec.stdout.readline()
        assert "[record]" in line, line
        time.sleep(1.0)
        rep = subprocess.run(_iea("replay", str(src), "--speed", "0", "--corridor-id", cid), capture_output=True,
                             text=True, env=env, cwd=ROOT, timeout=30)
        assert rep.returncode == 0, rep.stdout + rep.stderr
        assert f"{len(sent) + 1} messages published" in rep.stdout
        time.sleep(1.0)
    finally:
        stop_process(rec, timeout_s=15.0)
    def per_key(pairs):
        out: dict[str, list[bytes]] = {}
        for k, p in pairs:
            out.setdefault(k, []).append(p)
        return out

    got = per_key((m.key, m.payload) for m in read_recording(out))
    want = per_key([(rename_corridor(k, cid), p) for k, p, _ in sent]
                   + [(f"iea/{cid}/rsu/rsu1/objects", b"\xc1 not msgpack")])
    assert got == want  # every key, byte for byte, in order (kinds of different priority may interleave)
    topics = check_recording(out)["per_topic"]  # and, beside the keys, the corridor's Foxglove channels
    assert {"/scene/road", "/scene/objects", "/map/av1", "/log", "/vehicle/av1/cmd"} <= set(topics)
