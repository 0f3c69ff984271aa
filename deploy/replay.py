"""`iea replay run.mcap`: republish a recording (``deploy.record``), or replay it into a fresh DDM.

Two ways to replay:

- ``replay_to_transport`` republishes the recorded bytes (unchanged: signatures still verify) on a
  transport at their recorded receive times, scaled by ``speed`` (2: twice as fast; 0: as fast as
  possible), optionally only the keys matching ``keys`` and under another corridor id. This is what
  `iea replay` does over Zenoh: a DDM, a view or a recorder started against the corridor sees the run
  again.
- ``replay_into_ddm`` is the deterministic one: a fresh ``DdmService`` on a ``LocalBus`` and a
  ``SimClock`` is fed the recorded inputs of the DDM (every RSU topic, the vehicles' states and acks) in
  recorded order at their receive times, and stepped at its rate between them as the lockstep runner
  (``scenario.lockstep``) steps it: at an instant where a step is due, the RSUs' messages of that instant
  come before it (their tasks run first) and the others after. For a recording of a lockstep run it
  makes the same decisions: ``recorded_commands`` and the commands it returns are the same sequence of
  (vehicle, command id, manoeuvre, reason).
"""

from __future__ import annotations

import argparse
import sys
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from deploy.record import RecordedMessage, read_recording
from protocol.codec import ProtocolError, decode
from protocol.keys import KeyError_, parse_key
from protocol.runtime import stop_on_ctrl_c

DDM_INPUT_TOPICS = {"rsu": ("objects", "ev", "hazard", "health"), "vehicle": ("state", "ack")}


@dataclass(frozen=True)
class IssuedCommand:
    """One command as a decision: who, which, what and why (retransmissions are the same command)."""

    vehicle_id: str
    command_id: str
    manoeuvre: str
    reason: str
    issued_at_s: float


def rename_corridor(key: str, corridor_id: str | None) -> str:
    """``key`` with its corridor chunk replaced (None: unchanged)."""
    if corridor_id is None:
        return key
    parts = key.split("/")
    if len(parts) < 3:
        raise KeyError_(f"key {key!r} has no corridor chunk")
    parts[1] = corridor_id
    return "/".join(parts)


def schedule(messages: Iterable[RecordedMessage], speed: float) -> Iterator[tuple[float, RecordedMessage]]:
    """``(offset_s, message)``: when to publish each message after the start, for a replay at ``speed``."""
    if speed < 0:
        raise ValueError(f"speed must be >= 0 (0: as fast as possible), got {speed}")
    t0 = None
    for m in messages:
        t0 = m.receive_s if t0 is None else t0
        yield (0.0 if speed == 0 else (m.receive_s - t0) / speed), m


def replay_to_transport(path: str | Path, transport: Any, *, speed: float = 1.0, keys: str = "**",
                        corridor_id: str | None = None, stop: threading.Event | None = None,
                        progress: Callable[[int, float], None] | None = None, wait_subscribers_s: float = 0.0,
                        say: Callable[[str], None] = lambda _: None) -> int:
    """Publish the recorded bytes on ``transport`` at their recorded pace; returns how many were sent.

    With ``wait_subscribers_s`` the first message waits (before the pace's clock starts) until a subscriber
    of its key is known, so that a replay started beside its listeners loses nothing to discovery."""
    stop = stop or threading.Event()
    start = None
    sent = 0
    for offset_s, m in schedule(read_recording(path, keys), speed):
        key = rename_corridor(m.key, corridor_id)
        if start is None:
            if wait_subscribers_s > 0 and not transport.wait_for_subscribers(key, wait_subscribers_s):
                say(f"no subscriber of {key} after {wait_subscribers_s:g} s: publishing anyway")
            start = last_progress = time.monotonic()
        wait = start + offset_s - time.monotonic()
        if wait > 0 and stop.wait(wait):
            break
        if stop.is_set():
            break
        transport.publish_bytes(key, m.payload)
        sent += 1
        if progress is not None and time.monotonic() - last_progress >= 1.0:
            last_progress = time.monotonic()
            progress(sent, offset_s)
    return sent


def _decode_command(key: str, payload: bytes) -> IssuedCommand | None:
    try:
        c = decode(payload, parse_key(key).message_type)
    except (ProtocolError, KeyError_):
        return None
    return IssuedCommand(c.vehicle_id, c.command_id, c.manoeuvre.value, c.reason, round(c.issued_at, 6))


def _unique(commands: Iterable[IssuedCommand]) -> list[IssuedCommand]:
    seen: set[str] = set()
    out = []
    for c in commands:
        if c.command_id not in seen:
            seen.add(c.command_id)
            out.append(c)
    return out


def recorded_commands(path: str | Path) -> list[IssuedCommand]:
    """The commands of a recording, each once, in the order they were first published."""
    cmds = (_decode_command(m.key, m.payload) for m in read_recording(path, "iea/*/vehicle/*/cmd"))
    return _unique(c for c in cmds if c is not None)


def is_ddm_input(key: str) -> bool:
    try:
        pk = parse_key(key)
    except KeyError_:
        return False
    return pk.topic in DDM_INPUT_TOPICS.get(pk.domain, ())


