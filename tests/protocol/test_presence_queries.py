"""Presence by liveliness tokens, state by queryables, QoS by message kind, late-joining DDM.

In-process cases run on ``LocalBus``; the multi-process ones over real Zenoh on loopback (a router, the
scripted corridor ``bench/zenoh_corridor_stub.py`` in its own process, a real ``DdmService`` here),
bounded in time and cleaned up by the ``spawn`` fixture.
"""

from __future__ import annotations

import socket
import sys
import threading
import time
from pathlib import Path

import pytest

from ddm.build import DdmOptions, build_ddm
from ddm.service import DdmService
from deploy import status
from protocol import keys, presence, qos
from protocol.clock import SimClock, WallClock
from protocol.corridor import load_corridor
from protocol.local_bus import LocalBus
from protocol.messages import Health
from protocol.zenoh_transport import ZenohSettings, ZenohTransport

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "bench"))
from zenoh_corridor_stub import CorridorStub  # noqa: E402

pytestmark = pytest.mark.serial  # processes, Zenoh or its own timing: make test runs it alone



# ------------------------------------------------------------------------------------------ QoS
def test_qos_by_kind_commands_first_bulk_last_and_never_mixed():
    cmd, alert = qos.qos_for_key("iea/c/vehicle/av1/cmd"), qos.qos_for_key("iea/c/rsu/rsu1/ev")
    objs, world = qos.qos_for_key("iea/c/rsu/rsu1/objects"), qos.qos_for_key("iea/c/sim/world")
    assert (cmd.priority, cmd.congestion, cmd.express) == ("REAL_TIME", "BLOCK", True)
    assert qos.qos_for_key("iea/c/vehicle/av1/ack") == cmd
    assert (alert.priority, alert.congestion) == ("INTERACTIVE_HIGH", "BLOCK")
    assert (objs.priority, objs.congestion, world.priority, world.congestion) == ("DATA", "DROP", "BACKGROUND", "DROP")
    order = qos.PRIORITIES.index
    assert order(cmd.priority) < order(alert.priority) < order(objs.priority) < order(world.priority)
    with pytest.raises(ValueError, match="mix BLOCK and DROP"):
        qos.check_separation({"a": qos.COMMAND, "b": qos.QosClass("REAL_TIME", "DROP", True)})
    assert qos.is_bulk_expr("iea/c/rsu/*/objects") and qos.is_bulk_expr("iea/c/sim/world")
    assert not qos.is_bulk_expr("iea/c/rsu/*/*") and not qos.is_bulk_expr("iea/c/vehicle/av1/cmd")
    # a replay keeps each kind's priority but loses and batches nothing
    assert qos.qos_lossless("iea/c/sim/world") == qos.QosClass("BACKGROUND", "BLOCK", True)
    assert qos.qos_lossless("iea/c/vehicle/av1/cmd") == cmd


def test_zenoh_publishers_carry_their_kind_qos(corridor_id):
    import zenoh

    t = ZenohTransport()
    try:
        c = corridor_id
        for key in (keys.vehicle_key(c, "av1", "cmd"), keys.sim_world_key(c)):
            t.publish_bytes(key, b"x")
        cmd, world = t._publishers[keys.vehicle_key(c, "av1", "cmd")], t._publishers[keys.sim_world_key(c)]
        assert cmd.priority == zenoh.Priority.REAL_TIME and cmd.congestion_control == zenoh.CongestionControl.BLOCK
        assert world.priority == zenoh.Priority.BACKGROUND and world.congestion_control == zenoh.CongestionControl.DROP
    finally:
        t.close()


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="per-thread niceness is Linux's")
def test_zenoh_bulk_drain_thread_runs_niced(corridor_id):
    """Bulk decoding yields the CPU to the command path (zenoh_bench: flood p99 10.8-10.9 -> 6.5-7.3 ms)."""
    import os

    from protocol.zenoh_transport import BULK_THREAD_NICE

    t = ZenohTransport()
    try:
        t.subscribe_bytes(keys.sim_world_key(corridor_id), lambda key, payload: None)
        drain = next(th for th in threading.enumerate() if th.name.startswith("bulk "))
        deadline = time.monotonic() + 5.0
        while os.getpriority(os.PRIO_PROCESS, drain.native_id) != BULK_THREAD_NICE and time.monotonic() < deadline:
            time.sleep(0.01)
        assert os.getpriority(os.PRIO_PROCESS, drain.native_id) == BULK_THREAD_NICE
        assert os.getpriority(os.PRIO_PROCESS, threading.get_native_id()) != BULK_THREAD_NICE  # this thread untouched
    finally:
        t.close()


