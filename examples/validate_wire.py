"""An outside client of the corridor: validate every message on the wire against protocol/schema/*.json.

    python examples/validate_wire.py [--duration-s 40] [--key-expr 'iea/**'] [--connect tcp/HOST:7447] [--json]

Written as an integrator from another stack would write it: eclipse-zenoh, msgpack and jsonschema only,
none of the project's code. It subscribes (peer mode, scouting on loopback, as `iea demo` runs; or a
router with --connect), keeps every payload, and after the run validates each one:

1. msgpack -> the JSON view the schemas describe: maps with string keys, arrays, bin as base64
   (RFC 4648 section 4); NaN, +-inf and extension types have no JSON form and are invalid;
2. the schema is chosen by the payload's ``kind``; the key must match one of its ``x-key-expressions``;
3. Draft 2020-12 validation (``pattern`` with ECMA-262's ``$``, as the spec reads it).

Validation runs after the subscription ends so that the client takes no CPU from the services while
they run. Ends with one JSON line: messages, valid, valid_fraction, by_kind, by_corridor, first errors.
"""

from __future__ import annotations

import argparse
import base64
import json
import math
import re
import sys
import threading
import time
from pathlib import Path
from typing import Any

import msgpack
from jsonschema import Draft202012Validator, ValidationError, validators

SCHEMA_DIR = Path(__file__).resolve().parent.parent / "protocol" / "schema"


def _ecma_pattern(validator: Any, pattern: str, instance: Any, schema: dict) -> Any:
    """``pattern`` as JSON Schema reads it (ECMA-262): ``$`` ends the input; Python's re.search, which
    jsonschema uses, also lets ``$`` match before a final newline ("rsu1\\n" would pass)."""
    if validator.is_type(instance, "string"):
        python = pattern[:-1] + r"\Z" if pattern.endswith("$") and not pattern.endswith("\\$") else pattern
        if not re.search(python, instance):
            yield ValidationError(f"{instance!r} does not match {pattern!r}")


WireValidator = validators.extend(Draft202012Validator, {"pattern": _ecma_pattern})


def _no_ext(code: int, data: bytes) -> Any:
    raise ValueError(f"msgpack extension type {code} has no JSON form")


def _bin_to_base64(value: Any) -> str:
    if isinstance(value, bytes | bytearray):
        return base64.b64encode(bytes(value)).decode("ascii")
    raise ValueError(f"{type(value).__name__} has no JSON form")


def json_view(payload: bytes) -> Any:
    """The JSON value the schemas describe, or ValueError for bytes that are no msgpack value with one."""
    try:
        value = msgpack.unpackb(payload, raw=False, ext_hook=_no_ext, timestamp=0)
        text = json.dumps(value, allow_nan=False, default=_bin_to_base64)
    except (ValueError, TypeError, msgpack.UnpackException) as exc:
        raise ValueError(f"not a msgpack value with a JSON form: {exc.__class__.__name__}: {exc}") from None
    return json.loads(text)


CAMERA_SUFFIX, CAMERA_KIND = "/camera/jpeg", "foxglove.CompressedImage"
"""An RSU's annotated camera frames (docs/protocol.md): Foxglove's CompressedImage as JSON, not a msgpack message."""


def camera_frame_error(payload: bytes) -> str | None:
    """Why ``payload`` is not a ``foxglove.CompressedImage`` JSON object holding a JPEG (None: it is)."""
    try:
        value = json.loads(payload)
        image = base64.b64decode(value["data"], validate=True)
    except (ValueError, KeyError, TypeError) as exc:
        return f"not a CompressedImage JSON object with base64 data: {exc}"
    if value.get("format") != "jpeg" or not image.startswith(b"\xff\xd8"):
        return "a camera frame is a JPEG (format 'jpeg', data starting with the JPEG marker)"
    if not isinstance(value.get("frame_id"), str) or not isinstance(value.get("timestamp"), dict):
        return "a CompressedImage has a frame_id string and a timestamp {sec, nsec}"
    return None


def key_matches(pattern: str, key: str) -> bool:
    """Zenoh-style match where ``*`` stands for exactly one chunk (all the schemas' patterns use)."""
    p, k = pattern.split("/"), key.split("/")
    return len(p) == len(k) and all(a == "*" or a == b for a, b in zip(p, k, strict=True))


