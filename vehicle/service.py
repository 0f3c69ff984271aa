"""The vehicle process (imperative shell): wires ``SimulatedVehicle`` to a Transport and a Clock.

Subscribes to its ``cmd`` key (``PathSwitchCommand``), to the DDM's health (fail-safe watchdog) and,
with ``localisation="rsu"`` or ``"both"``, to the RSUs' object lists (the RSU track of the car as a
position fix). Publishes a ``CommandAck`` for every command decision, ``VehicleState`` at 20 Hz and
``Health`` at 1 Hz. Transport callbacks only queue; ``step(now)`` does all the work, so the same
service runs in lockstep (``SimClock`` + ``LocalBus``: publish, then ``step``) and in real time
(``run()`` calls ``step`` at the control rate, 100 Hz).
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections import Counter, deque
from dataclasses import dataclass

from protocol.clock import Clock, RateTimer
from protocol.keys import all_rsus_expr, ddm_health_key, parse_key, vehicle_key
from protocol.messages import (
    CommandAck,
    Health,
    HealthStatus,
    ObjectList,
    ObjectType,
    PathSwitchCommand,
    Role,
    VehicleMode,
    VehicleState,
)
from protocol.transport import Transport
from vehicle.core import CoreConfig, SimulatedVehicle
from vehicle.localisation import GNSS, Fix, FixSourceConfig
from vehicle.lockstep import RunRecord, record_step

log = logging.getLogger(__name__)

LOCALISATION_MODES = ("gnss", "rsu", "both")
RSU_FIX_GATE_M = 4.0
"""An RSU object is taken as this car when it lies this close to the predicted pose."""


@dataclass(frozen=True)
class ServiceTiming:
    control_period_s: float = 0.01
    state_period_s: float = 0.05
    health_period_s: float = 1.0
    max_catch_up_steps: int = 50
    """After a stall, at most this many control steps are replayed; the rest of the time is skipped."""


class VehicleService:
    def __init__(self, transport: Transport, clock: Clock, corridor, vehicle_id: str, *,
                 config: CoreConfig = CoreConfig(), localisation: str = "gnss",
                 fix_source: FixSourceConfig = GNSS, seed: int = 0, timing: ServiceTiming = ServiceTiming(),
                 record: bool = False) -> None:
        if localisation not in LOCALISATION_MODES:
            raise ValueError(f"localisation must be one of {LOCALISATION_MODES}, got {localisation!r}")
        self.transport, self.clock, self.corridor = transport, clock, corridor
        self.vehicle_id = vehicle_id
        self.timing = timing
        vc = corridor.vehicle(vehicle_id)  # KeyError names the corridor's vehicles
        self.vehicle_config = vc
        self.start_s = clock.now()
        self.sim = SimulatedVehicle(corridor.road, vehicle_id, vc.start_s_m, vc.start_lane, vc.cruise_speed_mps,
                                    config, fix_source if localisation in ("gnss", "both") else None, seed=seed,
                                    start_time_s=self.start_s)
        self.localisation = localisation
        c = corridor.corridor_id
        self.cmd_key, self.ack_key = vehicle_key(c, vehicle_id, "cmd"), vehicle_key(c, vehicle_id, "ack")
        self.state_key, self.health_key = vehicle_key(c, vehicle_id, "state"), vehicle_key(c, vehicle_id, "health")
        self._inbox: deque[tuple[str, object, float]] = deque()
        self._seq = Counter()
        self.rejected: Counter = Counter()
        self.acks_sent: list[CommandAck] = []
        self.states_sent = 0
        self._next_control_s = self.start_s
        self._state_timer = RateTimer(timing.state_period_s)
        self._health_timer = RateTimer(timing.health_period_s)
        self._ctrl_time_ns, self._ctrl_steps, self._ctrl_steps_total = 0, 0, 0
        self._states_in_period = 0
        self._last_health_s = self.start_s
        self.record = RunRecord(meta={"vehicle_id": vehicle_id, "corridor": c, "scenario": f"service_{vehicle_id}"}) \
            if record else None
        self._stop = threading.Event()
        self._subs = [
            transport.subscribe(self.cmd_key, self._on_cmd, on_reject=self._on_reject),
            transport.subscribe(ddm_health_key(c), self._on_ddm_health, on_reject=self._on_reject),
        ]
        if localisation in ("rsu", "both"):
            self._subs.append(transport.subscribe(all_rsus_expr(c), self._on_rsu, on_reject=self._on_reject))

    # ------------------------------------------------------------------ transport callbacks (queue only)
    def _on_cmd(self, key: str, msg) -> None:
        self._inbox.append(("cmd", msg, self.clock.now()))

    def _on_ddm_health(self, key: str, msg) -> None:
        self._inbox.append(("link", msg, self.clock.now()))

    def _on_rsu(self, key: str, msg) -> None:
        if isinstance(msg, ObjectList) and parse_key(key).topic == "objects":
            self._inbox.append(("rsu", msg, self.clock.now()))

    def _on_reject(self, key: str, exc: Exception) -> None:
        self.rejected[getattr(exc, "reason", "invalid")] += 1

    # ------------------------------------------------------------------ publishing
    def _next_seq(self, key: str) -> int:
        self._seq[key] += 1
        return self._seq[key]

    def _ack(self, decision, now_s: float) -> None:
        ack = CommandAck(src=self.vehicle_id, seq=self._next_seq(self.ack_key), stamp=now_s,
                         command_id=decision.command_id, vehicle_id=self.vehicle_id, status=decision.status,
                         reason=decision.reason[:250])
        self.acks_sent.append(ack)
        if decision.status.value == "rejected":
            self.rejected["command_" + decision.reason.split(":", 1)[0].split(" ", 1)[0]] += 1
        self.transport.publish(self.ack_key, ack)

    def state_message(self, now_s: float, *, publish: bool = True) -> VehicleState:
        """The VehicleState of now; ``publish=False`` leaves the key's sequence number untouched (a
        copy for the lockstep simulator, not a message on the link)."""
        core, st = self.sim.core, self.sim.truth
        x, y, yaw = core.estimator.pose
        lat, lon = self.corridor.to_latlon(x, y)
        last = core.last
        active = core.book.active
        age = core.estimator.age_s(now_s)
        return VehicleState(
            src=self.vehicle_id, seq=self._next_seq(self.state_key) if publish else self._seq[self.state_key],
            stamp=now_s, vehicle_id=self.vehicle_id,
            pos_x_m=x, pos_y_m=y, lat_deg=lat, lon_deg=lon, heading_rad=math.remainder(yaw, 2 * math.pi),
            speed_mps=max(0.0, core.speed_mps), yaw_rate_rps=core.yaw_rate_rps, accel_mps2=st.accel_mps2,
            steer_rad=st.steer_rad, length_m=self.vehicle_config.length_m, width_m=self.vehicle_config.width_m,
            lane=self.corridor.road.lane_at(x, y), mode=core.mode,
            active_command_id=None if active is None else active.command_id,
            lateral_error_m=0.0 if last is None else last.lateral.lateral_error_m,
            yaw_error_rad=0.0 if last is None else last.lateral.yaw_error_rad,
            yaw_rate_error_rps=0.0 if last is None else last.lateral.yaw_rate_error_rps,
            localisation_age_s=min(age, 1e6), detail=core.detail[:250])

    def _health(self, now_s: float) -> None:
        period = now_s - self._last_health_s
        period = period if period >= 0.5 * self.timing.health_period_s else math.inf  # none yet at the start
        core = self.sim.core
        status = HealthStatus.DEGRADED if core.mode == VehicleMode.MINIMAL_RISK else HealthStatus.OK
        rejected = {k[:64]: v for k, v in (self.rejected + Counter(self.transport.stats.rejected)).items()}
        mean_ms = self._ctrl_time_ns / max(1, self._ctrl_steps) / 1e6
        msg = Health(src=self.vehicle_id, seq=self._next_seq(self.health_key), stamp=now_s, role=Role.VEHICLE,
                     status=status, uptime_s=max(0.0, now_s - self.start_s),
                     rates_hz={"control": self._ctrl_steps / period, "state": self._states_in_period / period},
                     latency_ms={"control_step": mean_ms}, rejected=dict(list(rejected.items())[:64]),
                     drops={"rejected_fixes": core.estimator.rejected_fixes},
                     detail=f"{core.mode.value}: {core.detail}"[:250])
        self.transport.publish(self.health_key, msg)
        self._ctrl_time_ns, self._ctrl_steps, self._states_in_period = 0, 0, 0
        self._last_health_s = now_s

    # ------------------------------------------------------------------ the step
    def _drain(self, now_s: float) -> None:
        core = self.sim.core
        while self._inbox:
            kind, msg, _ = self._inbox.popleft()
            if kind == "cmd":
                assert isinstance(msg, PathSwitchCommand)
                for decision in core.on_command(msg, now_s):
                    self._ack(decision, now_s)
                    if self.record is not None and decision.status.value == "accepted":
                        st = self.sim.truth
                        self.record.events.append({
                            "t_s": now_s - self.start_s, "event": "command", "command_id": msg.command_id,
                            "x_m": st.x_m, "y_m": st.y_m,
                            "stop_point": list(msg.stop_point) if msg.stop_point else None})
            elif kind == "link":
                core.on_link(now_s)
            elif kind == "rsu":
                self._rsu_fix(msg)

    def _rsu_fix(self, msg: ObjectList) -> None:
        """The RSU object nearest the predicted pose (within the gate) is this car."""
        x, y, _ = self.sim.core.estimator.pose
        best, best_d = None, RSU_FIX_GATE_M
        for obj in msg.objects:
            if obj.obj_type in (ObjectType.VEHICLE, ObjectType.UNKNOWN):
                d = math.hypot(obj.pos_x_m - x, obj.pos_y_m - y)
                if d < best_d:
                    best, best_d = obj, d
        if best is None:
            return
        sigma = math.sqrt(max(best.pos_cov_m2[0], best.pos_cov_m2[2], 0.01))
        if self.sim.core.on_fix(Fix(msg.measurement_time, best.pos_x_m, best.pos_y_m, sigma)) is False:
            self.rejected["rsu_fix"] += 1

    def step(self, now_s: float) -> None:
        """Process queued input, advance the car to ``now_s`` at the control rate, publish what is due."""
        self._drain(now_s)
        dt = self.timing.control_period_s
        steps = 0
        while self._next_control_s <= now_s + 1e-9:
            if steps >= self.timing.max_catch_up_steps:
                skipped = int((now_s - self._next_control_s) // dt) + 1
                self._next_control_s += skipped * dt
                self.rejected["control_overrun_steps"] += skipped
                break
            t = self._next_control_s
            t0 = time.perf_counter_ns()
            out = self.sim.step(t, dt)
            self._ctrl_time_ns += time.perf_counter_ns() - t0
            self._ctrl_steps += 1
            self._ctrl_steps_total += 1
            for decision in out.decisions:
                self._ack(decision, now_s)
            if self.record is not None:
                record_step(self.record, self.sim, out, t - self.start_s)
            self._next_control_s = t + dt
            steps += 1
        if self._state_timer.due(now_s):
            self.transport.publish(self.state_key, self.state_message(now_s))
            self.states_sent += 1
            self._states_in_period += 1
        if self._health_timer.due(now_s):
            self._health(now_s)

    # ------------------------------------------------------------------ real-time loop
    def run(self, duration_s: float | None = None) -> None:
        end = None if duration_s is None else self.clock.now() + duration_s
        while not self._stop.is_set():
            now = self.clock.now()
            if end is not None and now >= end:
                break
            self.step(now)
            self.clock.sleep(max(0.0, self._next_control_s - self.clock.now()))

    def stop(self) -> None:
        self._stop.set()

    def close(self) -> None:
        self._stop.set()
        for sub in self._subs:
            sub.close()
        self._subs.clear()