def test_zenoh_close_ends_the_bulk_drain_threads(corridor_id):
    """A bulk subscription's drain thread still waiting in recv() at interpreter exit aborted the RSU (exit -6,
    "FATAL: exception not rethrown"): close() must end every one of them."""
    t = ZenohTransport()
    in_callback = threading.Event()

    def slow_callback(key: str, payload: bytes) -> None:  # still busy when close() is called
        in_callback.set()
        time.sleep(0.5)

    t.subscribe_bytes(keys.sim_world_key(corridor_id), slow_callback)
    drains = [th for th in threading.enumerate() if th.name.startswith("bulk ")]
    assert drains and all(th.is_alive() for th in drains)
    t.publish_bytes(keys.sim_world_key(corridor_id), b"x")
    assert in_callback.wait(5.0)
    t.close()
    assert not any(th.is_alive() for th in drains)


# ------------------------------------------------------------------------------ LocalBus primitives
def test_localbus_tokens_history_loss_and_queries():
    bus = LocalBus()
    a = bus.declare_token(keys.alive_key("c", "rsu", "rsu1"))
    seen: list[tuple[str, bool]] = []
    bus.subscribe_presence(keys.alive_expr("c", "rsu"), lambda k, up: seen.append((k, up)))
    assert seen == [("iea/c/alive/rsu/rsu1", True)]  # history: the token alive before the subscription
    bus.declare_token(keys.alive_key("c", "vehicle", "av1"))  # another role: not this subscriber's
    assert bus.query_presence(keys.alive_expr("c")) == ["iea/c/alive/rsu/rsu1", "iea/c/alive/vehicle/av1"]
    a.close()
    assert seen[-1] == ("iea/c/alive/rsu/rsu1", False)
    bus.declare_queryable("iea/c/rsu/rsu1/*", lambda q: [("iea/c/rsu/rsu1/state", b"{}"),
                                                         ("iea/c/rsu/rsu1/health", b"h")])
    assert bus.query_bytes("iea/c/**/state") == [("iea/c/rsu/rsu1/state", b"{}")]
    assert bus.query("iea/c/rsu/rsu1/health") == []  # b"h" is no Health: refused at the boundary
    assert bus.stats.rejected["format"] + bus.stats.rejected["invalid"] == 1


def test_presence_book_reports_changes_only():
    book = presence.PresenceBook()
    assert book.update("iea/c/alive/rsu/r1", True, 1.0) == ("rsu", "r1", True)
    assert book.update("iea/c/alive/rsu/r1", True, 1.1) is None
    assert book.update("iea/c/alive/rsu/r1", False, 2.0) == ("rsu", "r1", False)
    assert book.lost("rsu") == {"r1": 2.0} and not book.is_alive("rsu", "r1")
    assert book.update("not/a/token", True, 3.0) is None
    book.update("iea/c/alive/rsu/r1", True, 4.0)
    assert book.lost("rsu") == {}


# ------------------------------------------------------------------------------ services on LocalBus
def _ddm(bus, clock, **kw):
    return DdmService(bus, clock, load_corridor(), corridor_id="c", **kw)


def test_ddm_marks_an_rsu_stale_at_once_when_its_token_is_lost():
    bus, clock = LocalBus(), SimClock(100.0)
    healths: list[Health] = []
    bus.subscribe(keys.ddm_health_key("c"), lambda _k, m: healths.append(m))
    stub = CorridorStub(bus, load_corridor(), "c")
    stub.tick(clock.now())
    ddm = _ddm(bus, clock)
    ddm.step()
    assert ddm.presence.alive["rsu"] == {"rsu1", "rsu2", "rsu3", "rsu4"} and not ddm.stale_now
    n = len(healths)
    stub.handles[1].close()  # rsu1's token: its session ended
    assert ddm.stale_now == {"rsu1"}  # no step, no clock advance: the token's loss alone
    assert len(healths) == n + 1 and healths[-1].stale == ["rsu1"] and healths[-1].counts["rsus_lost"] == 1
    stub.handles[-1].close()  # the vehicle's token
    picture = ddm.world.snapshot(clock.now())
    assert picture.vehicle("av1") is not None
    assert "av1" not in [e.vehicle_id for e in ddm.decider.egos(picture, ddm.unreachable_vehicles())]


