"""Scripted object streams for the DDM's lockstep tests: cars on the RELLIS corridor seen by RSUs."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ddm.config import DdmConfig
from ddm.service import DdmService
from protocol.clock import SimClock
from protocol.corridor import Corridor, load_corridor
from protocol.enums import AckStatus, AlertState, EvState, ObjectType, VehicleMode
from protocol.keys import all_vehicles_expr, ddm_health_key, rsu_key, vehicle_key
from protocol.local_bus import LocalBus
from protocol.messages import (
    CommandAck,
    DetectedObject,
    EvAlert,
    Health,
    ObjectList,
    PathSwitchCommand,
    VehicleState,
)

LANE_W = 3.7


def lane_y(lane: int) -> float:
    """RELLIS road runs along +x on y = 0 (right edge of lane 0): lane centre y."""
    return (lane + 0.5) * LANE_W


def det(corridor: Corridor, oid: int, x: float, y: float, vx: float, vy: float = 0.0, *,
        ev: bool = False, ev_state: EvState | None = None, lane: int | None = None) -> DetectedObject:
    lat, lon = corridor.to_latlon(x, y)
    return DetectedObject(
        object_id=oid, pos_x_m=x, pos_y_m=y, lat_deg=lat, lon_deg=lon, bbox_px=(0.0, 0.0, 10.0, 10.0),
        obj_type=ObjectType.EV if ev else ObjectType.VEHICLE,
        ev_state=ev_state if ev_state is not None else (EvState.CONFIRMED if ev else EvState.NONE),
        ev_score=0.9 if ev else 0.0, vel_x_mps=vx, vel_y_mps=vy, speed_mps=math.hypot(vx, vy),
        heading_rad=math.atan2(vy, vx) if (vx or vy) else 0.0, length_m=4.8, width_m=1.9,
        pos_cov_m2=(0.25, 0.0, 0.25), lane=lane,
    )


def object_list(rsu: str, frame: int, t: float, objs: list[DetectedObject]) -> ObjectList:
    return ObjectList(src=rsu, seq=frame, stamp=t, rsu_id=rsu, frame=frame, measurement_time=t, objects=objs)


@dataclass
class Car:
    name: str
    x: float
    y: float
    vx: float
    vy: float = 0.0
    ev: bool = False
    visible: bool = True


@dataclass
class Rig:
    """LocalBus + SimClock + DdmService + a scripted world of cars seen by RSUs with local ids."""

    config: DdmConfig = field(default_factory=lambda: DdmConfig(startup_listen_s=0.5))
    start_s: float = 100.0
    coverage: dict[str, tuple[float, float]] = field(default_factory=lambda: {
        "rsu1": (-60.0, 60.0), "rsu2": (40.0, 160.0), "rsu3": (140.0, 260.0), "rsu4": (240.0, 360.0)})
    auto_ack: bool = True
    ack_after_sends: int = 1
    """The vehicle acknowledges a command on its N-th reception (the acks of earlier sends are lost)."""
    follow: bool = True
    """The scripted AV follows accepted commands' paths and speed profiles (kinematically)."""

    def __post_init__(self) -> None:
        self.corridor = load_corridor()
        self.c = self.corridor.corridor_id
        self.bus = LocalBus()
        self.clock = SimClock(self.start_s)
        self.svc = DdmService(self.bus, self.clock, self.corridor, self.config)
        self.cars: dict[str, Car] = {}
        self.local_ids: dict[tuple[str, str], int] = {}
        self._next_local = 100
        self.frame = 0
        self.commands: list[PathSwitchCommand] = []
        self.health: list[Health] = []
        self.silent: set[str] = set()
        self.av_active: str | None = None
        self.av_mode = VehicleMode.DRIVING
        self.acked: set[str] = set()
        self.av_path: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None
        self.av_arc = 0.0
        self.ev_alert: EvAlert | None = None
        self.hooks: list = []
        """Called after each step's publications, before the DDM steps (e.g. a DsrcLink's deliver_due)."""
        self.bus.subscribe(all_vehicles_expr(self.c, "cmd"), lambda k, m: self._on_cmd(m))
        self.bus.subscribe(ddm_health_key(self.c), lambda k, m: self.health.append(m))

    # -- the vehicle side
    def _on_cmd(self, cmd: PathSwitchCommand) -> None:
        self.commands.append(cmd)
        if self.auto_ack and cmd.command_id not in self.acked and self._count(cmd.command_id) >= self.ack_after_sends:
            self.ack(cmd.command_id)

    def _count(self, cid: str) -> int:
        return sum(1 for c in self.commands if c.command_id == cid)

    def ack(self, cid: str, status: AckStatus = AckStatus.ACCEPTED, reason: str = "") -> None:
        self.acked.add(cid)
        if status == AckStatus.ACCEPTED:
            self.av_active = cid
            self.av_mode = VehicleMode.MANOEUVRE
            cmd = next(c for c in self.commands if c.command_id == cid)
            if self.follow:
                xs = np.array([w[0] for w in cmd.waypoints])
                ys = np.array([w[1] for w in cmd.waypoints])
                arc = np.concatenate([[0.0], np.cumsum(np.hypot(np.diff(xs), np.diff(ys)))])
                sp = np.array(cmd.speed_profile_mps) if cmd.speed_profile_mps else np.full(len(xs), cmd.target_speed_mps)
                self.av_path, self.av_arc = (arc, xs, ys, sp), 0.0
        self.bus.publish(vehicle_key(self.c, "av1", "ack"),
                         CommandAck(src="av1", stamp=self.clock.now(), command_id=cid, vehicle_id="av1",
                                    status=status, reason=reason))

    def manoeuvres(self) -> list[str]:
        """Distinct commands in issue order: manoeuvre values."""
        seen, out = set(), []
        for c in self.commands:
            if c.command_id not in seen:
                seen.add(c.command_id)
                out.append(c.manoeuvre.value)
        return out

    # -- the world
    def add(self, name: str, x: float, lane: int, vx: float, *, ev: bool = False) -> Car:
        car = Car(name, x, lane_y(lane), vx, ev=ev)
        self.cars[name] = car
        return car

    def _local(self, rsu: str, name: str) -> int:
        key = (rsu, name)
        if key not in self.local_ids:
            self.local_ids[key] = self._next_local
            self._next_local += 1
        return self.local_ids[key]

    def publish_frame(self) -> None:
        t = self.clock.now()
        self.frame += 1
        for rsu, (lo, hi) in self.coverage.items():
            if rsu in self.silent:
                continue
            objs = [det(self.corridor, self._local(rsu, c.name), c.x, c.y, c.vx, c.vy, ev=c.ev)
                    for c in self.cars.values() if c.visible and lo <= c.x <= hi]
            self.bus.publish(rsu_key(self.c, rsu, "objects"), object_list(rsu, self.frame, t, objs))

    def publish_av(self) -> None:
        av = self.cars.get("av1")
        if av is None:
            return
        lat, lon = self.corridor.to_latlon(av.x, av.y)
        self.bus.publish(vehicle_key(self.c, "av1", "state"), VehicleState(
            src="av1", stamp=self.clock.now(), vehicle_id="av1", pos_x_m=av.x, pos_y_m=av.y, lat_deg=lat,
            lon_deg=lon, heading_rad=math.atan2(av.vy, av.vx) if av.vx or av.vy else 0.0,
            speed_mps=math.hypot(av.vx, av.vy), mode=self.av_mode, active_command_id=self.av_active))

    def alert(self, state: AlertState = AlertState.ACTIVE, name: str = "ev", rsu: str | None = None) -> None:
        car = self.cars[name]
        if rsu is None:
            rsu = next(r for r, (lo, hi) in self.coverage.items() if lo <= car.x <= hi)
        lat, lon = self.corridor.to_latlon(car.x, car.y)
        self.bus.publish(rsu_key(self.c, rsu, "ev"), EvAlert(
            src=rsu, stamp=self.clock.now(), alert_id=f"{rsu}-ev-{name}", state=state, rsu_id=rsu,
            object_id=self._local(rsu, name), pos_x_m=car.x, pos_y_m=car.y, lat_deg=lat, lon_deg=lon,
            vel_x_mps=car.vx, vel_y_mps=car.vy, speed_mps=abs(car.vx), lane=None, confidence=0.9,
            first_seen=self.clock.now()))

    def run(self, seconds: float, dt: float = 0.1, alert_every_s: float | None = None) -> None:
        """Advance the world: move cars, publish objects + AV state, step the DDM (lockstep)."""
        steps = int(round(seconds / dt))
        for i in range(steps):
            self.clock.advance(dt)
            for c in self.cars.values():
                if c.name == "av1" and self.av_path is not None:
                    self._follow(c, dt)
                    continue
                c.x += c.vx * dt
                c.y += c.vy * dt
            self.publish_frame()
            self.publish_av()
            if alert_every_s and self.ev_alert_on and i % max(1, int(round(alert_every_s / dt))) == 0:
                self.alert()
            for hook in self.hooks:
                hook()
            self.svc.step()

    ev_alert_on: bool = False

    def _follow(self, car: Car, dt: float) -> None:
        arc, xs, ys, sp = self.av_path
        v = float(np.interp(self.av_arc, arc, sp))
        if self.av_arc >= arc[-1] - 1e-6:
            v = float(sp[-1])
        if v < 0.05:
            car.vx = car.vy = 0.0
            self.av_mode = VehicleMode.STOPPED
            return
        self.av_arc += v * dt
        if self.av_arc <= arc[-1]:
            car.x = float(np.interp(self.av_arc, arc, xs))
            car.y = float(np.interp(self.av_arc, arc, ys))
            k = min(int(np.searchsorted(arc, self.av_arc)), len(arc) - 1)
            k = max(k, 1)
            h = math.atan2(ys[k] - ys[k - 1], xs[k] - xs[k - 1])
        else:
            h = math.atan2(ys[-1] - ys[-2], xs[-1] - xs[-2])
            car.x += v * math.cos(h) * dt
            car.y += v * math.sin(h) * dt
        car.vx, car.vy = v * math.cos(h), v * math.sin(h)
