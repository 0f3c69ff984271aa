"""The vehicle service in lockstep: SimClock + LocalBus, the same code that runs over Zenoh."""

import dataclasses

import numpy as np
import pytest
from vehicle_helpers import make_command

from protocol.clock import SimClock
from protocol.corridor import load_corridor
from protocol.enums import AckStatus, Role, VehicleMode
from protocol.keys import ddm_health_key, vehicle_key
from protocol.local_bus import LocalBus
from protocol.messages import Health, PathSwitchCommand
from vehicle.core import CoreConfig
from vehicle.failsafe import FailsafeConfig
from vehicle.service import VehicleService

C = "tsvc"


class Harness:
    def __init__(self, link_timeout_s=2.0, start_s=1000.0):
        corridor = dataclasses.replace(load_corridor(), corridor_id=C)
        self.road = corridor.road
        self.bus, self.clock = LocalBus(), SimClock(start_s)
        self.acks, self.states, self.health = [], [], []
        self.bus.subscribe(vehicle_key(C, "av1", "ack"), lambda k, m: self.acks.append(m))
        self.bus.subscribe(vehicle_key(C, "av1", "state"), lambda k, m: self.states.append(m))
        self.bus.subscribe(vehicle_key(C, "av1", "health"), lambda k, m: self.health.append(m))
        cfg = CoreConfig(failsafe=FailsafeConfig(link_timeout_s=link_timeout_s))
        self.svc = VehicleService(self.bus, self.clock, corridor, "av1", config=cfg, record=True)

    def run(self, seconds, ddm_health=True):
        for _ in range(int(round(seconds / 0.01))):
            now = self.clock.now()
            if ddm_health and int(round(now * 100)) % 100 == 0:
                self.bus.publish(ddm_health_key(C), Health(src="ddm", stamp=now, role=Role.DDM))
            self.svc.step(now)
            self.clock.advance(0.01)

    def send(self, cmd: PathSwitchCommand):
        self.bus.publish(vehicle_key(C, "av1", "cmd"), cmd)

    def s_car(self):
        return self.road.to_frenet(self.svc.sim.truth.x_m, self.svc.sim.truth.y_m)[0]


def command(h, **kw):
    now = h.clock.now()
    return make_command(h.road, h.s_car(), now=now, **kw)


def test_state_at_20_hz_and_health():
    h = Harness()
    h.run(2.0)
    assert 39 <= len(h.states) <= 41
    st = h.states[-1]
    assert st.vehicle_id == "av1" and st.mode == VehicleMode.DRIVING and st.lane == 1
    assert abs(st.speed_mps - 13.4) < 0.3 and st.localisation_age_s < 0.5
    assert [s.seq for s in h.states] == list(range(1, len(h.states) + 1))
    gaps = [b.stamp - a.stamp for a, b in zip(h.states, h.states[1:], strict=False)]
    assert min(gaps) > 0.05 - 1e-6  # never twice in one period (protocol.clock.RateTimer)
    assert len(h.health) == 2 and h.health[-1].role == Role.VEHICLE and h.health[-1].rates_hz["control"] > 90


def test_command_accepted_followed_and_completed():
    h = Harness()
    h.run(1.0)
    h.send(command(h, command_id="pull-1", seq=1, stop_ahead_m=90.0))
    h.svc.step(h.clock.now())
    assert [(a.command_id, a.status) for a in h.acks] == [("pull-1", AckStatus.ACCEPTED)]
    h.run(20.0)
    assert [(a.command_id, a.status) for a in h.acks][-1] == ("pull-1", AckStatus.COMPLETED)
    st = h.states[-1]
    assert st.mode == VehicleMode.STOPPED and st.lane == 0 and st.speed_mps < 0.05
    assert st.active_command_id is None
    # the run record holds the command event for the plots
    assert h.svc.record.events and h.svc.record.events[0]["command_id"] == "pull-1"


def test_duplicates_are_idempotent_and_old_commands_never_override():
    h = Harness()
    h.run(0.5)
    new = command(h, command_id="new", seq=7)
    h.send(new)
    h.send(new)  # a DDM retry
    h.svc.step(h.clock.now())
    old = command(h, command_id="old", seq=3, from_lane=1, to_lane=1, manoeuvre=new.manoeuvre)
    h.send(old)
    h.svc.step(h.clock.now())
    got = [(a.command_id, a.status) for a in h.acks]
    assert got == [("new", AckStatus.ACCEPTED), ("new", AckStatus.ACCEPTED), ("old", AckStatus.REJECTED)]
    assert "stale" in h.acks[-1].reason
    h.run(0.2)
    assert h.states[-1].active_command_id == "new"


