"""Security on the DDM and RSU side: commands leave signed, alerts are verified, peers cannot grow state."""

from __future__ import annotations

import dataclasses
import sys
from pathlib import Path

import msgpack
import pytest
from sec_helpers import corridor_with, ddm_entry, key, rsu_entry

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "ddm"))
from ddm_rig import Rig, det, object_list  # noqa: E402

from ddm import service as ddm_service  # noqa: E402
from ddm.service import DdmService  # noqa: E402
from protocol.clock import SimClock  # noqa: E402
from protocol.codec import ProtocolError, decode, encode  # noqa: E402
from protocol.enums import AlertState, Role, VehicleMode
from protocol.keys import all_rsus_expr, rsu_key, vehicle_key  # noqa: E402
from protocol.local_bus import LocalBus
from protocol.messages import EvAlert, Health, VehicleState
from protocol.security import AuthError, SecureTransport, TrustList, Verifier  # noqa: E402
from vehicle.commands import CommandGate  # noqa: E402

DDM, DDM_PUB = key("ddm-1")
RSU1, RSU1_PUB = key("rsu1-key")
RSU2, RSU2_PUB = key("rsu2-key")
TRUST = [ddm_entry("ddm-1", DDM_PUB, ["av1"]), rsu_entry("rsu1-key", RSU1_PUB, "rsu1"),
         rsu_entry("rsu2-key", RSU2_PUB, "rsu2")]


def signed_rig(verify_alerts: bool | None = None, sign_alerts: bool = True) -> Rig:
    """The DDM lockstep rig with a signing DDM on a corridor trusting the DDM and two RSU keys."""
    r = Rig()
    r.svc.close()
    r.corridor = corridor_with(TRUST)
    r.svc = DdmService(r.bus, r.clock, r.corridor, r.config, signer=DDM, verify_alerts=verify_alerts)
    if sign_alerts:  # the rig's RSUs publish through a signing wrapper, each with its own key
        bus, signers = r.bus, {"rsu1": RSU1, "rsu2": RSU2}

        class RsuBus:
            def publish(self, k, m):
                node = k.split("/")[3]
                if node in signers and isinstance(m, EvAlert):
                    m = signers[node].sign_message(k, m)
                bus.publish(k, m)

            def __getattr__(self, name):
                return getattr(bus, name)

        r.bus = RsuBus()
    r.add("av1", 20.0, 1, 13.4)
    r.add("ev", -30.0, 1, 20.0)
    r.run(1.0)
    r.ev_alert_on = True
    return r


def test_ddm_commands_are_signed_and_pass_the_vehicle_gate():
    r = signed_rig()
    r.run(4.0, alert_every_s=0.5)
    assert r.manoeuvres() == ["pull_over"]
    cmd = r.commands[0]
    assert cmd.auth is not None and cmd.auth.key_id == "ddm-1"
    assert cmd.auth.not_after == cmd.valid_until
    gate = CommandGate.from_trust(TrustList.from_entries(TRUST))
    k = vehicle_key(r.c, "av1", "cmd")
    gate.admit(k, cmd, r.clock.now())  # what the vehicle does with it
    gate.admit(k, cmd, r.clock.now())  # a retransmission: a duplicate, not a replay


def test_retransmissions_carry_the_same_signature():
    r = Rig(ack_after_sends=3)
    r.svc.close()
    r.svc = DdmService(r.bus, r.clock, corridor_with(TRUST), r.config, signer=DDM, verify_alerts=False)
    r.add("av1", 20.0, 1, 13.4)
    r.add("ev", -30.0, 1, 20.0)
    r.run(1.0)
    r.ev_alert_on = True
    r.run(3.0, alert_every_s=0.5)  # unsigned alerts pass: verify_alerts off
    sends = [c for c in r.commands if c.command_id == r.commands[0].command_id]
    assert len(sends) >= 3 and len({c.auth.sig for c in sends}) == 1


