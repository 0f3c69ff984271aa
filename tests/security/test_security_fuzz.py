"""Robustness: no input crashes a decoder or a service handler (hypothesis, small example
counts, derandomised; ``IEA_FUZZ_EXAMPLES=2000`` for more; ``bench/fuzz_bench.py`` runs 100,000
inputs per target)."""

from __future__ import annotations

import dataclasses
import math
import os

import msgpack
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bench import fuzz_bench
from protocol.clock import SimClock
from protocol.codec import ProtocolError, decode, encode
from protocol.corridor import load_corridor
from protocol.enums import AlertState, Manoeuvre, Role, VehicleMode
from protocol.examples import example_messages
from protocol.keys import ddm_health_key, rsu_key, vehicle_key
from protocol.local_bus import LocalBus
from protocol.messages import MESSAGE_TYPES, EvAlert, Health, PathSwitchCommand, VehicleState
from protocol.ranges import MAX_POSITION_M, MAX_SPEED_MPS

EXAMPLES = int(os.environ.get("IEA_FUZZ_EXAMPLES", "120"))
"""Examples per test (``IEA_FUZZ_EXAMPLES=2000`` for a longer, randomised run)."""
FAST = settings(max_examples=EXAMPLES, deadline=None, derandomize=EXAMPLES <= 120,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much])
C = "hfuzz"
SEEDS = {type(m): m for _, m in example_messages(C, stamp=10.0)}

# values a peer can put anywhere in a message
WILD = st.recursive(
    st.one_of(st.none(), st.booleans(), st.integers(min_value=-(2**63), max_value=2**64 - 1),
              st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=80), st.binary(max_size=80)),
    lambda inner: st.one_of(st.lists(inner, max_size=6), st.dictionaries(st.text(max_size=8), inner, max_size=4)),
    max_leaves=12)
# extreme but valid: anywhere in the physical range a message may carry (protocol/ranges.py)
POSITION = st.one_of(st.floats(min_value=-MAX_POSITION_M, max_value=MAX_POSITION_M),
                     st.floats(min_value=-2000.0, max_value=2000.0), st.floats(min_value=-150.0, max_value=150.0))
VELOCITY = st.one_of(st.floats(min_value=-MAX_SPEED_MPS, max_value=MAX_SPEED_MPS),
                     st.floats(min_value=-150.0, max_value=150.0))
SPEED = st.floats(0.0, MAX_SPEED_MPS)


def _only_protocol_errors(payload: bytes, kind) -> None:
    try:
        msg = decode(payload, kind)
    except ProtocolError:
        return
    assert type(msg) is kind
    for name in type(msg).model_fields:  # what decodes is finite
        v = getattr(msg, name)
        assert not (isinstance(v, float) and not math.isfinite(v)), name


@pytest.mark.parametrize("kind", MESSAGE_TYPES, ids=lambda k: k.KIND)
@FAST
@given(data=st.binary(max_size=3000))
def test_random_bytes_only_raise_protocol_error(kind, data):
    _only_protocol_errors(data, kind)


@pytest.mark.parametrize("kind", MESSAGE_TYPES, ids=lambda k: k.KIND)
@FAST
@given(data=st.data())
def test_field_replaced_by_anything_only_raises_protocol_error(kind, data):
    tree = msgpack.unpackb(encode(SEEDS[kind]), raw=False)
    field = data.draw(st.sampled_from(sorted(tree)))
    op = data.draw(st.sampled_from(["replace", "delete", "grow", "extra"]))
    if op == "replace":
        tree[field] = data.draw(WILD)
    elif op == "delete":
        del tree[field]
    elif op == "grow" and isinstance(tree[field], list) and tree[field]:
        tree[field] = tree[field] * data.draw(st.integers(2, 2000))
    else:
        tree[data.draw(st.text(max_size=10))] = data.draw(WILD)
    try:
        payload = msgpack.packb(tree, use_bin_type=True)
    except (OverflowError, ValueError, TypeError):
        return
    _only_protocol_errors(payload, kind)


# ----------------------------------------------------------------------------- handlers
CORRIDOR = dataclasses.replace(load_corridor(), corridor_id=C)


@FAST
@given(x=POSITION, y=POSITION, vx=VELOCITY, vy=VELOCITY, ax=POSITION, lane=st.one_of(st.none(), st.integers(0, 15)),
       dt=st.floats(-5.0, 5.0), state=st.sampled_from(list(AlertState)))