def test_late_ddm_is_ev_aware_at_construction_with_catch_up_and_not_without():
    bus, clock = LocalBus(), SimClock(time.time())
    stub = CorridorStub(bus, load_corridor(), "c")
    stub.tick(clock.now())
    late = _ddm(bus, clock)
    assert late.ev_aware_s == clock.now()  # decided with the EV in the picture before the first step
    assert late.catch_up_replies["ev"] == 1 and late.catch_up_replies["objects"] == 4
    assert late.catch_up_replies["state"] == 1
    late.close()
    blind = _ddm(bus, clock, catch_up=False)
    blind.step()
    assert blind.ev_aware_s is None  # listening, and no alert heard yet


def test_vehicle_learns_the_ddm_is_gone_from_its_token():
    from vehicle.service import VehicleService

    bus, clock = LocalBus(), SimClock(10.0)
    veh = VehicleService(bus, clock, load_corridor(), "av1")
    assert veh.ddm_present is None
    token = presence.announce(bus, "rellis", "ddm", "ddm")
    assert veh.ddm_present is True
    clock.advance(1.0)
    token.close()
    assert veh.ddm_present is False and veh.ddm_lost_s == 11.0
    # and the vehicle answers queries with its latest state
    veh.step(11.0)
    replies = bus.query(keys.vehicle_key("rellis", "av1", "state"))
    assert [type(m).__name__ for _, m in replies] == ["VehicleState"]
    veh.close()


def test_status_table_lists_every_service_and_the_missing_ones():
    bus, clock = LocalBus(), WallClock()
    corridor = load_corridor()
    stub = CorridorStub(bus, corridor, "c")
    stub.tick(time.time())
    ddm = _ddm(bus, clock)
    ddm.publish_health(clock.now())
    stub.handles[-1].close()  # av1 went away
    st = status.gather(bus, "c", 0.5, status.expected_services(corridor))
    table = {r[0]: r for r in status.rows(st)}
    assert table["ddm"][1] == "yes" and table["ddm"][2] == "ok" and "EVs rsu1-ev-102" in table["ddm"][4]
    assert all(table[f"rsu/rsu{i}"][1] == "yes" for i in range(1, 5))
    assert table["vehicle/av1"][1] == "missing"
    text = status.format_table(status.rows(st))
    assert text.splitlines()[0].split() == ["SERVICE", "UP", "STATUS", "UPTIME", "DETAIL"]


# ------------------------------------------------------------------------------ real Zenoh, processes
def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _wait_line(p, word: str, timeout_s: float) -> str:
    box: list[str] = []
    th = threading.Thread(target=lambda: box.append(p.stdout.readline()), daemon=True)
    th.start()
    th.join(timeout_s)
    assert box and word in box[0], f"{p.args} did not print {word!r} within {timeout_s} s: {box}"
    return box[0]


def _wait(cond, timeout_s: float, step=None) -> float | None:
    t0 = time.perf_counter()
    while time.perf_counter() - t0 < timeout_s:
        if cond():
            return time.perf_counter() - t0
        if step is not None:
            step()
        time.sleep(0.005)
    return None


@pytest.fixture
def router(spawn):
    port = _free_port()
    p = spawn("-m", "protocol.router", "--listen", f"tcp/127.0.0.1:{port}", "--no-multicast")
    _wait_line(p, "router ready", 20.0)
    return f"tcp/127.0.0.1:{port}"


def _stub(spawn, endpoint: str, corridor_id: str):
    p = spawn(str(ROOT / "bench" / "zenoh_corridor_stub.py"), "--corridor-id", corridor_id, "--connect", endpoint,
              "--duration-s", "30")
    _wait_line(p, "ready", 30.0)
    return p


