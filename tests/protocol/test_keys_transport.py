"""Key layout, key-expression matching (same cases on LocalBus and Zenoh), transports and DsrcLink."""

from __future__ import annotations

import math
import threading
import time

import pytest

from protocol import keys
from protocol.clock import RateTimer, SimClock, WallClock
from protocol.codec import ProtocolError, encode
from protocol.examples import example_messages
from protocol.local_bus import LocalBus
from protocol.messages import CommandAck, Health, ObjectList
from protocol.radio import ChannelModel, ChannelState, DsrcLink, GilbertElliott
from protocol.zenoh_transport import ZenohSettings, ZenohTransport

pytestmark = pytest.mark.serial  # processes, Zenoh or its own timing: make test runs it alone



# ------------------------------------------------------------------ key layout
def test_builders_and_parser_agree():
    for key, msg in example_messages("c1"):
        parsed = keys.parse_key(key)
        assert parsed.corridor == "c1"
        assert parsed.message_type is type(msg)
    assert keys.rsu_key("c1", "rsu2", "objects") == "iea/c1/rsu/rsu2/objects"
    assert keys.parse_key("iea/c1/vehicle/av1/cmd").node == "av1"
    assert keys.all_rsus_expr("c1") == "iea/c1/rsu/*/*"


@pytest.mark.parametrize("bad", ["", "iea", "foo/c1/rsu/r/objects", "iea/c1/rsu/r/bogus", "iea/c1/rsu/objects",
                                 "iea/c1/ddm/state", "iea/c 1/ddm/health", "iea/c1/vehicle/av1/cmd/extra"])
def test_parser_refuses_keys_outside_the_layout(bad):
    with pytest.raises(keys.KeyError_):
        keys.parse_key(bad)


def test_builders_refuse_bad_chunks():
    with pytest.raises(keys.KeyError_):
        keys.rsu_key("c1", "rsu/2", "objects")
    with pytest.raises(keys.KeyError_):
        keys.vehicle_key("c1", "av1", "steer")


MATCH_CASES = [
    ("iea/C/rsu/*/*", "iea/C/rsu/rsu1/objects", True),
    ("iea/C/rsu/*/*", "iea/C/rsu/rsu2/health", True),
    ("iea/C/rsu/*/*", "iea/C/vehicle/av1/state", False),
    ("iea/C/rsu/*/*", "iea/C/ddm/health", False),
    ("iea/C/**", "iea/C/ddm/health", True),
    ("iea/C/**", "iea/C/vehicle/av1/cmd", True),
    ("iea/C/vehicle/*/state", "iea/C/vehicle/av1/state", True),
    ("iea/C/vehicle/*/state", "iea/C/vehicle/av1/ack", False),
    ("iea/C/**/health", "iea/C/ddm/health", True),
    ("iea/C/**/health", "iea/C/rsu/rsu3/health", True),
    ("iea/C/**/health", "iea/C/rsu/rsu3/objects", False),
    ("iea/C/rsu/rsu$*/ev", "iea/C/rsu/rsu4/ev", True),
    ("iea/C/rsu/rsu$*/ev", "iea/C/rsu/cam4/ev", False),
    ("iea/C/vehicle/av1/cmd", "iea/C/vehicle/av1/cmd", True),
    ("iea/C/vehicle/av1/cmd", "iea/C/vehicle/av10/cmd", False),
]


def _deliveries(transport, corridor: str) -> set[tuple[str, str]]:
    got: set[tuple[str, str]] = set()
    lock = threading.Lock()
    exprs = sorted({e.replace("C", corridor, 1) for e, _, _ in MATCH_CASES})
    for expr in exprs:
        transport.subscribe(expr, lambda k, m, e=expr: (lock.acquire(), got.add((e, k)), lock.release()))
    messages = {type(m): m for _, m in example_messages(corridor)}
    return got, messages, exprs


def _run_matching(transport, corridor: str, settle_s: float = 0.0) -> set[tuple[str, str]]:
    got, messages, _ = _deliveries(transport, corridor)
    time.sleep(settle_s)
    for _, key, _ in MATCH_CASES:
        k = key.replace("C", corridor, 1)
        transport.publish(k, messages[keys.message_type_for_key(k)])
    time.sleep(settle_s)
    return {(e.replace(corridor, "C", 1), k.replace(corridor, "C", 1)) for e, k in got}


def _expected() -> set[tuple[str, str]]:
    out = set()
    for expr, _, _ in MATCH_CASES:
        for _, key, _ in MATCH_CASES:
            if keys.key_matches(expr, key):
                out.add((expr, key))
    return out