def test_expired_and_unreachable_commands_are_rejected():
    h = Harness()
    h.run(3.0)
    expired = make_command(h.road, h.s_car(), command_id="late", now=1000.5, valid_s=1.0)  # clock is at 1003
    h.send(expired)
    far = command(h, command_id="far", seq=2)
    far = far.model_copy(update={"waypoints": [(x + 200.0, y) for x, y in far.waypoints], "stop_point": None})
    h.send(far)
    h.svc.step(h.clock.now())
    reasons = {a.command_id: (a.status, a.reason) for a in h.acks}
    assert reasons["late"][0] == AckStatus.REJECTED and "expired" in reasons["late"][1]
    assert reasons["far"][0] == AckStatus.REJECTED and "unreachable" in reasons["far"][1]
    h.run(0.5)
    assert h.states[-1].mode == VehicleMode.DRIVING
    assert sum(v for k, v in h.health[-1].rejected.items() if k.startswith("command_")) == 2


def test_failsafe_minimal_risk_stop_when_the_ddm_goes_quiet():
    h = Harness(link_timeout_s=1.5)
    h.run(1.0)
    h.send(command(h, command_id="c", seq=1, stop_ahead_m=150.0))
    h.run(0.5)
    h.run(12.0, ddm_health=False)  # the DDM disappears mid-manoeuvre
    st = h.states[-1]
    assert st.mode == VehicleMode.MINIMAL_RISK and "link lost" in st.detail
    assert st.speed_mps < 0.05
    assert [a.status for a in h.acks] == [AckStatus.ACCEPTED, AckStatus.REJECTED]
    assert h.health[-1].status.value == "degraded"
    # a resume brings it back to cruise
    resume = PathSwitchCommand(src="ddm", stamp=h.clock.now(), command_id="r", command_seq=2, vehicle_id="av1",
                               manoeuvre="resume", reason="ok", target_lane=0, waypoints=[],
                               target_speed_mps=13.4, issued_at=h.clock.now(), valid_until=h.clock.now() + 5)
    h.send(resume)
    h.run(3.0)
    assert [a.status for a in h.acks][-2:] == [AckStatus.ACCEPTED, AckStatus.COMPLETED]
    assert h.states[-1].mode == VehicleMode.DRIVING and h.states[-1].speed_mps > 3.0


def test_bad_input_is_counted_not_fatal():
    h = Harness()
    h.bus.publish_bytes(vehicle_key(C, "av1", "cmd"), b"\x00garbage")
    h.run(1.1)
    assert sum(h.health[-1].rejected.values()) >= 1
    assert h.states[-1].mode == VehicleMode.DRIVING


def test_unknown_vehicle_is_refused():
    corridor = dataclasses.replace(load_corridor(), corridor_id=C)
    with pytest.raises(KeyError):
        VehicleService(LocalBus(), SimClock(), corridor, "nobody")


def test_rsu_track_localisation_and_its_loss():
    from protocol.keys import rsu_key
    from protocol.messages import DetectedObject, ObjectList

    corridor = dataclasses.replace(load_corridor(), corridor_id=C)
    bus, clock = LocalBus(), SimClock(500.0)
    states = []
    bus.subscribe(vehicle_key(C, "av1", "state"), lambda k, m: states.append(m))
    svc = VehicleService(bus, clock, corridor, "av1", localisation="rsu")
    rng = np.random.default_rng(0)
    for k in range(800):
        now = clock.now()
        if k % 7 == 0 and k < 400:  # ~15 Hz RSU track of the car, 0.2 s old, plus a stranger 20 m away
            st = svc.sim.truth
            objs = [DetectedObject(object_id=i, pos_x_m=x, pos_y_m=y, lat_deg=30.6, lon_deg=-96.5,
                                   bbox_px=(0.0, 0.0, 1.0, 1.0), pos_cov_m2=(0.09, 0.0, 0.09))
                    for i, (x, y) in enumerate([(st.x_m - 13.4 * 0.2 + rng.normal(0, 0.3), st.y_m + rng.normal(0, 0.3)),
                                                (st.x_m + 20.0, st.y_m - 3.7)])]
            bus.publish(rsu_key(C, "rsu1", "objects"),
                        ObjectList(src="rsu1", stamp=now, rsu_id="rsu1", frame=k, measurement_time=now - 0.2,
                                   objects=objs))
        svc.step(now)
        clock.advance(0.01)
        if k == 399:
            assert states[-1].mode == VehicleMode.DRIVING and states[-1].localisation_age_s < 0.4
            assert abs(states[-1].lateral_error_m) < 0.3
    # the RSU track stopped at 4 s: stale after 1 s more, then a minimal-risk stop
    assert states[-1].mode == VehicleMode.MINIMAL_RISK and "localisation stale" in states[-1].detail