@pytest.mark.timeout(90)
def test_killed_rsu_known_stale_from_its_token_over_zenoh(spawn, router, corridor_id):
    stub = _stub(spawn, router, corridor_id)
    t = ZenohTransport(ZenohSettings(mode="client", connect=[router]))
    ddm = build_ddm(DdmOptions(corridor_id=corridor_id), t, WallClock())
    try:
        assert _wait(lambda: len(ddm.presence.alive.get("rsu", ())) == 4, 10.0) is not None
        t_kill = time.perf_counter()
        stub.kill()  # SIGKILL: no goodbye, the token goes with the TCP link
        took = _wait(lambda: ddm.stale_now >= {"rsu1", "rsu2", "rsu3", "rsu4"}
                     and len(ddm.presence.lost("rsu")) == 4, 5.0)
        assert took is not None, "the DDM did not learn the RSUs were gone"
        assert time.perf_counter() - t_kill < 0.5
    finally:
        ddm.close()
        t.close()


@pytest.mark.timeout(90)
def test_late_ddm_ev_aware_at_once_over_zenoh(spawn, router, corridor_id):
    _stub(spawn, router, corridor_id)
    time.sleep(0.5)  # an alert repeat (2 Hz) is not what the late DDM waits for
    t0 = time.time()
    t = ZenohTransport(ZenohSettings(mode="client", connect=[router]))
    ddm = build_ddm(DdmOptions(corridor_id=corridor_id), t, WallClock())
    try:
        assert _wait(lambda: ddm.ev_aware_s is not None, 5.0, step=ddm.step) is not None
        assert ddm.catch_up_replies.get("ev") == 1  # learned from the RSU's answer, not a repeat
        assert ddm.ev_aware_s - t0 < 0.5
    finally:
        ddm.close()
        t.close()


def _acl_bundle(spawn, tmp_path, corridor_id: str, listen: str) -> Path:
    from protocol.corridor import DEFAULT_CORRIDOR

    corridor_file = tmp_path / "corridor.toml"  # the default corridor under this test's own id
    corridor_file.write_text(DEFAULT_CORRIDOR.read_text().replace('id = "rellis"', f'id = "{corridor_id}"', 1))
    gen = spawn("-m", "deploy", "deploy", "acl", "--corridor", str(corridor_file), "--out", str(tmp_path / "acl"),
                "--listen", listen)
    _, err = gen.communicate(timeout=30)
    assert gen.returncode == 0, err
    return tmp_path / "acl"


def _acl_checks(join, c: str) -> None:
    """rsu1 may declare its own token and answer on its own keys only; everyone may query."""
    rsu1, watcher = join("rsu1"), join("rsu4")
    try:
        rsu1.declare_token(keys.alive_key(c, "rsu", "rsu1"))
        rsu1.declare_token(keys.alive_key(c, "rsu", "rsu2"))  # posing as rsu2: the router refuses it
        for r in ("rsu1", "rsu2"):
            rsu1.declare_queryable(f"iea/{c}/rsu/{r}/*", lambda q, r=r: [(keys.rsu_state_key(c, r), b'{"by":"rsu1"}')])
        time.sleep(0.5)
        assert watcher.query_presence(keys.alive_expr(c)) == [keys.alive_key(c, "rsu", "rsu1")]
        assert [k for k, _ in watcher.query_bytes(f"iea/{c}/rsu/*/state")] == [keys.rsu_state_key(c, "rsu1")]
    finally:
        rsu1.close()
        watcher.close()


@pytest.mark.timeout(90)
def test_acl_router_admits_own_tokens_and_queryables_only(spawn, tmp_path, corridor_id):
    ep = f"tcp/127.0.0.1:{_free_port()}"
    acl = _acl_bundle(spawn, tmp_path, corridor_id, ep)
    router = spawn("-m", "deploy", "router", "--config", str(acl / "router-acl.json5"), "--duration-s", "40")
    _wait_line(router, "router ready", 20.0)
    _acl_checks(lambda user: ZenohTransport(ZenohSettings(mode="client", connect=[ep],
                                                          config_file=str(acl / f"{user}.json5"))), corridor_id)


def test_control_keys_are_commands_acks_and_beats():
    assert qos.is_control_expr("iea/c/vehicle/av1/cmd") and qos.is_control_expr("iea/c/vehicle/av1/ack")
    assert qos.is_control_expr("iea/c/ddm/health") and qos.is_control_expr("iea/c/vehicle/av1/health")
    for other in ("iea/c/vehicle/av1/state", "iea/c/rsu/*/ev", "iea/c/rsu/*/objects", "iea/c/sim/world"):
        assert not qos.is_control_expr(other)
