"""Conformance of the wire to the published schemas, checked by an outside client (examples/validate_wire.py:
msgpack + jsonschema, none of the project's decoding code): every message kind validates, as built and as
the real services publish it over Zenoh; a corpus of invalid payloads is refused by the schema AND by
protocol.codec.decode; what only the decoder can refuse is listed (and stated in the schemas)."""

from __future__ import annotations

import ast
import importlib.util
import json
import math
import re
import shutil
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import msgpack
import pytest
from conftest import node_harness, run_node

from protocol import keys
from protocol.codec import ProtocolError, decode, encode
from protocol.examples import example_messages

pytestmark = pytest.mark.serial  # processes, Zenoh or its own timing: make test runs it alone


pytest.importorskip("jsonschema", reason="jsonschema is in the dev extra: pip install -e '.[dev]'")

ROOT = Path(__file__).resolve().parents[2]
CLIENTS = [ROOT / "examples" / "validate_wire.py", ROOT / "examples" / "read_object_list.py"]
OUTSIDE_MODULES = {"msgpack", "jsonschema", "zenoh"}


def _load_client():
    spec = importlib.util.spec_from_file_location("outside_validate_wire", CLIENTS[0])
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


CLIENT = _load_client()
CHECKER = CLIENT.WireChecker()
EXAMPLES = {msg.KIND: (key, msg) for key, msg in example_messages()}
DETECTED_OBJECT_FIELDS = CHECKER.schemas["ObjectList"]["$defs"]["DetectedObject"]["x-fields"]
ACTOR_FIELDS = CHECKER.schemas["WorldSnapshot"]["$defs"]["Actor"]["x-fields"]


def _signed(kind: str) -> tuple[str, Any]:
    from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

    from protocol.security import Signer

    key, msg = EXAMPLES[kind]
    return key, Signer("test-key", Ed25519PrivateKey.generate()).sign_message(key, msg)


def _decoder_error(key: str, payload: bytes) -> str | None:
    try:
        decode(payload, keys.message_type_for_key(key))
    except ProtocolError as exc:
        return str(exc)
    return None