def test_ddm_handlers_survive_extreme_but_valid_messages(x, y, vx, vy, ax, lane, dt, state):
    """Found the KD-tree overflow on 1e16 m/s velocities (refused by the codec's ranges)."""
    from ddm.config import DdmConfig
    from ddm.service import DdmService

    bus, clock = LocalBus(), SimClock(100.0)
    svc = DdmService(bus, clock, CORRIDOR, DdmConfig(startup_listen_s=0.0))
    now = clock.now()
    bus.publish(vehicle_key(C, "av1", "state"), VehicleState(
        src="av1", stamp=now, vehicle_id="av1", pos_x_m=ax, pos_y_m=5.55, lat_deg=30.0, lon_deg=-96.0,
        heading_rad=0.0, speed_mps=abs(vx), mode=VehicleMode.DRIVING))
    bus.publish(rsu_key(C, "rsu1", "ev"), EvAlert(
        src="rsu1", stamp=max(0.0, now + dt), alert_id="rsu1-ev-1", state=state, rsu_id="rsu1", object_id=1,
        pos_x_m=x, pos_y_m=y, lat_deg=30.0, lon_deg=-96.0, vel_x_mps=vx, vel_y_mps=vy, speed_mps=abs(vx),
        lane=lane, confidence=0.9, first_seen=max(0.0, now + dt)))
    from protocol.examples import object_list

    ol = object_list(3, max(0.0, now + dt))
    # objects 1 m apart, kept inside the position range at its ends
    objs = [dataclasses.replace(o, pos_x_m=min(MAX_POSITION_M, x + i), pos_y_m=y, vel_x_mps=vx, vel_y_mps=vy)
            for i, o in enumerate(ol.objects)]
    bus.publish(rsu_key(C, "rsu1", "objects"), ol.model_copy(update={"objects": objs}))
    for _ in range(3):
        clock.advance(0.05)
        svc.step()
    assert bus.stats.handler_errors == 0


@FAST
@given(points=st.lists(st.tuples(POSITION, POSITION), min_size=0, max_size=40),
       speeds=st.lists(SPEED, max_size=40), stop=st.one_of(st.none(), st.tuples(POSITION, POSITION)),
       manoeuvre=st.sampled_from(list(Manoeuvre)), speed=SPEED, seq=st.integers(0, 2**53),
       fix=st.tuples(POSITION, POSITION))
def test_vehicle_handlers_survive_extreme_commands_and_fixes(points, speeds, stop, manoeuvre, speed, seq, fix):
    from vehicle.service import VehicleService

    bus, clock = LocalBus(), SimClock(1000.0)
    svc = VehicleService(bus, clock, CORRIDOR, "av1", localisation="both")
    clock.advance(0.5)
    now = clock.now()
    if len(speeds) != len(points):
        speeds = []
    try:
        cmd = PathSwitchCommand(src="ddm", stamp=now, command_id=f"h{seq}", command_seq=seq, vehicle_id="av1",
                                manoeuvre=manoeuvre, reason="h", target_lane=0, waypoints=points,
                                speed_profile_mps=speeds, target_speed_mps=speed, stop_point=stop, issued_at=now,
                                valid_until=now + 5.0)
    except ValueError:
        cmd = None
    if cmd is not None:
        bus.publish(vehicle_key(C, "av1", "cmd"), cmd)
    from protocol.examples import object_list

    ol = object_list(1, now)
    bus.publish(rsu_key(C, "rsu1", "objects"), ol.model_copy(update={
        "objects": [dataclasses.replace(ol.objects[0], pos_x_m=fix[0], pos_y_m=fix[1])]}))
    bus.publish(ddm_health_key(C), Health(src="ddm", stamp=now, role=Role.DDM))
    for _ in range(3):
        svc.step(clock.now())
        clock.advance(0.01)
    assert bus.stats.handler_errors == 0


def test_fuzz_bench_smoke_every_target_no_crash():
    """The 100k-input harness, 60 inputs per target: it runs, reaches every handler, finds nothing."""
    out = fuzz_bench.run(60, say=lambda _s: None)
    assert out["fuzz_crashes"] == 0, {k: v["crash_samples"] for k, v in out["targets"].items() if v["crashes"]}
    assert out["fuzz_targets"] == 20 and out["fuzz_inputs"] == 20 * 60
    assert all(t["accepted"] > 0 for t in out["targets"].values())  # every handler saw decodable input
