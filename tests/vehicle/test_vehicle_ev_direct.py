"""A car acts on a signed EvAlert it hears itself when its command is late (vehicle/ev_direct.py).

Pure rule first (who is behind, how soon it reaches the car, whether the DDM has spoken), then the service
on a LocalBus + SimClock in a signed corridor: a signed alert with no command moves the car to the curb; an
unsigned, forged or unknown-key alert, an unsigned corridor, an occupied curb side or a command in time do
not; a late DDM pull-over takes over the car's own lane change without restarting it.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

from protocol.clock import SimClock
from protocol.corridor import load_corridor
from protocol.enums import AlertState, Manoeuvre, Role, VehicleMode
from protocol.keys import ddm_health_key, rsu_key, vehicle_key
from protocol.local_bus import LocalBus
from protocol.messages import DetectedObject, EvAlert, Health, ObjectList, PathSwitchCommand
from protocol.security import Signer, public_key_b64
from vehicle.ev_direct import DirectAlertConfig, HeardAlert, act_on_alert, time_to_reach_s
from vehicle.reference import lane_change_waypoints
from vehicle.service import VehicleService

C = "tdirect"
CFG = DirectAlertConfig()


def _key(kid: str) -> tuple[Signer, str]:
    private = Ed25519PrivateKey.generate()
    return Signer(kid, private), public_key_b64(private.public_key())


DDM, DDM_PUB = _key("ddm-1")
RSU, RSU_PUB = _key("rsu1-key")
ROGUE, _ = _key("rsu1-key")  # claims the RSU's key id
STRANGER, _ = _key("nobody")
TRUST = ({"key_id": "ddm-1", "role": "ddm", "public_key": DDM_PUB, "vehicles": ["*"]},
         {"key_id": "rsu1-key", "role": "rsu", "public_key": RSU_PUB, "rsu_id": "rsu1"})
ROAD = load_corridor().road


def _alert_at(s_m: float, lane: int, speed_mps: float = 17.0, stamp_s: float = 10.0) -> HeardAlert:
    x, y, _ = ROAD.pose_at(s_m, ROAD.lane_centre_offset_m(lane))
    return HeardAlert(stamp_s, float(x), float(y), speed_mps, 0.0, "rsu1")


def _car_pose(s_m: float, lane: int = 1) -> tuple[float, float, float]:
    x, y, h = ROAD.pose_at(s_m, ROAD.lane_centre_offset_m(lane))
    return float(x), float(y), float(h)


def _act(alert: HeardAlert, now: float = 10.4, car_s: float = 130.0, car_lane: int = 1, speed: float = 13.4,
         first: float = 10.0, last_cmd: float | None = None, cruising: bool = True) -> str | None:
    return act_on_alert(alert, now, ROAD, _car_pose(car_s, car_lane), speed, 4.8, first, last_cmd, cruising, CFG)


# ---------------------------------------------------------------------------------------------- the rule
def test_time_to_reach_is_the_gap_beyond_the_following_distance_over_the_closing_speed():
    assert time_to_reach_s(30.0, 17.0, 13.0, CFG) == pytest.approx((30.0 - 2.0 - 17.0) / 4.0)
    assert time_to_reach_s(10.0, 17.0, 13.0, CFG) == 0.0  # already within 2 m + 1 s x 17 m/s
    assert math.isinf(time_to_reach_s(40.0, 13.0, 13.4, CFG))  # not closing


def test_an_ev_closing_behind_in_the_cars_lane_with_the_command_late_moves_the_car():
    why = _act(_alert_at(100.0, 1))  # 30 m behind, 3.6 m/s faster, 0.4 s after the first alert
    assert why is not None and "rsu1" in why and "lane 1" in why and "nothing from the DDM" in why


@pytest.mark.parametrize("case", ["before_deadline", "ddm_spoke", "other_lane", "ahead", "far", "not_closing",
                                  "manoeuvring", "stale_alert"])
def test_the_car_leaves_it_to_the_ddm_unless_every_condition_holds(case):
    a = _alert_at(100.0, 1)
    kw = {"before_deadline": dict(now=10.0 + CFG.command_deadline_s - 0.05),
          "ddm_spoke": dict(last_cmd=10.1),  # a command or heartbeat after the first alert: the DDM is in charge
          "manoeuvring": dict(cruising=False)}.get(case, {})
    if case == "other_lane":
        a = _alert_at(100.0, 0)
    elif case == "ahead":
        a = _alert_at(160.0, 1)
    elif case == "far":  # 100 m behind: reaches in ~22 s, beyond the 5 s horizon
        a = _alert_at(30.0, 1)
    elif case == "not_closing":
        a = _alert_at(100.0, 1, speed_mps=13.0)
    elif case == "stale_alert":
        kw = dict(now=10.0 + CFG.alert_max_age_s + 0.1)
    assert _act(a, **kw) is None
    assert _act(_alert_at(100.0, 1), last_cmd=10.0) is not None  # heard before or with the first alert: silent since


# ---------------------------------------------------------------------------------------------- the service
class Car:
    """av1 (lane 1, 13.4 m/s) as a VehicleService on a LocalBus + SimClock; the DDM's signed heartbeat at
    1 Hz keeps its link watchdog quiet, so only the alert can move it."""

    def __init__(self, trust=TRUST, direct: DirectAlertConfig = CFG) -> None:
        corridor = dataclasses.replace(load_corridor(), trust=tuple(trust), corridor_id=C)
        self.road = corridor.road
        self.bus, self.clock = LocalBus(), SimClock(1000.0)
        self.svc = VehicleService(self.bus, self.clock, corridor, "av1", direct_alerts=direct)
        self.d_track: list[float] = []

    def run(self, seconds: float, every_step=None) -> None:
        for _ in range(int(round(seconds / 0.01))):
            now = self.clock.now()
            if int(round(now * 100)) % 100 == 0:
                self.bus.publish(ddm_health_key(C), DDM.sign_message(ddm_health_key(C),
                                                                     Health(src="ddm", stamp=now, role=Role.DDM)))
            if every_step is not None:
                every_step(now)
            self.svc.step(now)
            t = self.svc.sim.truth
            self.d_track.append(float(self.road.to_frenet(t.x_m, t.y_m)[1]))
            self.clock.advance(0.01)

    @property
    def s_m(self) -> float:
        t = self.svc.sim.truth
        return float(self.road.to_frenet(t.x_m, t.y_m)[0])

    def alert(self, gap_m: float = 28.0, signer: Signer | None = RSU) -> EvAlert:
        """An active EvAlert for an EV ``gap_m`` behind the car's centre in lane 1 at 17 m/s."""
        now = self.clock.now()
        x, y, _ = self.road.pose_at(self.s_m - gap_m, self.road.lane_centre_offset_m(1))
        lat, lon = load_corridor().to_latlon(float(x), float(y))
        k = rsu_key(C, "rsu1", "ev")
        msg = EvAlert(src="rsu1", stamp=now, alert_id="rsu1-ev", state=AlertState.ACTIVE, rsu_id="rsu1", object_id=2,
                      pos_x_m=float(x), pos_y_m=float(y), lat_deg=lat, lon_deg=lon, vel_x_mps=17.0, speed_mps=17.0,
                      confidence=0.9, first_seen=now)
        return msg if signer is None else signer.sign_message(k, msg)

    def send_alerts(self, seconds: float, signer: Signer | None = RSU, gap_m: float = 28.0) -> None:
        """The RSU's alert at 2 Hz for ``seconds``, the EV closing at 3.6 m/s."""
        t0 = self.clock.now()

        def each(now: float) -> None:
            if int(round((now - t0) * 100)) % 50 == 0:
                self.bus.publish(rsu_key(C, "rsu1", "ev"), self.alert(gap_m - 3.6 * (now - t0), signer))

        self.run(seconds, each)