# ------------------------------------------------------------------ the client is an outside program
@pytest.mark.parametrize("path", CLIENTS, ids=lambda p: p.name)
def test_outside_clients_use_no_project_code(path):
    imported = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            imported |= {a.name.split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            imported.add((node.module or "").split(".")[0])
    foreign = imported - OUTSIDE_MODULES - set(sys.stdlib_module_names) - {"__future__"}
    assert not foreign, f"{path.name} imports {foreign}: an outside client may use zenoh, msgpack, jsonschema only"


# ------------------------------------------------------------------ valid: every kind
@pytest.mark.parametrize("kind", sorted(EXAMPLES))
def test_every_example_kind_validates(kind):
    key, msg = EXAMPLES[kind]
    assert CHECKER.error(key, encode(msg)) is None


@pytest.mark.parametrize("kind", ["EvAlert", "HazardAlert", "PathSwitchCommand"])
def test_signed_messages_validate(kind):
    key, msg = _signed(kind)
    payload = encode(msg)
    assert _decoder_error(key, payload) is None
    assert CHECKER.error(key, payload) is None


# ------------------------------------------------------------------ invalid: refused by both
def _body(kind: str, signed: bool = False) -> tuple[str, dict]:
    key, msg = _signed(kind) if signed else EXAMPLES[kind]
    return key, msgpack.unpackb(encode(msg), raw=False)


def _mutated(kind: str, change: Callable[[dict], Any], signed: bool = False, key: str | None = None):
    k, body = _body(kind, signed)
    change(body)
    return key or k, msgpack.packb(body, use_bin_type=True)


def _set(path: tuple, value: Any) -> Callable[[dict], None]:
    def change(body: dict) -> None:
        target = body
        for p in path[:-1]:
            target = target[p]
        target[path[-1]] = value
    return change


OBJ = DETECTED_OBJECT_FIELDS.index
ACT = ACTOR_FIELDS.index
OL_KEY, OL = EXAMPLES["ObjectList"]
OL_BYTES = encode(OL)

INVALID: dict[str, tuple[str, bytes]] = {
    "empty payload": (OL_KEY, b""),
    "truncated": (OL_KEY, OL_BYTES[:-3]),
    "trailing byte": (OL_KEY, OL_BYTES + b"\xc0"),
    "not msgpack": (OL_KEY, b"\xc1\xc1\xc1"),
    "top level array": (OL_KEY, msgpack.packb(["ObjectList", 1])),
    "integer map key": (OL_KEY, msgpack.packb({**msgpack.unpackb(OL_BYTES), 7: 1})),
    "extension type": _mutated("ObjectList", _set(("src",), msgpack.ExtType(5, b"rsu1"))),
    "kind missing": _mutated("ObjectList", lambda b: b.pop("kind")),
    "kind unknown": _mutated("ObjectList", _set(("kind",), "ObjectListV2")),
    "kind not the key's": _mutated("ObjectList", lambda b: None, key=EXAMPLES["EvAlert"][0]),
    "version 2": _mutated("ObjectList", _set(("v",), 2)),
    "version missing": _mutated("ObjectList", lambda b: b.pop("v")),
    "extra field": _mutated("ObjectList", _set(("speed",), 1.0)),
    "required field missing": _mutated("ObjectList", lambda b: b.pop("rsu_id")),
    "record sent as a map": _mutated("ObjectList", lambda b: b["objects"].__setitem__(
        0, dict(zip(DETECTED_OBJECT_FIELDS, b["objects"][0], strict=True)))),
    "record one item short": _mutated("ObjectList", lambda b: b["objects"][0].pop()),
    "record one item long": _mutated("ObjectList", lambda b: b["objects"][0].append(0)),
    "latitude 91": _mutated("ObjectList", _set(("objects", 0, OBJ("lat_deg")), 91.0)),
    "lane -1": _mutated("ObjectList", _set(("objects", 0, OBJ("lane")), -1)),
    "lane 16": _mutated("ObjectList", _set(("objects", 0, OBJ("lane")), 16)),
    "probability 1.5": _mutated("ObjectList", _set(("objects", 0, OBJ("obj_type_cfd")), 1.5)),
    "NaN": _mutated("ObjectList", _set(("objects", 0, OBJ("pos_x_m")), math.nan)),
    "infinity": _mutated("ObjectList", _set(("stamp",), math.inf)),
    "text for a number": _mutated("ObjectList", _set(("objects", 0, OBJ("pos_x_m")), "20.0")),
    "null where not nullable": _mutated("ObjectList", _set(("objects", 0, OBJ("pos_y_m")), None)),
    "boolean for an integer": _mutated("ObjectList", _set(("seq",), True)),
    "box of 3 numbers": _mutated("ObjectList", _set(("objects", 0, OBJ("bbox_px")), [1.0, 2.0, 3.0])),
    "unknown enum value": _mutated("ObjectList", _set(("objects", 0, OBJ("light_state")), "disco")),
    "id with a space": _mutated("ObjectList", _set(("src",), "rsu 1")),
    "id ending in a newline": _mutated("ObjectList", _set(("rsu_id",), "rsu1\n")),
    "id of 65 characters": _mutated("ObjectList", _set(("rsu_id",), "r" * 65)),
    "negative speed": _mutated("VehicleState", _set(("speed_mps",), -1.0)),
    "evidence of 4 fields": _mutated("EvAlert", lambda b: b["evidence"].pop()),
    "signature of 63 bytes": _mutated("EvAlert", _set(("auth", 3), bytes(63)), signed=True),
    "signature as text, not base64": _mutated("EvAlert", _set(("auth", 3), "not a signature"), signed=True),
    "health key with a slash": _mutated("Health", _set(("rates_hz",), {"a/b": 1.0})),
    "health count negative": _mutated("Health", _set(("drops",), {"x": -1})),
    "health key empty": _mutated("Health", _set(("rejected",), {"": 1})),
    "pull over with one waypoint": _mutated("PathSwitchCommand", lambda b: b.update(
        waypoints=b["waypoints"][:1], speed_profile_mps=[])),
    "light bar pattern unknown": _mutated("WorldSnapshot", _set(("actors", 1, ACT("light_bar"), 1), "disco")),
    "actor of zero length": _mutated("WorldSnapshot", _set(("actors", 0, ACT("length_m")), 0.0)),
    "colour of two channels": _mutated("WorldSnapshot", _set(("actors", 0, ACT("colour_bgr")), [1, 2])),
    "257 objects": _mutated("ObjectList", lambda b: b.__setitem__("objects", (b["objects"] * 9)[:257])),
}


@pytest.mark.parametrize("case", sorted(INVALID))
def test_invalid_payload_is_refused_by_the_schema_and_the_decoder(case):
    key, payload = INVALID[case]
    assert _decoder_error(key, payload) is not None, f"{case}: the decoder accepted it"
    assert CHECKER.error(key, payload) is not None, f"{case}: the schema accepted it"


GAPS: dict[str, tuple[tuple[str, bytes], str]] = {
    "box with x2 < x1": (_mutated("ObjectList", _set(("objects", 0, OBJ("bbox_px")), [9.0, 0.0, 1.0, 5.0])),
                         "bbox_px: x2 >= x1"),
    "valid_until before issued_at": (_mutated("PathSwitchCommand", _set(("valid_until",), 0.5)),
                                     "valid_until > issued_at"),
    "speed profile shorter than the path": (_mutated("PathSwitchCommand", lambda b: b["speed_profile_mps"].pop()),
                                            "one entry per waypoint"),
    "1.0 for an integer": (_mutated("ObjectList", _set(("frame",), 1.0)), "integer vs float"),
    "signature sent as text": (_mutated("EvAlert", _set(("auth", 3), "A" * 86 + "=="), signed=True), "x-msgpack"),
    "id sent as bin": (_mutated("ObjectList", _set(("src",), b"abc")), "x-msgpack"),
}


@pytest.mark.parametrize("case", sorted(GAPS))
def test_what_only_the_decoder_refuses_is_stated_in_the_schema(case):
    """JSON Schema cannot state cross-field rules, tell 1.0 from 1 nor msgpack bin from str (both are JSON
    strings): the decoder refuses these, the schema accepts them, and the schema's $comment says so."""
    (key, payload), stated = GAPS[case]
    assert _decoder_error(key, payload) is not None
    assert CHECKER.error(key, payload) is None
    kind = msgpack.unpackb(payload)["kind"]
    assert stated in CHECKER.schemas[kind]["$comment"]


def _leaf_paths(value: Any, path: tuple = ()):
    yield path
    if isinstance(value, dict):
        for k, x in value.items():
            yield from _leaf_paths(x, (*path, k))
    elif isinstance(value, list):
        for i, x in enumerate(value):
            yield from _leaf_paths(x, (*path, i))


def test_the_schema_never_refuses_what_the_decoder_accepts():
    """Differential run: 600 seeded mutations of the examples (one value replaced by an edge value); any
    payload the project's decoder accepts, the outside client accepts too."""
    import random

    rng = random.Random(26)
    pool = [0, 1, -1, 2**53, 2**53 + 1, 2**64 - 1, -(2**63), 0.5, 1.0, -0.0, 1e300, -1e300, 91.0, 181.0, 16, 255,
            256, "", "a", "rsu1", "rsu1\n", "x" * 65, "a b", "none", "vehicle", "resume", True, False, None, [],
            [1.0, 2.0], {}, {"a": 1}, b"abc", bytes(64)]
    accepted = 0
    for _ in range(600):
        key, msg = rng.choice(list(EXAMPLES.values()))
        body = msgpack.unpackb(encode(msg), raw=False)
        path = rng.choice([p for p in _leaf_paths(body) if p])
        _set(path, rng.choice(pool))(body)
        payload = msgpack.packb(body, use_bin_type=True)
        if _decoder_error(key, payload) is None:
            accepted += 1
            assert CHECKER.error(key, payload) is None, (path, body)
    assert accepted > 50


def test_json_view_maps_bin_to_base64_and_refuses_what_json_cannot_hold():
    assert CLIENT.json_view(msgpack.packb({"a": b"\x00\x01"}, use_bin_type=True)) == {"a": "AAE="}
    for bad in (msgpack.packb(math.nan), msgpack.packb(msgpack.ExtType(1, b"")), b"\x91", b"\xc0\xc0"):
        with pytest.raises(ValueError):
            CLIENT.json_view(bad)


# ------------------------------------------------------------------ the real services over Zenoh
@pytest.mark.slow
def test_every_message_of_an_iea_demo_run_validates(tmp_path):
    """``bench/wire_conformance_bench.py --quick``: `iea demo` (10 s of scenario: the EV alert, the signed command
    and its ack happen) while the outside client listens on iea/**; every payload of the demo's corridor
    validates, and the bench ends with its figures as one JSON line. Its recording is read by the reference MCAP
    reader in Node (@mcap/core): every channel JSON, every message valid against its schema, the Foxglove scene,
    map and camera channels there."""
    t0 = time.monotonic()
    bench = subprocess.run([sys.executable, str(ROOT / "bench" / "wire_conformance_bench.py"), "--quick", "--json",
                            "--runs", str(tmp_path)], cwd=ROOT, capture_output=True, text=True, timeout=240)
    assert bench.returncode == 0, bench.stdout[-3000:] + bench.stderr[-2000:]
    figures = json.loads(bench.stdout.strip().splitlines()[-1])
    assert figures["outside_client_valid"] == figures["outside_client_messages"] > 300, bench.stdout[-3000:]
    assert figures["outside_client_valid_fraction"] == 1.0
    kinds = set(figures["runs"][0]["by_kind_all_corridors"])
    assert {"ObjectList", "EvAlert", "PathSwitchCommand", "CommandAck", "VehicleState", "Health",
            "WorldSnapshot"} <= kinds, kinds
    assert time.monotonic() - t0 < 240
    recordings = sorted(tmp_path.glob("demo-*/run.mcap"))
    assert recordings, bench.stdout[-2000:]
    if shutil.which("node") is None:
        return  # the Node reader is optional here: tests/deploy/test_foxglove_node.py says why it skips
    rc, rep = run_node(node_harness(), "read_mcap.mjs", str(recordings[-1]))
    assert rc == 0 and rep["problemCount"] == 0, rep["problems"]
    assert rep["encodings"] == {"json": rep["channels"]}
    for kind in ("ObjectList", "EvAlert", "PathSwitchCommand", "foxglove.SceneUpdate", "foxglove.LocationFix",
                 "foxglove.CompressedImage"):
        assert rep["perSchema"].get(kind, 0) > 0, (kind, rep["perSchema"])


# ------------------------------------------------------------------ the documented example
def test_protocol_doc_shows_the_object_list_example_verbatim():
    code = CLIENTS[1].read_text()
    body = code[code.index("import json"):]
    doc = ROOT / "docs" / "protocol.md"
    assert body.strip() in doc.read_text(), f"{doc.name}'s ObjectList example differs from the file"
    assert len(body.strip().splitlines()) <= 26


def test_object_list_example_reads_a_publisher(spawn, corridor_id):
    reader = spawn(str(CLIENTS[1]), corridor_id, "3")
    time.sleep(1.0)
    spawn("-m", "protocol.loopback", "pub", "--corridor-id", corridor_id, "--rate-hz", "20", "--duration-s", "4",
          "--settle-s", "1.5")
    out, err = reader.communicate(timeout=30)
    assert reader.returncode == 0, err
    lines = out.splitlines()
    assert len(lines) == 90, out[-500:]  # 3 messages of 30 objects
    line = re.compile(r"^rsu1 frame \d+: object \d+ vehicle at \(\d+\.\d, \d\.\d\) m, 13\.2 m/s$")
    assert all(line.match(x) for x in lines), lines[:3]
