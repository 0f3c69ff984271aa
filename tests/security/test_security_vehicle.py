"""The vehicle only obeys commands signed by a trusted DDM key, in time, in scope, not replayed.

Each refused command is counted in Health ``rejected`` (``auth_<reason>``) and the car's trajectory is
exactly that of a twin car that received nothing (same seed, same clock: the simulation is
deterministic), or of a twin that only received the valid commands.
"""

from __future__ import annotations

import pytest
from sec_helpers import corridor_with, ddm_entry, key, pull_over, resume, rsu_entry

from protocol.clock import SimClock
from protocol.enums import AckStatus, Role, VehicleMode
from protocol.keys import ddm_health_key, vehicle_key
from protocol.local_bus import LocalBus
from protocol.messages import Health
from protocol.security import TrustList
from vehicle.commands import CommandGate
from vehicle.service import MAX_INBOX, VehicleService

C = "tsec"
DDM, DDM_PUB = key("ddm-1")
RSU, RSU_PUB = key("rsu1-key")
NARROW, NARROW_PUB = key("ddm-av2")  # a trusted DDM key that may command av2 only
ROGUE, _ = key("ddm-1")  # claims the DDM's key id
STRANGER, _ = key("nobody")
TRUST = [ddm_entry("ddm-1", DDM_PUB), ddm_entry("ddm-av2", NARROW_PUB, ["av2"]), rsu_entry("rsu1-key", RSU_PUB, "rsu1")]
CMD_KEY = vehicle_key(C, "av1", "cmd")


class Car:
    """A VehicleService on LocalBus + SimClock with the DDM's health beating at 1 Hz (signed by the DDM's key:
    in a signed corridor only a signed DDM heartbeat feeds the car's link watchdog; ``beat_signer`` None:
    unsigned beats)."""

    def __init__(self, trust=TRUST, require_signed: bool | None = None, start_s: float = 1000.0,
                 beat_signer=DDM):
        self.beat_signer = beat_signer
        corridor = corridor_with(trust, C)
        self.road = corridor.road
        self.bus, self.clock = LocalBus(), SimClock(start_s)
        self.acks, self.health, self.track = [], [], []
        self.bus.subscribe(vehicle_key(C, "av1", "ack"), lambda k, m: self.acks.append(m))
        self.bus.subscribe(vehicle_key(C, "av1", "health"), lambda k, m: self.health.append(m))
        gate = None if require_signed is None else CommandGate.from_trust(TrustList.from_corridor(corridor),
                                                                           require_signed)
        self.svc = VehicleService(self.bus, self.clock, corridor, "av1", gate=gate)

    def run(self, seconds: float) -> None:
        for _ in range(int(round(seconds / 0.01))):
            now = self.clock.now()
            if int(round(now * 100)) % 100 == 0:
                beat = Health(src="ddm", stamp=now, role=Role.DDM)
                if self.beat_signer is not None:
                    beat = self.beat_signer.sign_message(ddm_health_key(C), beat)
                self.bus.publish(ddm_health_key(C), beat)
            self.svc.step(now)
            t = self.svc.sim.truth
            self.track.append((t.x_m, t.y_m, t.yaw_rad, t.vx_mps))
            self.clock.advance(0.01)

    def send(self, cmd) -> None:
        self.bus.publish(CMD_KEY, cmd)

    @property
    def s_m(self) -> float:
        return self.road.to_frenet(self.svc.sim.truth.x_m, self.svc.sim.truth.y_m)[0]

    @property
    def mode(self) -> VehicleMode:
        return self.svc.sim.core.mode

    def rejected(self) -> dict[str, int]:
        return dict(self.health[-1].rejected)