@pytest.mark.parametrize("expr,key,expected", MATCH_CASES)
def test_key_matches(expr, key, expected):
    assert keys.key_matches(expr, key) is expected


def test_localbus_matching_cases():
    with LocalBus() as bus:
        assert _run_matching(bus, "C") == _expected()


def test_zenoh_matching_cases_are_the_same(corridor_id):
    with ZenohTransport() as z:
        got = _run_matching(z, corridor_id, settle_s=0.5)
    assert got == _expected()


def test_zenoh_waits_for_a_subscriber_of_another_session_before_publishing(corridor_id):
    """A replay that publishes right after opening its session waits for the listener's subscription to
    reach it (the CI failure of test_iea_record_and_iea_replay_over_zenoh lost every object list)."""
    key = keys.rsu_key(corridor_id, "rsu1", "health")
    got: list[bytes] = []
    with ZenohTransport() as pub_side:
        t0 = time.monotonic()
        assert not pub_side.wait_for_subscribers(key, 0.3)  # nobody listens: False at the timeout
        assert time.monotonic() - t0 >= 0.3
        with ZenohTransport() as sub_side:
            sub_side.subscribe_bytes(f"iea/{corridor_id}/**", lambda k, p: got.append(p))
            assert pub_side.wait_for_subscribers(key, 10.0)
            pub_side.publish_bytes(key, b"first")
            deadline = time.monotonic() + 5.0
            while not got and time.monotonic() < deadline:
                time.sleep(0.01)
    assert got == [b"first"]  # the first message published after the wait arrives
    assert LocalBus().wait_for_subscribers(key, 0.0)  # in-process: nothing to wait for


def test_zenoh_stream_connection_carries_streams_on_a_second_session(corridor_id):
    """With ``stream_connection`` object lists arrive and the vehicle's state leaves over a session of their own
    (its own connection to a router); commands keep the first."""
    objects_key = keys.rsu_key(corridor_id, "rsu1", "objects")
    cmd_key = keys.vehicle_key(corridor_id, "av1", "cmd")
    state_key = keys.vehicle_key(corridor_id, "av1", "state")
    got: dict[str, list[bytes]] = {"objects": [], "cmd": [], "state": []}
    with ZenohTransport(stream_connection=True) as car, ZenohTransport() as corridor:
        car.subscribe_bytes(keys.rsu_topic_expr(corridor_id, "objects"), lambda k, p: got["objects"].append(p))
        car.subscribe_bytes(cmd_key, lambda k, p: got["cmd"].append(p))
        corridor.subscribe_bytes(state_key, lambda k, p: got["state"].append(p))
        assert car._stream_session is not None
        assert str(car._stream_session.info.zid()) != str(car.session.info.zid())
        assert corridor.wait_for_subscribers(objects_key, 10.0) and corridor.wait_for_subscribers(cmd_key, 10.0)
        assert car.wait_for_subscribers(state_key, 10.0)
        corridor.publish_bytes(objects_key, b"objects")
        corridor.publish_bytes(cmd_key, b"cmd")
        car.publish_bytes(state_key, b"state")
        deadline = time.monotonic() + 5.0
        while not all(got.values()) and time.monotonic() < deadline:
            time.sleep(0.01)
    assert got == {"objects": [b"objects"], "cmd": [b"cmd"], "state": [b"state"]}
    with ZenohTransport() as plain:  # by default one session carries everything
        plain.subscribe_bytes(keys.rsu_topic_expr(corridor_id, "objects"), lambda k, p: None)
        assert plain._stream_session is None


def test_zenoh_command_connections_carry_commands_and_acks_twice(corridor_id):
    """With ``command_connections=2`` a command arrives and an ack leaves over two sessions (two copies each);
    state and health travel once."""
    cmd_key, ack_key = keys.vehicle_key(corridor_id, "av1", "cmd"), keys.vehicle_key(corridor_id, "av1", "ack")
    health_key = keys.vehicle_key(corridor_id, "av1", "health")
    got: dict[str, list[bytes]] = {"cmd": [], "ack": [], "health": []}
    with ZenohTransport(stream_connection=True, command_connections=2) as car, ZenohTransport() as ddm:
        car.subscribe_bytes(cmd_key, lambda k, p: got["cmd"].append(p))
        ddm.subscribe_bytes(ack_key, lambda k, p: got["ack"].append(p))
        ddm.subscribe_bytes(health_key, lambda k, p: got["health"].append(p))
        assert len(car._command_sessions) == 1
        assert ddm.wait_for_subscribers(cmd_key, 10.0) and car.wait_for_subscribers(ack_key, 10.0)
        assert car.wait_for_subscribers(health_key, 10.0)
        time.sleep(0.5)  # the extra command connection's subscription reaches the publisher too
        ddm.publish_bytes(cmd_key, b"cmd")
        car.publish_bytes(ack_key, b"ack")
        car.publish_bytes(health_key, b"beat")
        deadline = time.monotonic() + 5.0
        while (len(got["cmd"]) < 2 or len(got["ack"]) < 2) and time.monotonic() < deadline:
            time.sleep(0.01)
        time.sleep(0.2)
    assert got == {"cmd": [b"cmd"] * 2, "ack": [b"ack"] * 2, "health": [b"beat"]}
    with pytest.raises(ValueError, match="command_connections"):
        ZenohTransport(command_connections=0)


