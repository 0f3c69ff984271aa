"""`iea record`: every key of a corridor into an MCAP file that Foxglove, Lichtblick and any MCAP reader decode.

One MCAP channel per key (its topic is the key, e.g. ``iea/rellis/rsu/rsu1/objects``) with message
encoding ``json``: each message is the record view of its wire payload (``protocol.record_view``: the
msgpack map as a JSON object with every record's fields named, a null field left out, a signature as
base64 text) and its channel's schema record (encoding ``jsonschema``, name: the kind) is the record
view of ``protocol/schema/<Kind>.json``, with every range, pattern and unit of it, in the form Foxglove
and Lichtblick read (each field one plain type). The view gives back the very wire bytes
(``protocol.record_view.to_wire``), so a replay publishes what was received and signatures still verify. A payload whose view would not give
its bytes back (not a valid message, or not encoded as this project encodes) is kept on a channel
``_wire/<key>`` as ``{"key", "payload_base64"}`` (schema ``iea.WirePayload``); an RSU's camera frames
(``iea/<c>/rsu/<rsu>/camera/jpeg``) are ``foxglove.CompressedImage`` JSON on the wire and recorded
as they came.

Each message's ``log_time`` is its receive time here, its ``publish_time`` the publisher's ``stamp``
and its ``sequence`` the publisher's per-key ``seq`` (a payload without them - not a valid message,
recorded anyway - gets the receive time and 0). With a ``derive`` function (``deploy.foxglove_scene``)
the recorder also writes derived channels (the 3D scene, transforms, map fixes, the event log: their
channels carry ``derived: true`` in their metadata and are not replayed).

``McapRecorder`` is the writer (thread-safe: Zenoh delivers on several threads); ``read_recording``
reads a file back in receive-time order as wire payloads, filtered by a key expression;
``check_recording`` validates a file with the ``mcap`` reader (summary, every message's channel and
schema) and counts it. Recordings written with message encoding ``msgpack`` (the wire bytes) read too.
"""

from __future__ import annotations

import argparse
import base64
import json
import signal
import sys
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, BinaryIO

import msgpack

from protocol.json_view import JsonViewError
from protocol.keys import KeyError_, is_camera_key, key_matches, message_type_for_key
from protocol.record_view import record_view_schema, to_json, to_wire
from protocol.runtime import stop_on_ctrl_c

MESSAGE_ENCODING = "json"
LEGACY_ENCODING = "msgpack"
"""Recordings made before the record view: the wire bytes as they came (still read by ``read_recording``)."""
SCHEMA_ENCODING = "jsonschema"
PROFILE = "iea-corridor"
NS_PER_S = 1_000_000_000
WIRE_PREFIX = "_wire/"
WIRE_KIND = "iea.WirePayload"
WIRE_SCHEMA = {
    "$schema": "https://json-schema.org/draft/2020-12/schema",
    "title": WIRE_KIND,
    "description": "A payload received on a corridor key whose record view would not give its bytes back "
                   "(not a valid message): the key and the bytes as they came.",
    "type": "object",
    "properties": {"key": {"type": "string", "description": "the Zenoh key it was received on"},
                   "payload_base64": {"type": "string", "contentEncoding": "base64",
                                      "description": "the payload bytes (RFC 4648 section 4)"}},
    "required": ["key", "payload_base64"],
    "additionalProperties": False,
}
CAMERA_KIND = "foxglove.CompressedImage"
FOXGLOVE_SCHEMA_DIR = Path(__file__).resolve().parent / "foxglove_schema"


def foxglove_schema(name: str) -> bytes:
    """The JSON Schema of one of Foxglove's well-known message types (``deploy/foxglove_schema``, as the
    ``@foxglove/schemas`` package publishes them)."""
    path = FOXGLOVE_SCHEMA_DIR / f"{name}.json"
    if not path.is_file():
        raise ValueError(f"no Foxglove schema {name!r} in {FOXGLOVE_SCHEMA_DIR}")
    return path.read_bytes()


Derived = tuple[str, str, bytes, float]
"""One derived message: ``(topic, schema name, JSON bytes, time_s)``; the schema is Foxglove's."""