class WireChecker:
    """Validates (key, payload) pairs against the published schemas and counts the outcome by kind."""

    def __init__(self, schema_dir: Path = SCHEMA_DIR) -> None:
        self.schemas = {p.stem: json.loads(p.read_text(encoding="utf-8")) for p in sorted(schema_dir.glob("*.json"))}
        if not self.schemas:
            raise FileNotFoundError(f"no *.json schema in {schema_dir}")
        for schema in self.schemas.values():
            Draft202012Validator.check_schema(schema)
        self.validators = {kind: WireValidator(s) for kind, s in self.schemas.items()}
        self.messages = 0
        self.valid = 0
        self.by_kind: dict[str, list[int]] = {}
        self.by_corridor: dict[str, list[int]] = {}
        self.errors: list[str] = []

    def error(self, key: str, payload: bytes) -> str | None:
        """Why ``payload`` on ``key`` is not a valid message (None: it is)."""
        return self._classify(key, payload)[1]

    def _classify(self, key: str, payload: bytes) -> tuple[str, str | None]:
        if key.endswith(CAMERA_SUFFIX):
            return CAMERA_KIND, camera_frame_error(payload)
        try:
            value = json_view(payload)
        except ValueError as exc:
            return "?", str(exc)
        kind = value.get("kind") if isinstance(value, dict) else None
        validator = self.validators.get(kind) if isinstance(kind, str) else None
        if validator is None:
            return "?", f"no schema for kind {kind!r}"
        if key and not any(key_matches(p, key) for p in self.schemas[kind]["x-key-expressions"]):
            return kind, f"a {kind} is not published on {key}"
        problem = min(validator.iter_errors(value), key=lambda e: list(map(str, e.absolute_path)), default=None)
        if problem is not None:
            where = "/".join(str(x) for x in problem.absolute_path) or "<message>"
            return kind, f"{kind} at {where}: {problem.message[:200]}"
        return kind, None

    def check(self, key: str, payload: bytes) -> bool:
        """Validate one message and count it under its kind (``?``: none readable)."""
        kind, reason = self._classify(key, payload)
        corridor = key.split("/")[1] if key.count("/") >= 2 else "?"
        ok = reason is None
        self.messages += 1
        self.valid += ok
        for counts in (self.by_kind.setdefault(kind, [0, 0]), self.by_corridor.setdefault(corridor, [0, 0])):
            counts[0] += 1
            counts[1] += ok
        if not ok and len(self.errors) < 20:
            self.errors.append(f"{key}: {reason}")
        return ok

    def summary(self) -> dict[str, Any]:
        fraction = self.valid / self.messages if self.messages else math.nan
        return {"messages": self.messages, "valid": self.valid,
                "valid_fraction": round(fraction, 6) if self.messages else None,
                "by_kind": {k: {"messages": n, "valid": v} for k, (n, v) in sorted(self.by_kind.items())},
                "by_corridor": {k: {"messages": n, "valid": v} for k, (n, v) in sorted(self.by_corridor.items())},
                "errors": self.errors}


def record(key_expr: str, duration_s: float, connect: list[str], ready=lambda: None,
           idle_stop_s: float | None = None) -> list[tuple[str, bytes]]:
    """Every (key, payload) seen on ``key_expr`` for ``duration_s`` (or until ``idle_stop_s`` of silence
    after the first message)."""
    import zenoh

    conf = zenoh.Config()
    if connect:
        conf.insert_json5("mode", '"client"')
        conf.insert_json5("connect/endpoints", json.dumps(connect))
    else:  # the services' default: peers on loopback, found by multicast scouting there
        conf.insert_json5("listen/endpoints", '["tcp/127.0.0.1:0"]')
        conf.insert_json5("scouting/multicast/interface", '"lo"')
    got: list[tuple[str, bytes]] = []
    last = [0.0]
    lock = threading.Lock()

    def on_sample(sample: Any) -> None:
        with lock:
            got.append((str(sample.key_expr), sample.payload.to_bytes()))
            last[0] = time.monotonic()

    session = zenoh.open(conf)
    try:
        sub = session.declare_subscriber(key_expr, on_sample)
        ready()
        end = time.monotonic() + duration_s
        while time.monotonic() < end:
            time.sleep(0.2)
            if idle_stop_s is not None and last[0] and time.monotonic() - last[0] > idle_stop_s:
                break
        sub.undeclare()
    finally:
        session.close()
    with lock:
        return list(got)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--key-expr", default="iea/**", help="what to subscribe to (default iea/**)")
    ap.add_argument("--duration-s", type=float, default=40.0, help="how long to listen")
    ap.add_argument("--idle-stop-s", type=float, default=None,
                    help="stop earlier after this much silence following the first message")
    ap.add_argument("--connect", action="append", default=[], help="a Zenoh router endpoint (default: peer on lo)")
    ap.add_argument("--schema-dir", default=str(SCHEMA_DIR), help="folder of the published *.json schemas")
    ap.add_argument("--json", action="store_true", help="end with one JSON line of the figures")
    args = ap.parse_args(argv)
    checker = WireChecker(Path(args.schema_dir))
    print(f"listening on {args.key_expr} for up to {args.duration_s:g} s", flush=True)
    got = record(args.key_expr, args.duration_s, args.connect, ready=lambda: print("ready", flush=True),
                 idle_stop_s=args.idle_stop_s)
    t0 = time.perf_counter()
    for key, payload in got:
        checker.check(key, payload)
    s = checker.summary()
    print(f"validated {s['messages']} messages in {time.perf_counter() - t0:.1f} s: {s['valid']} valid")
    for kind, c in s["by_kind"].items():
        print(f"  {kind:<20}{c['valid']:>7} / {c['messages']}")
    for e in s["errors"][:5]:
        print(f"  invalid: {e}")
    if args.json:
        print(json.dumps(s))
    return 0 if s["messages"] and s["valid"] == s["messages"] else 1


if __name__ == "__main__":
    sys.exit(main())
