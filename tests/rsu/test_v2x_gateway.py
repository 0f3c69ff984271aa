"""An RSU's V2X gateway (CPM of its objects, DENM of its EV alerts, its radio's CAMs passed on signed) and the
equipped EV's radio (CAMs at 10 Hz through the DSRC model)."""

from __future__ import annotations

import pytest

from protocol.clock import SimClock
from protocol.corridor import load_corridor
from protocol.enums import ActorKind, AlertState
from protocol.examples import example_messages, object_list
from protocol.keys import rsu_key, sim_world_key
from protocol.local_bus import LocalBus
from protocol.messages import Actor, EvAlert, LightBar, WorldSnapshot
from protocol.radio import ChannelModel, DsrcLink
from protocol.security import Signer, load_private_key, new_key_pair
from protocol.v2x.build import cam_info
from protocol.v2x.codec import decode
from protocol.v2x.keys import v2x_obu_cam_expr, v2x_rsu_key
from protocol.v2x.secure import open_envelope
from rsu.v2x_gateway import V2xGateway
from sim.ev_radio import EvRadio
from sim.scenario import parse_scenario

C = "gw"


@pytest.fixture
def signer(tmp_path) -> Signer:
    pem, _ = new_key_pair()
    (tmp_path / "k.pem").write_bytes(pem)
    return Signer("rsu1-key", load_private_key(tmp_path / "k.pem"))


def _collect(bus: LocalBus, expr: str) -> list[tuple[str, bytes]]:
    out: list[tuple[str, bytes]] = []
    bus.subscribe_bytes(expr, lambda k, p: out.append((k, p)))
    return out


def test_objects_become_cpms_and_alerts_denms(signer):
    bus, clock, corridor = LocalBus(), SimClock(10.0), load_corridor()
    gw = V2xGateway(bus, corridor, C, "rsu1", clock=clock.now, signer=signer, cpm_period_s=0.1).start()
    cpms, denms = _collect(bus, v2x_rsu_key(C, "rsu1", "cpm")), _collect(bus, v2x_rsu_key(C, "rsu1", "denm"))
    for i in range(5):  # 5 lists within 0.1 s: one CPM (at most 10 Hz)
        bus.publish(rsu_key(C, "rsu1", "objects"), object_list(4, 10.0, seq=i))
    clock.advance(0.1)
    bus.publish(rsu_key(C, "rsu1", "objects"), object_list(4, 10.1, seq=9))
    assert len(cpms) == 2
    cpm = decode(cpms[0][1], expected="CPM")
    objects = cpm.value["payload"]["cpmContainers"][1]["containerData"]["perceivedObjects"]
    assert len(objects) == 4 and objects[0]["classification"][0]["objectClass"] == ("vehicleSubClass", 5)
    alert = next(m for _k, m in example_messages(C, stamp=10.0) if isinstance(m, EvAlert))
    bus.publish(rsu_key(C, "rsu1", "ev"), alert)
    bus.publish(rsu_key(C, "rsu1", "ev"), alert.model_copy(update={"state": AlertState.CLEARED}))
    active, cleared = (decode(p, expected="DENM").value["denm"] for _k, p in denms)
    assert active["situation"]["eventType"]["ccAndScc"] == ("emergencyVehicleApproaching95", 1)
    assert cleared["management"]["termination"] == "isCancellation" and "situation" not in cleared
    gw.close()


def _snapshot(t: float, x: float, on: bool) -> WorldSnapshot:
    ev = Actor(actor_id="ev1", kind=ActorKind.EV, pos_x_m=x, pos_y_m=5.55, heading_rad=0.0, length_m=6.5,
               width_m=2.4, height_m=2.8, speed_mps=20.0, light_bar=LightBar(on=on))
    car = Actor(actor_id="car1", kind=ActorKind.CAR, pos_x_m=x + 30, pos_y_m=1.85, heading_rad=0.0, length_m=4.5,
                width_m=1.8, height_m=1.5, speed_mps=13.0)
    return WorldSnapshot(src="sim", stamp=t, scenario="s", sim_time_s=t, actors=[ev, car])


