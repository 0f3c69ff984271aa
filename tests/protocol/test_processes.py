"""Two separate processes exchange every message kind over real Zenoh on loopback; the same exchange
over LocalBus and over DsrcLink with 30% loss; a router started by `iea router` joins clients."""

from __future__ import annotations

import json
import socket
import time

import pytest

from protocol import keys
from protocol.clock import SimClock
from protocol.examples import example_messages
from protocol.local_bus import LocalBus
from protocol.radio import ChannelModel, DsrcLink
from protocol.zenoh_transport import ZenohSettings, ZenohTransport

pytestmark = pytest.mark.serial  # processes, Zenoh or its own timing: make test runs it alone


KINDS = {m.KIND for _, m in example_messages()}


def _last_json(text: str) -> dict:
    return json.loads(text.strip().splitlines()[-1])


def test_two_processes_exchange_every_message_kind_over_zenoh(spawn, corridor_id):
    recv = spawn("-m", "protocol.loopback", "receive", "--corridor-id", corridor_id, "--expect", "3",
                 "--timeout-s", "25")
    assert recv.stdout.readline().strip() == "ready"
    send = spawn("-m", "protocol.loopback", "send", "--corridor-id", corridor_id, "--rounds", "5",
                 "--settle-s", "1.0", "--interval-s", "0.1")
    out, err = recv.communicate(timeout=40)
    send.communicate(timeout=20)
    result = _last_json(out)
    assert result["complete"], (result, err)
    assert set(result["kinds"]) == KINDS
    assert all(n >= 3 for n in result["kinds"].values())
    assert result["rejected"] == {}


def _exchange(transport_pub, transport_sub, rounds: int, after_publish=lambda: None) -> dict[str, int]:
    got: dict[str, int] = {}
    transport_sub.subscribe(keys.corridor_expr("c"), lambda k, m: got.__setitem__(m.KIND, got.get(m.KIND, 0) + 1))
    for r in range(rounds):
        for key, msg in example_messages("c", stamp=float(r), seq=r):
            transport_pub.publish(key, msg)
        after_publish()
    return got


def test_same_exchange_over_localbus():
    bus = LocalBus()
    got = _exchange(bus, bus, rounds=5)
    assert got == {k: 5 for k in KINDS}


def test_same_exchange_over_dsrc_link_with_30_percent_loss():
    bus, clock = LocalBus(), SimClock()
    link = DsrcLink(bus, ChannelModel(latency_s=0.02, jitter_s=0.005, loss=0.3), seed=5, clock=clock,
                    directions=("tx",))

    def step():
        clock.advance(0.1)
        link.deliver_due()

    rounds = 400
    got = _exchange(link, bus, rounds=rounds, after_publish=step)
    counts = link.counts["tx"]
    n = rounds * len(KINDS)
    assert counts["offered"] == n
    assert sum(got.values()) == counts["delivered"] == n - counts["dropped_loss"]
    # binomial: 30% of 3200 = 960 +- 5 sigma (5 * 25.9)
    assert abs(counts["dropped_loss"] - 0.3 * n) < 5 * (n * 0.3 * 0.7) ** 0.5
    for kind in KINDS:  # every kind goes through at about 70%
        assert 0.6 * rounds < got[kind] < 0.8 * rounds


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_router_joins_clients(spawn, corridor_id):
    port = _free_port()
    router = spawn("-m", "deploy", "router", "--listen", f"tcp/127.0.0.1:{port}", "--no-multicast",
                   "--duration-s", "30")
    assert "router ready" in router.stdout.readline()
    ep = f"tcp/127.0.0.1:{port}"
    a = ZenohTransport(ZenohSettings(mode="client", connect=[ep]))
    b = ZenohTransport(ZenohSettings(mode="client", connect=[ep]))
    try:
        got = []
        b.subscribe(keys.corridor_expr(corridor_id), lambda k, m: got.append(m.KIND))
        time.sleep(0.5)
        deadline = time.monotonic() + 10
        while len(got) < len(KINDS) and time.monotonic() < deadline:
            got.clear()
            for key, msg in example_messages(corridor_id):
                a.publish(key, msg)
            time.sleep(0.3)
        assert set(got) == KINDS
    finally:
        a.close()
        b.close()


@pytest.mark.parametrize("cmd", [["-m", "deploy", "--help"], ["-m", "protocol.router", "--help"],
                                 ["-m", "deploy", "schema", "--help"], ["-m", "deploy", "corridor"]])
def test_cli_help_runs(spawn, cmd):
    p = spawn(*cmd)
    out, err = p.communicate(timeout=30)
    assert p.returncode == 0, err
    assert out.strip()