def test_a_signed_alert_with_no_command_moves_the_car_to_the_curb():
    car = Car()
    car.run(1.0)
    car.send_alerts(4.0)
    core = car.svc.sim.core
    assert car.svc.direct_pull_overs == 1 and core.mode == VehicleMode.MINIMAL_RISK
    assert "on its own" in core.detail and "rsu1" in core.detail
    lane1_right_edge = car.road.lane_width_m
    half_w = core.config.params.width_m / 2
    assert car.d_track[-1] + half_w < lane1_right_edge, "the whole body has left lane 1 within 4 s"
    car.run(8.0)
    assert core.speed_mps < 0.1 and car.d_track[-1] < car.road.lane_centre_offset_m(0)  # stopped at the curb side


@pytest.mark.parametrize("signer,reason", [(None, "unsigned"), (ROGUE, "bad_signature"), (STRANGER, "unknown_key")])
def test_an_unauthenticated_alert_never_moves_the_car(signer, reason):
    car, twin = Car(), Car()
    car.run(1.0)
    twin.run(1.0)
    car.send_alerts(4.0, signer=signer)
    twin.run(4.0)
    assert car.d_track == twin.d_track and car.svc.sim.core.mode == VehicleMode.DRIVING
    assert car.svc.rejected[f"alert_auth_{reason}"] == 8  # 2 Hz for 4 s, each refused


def test_an_unsigned_corridor_never_moves_a_car_on_an_alert():
    car = Car(trust=())
    car.run(1.0)
    car.send_alerts(4.0)
    assert car.svc.alert_verifier is None and car.svc.direct_pull_overs == 0
    assert car.svc.sim.core.mode == VehicleMode.DRIVING