def test_the_ev_radio_sends_10_hz_and_the_rsu_passes_on_what_is_in_range(signer):
    bus, clock, corridor = LocalBus(), SimClock(0.0), load_corridor()
    ev_signer = signer
    radio = EvRadio(bus, corridor, C, signer=ev_signer, clock=clock.now).start()
    gw = V2xGateway(bus, corridor, C, "rsu1", clock=clock.now, signer=signer, radio_range_m=300.0).start()
    air, relays = _collect(bus, v2x_obu_cam_expr(C)), _collect(bus, v2x_rsu_key(C, "rsu1", "rx"))
    for _ in range(60):  # 2 s of snapshots at 30 Hz, the EV from 100 m to 140 m, lights on after 1 s
        bus.publish(sim_world_key(C), _snapshot(clock.now(), 100.0 + 20.0 * clock.now(), clock.now() >= 1.0))
        clock.advance(1 / 30)
    assert 19 <= len(air) <= 21 and radio.sent == len(air)
    info = cam_info(decode(open_envelope(air[-1][1]).payload))
    assert info.ev_on_duty and info.emergency_role and abs(corridor.from_latlon(info.lat_deg, info.lon_deg)[0] - 138) < 5
    assert not cam_info(decode(open_envelope(air[0][1]).payload)).ev_on_duty
    assert len(relays) == len(air)  # rsu1 at x = 0: 100-140 m away, within 300 m
    relay = open_envelope(relays[0][1])
    assert relay.rsu_id == "rsu1" and relay.payload == air[0][1] and relay.heard_on == air[0][0]
    far = V2xGateway(bus, corridor, C, "rsu2", clock=clock.now, signer=signer, radio_range_m=30.0)
    assert not far.in_range(open_envelope(air[-1][1]).payload)  # rsu2 at x = 50: the EV 88 m away
    gw.close()
    radio.close()


def test_the_dsrc_model_drops_broadcasts_beyond_range_and_at_its_loss(signer):
    bus, clock, corridor = LocalBus(), SimClock(0.0), load_corridor()
    masts = [r.position for r in corridor.rsus]
    radio_holder: list[EvRadio] = []
    link = DsrcLink(bus, ChannelModel(loss=0.3, range_m=300.0), seed=4, clock=clock, directions=("tx",),
                    position=lambda: radio_holder[0].position, peers=masts, threaded=False)
    radio = EvRadio(link, corridor, C, signer=signer, clock=clock.now)
    radio_holder.append(radio)
    air = _collect(bus, v2x_obu_cam_expr(C))
    for _ in range(400):
        radio.on_snapshot(_snapshot(clock.now(), 100.0, True))
        clock.advance(0.1)
        link.deliver_due()
    assert 0.6 < len(air) / radio.sent < 0.8  # 30 % loss
    before = len(air)
    for _ in range(50):
        radio.on_snapshot(_snapshot(clock.now(), 1200.0, True))  # 1 km from every mast
        clock.advance(0.1)
        link.deliver_due()
    assert len(air) == before


def test_scenarios_say_whether_the_ev_is_equipped():
    import tomllib

    from sim.scenario import resolve_scenario_path

    data = tomllib.loads(resolve_scenario_path("rellis_ev_yield").read_text(encoding="utf-8"))
    assert parse_scenario(data).ev.equipped is False
    data["ev"]["equipped"] = True
    assert parse_scenario(data).ev.equipped is True
    data["ev"]["equipped"] = "yes"
    with pytest.raises(ValueError, match="equipped"):
        parse_scenario(data)


@pytest.mark.parametrize("snapshot_hz", [20.0, 30.0, 50.0])
def test_the_ev_radio_keeps_10_hz_whatever_the_snapshot_rate(signer, snapshot_hz):
    """CAMs on the 0.1 s grid (TS 103 900 6.1.3): 20 Hz snapshots meet it exactly, float stamps or not."""
    bus, clock, corridor = LocalBus(), SimClock(0.0), load_corridor()
    radio = EvRadio(bus, corridor, C, signer=signer, clock=clock.now).start()
    steps = int(round(4.0 * snapshot_hz))
    for _ in range(steps):  # 4 s of snapshots
        bus.publish(sim_world_key(C), _snapshot(clock.now(), 100.0 + 20.0 * clock.now(), True))
        clock.advance(1 / snapshot_hz)
    assert 39 <= radio.sent <= 41
    radio.close()
