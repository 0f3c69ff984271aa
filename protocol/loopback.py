"""Two-process Zenoh exchange, used by the integration test and bench/protocol_bench.py.

    python -m protocol.loopback send --corridor-id ID [--rounds N]
        publish every example message kind (protocol/examples.py), N rounds
    python -m protocol.loopback receive --corridor-id ID --expect N [--timeout-s T]
        print one JSON line {"kinds": {kind: count}, "rejected": ...} once N messages of each kind arrived
    python -m protocol.loopback pub --corridor-id ID --rate-hz R --duration-s D
        stream 30-object ObjectLists stamped with the wall clock
    python -m protocol.loopback sub --corridor-id ID --duration-s D
        print one JSON line with the count and one-way latencies (receive time - stamp) in ms
"""

from __future__ import annotations

import argparse
import json
import sys
import threading
import time
from collections import Counter

from protocol import keys
from protocol.examples import example_messages, object_list
from protocol.zenoh_transport import ZenohSettings, ZenohTransport


def _send(t: ZenohTransport, args: argparse.Namespace) -> dict:
    time.sleep(args.settle_s)
    for r in range(args.rounds):
        for key, msg in example_messages(args.corridor_id, stamp=time.time(), seq=r):
            t.publish(key, msg)
        time.sleep(args.interval_s)
    return {"sent_rounds": args.rounds}


def _receive(t: ZenohTransport, args: argparse.Namespace) -> dict:
    got: Counter = Counter()
    done = threading.Event()
    want = {m.KIND for _, m in example_messages(args.corridor_id)}

    def on_msg(key: str, msg) -> None:
        got[msg.KIND] += 1
        if all(got[k] >= args.expect for k in want):
            done.set()

    t.subscribe(keys.corridor_expr(args.corridor_id), on_msg)
    print("ready", flush=True)
    done.wait(args.timeout_s)
    return {"kinds": dict(got), "rejected": dict(t.stats.rejected), "complete": done.is_set()}


def _pub(t: ZenohTransport, args: argparse.Namespace) -> dict:
    time.sleep(args.settle_s)
    key = keys.rsu_key(args.corridor_id, "rsu1", "objects")
    template = object_list(30)
    period = 1.0 / args.rate_hz if args.rate_hz > 0 else 0.0
    n, start = 0, time.perf_counter()
    end = start + args.duration_s
    while True:
        now = time.perf_counter()
        if now >= end:
            break
        msg = template.model_copy(update={"seq": n, "frame": n, "stamp": time.time()})
        t.publish(key, msg)
        n += 1
        if period:
            delay = start + n * period - time.perf_counter()
            if delay > 0:
                time.sleep(delay)
    return {"sent": n, "elapsed_s": time.perf_counter() - start}


def _sub(t: ZenohTransport, args: argparse.Namespace) -> dict:
    lat: list[float] = []
    first: list[float] = []
    lock = threading.Lock()

    def on_msg(key: str, msg) -> None:
        now = time.time()
        with lock:
            if not first:
                first.append(time.perf_counter())
            lat.append((now - msg.stamp) * 1000.0)

    t.subscribe(keys.rsu_key(args.corridor_id, "rsu1", "objects"), on_msg)
    print("ready", flush=True)
    time.sleep(args.duration_s)
    with lock:
        span = (time.perf_counter() - first[0]) if first else 0.0
        return {"received": len(lat), "latency_ms": lat, "span_s": span, "rejected": dict(t.stats.rejected)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m protocol.loopback", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("role", choices=["send", "receive", "pub", "sub"])
    ap.add_argument("--corridor-id", required=True)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--expect", type=int, default=1)
    ap.add_argument("--interval-s", type=float, default=0.2)
    ap.add_argument("--settle-s", type=float, default=1.5, help="wait for discovery before sending")
    ap.add_argument("--timeout-s", type=float, default=20.0)
    ap.add_argument("--rate-hz", type=float, default=1000.0, help="0: as fast as possible")
    ap.add_argument("--duration-s", type=float, default=10.0)
    ZenohSettings.add_arguments(ap)
    args = ap.parse_args(argv)
    t = ZenohTransport(ZenohSettings.from_args(args))
    try:
        result = {"send": _send, "receive": _receive, "pub": _pub, "sub": _sub}[args.role](t, args)
    finally:
        t.close()
    print(json.dumps(result), flush=True)
    return 0 if result.get("complete", True) else 1


if __name__ == "__main__":
    sys.exit(main())