def peek_header(payload: bytes) -> tuple[float | None, int]:
    """``(stamp_s, seq)`` from a payload's map without building its body (the header fields come first:
    ``protocol.messages.Envelope``); ``(None, 0)`` when the payload is not a map holding them."""
    stamp, seq, found = None, 0, 0
    try:
        up = msgpack.Unpacker(raw=False, strict_map_key=False, max_buffer_size=len(payload) + 1)
        up.feed(payload)
        n = up.read_map_header()
        for _ in range(min(n, 16)):
            name = up.unpack()
            if name == "stamp":
                v = up.unpack()
                stamp = float(v) if isinstance(v, int | float) and not isinstance(v, bool) else None
            elif name == "seq":
                v = up.unpack()
                seq = v if isinstance(v, int) and 0 <= v < 2**63 else 0
            else:
                up.skip()
                continue
            found += 1
            if found == 2:
                break
    except Exception:  # not a msgpack map: recorded as it came, with no header
        return None, 0
    return stamp, seq


def _ns(t_s: float) -> int:
    return max(0, int(round(t_s * NS_PER_S)))


def _key_kind(key: str) -> str:
    try:
        return message_type_for_key(key).KIND
    except KeyError_:
        return CAMERA_KIND if is_camera_key(key) else "unknown"


def json_record(key: str, payload: bytes) -> tuple[str, str, bytes]:
    """``(topic, kind, JSON bytes)`` of one received payload: its record view on its key's channel when the
    view gives the same bytes back, else the bytes on ``_wire/<key>`` (module docstring)."""
    kind = _key_kind(key)
    if kind == CAMERA_KIND:
        try:
            if isinstance(json.loads(payload), dict):
                return key, kind, bytes(payload)
        except ValueError:
            pass
    elif kind != "unknown":
        try:
            view = to_json(payload)
            if to_wire(view) == bytes(payload):
                return key, kind, view
        except JsonViewError:
            pass
    wire = {"key": key, "payload_base64": base64.b64encode(bytes(payload)).decode("ascii")}
    return WIRE_PREFIX + key, WIRE_KIND, json.dumps(wire, separators=(",", ":")).encode()


class McapRecorder:
    """Writes ``(key, payload)`` pairs to an MCAP file; ``on_bytes`` is a ``subscribe_bytes`` callback.

    ``derive(key, payload, now_s)``, when given, returns the derived messages to write beside it."""

    def __init__(self, out: str | Path | BinaryIO, *, clock: Callable[[], float] = time.time,
                 metadata: dict[str, str] | None = None,
                 derive: Callable[[str, bytes, float], Iterable[Derived]] | None = None) -> None:
        from mcap.writer import Writer

        self._own = isinstance(out, str | Path)
        if self._own:
            Path(out).parent.mkdir(parents=True, exist_ok=True)
        self._stream = open(out, "wb") if self._own else out  # noqa: SIM115 (closed in close())
        self.path = Path(out) if self._own else None
        self.clock = clock
        self.derive = derive
        self._writer = Writer(self._stream)
        self._writer.start(profile=PROFILE, library="iea-corridor deploy.record (mcap-python)")
        if metadata:
            self._writer.add_metadata("corridor", {k: str(v) for k, v in metadata.items()})
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self._lock = threading.Lock()
        self._closed = False
        self.counts: Counter = Counter()
        """Messages written, by kind (``iea.WirePayload`` for bytes kept as they came, ``derived`` for the
        derived channels)."""
        self.bytes_by_kind: Counter = Counter()
        """Message bytes written, by kind (as ``counts``)."""

    def _schema_id(self, kind: str) -> int:
        sid = self._schemas.get(kind)
        if sid is None:
            if kind == WIRE_KIND:
                data = json.dumps(WIRE_SCHEMA, indent=1).encode()
            elif kind.startswith("foxglove."):
                data = foxglove_schema(kind)
            else:
                data = json.dumps(record_view_schema(kind), indent=1).encode()
            sid = self._schemas[kind] = self._writer.register_schema(kind, SCHEMA_ENCODING, data)
        return sid

    def _channel_id(self, topic: str, kind: str, metadata: dict[str, str]) -> int:
        cid = self._channels.get(topic)
        if cid is None:
            cid = self._channels[topic] = self._writer.register_channel(
                topic, MESSAGE_ENCODING, self._schema_id(kind), {"kind": kind, **metadata})
        return cid

    def on_bytes(self, key: str, payload: bytes) -> None:
        """Record one message as received now (and what ``derive`` makes of it)."""
        received = self.clock()
        stamp, seq = peek_header(payload)
        topic, kind, data = json_record(key, payload)
        derived = list(self.derive(key, payload, received)) if self.derive is not None else []
        with self._lock:
            if self._closed:
                return
            meta = {"key": key} if kind == WIRE_KIND else {}
            cid = self._channel_id(topic, kind, meta)
            self._writer.add_message(cid, log_time=_ns(received), data=data,
                                     publish_time=_ns(received if stamp is None else stamp), sequence=seq % 2**32)
            self.counts[kind] += 1
            self.bytes_by_kind[kind] += len(data)
            self._write_derived(derived)

    def write_derived(self, derived: Iterable[Derived]) -> None:
        """Write derived messages (e.g. a scene made on a timer rather than on a message)."""
        derived = list(derived)
        with self._lock:
            if not self._closed:
                self._write_derived(derived)

    def _write_derived(self, derived: list[Derived]) -> None:
        for topic, schema, data, t_s in derived:
            cid = self._channel_id(topic, schema, {"derived": "true"})
            self._writer.add_message(cid, log_time=_ns(t_s), data=data, publish_time=_ns(t_s), sequence=0)
            self.counts["derived"] += 1
            self.bytes_by_kind["derived" if schema != CAMERA_KIND else CAMERA_KIND] += len(data)

    @property
    def messages(self) -> int:
        return sum(self.counts.values())

    def close(self) -> None:
        with self._lock:
            if self._closed:
                return
            self._closed = True
            self._writer.finish()
            if self._own:
                self._stream.close()

    def __enter__(self) -> McapRecorder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