def replay_into_ddm(path: str | Path, corridor: Any, config: Any = None, *, duration_s: float | None = None,
                    **ddm_kwargs: Any) -> list[IssuedCommand]:
    """Feed a recording's DDM inputs to a fresh DDM on a simulated clock; returns the commands it issues
    (each once, in order). ``corridor``: the recorded run's corridor (``with_vehicle`` applied as the run
    did); ``config``: its ``DdmConfig``."""
    from ddm.config import DdmConfig
    from ddm.service import DdmService
    from protocol.clock import SimClock
    from protocol.keys import all_vehicles_expr
    from protocol.local_bus import LocalBus

    class ReplayClock(SimClock):
        def set(self, t_s: float) -> None:
            """Jump to exactly ``t_s`` (a recorded receive time), never backwards."""
            self._t = max(self._t, float(t_s))

    config = config or DdmConfig()
    clock, bus = ReplayClock(0.0), LocalBus()
    issued: list[IssuedCommand] = []
    bus.subscribe_bytes(all_vehicles_expr(corridor.corridor_id, "cmd"),
                        lambda k, p: issued.append(c) if (c := _decode_command(k, p)) is not None else None)
    ddm = DdmService(bus, clock, corridor, config, **ddm_kwargs)
    period = 1.0 / config.rate_hz
    next_tick = 0.0

    def tick_until(t: float, inclusive: bool) -> None:
        nonlocal next_tick
        while next_tick < t - 1e-9 or (inclusive and next_tick <= t + 1e-9):
            now = t if abs(next_tick - t) <= 1e-9 else next_tick
            clock.set(now)
            ddm.step(now)
            next_tick += period

    try:
        for m in read_recording(path):
            if duration_s is not None and m.receive_s > duration_s:
                break
            if not is_ddm_input(m.key):
                continue
            tick_until(m.receive_s, inclusive=parse_key(m.key).domain != "rsu")
            clock.set(m.receive_s)
            bus.publish_bytes(m.key, m.payload)
        if duration_s is not None:
            tick_until(duration_s, inclusive=True)
    finally:
        ddm.close()
        bus.close()
    return _unique(issued)


def main(argv: list[str] | None = None) -> int:
    stop_on_ctrl_c()  # SIGINT stops it even when started with SIGINT ignored (protocol.runtime)
    from protocol.zenoh_transport import ZenohSettings, ZenohTransport

    ap = argparse.ArgumentParser(prog="iea replay", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("recording", help="an MCAP file written by `iea record` (or by `iea demo` / `iea up`)")
    ap.add_argument("--speed", type=float, default=1.0, help="pace: 1 real time (default), 2 twice as fast, "
                    "0 as fast as possible")
    ap.add_argument("--keys", default="**", help="replay only the keys matching this key expression, e.g. "
                    "'iea/*/rsu/**' (default: every key)")
    ap.add_argument("--corridor-id", default=None, help="publish under this corridor id instead of the recorded one")
    ap.add_argument("--wait-subscribers-s", type=float, default=5.0, metavar="S",
                    help="before the first message, wait up to S seconds for a subscriber of its key to be known "
                         "(discovery; default 5, 0: publish at once)")
    ap.add_argument("--list", action="store_true", help="print what the file holds (check it) and exit")
    ZenohSettings.add_arguments(ap)
    args = ap.parse_args(argv)
    if not Path(args.recording).is_file():
        print(f"iea replay: {args.recording} does not exist", file=sys.stderr)
        return 2
    from deploy.record import check_recording

    try:
        info = check_recording(args.recording)
    except Exception as exc:  # the mcap reader's errors are many kinds
        print(f"iea replay: {args.recording} is not a readable recording: {exc}", file=sys.stderr)
        return 2
    print(f"[replay] {args.recording}: {info['messages']} messages on {info['channels']} keys over "
          f"{info['duration_s']} s", flush=True)
    if args.list:
        for topic, n in sorted(info["per_topic"].items()):
            print(f"  {n:7d}  {topic}")
        return 0
    try:
        settings = ZenohSettings.from_args(args)
        if args.speed < 0:
            raise ValueError("--speed must be >= 0")
        if args.wait_subscribers_s < 0:
            raise ValueError("--wait-subscribers-s must be >= 0")
    except ValueError as exc:
        print(f"iea replay: {exc}", file=sys.stderr)
        return 2
    from protocol.qos import qos_lossless

    # each kind at its own priority, but blocking and express: a recording replays whole at any --speed
    transport = ZenohTransport(settings, qos=qos_lossless)
    try:
        n = replay_to_transport(args.recording, transport, speed=args.speed, keys=args.keys,
                                corridor_id=args.corridor_id, wait_subscribers_s=args.wait_subscribers_s,
                                say=lambda s: print(f"[replay] {s}", flush=True),
                                progress=lambda sent, t: print(f"[replay] t={t:6.1f} s  {sent} sent", flush=True))
    except KeyboardInterrupt:
        n = -1
    finally:
        transport.close()
    print(f"[replay] done: {n} messages published" if n >= 0 else "[replay] interrupted")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