def _bad(car: Car, case: str):
    """A command the car must refuse, and the reason it must give."""
    now = car.clock.now()
    cmd = pull_over(car.road, car.s_m, now, command_id=f"bad-{case}", seq=50)
    if case == "unsigned":
        return cmd, "unsigned"
    if case == "forged":  # a rogue key claiming the DDM's key id
        return ROGUE.sign_message(CMD_KEY, cmd), "bad_signature"
    if case == "tampered":  # a valid signature, then the path moved
        signed = DDM.sign_message(CMD_KEY, cmd)
        return signed.model_copy(update={"target_lane": 1}), "bad_signature"
    if case == "unknown_key":
        return STRANGER.sign_message(CMD_KEY, cmd), "unknown_key"
    if case == "expired":  # captured 100 s ago, valid for 5 s
        old = pull_over(car.road, car.s_m, now - 100.0, command_id="bad-expired", seq=50)
        return DDM.sign_message(CMD_KEY, old), "expired"
    if case == "out_of_scope_vehicle":  # a DDM key that may only command av2
        return NARROW.sign_message(CMD_KEY, cmd), "out_of_scope"
    if case == "out_of_scope_rsu":  # an RSU key cannot command a car
        return RSU.sign_message(CMD_KEY, cmd), "out_of_scope"
    if case == "other_vehicle":  # av2's command, validly signed for av2's key, replayed onto av1's
        other = cmd.model_copy(update={"vehicle_id": "av2"})
        return DDM.sign_message(vehicle_key(C, "av2", "cmd"), other).model_copy(
            update={"vehicle_id": "av1"}), "bad_signature"
    raise AssertionError(case)


ANSWERED = {"expired", "out_of_scope"}


@pytest.mark.parametrize("case", ["unsigned", "forged", "tampered", "unknown_key", "expired", "out_of_scope_vehicle",
                                  "out_of_scope_rsu", "other_vehicle"])
def test_refused_commands_are_counted_and_do_not_move_the_car(case):
    car, twin = Car(), Car()
    car.run(1.0)
    twin.run(1.0)
    msg, reason = _bad(car, case)
    for _ in range(3):  # sent three times (a flood): refused and counted each time
        car.send(msg)
        car.run(0.5)
        twin.run(0.5)
    car.run(1.0)
    twin.run(1.0)
    assert car.track == twin.track  # not one control step differs
    assert car.mode == VehicleMode.DRIVING and car.svc.sim.core.book.active is None
    assert car.rejected().get(f"auth_{reason}") == 3
    if reason in ANSWERED:  # the signature held: the DDM is told why
        assert [(a.command_id, a.status) for a in car.acks] == [(msg.command_id, AckStatus.REJECTED)] * 3
        assert car.acks[0].reason.startswith(reason)
    else:  # an unauthenticated sender gets no answer
        assert car.acks == []


def test_valid_signed_command_is_followed_and_retransmission_is_a_duplicate():
    car = Car()
    car.run(1.0)
    cmd = DDM.sign_message(CMD_KEY, pull_over(car.road, car.s_m, car.clock.now(), command_id="ok-1", seq=1))
    car.send(cmd)
    car.send(cmd)  # the DDM's retransmission: the same bytes
    car.run(0.1)
    assert [(a.command_id, a.status) for a in car.acks] == [("ok-1", AckStatus.ACCEPTED)] * 2
    assert car.mode == VehicleMode.MANOEUVRE
    car.run(15.0)
    assert car.svc.sim.core.mode == VehicleMode.STOPPED
    assert car.road.lane_at(car.svc.sim.truth.x_m, car.svc.sim.truth.y_m) in (0, None)  # lane 0 or the shoulder
    assert not any(k.startswith("auth_") for k in car.rejected())


def test_replays_are_refused_and_the_car_keeps_its_last_valid_command():
    car, twin = Car(), Car()
    for c in (car, twin):
        c.run(1.0)
    now = car.clock.now()
    a = DDM.sign_message(CMD_KEY, pull_over(car.road, car.s_m, now, command_id="a", seq=10, valid_s=30.0))
    b = DDM.sign_message(CMD_KEY, resume(now + 1.0, command_id="b", seq=11, valid_s=30.0))
    older = DDM.sign_message(CMD_KEY, pull_over(car.road, car.s_m, now, command_id="never-seen", seq=9,
                                                 valid_s=30.0))
    for c in (car, twin):
        c.send(a)
        c.run(1.0)
        c.send(b)
        c.run(1.0)
    assert car.mode == VehicleMode.DRIVING and twin.track == car.track  # resumed on b
    car.send(a)  # a replay of the superseded pull-over (validly signed, still in its window)
    car.send(older)  # a command with an older sequence number
    rewritten = DDM.sign_message(CMD_KEY, resume(now + 1.0, command_id="b", seq=11, valid_s=29.0))
    car.send(rewritten)  # a known command id, different content
    car.run(3.0)
    twin.run(3.0)
    assert car.track == twin.track and car.mode == VehicleMode.DRIVING
    assert car.rejected()["auth_replayed"] == 3
    assert [x.status for x in car.acks[-3:]] == [AckStatus.REJECTED] * 3
    assert all(x.reason.startswith("replayed") for x in car.acks[-3:])