def test_switched_off_the_car_waits_for_its_command():
    car = Car(direct=DirectAlertConfig(enabled=False))
    car.run(1.0)
    car.send_alerts(4.0)
    assert car.svc.direct_pull_overs == 0 and car.svc.sim.core.mode == VehicleMode.DRIVING


def test_an_occupied_curb_side_keeps_the_car_driving_in_its_lane():
    car = Car()
    car.run(1.0)

    def beside(now: float) -> None:  # the RSU sees a car in lane 0 next to av1
        x, y, _ = car.road.pose_at(car.s_m - 3.0, car.road.lane_centre_offset_m(0))
        obj = DetectedObject(object_id=7, pos_x_m=float(x), pos_y_m=float(y), lat_deg=30.0, lon_deg=-96.0,
                             bbox_px=(0.0, 0.0, 10.0, 10.0), vel_x_mps=13.4, speed_mps=13.4, length_m=4.8,
                             width_m=1.9, pos_cov_m2=(0.09, 0.0, 0.09))
        if int(round(now * 100)) % 7 == 0:
            car.bus.publish(rsu_key(C, "rsu1", "objects"), ObjectList(src="rsu1", stamp=now, rsu_id="rsu1", frame=1,
                                                                      measurement_time=now, objects=[obj]))

    car.run(0.2, beside)
    t0 = car.clock.now()

    def both(now: float) -> None:
        beside(now)
        if int(round((now - t0) * 100)) % 50 == 0:
            car.bus.publish(rsu_key(C, "rsu1", "ev"), car.alert(28.0 - 3.6 * (now - t0)))

    car.run(2.0, both)
    assert car.svc.direct_pull_overs == 0 and car.svc.direct_held_back > 0
    assert car.svc.sim.core.mode == VehicleMode.DRIVING  # never a stop in the EV's lane


def _pull_over(car: Car, now: float, command_id: str = "c1") -> PathSwitchCommand:
    wp = np.asarray(lane_change_waypoints(car.road, car.s_m + 3.0, 1, 0, 40.0, 150.0, lead_m=4.0))
    sx, sy, _ = car.road.pose_at(car.s_m + 100.0, car.road.lane_centre_offset_m(0))
    cmd = PathSwitchCommand(src="ddm", stamp=now, command_id=command_id, command_seq=1, vehicle_id="av1",
                            manoeuvre=Manoeuvre.PULL_OVER, reason="test", target_lane=0,
                            waypoints=[(float(x), float(y)) for x, y in wp], target_speed_mps=13.4,
                            stop_point=(float(sx), float(sy)), issued_at=now, valid_until=now + 5.0)
    return DDM.sign_message(vehicle_key(C, "av1", "cmd"), cmd)


def test_a_ddm_heard_alive_after_the_alert_is_left_to_wait_for_its_gap():
    """A signed DDM heartbeat after the first alert and no command: the DDM is waiting on purpose."""
    car = Car()
    car.run(0.9)  # the first alert at 1000.9, the DDM's heartbeat at 1001.0, the deadline at 1001.2
    car.send_alerts(2.0)
    assert car.svc.direct_pull_overs == 0 and car.svc.sim.core.mode == VehicleMode.DRIVING


def test_a_command_in_time_is_followed_and_the_car_does_not_act_on_its_own():
    car = Car()
    car.run(1.0)
    t0 = car.clock.now()

    def alert_then_command(now: float) -> None:
        if int(round((now - t0) * 100)) % 50 == 0:
            car.bus.publish(rsu_key(C, "rsu1", "ev"), car.alert(28.0 - 3.6 * (now - t0)))
        if abs(now - t0 - 0.1) < 0.005:  # the DDM's command 0.1 s after the alert
            car.bus.publish(vehicle_key(C, "av1", "cmd"), _pull_over(car, now))

    car.run(3.0, alert_then_command)
    assert car.svc.direct_pull_overs == 0 and car.svc.sim.core.mode == VehicleMode.MANOEUVRE
    assert car.svc.sim.core.book.active.command_id == "c1"


def test_a_late_pull_over_takes_over_the_cars_own_lane_change_without_restarting_it():
    car = Car()
    car.run(1.0)
    car.send_alerts(1.0)  # the car moves over on its own after 0.3 s
    core = car.svc.sim.core
    assert core.mode == VehicleMode.MINIMAL_RISK
    own_path, d_before = core.path, car.d_track[-1]
    car.bus.publish(vehicle_key(C, "av1", "cmd"), _pull_over(car, car.clock.now()))  # the command, late
    car.run(0.5)
    assert core.mode == VehicleMode.MANOEUVRE and core.book.active.command_id == "c1"  # accepted: the DDM leads
    assert core.path is own_path  # ... along the lane change already under way
    assert car.d_track[-1] < d_before - 0.3  # still moving right, not straightened out
