"""One LocalBus input costs a bounded amount of time and memory, whatever its bytes.

A 1 MB payload of nested one-element arrays (what the fuzzer's "list grown to 5,000 items of a 200-deep
nesting" makes) would take 16 s and 123 MB if unpacked whole, and an unbounded decoder builds up to ~250,000
tuples from a 512 kB payload before validating. So the decoder refuses a payload over 256 kB before parsing, caps every
array, map, string and binary at the largest any valid message has, and stops building once a payload
holds more arrays and maps than any valid message (``protocol.codec``)."""

from __future__ import annotations

import gc
import time
import tracemalloc

import msgpack
import pytest

from protocol import keys
from protocol.codec import (
    MAX_CONTAINER_ITEMS,
    MAX_CONTAINERS,
    MAX_PAYLOAD_BYTES,
    ProtocolError,
    decode,
    encode,
)
from protocol.examples import example_messages, object_list
from protocol.local_bus import LocalBus
from protocol.messages import MAX_ACTORS, MAX_OBJECTS, Actor, LightBar, WorldSnapshot

C = "b24"
MAX_INPUT_CPU_S = 0.05
"""The bound on one input (measured worst: ~3 ms for a 1,024-actor snapshot)."""
MAX_INPUT_TRACED_BYTES = 4 * 2**20
"""Python memory one input may allocate at its peak (decoding the largest valid snapshot: ~1.8 MB; a
256 kB tuple bomb builds ~0.1 MB; unbounded it would build ~6.8 MB)."""


def _deep(depth: int):
    v = 0
    for _ in range(depth):
        v = [v]
    return v


def _with(kind_index: int, **fields) -> bytes:
    body = msgpack.unpackb(encode(example_messages(C, stamp=10.0)[kind_index][1]), raw=False)
    body.update(fields)
    return msgpack.packb(body)


def _largest_snapshot() -> WorldSnapshot:
    actor = Actor(actor_id="a" * 64, kind="ev", pos_x_m=123456.789, pos_y_m=-98765.4321, heading_rad=3.1,
                  length_m=29.9, width_m=4.9, height_m=5.9, speed_mps=99.1, lane=15, colour_bgr=(255, 255, 255),
                  light_bar=LightBar(on=True, frequency_hz=19.1, phase_s=0.123), style=2**53)
    return WorldSnapshot(src="s" * 64, seq=2**53, stamp=1.7e9, scenario="x" * 64, sim_time_s=1e7, seed=2**53,
                         actors=[actor] * MAX_ACTORS)


HOSTILE = {
    # a CommandAck whose ``v`` is 5,000 copies of a 200-deep nesting (1 MB)
    "nested_1MB": _with(4, v=[_deep(200)] * 5000),
    # under the size cap: as many tuples as the bytes allow, in arrays of legal length
    "tuple_bomb_256kB": b"\xdc\x03\xe8" + (b"\xdc\x00\x7f" + b"\x91\x90" * 127) * 1000,
    "tuple_bomb_500kB": b"\xdc\x03\xe8" + (b"\xdc\x00\xfa" + b"\x91\x90" * 250) * 1000,
    "tuple_bomb_in_a_message": _with(7, actors=[[_deep(1)] * 127] * 1000),
    "maps_bomb": _with(6, rates_hz=[{"a": None}] * 1024),
    "deep_nesting": _with(0, objects="@@").replace(b"\xa2@@", b"\x91" * 100_000 + b"\x00"),
    "array32_header": b"\x81\xa4kind\xdd\xff\xff\xff\xff" + b"\xc0" * 1000,
    "long_string": _with(4, reason="x" * 100_000),
    "objects_past_cap": _with(0, objects=[msgpack.unpackb(encode(object_list(1)))["objects"][0]] * 1024),
    "actors_all_invalid": _with(7, actors=[[0] * 14] * 1024),
    "largest_valid_snapshot": encode(_largest_snapshot()),
}


def test_the_largest_valid_messages_fit_the_caps():
    snap = encode(_largest_snapshot())
    assert len(snap) < MAX_PAYLOAD_BYTES and decode(snap, WorldSnapshot).actors[-1].style == 2**53
    ol = object_list(MAX_OBJECTS)
    assert decode(encode(ol)) == ol
    assert MAX_CONTAINER_ITEMS >= MAX_ACTORS and MAX_CONTAINERS >= 3 * MAX_ACTORS + 1


def test_more_arrays_than_any_message_are_refused_before_they_are_built():
    with pytest.raises(ProtocolError, match=f"more than {MAX_CONTAINERS} arrays and maps") as info:
        decode(HOSTILE["tuple_bomb_256kB"])
    assert info.value.reason == "format"
    with pytest.raises(ProtocolError, match="exceeds max_array_len"):
        decode(msgpack.packb([0] * (MAX_CONTAINER_ITEMS + 1)))
    with pytest.raises(ProtocolError, match="ObjectList.objects: at most 256 items, got 1024"):
        decode(HOSTILE["objects_past_cap"])


@pytest.mark.parametrize("name", sorted(HOSTILE))
def test_one_bus_input_is_bounded_in_time_and_memory(name):
    payload = HOSTILE[name]
    bus = LocalBus()
    got = []
    bus.subscribe(keys.corridor_expr(C), lambda k, m: got.append(m))
    key = keys.sim_world_key(C) if name == "largest_valid_snapshot" else keys.vehicle_key(C, "av1", "ack")
    gc.collect()
    t0 = time.thread_time()
    bus.publish_bytes(key, payload)
    cpu_s = time.thread_time() - t0
    tracemalloc.start()
    try:
        bus.publish_bytes(key, payload)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert cpu_s < MAX_INPUT_CPU_S, f"{name}: {cpu_s * 1e3:.1f} ms of CPU for one input"
    assert peak < MAX_INPUT_TRACED_BYTES, f"{name}: {peak / 2**20:.1f} MB allocated for one input"
    assert bus.stats.handler_errors == 0
    assert len(got) == 2 * (name == "largest_valid_snapshot")


def test_a_thousand_hostile_inputs_keep_the_process_size():
    """RSS after 1,100 hostile inputs (100 of each of 11) is within 20 MB of the size after the first round."""
    bus = LocalBus()
    bus.subscribe(keys.corridor_expr(C), lambda k, m: None)
    key = keys.vehicle_key(C, "av1", "ack")
    payloads = [p for n, p in sorted(HOSTILE.items()) if n != "largest_valid_snapshot"]

    def rss_kb() -> float:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * 4096 / 1024

    for p in payloads:
        bus.publish_bytes(key, p)
    gc.collect()
    try:
        start = rss_kb()
    except OSError:
        pytest.skip("needs /proc/self/statm (Linux) to read the resident set size")
    t0 = time.thread_time()
    for _ in range(100):
        for p in payloads:
            bus.publish_bytes(key, p)
    cpu_s = time.thread_time() - t0
    gc.collect()
    assert rss_kb() - start < 20 * 1024
    assert cpu_s / (100 * len(payloads)) < MAX_INPUT_CPU_S
    assert sum(bus.stats.rejected.values()) == 101 * len(payloads)