@dataclass(frozen=True)
class RecordedMessage:
    key: str
    payload: bytes
    receive_s: float
    stamp_s: float
    seq: int
    kind: str


def wire_payload(channel: Any, schema: Any, data: bytes) -> bytes:
    """The wire bytes of one recorded message (``JsonViewError`` for a view that is not a message)."""
    if channel.message_encoding == LEGACY_ENCODING:
        return bytes(data)
    kind = channel.metadata.get("kind", "")
    if kind == WIRE_KIND:
        return base64.b64decode(json.loads(data)["payload_base64"])
    if kind == CAMERA_KIND:
        return bytes(data)
    return to_wire(data)


def read_recording(path: str | Path, keys: str = "**") -> Iterator[RecordedMessage]:
    """The messages of ``path`` whose key matches the key expression ``keys``, in receive-time order
    (messages received at the same time keep their recorded order), as the wire payloads they were;
    derived channels are left out."""
    from mcap.reader import make_reader

    with open(path, "rb") as f:
        reader = make_reader(f)
        for schema, channel, msg in reader.iter_messages(log_time_order=True):
            if channel.metadata.get("derived") == "true":
                continue
            key = channel.metadata.get("key", channel.topic)
            if keys != "**" and not key_matches(keys, key):
                continue
            kind = channel.metadata.get("kind", "unknown")
            yield RecordedMessage(key, wire_payload(channel, schema, msg.data), msg.log_time / NS_PER_S,
                                  msg.publish_time / NS_PER_S, msg.sequence,
                                  "unknown" if kind == WIRE_KIND else kind)


def check_recording(path: str | Path) -> dict[str, Any]:
    """Validate ``path`` with the ``mcap`` reader; returns counts. Raises ``ValueError`` naming the problem:
    no summary, a channel with an unexpected encoding, a schema that is not the kind's JSON Schema, or a
    message on an undeclared channel."""
    from mcap.reader import make_reader

    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        if summary is None or summary.statistics is None:
            raise ValueError(f"{path}: no MCAP summary (was the recording closed?)")
        header = reader.get_header()
        for ch in summary.channels.values():
            if ch.message_encoding not in (MESSAGE_ENCODING, LEGACY_ENCODING):
                raise ValueError(f"{path}: channel {ch.topic} has encoding {ch.message_encoding!r}")
            if ch.schema_id:
                sc = summary.schemas[ch.schema_id]
                if sc.encoding != SCHEMA_ENCODING or sc.name != ch.metadata.get("kind"):
                    raise ValueError(f"{path}: channel {ch.topic} has schema {sc.name!r} ({sc.encoding})")
                json.loads(sc.data)
        per_topic: Counter = Counter()
        for _schema, channel, _msg in reader.iter_messages(log_time_order=False):
            per_topic[channel.topic] += 1
    st = summary.statistics
    if sum(per_topic.values()) != st.message_count:
        raise ValueError(f"{path}: {sum(per_topic.values())} messages read, the summary says {st.message_count}")
    return {"profile": header.profile, "messages": st.message_count, "channels": len(summary.channels),
            "schemas": sorted(s.name for s in summary.schemas.values()),
            "duration_s": round((st.message_end_time - st.message_start_time) / NS_PER_S, 3),
            "per_topic": dict(per_topic)}