# ------------------------------------------------------------------ transports
def test_localbus_rejects_bad_input_and_isolates_handler_errors():
    bus = LocalBus()
    good: list = []
    rejected: list = []
    key = keys.vehicle_key("c", "av1", "ack")
    bus.subscribe(key, lambda k, m: good.append(m), on_reject=lambda k, e: rejected.append(e))
    bus.subscribe(key, lambda k, m: 1 / 0)  # a buggy handler
    ack = CommandAck(src="av1", stamp=1.0, command_id="c1", vehicle_id="av1", status="accepted")
    bus.publish(key, ack)
    bus.publish_bytes(key, b"\xc1garbage")
    bus.publish_bytes(key, encode(Health(src="x", stamp=1.0, role="ddm")))
    assert good == [ack]
    assert [type(e) for e in rejected] == [ProtocolError, ProtocolError]
    assert bus.stats.rejected == {"format": 2, "kind": 2}
    assert bus.stats.handler_errors == 1


def test_publish_refuses_the_wrong_kind_for_a_key():
    with pytest.raises(ProtocolError):
        LocalBus().publish(keys.vehicle_key("c", "av1", "cmd"), Health(src="x", stamp=1.0, role="ddm"))


def test_subscription_close_stops_delivery():
    bus = LocalBus()
    got: list = []
    sub = bus.subscribe("iea/c/**", lambda k, m: got.append(m))
    key, msg = example_messages("c")[4]
    bus.publish(key, msg)
    sub.close()
    bus.publish(key, msg)
    assert len(got) == 1


def test_zenoh_settings_from_args_and_env():
    import argparse

    ap = argparse.ArgumentParser()
    ZenohSettings.add_arguments(ap)
    s = ZenohSettings.from_args(ap.parse_args([]), env={})
    assert (s.mode, s.connect) == ("peer", [])
    s = ZenohSettings.from_args(ap.parse_args([]), env={"IEA_ZENOH_CONNECT": "tcp/10.0.0.1:7447"})
    assert (s.mode, s.connect) == ("client", ["tcp/10.0.0.1:7447"])
    s = ZenohSettings.from_args(ap.parse_args(["--connect", "tcp/127.0.0.1:7447", "--mode", "peer"]), env={})
    assert s.mode == "peer"
    with pytest.raises(ValueError, match="tcp/"):
        ZenohSettings(connect=["localhost"])
    with pytest.raises(ValueError, match="client mode needs"):
        ZenohSettings(mode="client")
    with pytest.raises(ValueError, match="does not exist"):
        ZenohSettings.from_args(ap.parse_args(["--zenoh-config", "/nonexistent.json5"]), env={})


# ------------------------------------------------------------------ channel model and DsrcLink
def _binomial_bound(n: int, p: float, sigmas: float = 5.0) -> float:
    return sigmas * math.sqrt(n * p * (1 - p))


def test_independent_loss_matches_the_model():
    n, p = 20000, 0.3
    st = ChannelState(ChannelModel(loss=p), seed=7)
    delivered = sum(st.admit(i * 0.01, 100) is not None for i in range(n))
    assert abs((n - delivered) - n * p) < _binomial_bound(n, p)


def test_gilbert_elliott_bursts_match_the_model():
    ge = GilbertElliott.from_mean(mean_loss=0.2, mean_burst_length=5.0)
    assert ge.mean_loss == pytest.approx(0.2)
    st = ChannelState(ChannelModel(burst=ge), seed=3)
    n = 50000
    lost = [st.admit(i * 0.01, 100) is None for i in range(n)]
    rate = sum(lost) / n
    bursts, run = [], 0
    for x in lost:
        if x:
            run += 1
        elif run:
            bursts.append(run)
            run = 0
    assert abs(rate - 0.2) < 0.02
    assert 4.0 < sum(bursts) / len(bursts) < 6.0  # bursty: mean run of 5, not 1.25 as if independent