def test_ddm_refuses_unsigned_and_misattributed_alerts():
    r = signed_rig(sign_alerts=False)  # the corridor trusts RSU keys: alerts must be signed
    r.run(3.0, alert_every_s=0.5)
    assert r.commands == []  # the EV is never acted on
    h = r.svc.health(r.clock.now())
    assert h.rejected["decode_auth_unsigned"] >= 5
    # rsu2's key signing an alert published under rsu1: out of scope
    alert = EvAlert(src="rsu1", stamp=r.clock.now(), alert_id="rsu1-ev-x", state=AlertState.ACTIVE, rsu_id="rsu1",
                    object_id=1, pos_x_m=0.0, pos_y_m=5.0, lat_deg=30.0, lon_deg=-96.0, confidence=0.9,
                    first_seen=r.clock.now())
    k = rsu_key(r.c, "rsu1", "ev")
    r.bus.publish(k, RSU2.sign_message(k, alert))
    assert r.svc.health(r.clock.now()).rejected["decode_auth_out_of_scope"] == 1
    assert "rsu1-ev-x" not in r.svc.world.alerts


def test_ddm_acts_on_signed_alerts():
    r = signed_rig()
    r.run(4.0, alert_every_s=0.5)
    assert r.manoeuvres() == ["pull_over"]
    assert not any(k.startswith("decode_auth") for k in r.svc.health(r.clock.now()).rejected)


def test_secure_transport_signs_alerts_and_counts_refusals():
    bus = LocalBus()
    clock = SimClock(50.0)
    got, refused = [], []
    rx = SecureTransport(bus, clock, verifier=Verifier(TrustList.from_entries(TRUST)))
    rx.subscribe(all_rsus_expr("c"), lambda k, m: got.append(m), on_reject=lambda k, e: refused.append(e))
    tx = SecureTransport(bus, clock, signer=RSU1)
    alert = EvAlert(src="rsu1", stamp=50.0, alert_id="a", state=AlertState.ACTIVE, rsu_id="rsu1", object_id=1,
                    pos_x_m=0.0, pos_y_m=5.0, lat_deg=30.0, lon_deg=-96.0, confidence=0.9, first_seen=50.0)
    tx.publish(rsu_key("c", "rsu1", "ev"), alert)
    assert len(got) == 1 and got[0].auth.key_id == "rsu1-key"
    clock.advance(10.0)  # the same alert replayed 10 s later: past its 5 s window
    bus.publish(rsu_key("c", "rsu1", "ev"), got[0])
    bus.publish(rsu_key("c", "rsu1", "ev"), alert)  # unsigned
    assert [e.reason for e in refused] == ["expired", "unsigned"] and isinstance(refused[0], AuthError)
    assert bus.stats.rejected["auth_expired"] == 1 and bus.stats.rejected["auth_unsigned"] == 1


# ----------------------------------------------------------------------------- bounded state
def _vehicle_state(vid: str, t: float) -> VehicleState:
    return VehicleState(src=vid, stamp=t, vehicle_id=vid, pos_x_m=0.0, pos_y_m=5.0, lat_deg=30.0, lon_deg=-96.0,
                        heading_rad=0.0, speed_mps=10.0, mode=VehicleMode.DRIVING)


def test_peers_cannot_grow_the_ddm_without_bound(monkeypatch):
    monkeypatch.setattr(ddm_service, "MAX_TRACKS", 300)
    r = Rig()
    corridor = r.corridor
    t = r.clock.now()
    for i in range(ddm_service.MAX_VEHICLES + 20):  # invented vehicle ids
        r.bus.publish(vehicle_key(r.c, f"v{i}", "state"), _vehicle_state(f"v{i}", t))
    for i in range(ddm_service.MAX_RSUS + 20):  # invented RSUs (health only)
        r.bus.publish(rsu_key(r.c, f"fake{i}", "health"), Health(src=f"fake{i}", stamp=t, role=Role.RSU))
    for i in range(ddm_service.MAX_ALERTS + 20):  # invented alerts
        r.bus.publish(rsu_key(r.c, "rsu1", "ev"), EvAlert(
            src="rsu1", stamp=t, alert_id=f"a{i}", state=AlertState.ACTIVE, rsu_id="rsu1", object_id=10_000 + i,
            pos_x_m=float(i), pos_y_m=-50.0, lat_deg=30.0, lon_deg=-96.0, confidence=0.9, first_seen=t))
    for f in range(10):  # 256 new objects per list
        objs = [det(corridor, f * 256 + k, 10.0 * k, 100.0 + 5.0 * f, 0.0) for k in range(256)]
        r.bus.publish(rsu_key(r.c, "rsu2", "objects"), object_list("rsu2", f, t, objs))
    w = r.svc.world
    assert len(w.vehicles) == ddm_service.MAX_VEHICLES
    assert len(w.rsu_ids) == ddm_service.MAX_RSUS
    assert len(w.alerts) == ddm_service.MAX_ALERTS
    assert w.track_count <= 300 + 256 + ddm_service.MAX_ALERTS
    rej = r.svc.rejected
    assert rej["vehicle_limit"] == 20 and rej["rsu_limit"] >= 20 and rej["alert_limit"] == 20
    assert rej["track_limit"] >= 1
    r.svc.step(t + 0.05)  # still runs


