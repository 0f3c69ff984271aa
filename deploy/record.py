"""`iea record`: every key of a corridor into an MCAP file, each message as it went on the wire.

One MCAP channel per key (its topic is the key, e.g. ``iea/rellis/rsu/rsu1/objects``), message encoding
``msgpack`` (the payload bytes exactly as received: ``protocol.codec``), and per message kind one schema
record of encoding ``jsonschema`` holding ``protocol/schema/<Kind>.json``, the JSON Schema of the JSON view
of those bytes. Each message's ``log_time`` is its receive time here, its ``publish_time`` the publisher's
``stamp`` and its ``sequence`` the publisher's per-key ``seq`` (both read from the payload's header
without decoding the whole message; a payload without them - not a valid message, recorded anyway as it
went on the wire - gets the receive time and 0). Keys outside the corridor layout are recorded on a
channel with no schema.

``McapRecorder`` is the writer (thread-safe: Zenoh delivers on several threads); ``read_recording``
reads a file back in receive-time order, filtered by a key expression; ``check_recording`` validates a
file with the ``mcap`` reader (summary, every message's channel and schema) and counts it.
"""

from __future__ import annotations

import argparse
import json
import signal
import sys
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, BinaryIO

import msgpack

from protocol.keys import KeyError_, key_matches, message_type_for_key
from protocol.runtime import stop_on_ctrl_c
from protocol.schema_export import SCHEMA_DIR

MESSAGE_ENCODING = "msgpack"
SCHEMA_ENCODING = "jsonschema"
PROFILE = "iea-corridor"
NS_PER_S = 1_000_000_000


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


class McapRecorder:
    """Writes ``(key, payload)`` pairs to an MCAP file; ``on_bytes`` is a ``subscribe_bytes`` callback."""

    def __init__(self, out: str | Path | BinaryIO, *, clock: Callable[[], float] = time.time,
                 metadata: dict[str, str] | None = None) -> None:
        from mcap.writer import Writer

        self._own = isinstance(out, str | Path)
        if self._own:
            Path(out).parent.mkdir(parents=True, exist_ok=True)
        self._stream = open(out, "wb") if self._own else out  # noqa: SIM115 (closed in close())
        self.path = Path(out) if self._own else None
        self.clock = clock
        self._writer = Writer(self._stream)
        self._writer.start(profile=PROFILE, library="iea-corridor deploy.record (mcap-python)")
        if metadata:
            self._writer.add_metadata("corridor", {k: str(v) for k, v in metadata.items()})
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self._lock = threading.Lock()
        self._closed = False
        self.counts: Counter = Counter()
        """Messages written, by kind (``unknown`` for keys outside the layout)."""

    def _schema_id(self, kind: str) -> int:
        sid = self._schemas.get(kind)
        if sid is None:
            data = (SCHEMA_DIR / f"{kind}.json").read_bytes()
            sid = self._schemas[kind] = self._writer.register_schema(kind, SCHEMA_ENCODING, data)
        return sid

    def _channel_id(self, key: str) -> tuple[int, str]:
        cid = self._channels.get(key)
        try:
            kind = message_type_for_key(key).KIND
        except KeyError_:
            kind = "unknown"
        if cid is None:
            sid = 0 if kind == "unknown" else self._schema_id(kind)
            cid = self._channels[key] = self._writer.register_channel(key, MESSAGE_ENCODING, sid, {"kind": kind})
        return cid, kind

    def on_bytes(self, key: str, payload: bytes) -> None:
        """Record one message as received now."""
        received = self.clock()
        stamp, seq = peek_header(payload)
        with self._lock:
            if self._closed:
                return
            cid, kind = self._channel_id(key)
            self._writer.add_message(cid, log_time=_ns(received), data=bytes(payload),
                                     publish_time=_ns(received if stamp is None else stamp), sequence=seq % 2**32)
            self.counts[kind] += 1

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


def read_recording(path: str | Path, keys: str = "**") -> Iterator[RecordedMessage]:
    """The messages of ``path`` whose key matches the key expression ``keys``, in receive-time order
    (messages received at the same time keep their recorded order)."""
    from mcap.reader import make_reader

    with open(path, "rb") as f:
        reader = make_reader(f)
        for _schema, channel, msg in reader.iter_messages(log_time_order=True):
            if keys != "**" and not key_matches(keys, channel.topic):
                continue
            yield RecordedMessage(channel.topic, msg.data, msg.log_time / NS_PER_S, msg.publish_time / NS_PER_S,
                                  msg.sequence, channel.metadata.get("kind", "unknown"))


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
            if ch.message_encoding != MESSAGE_ENCODING:
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


# ---------------------------------------------------------------------- CLI
def record(out: Path, corridor_id: str, settings: Any, duration_s: float | None = None,
           keys: str | None = None, say: Callable[[str], None] = print, stop: threading.Event | None = None) -> dict:
    """Record ``keys`` (default every key of the corridor) over Zenoh until ``stop``, Ctrl-C or ``duration_s``."""
    from protocol.keys import corridor_expr
    from protocol.zenoh_transport import ZenohTransport

    expr = keys or corridor_expr(corridor_id)
    stop = stop or threading.Event()
    rec = McapRecorder(out, metadata={"corridor_id": corridor_id, "keys": expr})
    transport = ZenohTransport(settings, bulk_queue=0)  # every sample on the network thread: none dropped here
    try:
        transport.subscribe_bytes(expr, rec.on_bytes)
        say(f"[record] {expr} -> {out} (Ctrl-C to stop)")
        t0 = time.monotonic()
        while not stop.wait(1.0):
            if duration_s is not None and time.monotonic() - t0 >= duration_s:
                break
            say(f"[record] {time.monotonic() - t0:5.0f} s  {rec.messages} messages  "
                + " ".join(f"{k}={v}" for k, v in sorted(rec.counts.items())))
    except KeyboardInterrupt:
        pass
    finally:
        transport.close()
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
    ZenohSettings.add_arguments(ap)
    args = ap.parse_args(argv)
    try:
        cid = args.corridor_id or load_corridor(args.corridor).corridor_id
        settings = ZenohSettings.from_args(args)
    except (CorridorError, ValueError) as exc:
        print(f"iea record: {exc}", file=sys.stderr)
        return 2
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    record(Path(args.out), cid, settings, args.duration_s, args.keys, stop=stop,
           say=lambda s: print(s, flush=True))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