def test_forged_resume_does_not_cancel_a_valid_pull_over():
    car = Car()
    car.run(1.0)
    now = car.clock.now()
    car.send(DDM.sign_message(CMD_KEY, pull_over(car.road, car.s_m, now, command_id="p", seq=1, valid_s=30.0)))
    car.run(0.5)
    car.send(ROGUE.sign_message(CMD_KEY, resume(car.clock.now(), command_id="evil", seq=99)))
    car.send(resume(car.clock.now(), command_id="evil2", seq=100))
    car.run(1.0)
    assert car.mode == VehicleMode.MANOEUVRE and car.svc.sim.core.book.active.command_id == "p"
    assert car.rejected()["auth_bad_signature"] == 1 and car.rejected()["auth_unsigned"] == 1


def test_without_trust_list_or_with_require_signed_off():
    plain = Car(trust=[])  # no trust list: the pre-signature behaviour
    plain.run(0.5)
    plain.send(pull_over(plain.road, plain.s_m, plain.clock.now(), command_id="u", seq=1))
    plain.run(0.2)
    assert plain.mode == VehicleMode.MANOEUVRE
    lax = Car(require_signed=False)  # migration: unsigned accepted, signed ones still verified
    lax.run(0.5)
    lax.send(ROGUE.sign_message(CMD_KEY, pull_over(lax.road, lax.s_m, lax.clock.now(), command_id="f", seq=1)))
    lax.run(0.2)
    assert lax.mode == VehicleMode.DRIVING
    lax.send(pull_over(lax.road, lax.s_m, lax.clock.now(), command_id="u", seq=2))
    lax.run(1.0)
    assert lax.mode == VehicleMode.MANOEUVRE and lax.rejected()["auth_bad_signature"] == 1


def test_inbox_is_bounded():
    car = Car()
    cmd = resume(car.clock.now(), command_id="flood", seq=1)
    for _ in range(MAX_INBOX + 500):  # no step in between: a flood
        car.send(cmd)
    assert len(car.svc._inbox) == MAX_INBOX and car.svc.rejected["inbox_full"] == 500
    car.svc._on_ddm_health(ddm_health_key(C), Health(src="ddm", stamp=car.clock.now(), role=Role.DDM))
    assert car.svc._inbox[-1][0] == "link"  # the heartbeat still gets in
    car.run(1.0)
    assert car.rejected()["auth_unsigned"] == MAX_INBOX and len(car.svc._inbox) == 0


@pytest.mark.parametrize("signer, reason", [(None, "unsigned"), (ROGUE, "bad_signature"), (STRANGER, "unknown_key"),
                                            (RSU, "out_of_scope")])
def test_only_a_signed_ddm_heartbeat_feeds_the_link_watchdog(signer, reason):
    """In a signed corridor an unsigned, forged, unknown or RSU-signed DDM Health is no heartbeat:
    the cruising car goes degraded after 3.5 s (Health status degraded, speed capped) and stops at the curb
    after 10 s; with the DDM's signed beats it cruises on."""
    good = Car()
    good.run(12.0)
    assert good.mode == VehicleMode.DRIVING and good.health[-1].status.value == "ok"
    bad = Car(beat_signer=signer)
    bad.run(5.0)
    assert bad.svc.sim.core.watchdog.degraded is not None and bad.health[-1].status.value == "degraded"
    assert bad.rejected().get(f"heartbeat_auth_{reason}", 0) >= 4
    bad.run(7.0)
    assert bad.mode == VehicleMode.MINIMAL_RISK and "while cruising" in bad.svc.sim.core.watchdog.reason


def test_unsigned_corridor_counts_any_ddm_health():
    car = Car(trust=[], beat_signer=None)
    car.run(12.0)
    assert car.mode == VehicleMode.DRIVING and car.svc.sim.core.watchdog.degraded is None