def test_gate_without_ddm_keys_is_inactive():
    gate = CommandGate.from_trust(TrustList.from_entries([rsu_entry("rsu1-key", RSU1_PUB, "rsu1")]))
    assert not gate.active


def _with_field(msg, path: tuple, value) -> bytes:
    """``msg``'s payload with one field (by msgpack path) set to ``value``: what a peer can send."""
    body = msgpack.unpackb(encode(msg), raw=False)
    node = body
    for p in path[:-1]:
        node = node[p]
    node[path[-1]] = value
    return msgpack.packb(body)


def test_implausible_numbers_are_kept_from_the_fusion():
    """1e16 m/s is finite, and would make every DDM step raise in the KD-tree merge. The codec refuses numbers outside their physical range (the bus counts the whole message as
    ``invalid``, the DDM never sees it); the DDM's own limits still drop an object the codec lets through
    but the fusion cannot use (a variance beyond ``MAX_POS_VAR_M2``), and keep a runaway SORT track."""
    r = Rig()
    t = r.clock.now()
    objs = [det(r.corridor, 10, 30.0, 5.55, 110.0),  # a runaway SORT track: real RSU output, kept
            det(r.corridor, 11, 60.0, 1.85, 13.0),
            dataclasses.replace(det(r.corridor, 12, 90.0, 1.85, 13.0), pos_cov_m2=(1e9, 0.0, 1e9))]
    ol = object_list("rsu1", 1, t, objs)
    vel_y = next(i for i, f in enumerate(dataclasses.fields(objs[0])) if f.name == "vel_y_mps")
    state = _vehicle_state("av1", t)
    alert = EvAlert(src="rsu1", stamp=t, alert_id="x", state=AlertState.ACTIVE, rsu_id="rsu1", object_id=1,
                    pos_x_m=0.0, pos_y_m=5.0, lat_deg=30.0, lon_deg=-96.0, confidence=0.9, first_seen=t)
    refused = [(rsu_key(r.c, "rsu1", "objects"), _with_field(ol, ("objects", 0, vel_y), 4.1e16)),
               (vehicle_key(r.c, "av1", "state"), _with_field(state, ("pos_x_m",), -1e200)),
               (rsu_key(r.c, "rsu1", "ev"), _with_field(alert, ("vel_x_mps",), 1e9))]
    for k, payload in refused:
        with pytest.raises(ProtocolError, match="less than or equal|greater than or equal"):
            decode(payload)
        r.bus.publish_bytes(k, payload)
    assert r.bus.stats.rejected["invalid"] == 3
    r.bus.publish(rsu_key(r.c, "rsu1", "objects"), ol)
    assert r.svc.rejected["implausible_object"] == 1 and r.svc.rejected["implausible"] == 0
    assert r.svc.world.track_count == 2 and not r.svc.world.alerts and not r.svc.world.vehicles
    for _ in range(5):
        r.clock.advance(0.05)
        r.svc.step()
    assert r.bus.stats.handler_errors == 0


def test_seq_jumps_cannot_make_the_ddm_health_unpublishable():
    """Found by fuzzing: acks whose seq jump by 2**53 on two vehicles' keys would sum past the largest Count a
    Health may carry and make every health beat of the DDM raise."""
    from protocol.enums import AckStatus
    from protocol.messages import CommandAck
    from protocol.ranges import MAX_COUNT

    r = Rig()
    for vid in ("av1", "av2"):
        for seq in (0, 2**53):
            r.bus.publish(vehicle_key(r.c, vid, "ack"), CommandAck(
                src=vid, seq=seq, stamp=r.clock.now(), command_id=f"ddm-{vid}-1", vehicle_id=vid,
                status=AckStatus.ACCEPTED))
    health = r.svc.publish_health(r.clock.now())
    assert health.drops["missed_ack_samples"] == MAX_COUNT
    assert r.bus.stats.handler_errors == 0
