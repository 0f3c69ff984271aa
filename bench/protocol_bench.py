"""Protocol benchmark: codec cost per message and Zenoh loopback throughput and latency.

    python bench/protocol_bench.py [--quick] [--json] [--duration-s 10]

Prints the encode+decode time of every message kind (an ObjectList of 30 objects is the headline
figure; target <= 100 us), the same ObjectList with its records sent as maps instead of positional
arrays (the alternative layout: size and round trip both ways), then runs two separate processes over Zenoh on
loopback (peer mode, no router): a publisher streaming 30-object ObjectLists as fast as it can (messages/s received), and
the same at 1,000 msg/s for the one-way latency p50/p99 (target p99 <= 2 ms).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import subprocess
import sys
import time
import uuid
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from protocol import codec  # noqa: E402
from protocol.codec import decode, encode  # noqa: E402
from protocol.examples import example_messages, object_list  # noqa: E402


def codec_us(message, repeat: int) -> tuple[float, float, float]:
    """Best-of-5 mean (encode us, decode us, round trip us) over ``repeat`` iterations."""
    kind = type(message)
    payload = encode(message)
    enc, dec = [], []
    for _ in range(5):
        t0 = time.perf_counter()
        for _ in range(repeat):
            encode(message)
        t1 = time.perf_counter()
        for _ in range(repeat):
            decode(payload, kind)
        t2 = time.perf_counter()
        enc.append((t1 - t0) / repeat * 1e6)
        dec.append((t2 - t1) / repeat * 1e6)
    e, d = min(enc), min(dec)
    return e, d, e + d


@contextlib.contextmanager
def records_as_maps():
    """The codec with nested records sent as maps {field: value} instead of arrays (the alternative layout)."""

    def to_map(plan, obj):
        row = plan.getter(obj)
        out = dict(zip(plan.names, (row,) if len(plan.names) == 1 else row, strict=True))
        for n in plan.nested:
            v = out[n.name]
            if v is not None:
                out[n.name] = [n.plan.to_row(x) for x in v] if n.many else n.plan.to_row(v)
        return out

    def from_map(plan, value, where):
        if not isinstance(value, dict):
            raise codec.ProtocolError(f"{where}: a {plan.cls.__name__} must be a map", "invalid")
        if plan.nested:
            value = dict(value)
            for n in plan.nested:
                if n.name in value:
                    value[n.name] = codec._from_wire(n, value[n.name], f"{where}.{n.name}")
        return value

    saved = codec._RecordPlan.to_row, codec._RecordPlan.from_row
    codec._RecordPlan.to_row, codec._RecordPlan.from_row = to_map, from_map
    try:
        yield
    finally:
        codec._RecordPlan.to_row, codec._RecordPlan.from_row = saved


def zenoh_run(rate_hz: float, duration_s: float) -> dict:
    corridor = f"bench{uuid.uuid4().hex[:8]}"
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    base = [sys.executable, "-m", "protocol.loopback"]
    sub = subprocess.Popen([*base, "sub", "--corridor-id", corridor, "--duration-s", str(duration_s + 3.0)],
                           stdout=subprocess.PIPE, text=True, env=env, cwd=ROOT)
    assert sub.stdout is not None
    sub.stdout.readline()  # "ready"
    pub = subprocess.run([*base, "pub", "--corridor-id", corridor, "--rate-hz", str(rate_hz),
                          "--duration-s", str(duration_s), "--settle-s", "1.5"],
                         capture_output=True, text=True, env=env, cwd=ROOT, timeout=duration_s + 60)
    out, _ = sub.communicate(timeout=duration_s + 60)
    sent = json.loads(pub.stdout.strip().splitlines()[-1])
    got = json.loads(out.strip().splitlines()[-1])
    lat = np.array(got["latency_ms"]) if got["latency_ms"] else np.array([np.nan])
    return {
        "sent": sent["sent"],
        "received": got["received"],
        "msgs_per_s": got["received"] / sent["elapsed_s"],
        "latency_p50_ms": float(np.percentile(lat, 50)),
        "latency_p99_ms": float(np.percentile(lat, 99)),
        "latency_max_ms": float(np.max(lat)),
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--json", action="store_true", help="end with one JSON line of the figures")
    ap.add_argument("--duration-s", type=float, default=10.0, help="length of each Zenoh run")
    ap.add_argument("--repeat", type=int, default=2000, help="codec iterations per measurement")
    ap.add_argument("--skip-zenoh", action="store_true", help="codec figures only")
    ap.add_argument("--quick", action="store_true", help="200 codec iterations, 2 s Zenoh runs (a smoke run)")
    args = ap.parse_args()
    if args.quick:
        args.repeat, args.duration_s = 200, 2.0

    print("codec (msgpack + strict pydantic validation), best of 5, microseconds per message")
    print(f"{'kind':<20}{'bytes':>8}{'encode':>10}{'decode':>10}{'round trip':>12}")
    figures: dict[str, float] = {}
    for _, msg in example_messages():
        e, d, rt = codec_us(msg, args.repeat)
        print(f"{msg.KIND:<20}{len(encode(msg)):>8}{e:>10.1f}{d:>10.1f}{rt:>12.1f}")
    ol = object_list(30)
    e, d, rt = codec_us(ol, args.repeat)
    with records_as_maps():
        assert decode(encode(ol), type(ol)) == ol
        map_bytes = len(encode(ol))
        me, md, mrt = codec_us(ol, args.repeat)
    figures["codec_roundtrip_us_30obj"] = round(rt, 2)
    figures["objectlist_30obj_bytes"] = len(encode(ol))
    figures["codec_roundtrip_us_30obj_records_as_maps"] = round(mrt, 2)
    figures["objectlist_30obj_bytes_records_as_maps"] = map_bytes
    print(f"ObjectList, 30 objects: round trip {rt:.1f} us (target <= 100 us), {len(encode(ol))} bytes")
    print(f"  the same with records as maps (not the wire format): round trip {mrt:.1f} us "
          f"(encode {me:.1f}, decode {md:.1f}), {map_bytes} bytes")

    if not args.skip_zenoh:
        print(f"\nZenoh loopback, two processes, peer mode, 30-object ObjectLists, {args.duration_s:g} s each")
        flat = zenoh_run(0.0, args.duration_s)
        print(f"  unthrottled: sent {flat['sent']}, received {flat['received']}, {flat['msgs_per_s']:.0f} msg/s")
        paced = zenoh_run(1000.0, args.duration_s)
        print(f"  1,000 msg/s: received {paced['received']}/{paced['sent']}, one-way latency "
              f"p50 {paced['latency_p50_ms']:.3f} ms, p99 {paced['latency_p99_ms']:.3f} ms, "
              f"max {paced['latency_max_ms']:.2f} ms (target p99 <= 2 ms)")
        figures.update(
            zenoh_msgs_per_s=round(flat["msgs_per_s"], 1),
            zenoh_latency_p50_ms=round(paced["latency_p50_ms"], 4),
            zenoh_latency_p99_ms=round(paced["latency_p99_ms"], 4),
            zenoh_delivered_fraction_at_1000hz=round(paced["received"] / max(paced["sent"], 1), 4),
        )
    if args.json:
        print(json.dumps(figures))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