def scene_recorder(path: Any, corridor: Any, **recorder_options: Any) -> Any:
    """A ``scenario.lockstep.RecorderFactory``: an MCAP recorder (``deploy.record.McapRecorder``) of ``path``
    on the run's clock, writing this corridor's Foxglove channels beside the keys."""
    from deploy.foxglove_scene import CorridorScene

    def factory(now: Any, metadata: dict[str, str]) -> Any:
        return McapRecorder(path, clock=now, metadata=metadata, derive=CorridorScene(corridor).feed,
                            **recorder_options)

    return factory


# ---------------------------------------------------------------------- CLI
def record(out: Path, corridor_id: str, settings: Any, duration_s: float | None = None,
           keys: str | None = None, say: Callable[[str], None] = print, stop: threading.Event | None = None,
           corridor: Any = None) -> dict:
    """Record ``keys`` (default every key of the corridor) over Zenoh until ``stop``, Ctrl-C or ``duration_s``;
    with ``corridor``, also its Foxglove channels (``deploy.foxglove_scene``, the DDM's fused tracks polled)."""
    from protocol.keys import corridor_expr
    from protocol.zenoh_transport import ZenohTransport

    expr = keys or corridor_expr(corridor_id)
    stop = stop or threading.Event()
    scene = poll = None
    if corridor is not None:
        from deploy.foxglove_scene import CorridorScene

        scene = CorridorScene(corridor)
    rec = McapRecorder(out, metadata={"corridor_id": corridor_id, "keys": expr},
                       derive=scene.feed if scene is not None else None)
    transport = ZenohTransport(settings, bulk_queue=0)  # every sample on the network thread: none dropped here
    try:
        if scene is not None:
            from deploy.foxglove_scene import DdmStatePoll

            poll = DdmStatePoll(transport, corridor_id, scene).start()
        transport.subscribe_bytes(expr, rec.on_bytes)
        say(f"[record] {expr} -> {out} (Ctrl-C to stop)")
        t0 = time.monotonic()
        while not stop.wait(1.0):
            if scene is not None:  # the scene stays current while the corridor is quiet
                rec.write_derived(scene.tick(time.time()))
            if duration_s is not None and time.monotonic() - t0 >= duration_s:
                break
            say(f"[record] {time.monotonic() - t0:5.0f} s  {rec.messages} messages  "
                + " ".join(f"{k}={v}" for k, v in sorted(rec.counts.items())))
    except KeyboardInterrupt:
        pass
    finally:
        if poll is not None:
            poll.close()
        transport.close()
        if scene is not None:  # the last picture of what was heard, whatever the scene period
            rec.write_derived(scene.tick(time.time(), force=True))
        rec.close()
    info = check_recording(out)
    say(f"[record] wrote {out}: {info['messages']} messages on {info['channels']} keys over {info['duration_s']} s")
    return info


def main(argv: list[str] | None = None) -> int:
    stop_on_ctrl_c()  # SIGINT stops it even when started with SIGINT ignored (protocol.runtime)
    from protocol.corridor import CorridorError, load_corridor
    from protocol.zenoh_transport import ZenohSettings

    ap = argparse.ArgumentParser(prog="iea record", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", required=True, help="MCAP file to write, e.g. run.mcap")
    ap.add_argument("--corridor", default=None, help="corridor file (its id names the keys; default rellis)")
    ap.add_argument("--corridor-id", default=None, help="corridor id (overrides the file's)")
    ap.add_argument("--keys", default=None, help="key expression to record (default iea/<corridor>/**)")
    ap.add_argument("--duration-s", type=float, default=None, help="stop after this long (default: Ctrl-C)")
    ap.add_argument("--no-scene", action="store_true",
                    help="record the keys only, not the Foxglove scene, map and log channels beside them")
    ZenohSettings.add_arguments(ap)
    args = ap.parse_args(argv)
    try:
        corridor = load_corridor(args.corridor)
        cid = args.corridor_id or corridor.corridor_id
        settings = ZenohSettings.from_args(args)
    except (CorridorError, ValueError) as exc:
        print(f"iea record: {exc}", file=sys.stderr)
        return 2
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    record(Path(args.out), cid, settings, args.duration_s, args.keys, stop=stop,
           say=lambda s: print(s, flush=True), corridor=None if args.no_scene else corridor)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