def test_latency_jitter_order_range_bandwidth_outage():
    st = ChannelState(ChannelModel(latency_s=0.1, jitter_s=0.05), seed=1)
    times = [st.admit(i * 0.001, 100) for i in range(500)]
    assert all(t >= i * 0.001 + 0.1 for i, t in enumerate(times))
    assert times == sorted(times)  # never reordered
    st = ChannelState(ChannelModel(range_m=300.0))
    assert st.admit(0.0, 100, distance_m=299.0) is not None
    assert st.admit(0.0, 100, distance_m=301.0) is None and st.counts["dropped_range"] == 1
    st = ChannelState(ChannelModel(bandwidth_bps=8000.0, max_queue_s=0.5))  # 1 kB/s
    at = [st.admit(0.0, 100) for _ in range(8)]
    assert at[0] == pytest.approx(0.1) and at[4] == pytest.approx(0.5)
    assert at[5] == pytest.approx(0.6)  # waited 0.5 s: the most the queue holds
    assert at[6] is None and at[7] is None and st.counts["dropped_bandwidth"] == 2
    st = ChannelState(ChannelModel(outages=((1.0, 2.0),)))
    assert [st.admit(t, 10) is None for t in (0.5, 1.0, 1.5, 2.0)] == [False, True, True, False]


def test_channel_model_validates():
    with pytest.raises(ValueError, match="loss"):
        ChannelModel(loss=1.5)
    with pytest.raises(ValueError, match="latency_s"):
        ChannelModel(latency_s=-1.0)
    with pytest.raises(ValueError, match="outage"):
        ChannelModel(outages=((2.0, 1.0),))


def test_dsrc_link_over_localbus_with_sim_clock():
    bus, clock = LocalBus(), SimClock()
    link = DsrcLink(bus, ChannelModel(latency_s=0.05, loss=0.3), seed=11, clock=clock, directions=("tx",))
    got: list = []
    bus.subscribe("iea/c/**", lambda k, m: got.append(m.seq))
    key, msg = example_messages("c")[4]
    n = 4000
    for i in range(n):
        link.publish(key, msg.model_copy(update={"seq": i}))
    assert got == []  # nothing arrives before its latency
    clock.advance(0.049)
    assert link.deliver_due() == 0
    clock.advance(0.002)
    delivered = link.deliver_due()
    counts = link.counts["tx"]
    assert delivered == len(got) == counts["delivered"]
    assert counts["offered"] == n and counts["dropped_loss"] == n - delivered
    assert abs((n - delivered) - 0.3 * n) < _binomial_bound(n, 0.3)
    assert got == sorted(got)


def test_dsrc_link_rx_direction_and_wall_clock_thread():
    bus = LocalBus()
    link = DsrcLink(bus, ChannelModel(latency_s=0.05), seed=1, clock=WallClock())
    arrived = threading.Event()
    t0 = [0.0]
    t1 = [0.0]

    def on(k, m):
        t1[0] = time.monotonic()
        arrived.set()

    link.subscribe("iea/c/**", on)
    key, msg = example_messages("c")[4]
    t0[0] = time.monotonic()
    bus.publish(key, msg)  # published on the bus, received through the link
    assert arrived.wait(2.0)
    assert t1[0] - t0[0] >= 0.045
    link.close()


def test_dsrc_link_range_uses_the_node_position():
    bus, clock = LocalBus(), SimClock()
    pos = [(0.0, 0.0)]
    link = DsrcLink(bus, ChannelModel(range_m=100.0), clock=clock, position=lambda: pos[0], peers=[(0.0, 0.0)],
                    directions=("tx",))
    got: list = []
    bus.subscribe("iea/c/**", lambda k, m: got.append(m))
    key, msg = example_messages("c")[4]
    link.publish(key, msg)
    pos[0] = (150.0, 0.0)
    link.publish(key, msg)
    link.deliver_due()
    assert len(got) == 1 and link.counts["tx"]["dropped_range"] == 1


# ------------------------------------------------------------------ clocks
def test_sim_clock_and_rate_timer():
    c = SimClock()
    timer = RateTimer(0.5)
    fired = []
    for _ in range(40):
        if timer.due(c.now()):
            fired.append(round(c.now(), 3))
        c.advance(0.1)
    assert fired[:4] == [0.0, 0.5, 1.0, 1.5]
    with pytest.raises(ValueError):
        c.advance(-1.0)
    assert isinstance(WallClock().now(), float)


def test_object_list_key_layout_matches_message():
    assert keys.message_type_for_key(keys.rsu_key("c", "r", "objects")) is ObjectList
