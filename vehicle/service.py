"""The vehicle process (imperative shell): wires ``SimulatedVehicle`` to a Transport and a Clock.

Subscribes to its ``cmd`` key (``PathSwitchCommand``), to the DDM's health (fail-safe watchdog) and,
with ``localisation="rsu"`` or ``"both"``, to the RSUs' object lists (the RSU track of the car as a
position fix). Publishes a ``CommandAck`` for every command decision, ``VehicleState`` at 20 Hz and
``Health`` at 1 Hz. Transport callbacks only queue; ``step(now)`` does all the work, so the same
service runs in lockstep (``SimClock`` + ``LocalBus``: publish, then ``step``) and in real time
(``run()`` calls ``step`` at the control rate, 100 Hz).

Commands are authenticated first (``vehicle.commands.CommandGate``; by default from the corridor's
``[[trust]]`` entries: when they name DDM keys, only commands signed by one of them, in time, in
scope and not replayed are offered to the command book). Each refusal is counted in Health
``rejected`` as ``auth_<reason>``; the inbox is bounded (``MAX_INBOX``, overflow counted as
``inbox_full``).

A signed EvAlert the car hears itself (``vehicle.ev_direct``): in a corridor whose trust list
names RSU keys the service also subscribes to the RSUs' alerts, keeps the newest that verifies, and pulls
over to the curb on its own when the EV is behind it in its lane, about to reach it, and nothing came from
the DDM (no command, no heartbeat) within the deadline (a cut command link); the DDM's next command takes over.

Presence: the service declares its liveliness token ``iea/{c}/alive/vehicle/{id}``, answers
queries on its keys (latest ``state`` and ``health``: a restarted DDM learns the active command at
once) and watches the DDM's token: ``ddm_present`` is True while a DDM token is alive, False once the
last one was lost (``ddm_lost_s``: when, on the service clock), None before any was seen. A lost token
is a lost heartbeat: the link watchdog may act on it without waiting ``link_timeout_s``.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections import Counter, deque
from dataclasses import dataclass

from protocol import metrics, presence
from protocol.clock import Clock, RateTimer
from protocol.codec import encode
from protocol.enums import AckStatus, AlertState, HealthStatus, ObjectType, Role, VehicleMode
from protocol.keys import ddm_health_key, parse_key, rsu_topic_expr, vehicle_key
from protocol.messages import CommandAck, EvAlert, Health, ObjectList, PathSwitchCommand, VehicleState
from protocol.runtime import freeze_startup_heap
from protocol.security import AuthError, TrustList, Verifier
from protocol.transport import Transport
from vehicle.commands import ANSWERED_AUTH_REASONS, CommandGate
from vehicle.core import CoreConfig
from vehicle.ev_direct import DirectAlertConfig, HeardAlert, act_on_alert
from vehicle.localisation import GNSS, Fix, FixSourceConfig
from vehicle.record import RunRecord, record_step
from vehicle.simulated import SimulatedVehicle

log = logging.getLogger(__name__)

LOCALISATION_MODES = ("gnss", "rsu", "both")
RSU_FIX_GATE_M = 4.0
"""An RSU object is taken as this car when it lies this close to the predicted pose."""
MAX_INBOX = 1024
"""Messages queued between two steps (10 ms at 100 Hz); more is a flood: dropped and counted (the
DDM's health beats have 16 places more, so a command flood does not trip the link watchdog)."""


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
                 record: bool = False, gate: CommandGate | None = None,
                 direct_alerts: DirectAlertConfig = DirectAlertConfig()) -> None:
        """``gate``: command authentication (default: from the corridor's trust list, see the module doc);
        ``direct_alerts``: when the car acts on a signed EvAlert it hears itself (``vehicle.ev_direct``)."""
        if localisation not in LOCALISATION_MODES:
            raise ValueError(f"localisation must be one of {LOCALISATION_MODES}, got {localisation!r}")
        self.transport, self.clock, self.corridor = transport, clock, corridor
        corridor.road.prepare()  # its first road query would cost 0.4 s at the scenario's start
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
        trust = TrustList.from_corridor(corridor)
        self.gate = gate if gate is not None else CommandGate.from_trust(trust)
        self.direct_alerts = direct_alerts
        self.alert_verifier = Verifier(trust) if trust.has_role("rsu") else None
        """Checks the EvAlerts the car hears itself; None (no RSU key trusted): they never move the car."""
        self.heard_alert: HeardAlert | None = None
        self._first_alert_s: float | None = None
        self.direct_pull_overs = 0
        self.direct_held_back = 0
        self._seq = Counter()
        self.rejected: Counter = Counter()
        self.acks_sent: deque[CommandAck] = deque(maxlen=256)  # the latest, for tests and debugging
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
        # the RSUs' object lists: the car's picture for the fail-safe's curb check, and fixes in "rsu"/"both"
        self._subs.append(transport.subscribe(rsu_topic_expr(c, "objects"), self._on_rsu, on_reject=self._on_reject))
        if self.alert_verifier is not None and direct_alerts.enabled:  # signed EvAlerts the car hears itself
            self._subs.append(transport.subscribe(rsu_topic_expr(c, "ev"), self._on_alert, on_reject=self._on_reject))
        self.heartbeats_refused = Counter()
        """DDM Health not counted as a heartbeat, by reason (``auth_<reason>``): a signed corridor counts
        only a DDM Health signed by a trusted DDM key."""
        self.ddm_present: bool | None = None
        self.ddm_lost_s: float | None = None
        self._ddm_tokens = presence.PresenceBook()
        self._latest: dict[str, object] = {}  # key -> the last state / health published
        self._handles = [
            *(presence.serve(transport, key, lambda _q, k=key: [(k, encode(m)) for m in [self._latest.get(k)] if m])
              for key in (self.state_key, self.health_key)),
            presence.watch(transport, c, self._on_ddm_presence, role="ddm"),
            presence.announce(transport, c, "vehicle", vehicle_id),
        ]

    # ------------------------------------------------------------------ transport callbacks (queue only)
    def _queue(self, kind: str, msg) -> None:
        # the DDM's heartbeat keeps a little headroom: a command flood must not starve the link watchdog
        if len(self._inbox) >= MAX_INBOX + (16 if kind == "link" else 0):
            self.rejected["inbox_full"] += 1
            return
        self._inbox.append((kind, msg, self.clock.now()))

    def _on_cmd(self, key: str, msg) -> None:
        self._queue("cmd", msg)

    def _on_ddm_health(self, key: str, msg) -> None:
        self._queue("link", msg)

    def _on_ddm_presence(self, key: str, alive: bool) -> None:
        """A DDM token appeared or was lost (Zenoh's thread: only record it, as the other callbacks queue)."""
        now = self.clock.now()
        if self._ddm_tokens.update(key, alive, now) is None:
            return
        if self._ddm_tokens.alive.get("ddm"):
            self.ddm_present, self.ddm_lost_s = True, None
        else:
            self.ddm_present, self.ddm_lost_s = False, now
            log.warning("%s: the DDM's liveliness token is lost (%s)", self.vehicle_id, key)

    def _on_rsu(self, key: str, msg) -> None:
        if isinstance(msg, ObjectList) and parse_key(key).topic == "objects":
            self._queue("rsu", msg)

    def _on_alert(self, key: str, msg) -> None:
        if isinstance(msg, EvAlert):
            self._queue("alert", (key, msg))

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

    def _refuse(self, cmd: PathSwitchCommand, exc: AuthError, now_s: float) -> None:
        """A command that failed authentication: counted, logged, answered only when a trusted DDM sent it."""
        name = "auth_" + exc.reason
        self.rejected[name] += 1
        n = self.rejected[name]
        if n == 1 or n % 100 == 0:
            log.warning("%s: refused command %s (%d so far): %s", self.vehicle_id, cmd.command_id, n, exc)
        if exc.reason in ANSWERED_AUTH_REASONS:
            ack = CommandAck(src=self.vehicle_id, seq=self._next_seq(self.ack_key), stamp=now_s,
                             command_id=cmd.command_id, vehicle_id=self.vehicle_id, status=AckStatus.REJECTED,
                             reason=str(exc)[:250])
            self.acks_sent.append(ack)
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
        degraded = core.mode == VehicleMode.MINIMAL_RISK or core.watchdog.degraded is not None
        status = HealthStatus.DEGRADED if degraded else HealthStatus.OK
        rejected = {k[:64]: v for k, v in (self.rejected + Counter(self.transport.stats.rejected)).items()}
        mean_ms = self._ctrl_time_ns / max(1, self._ctrl_steps) / 1e6
        msg = Health(src=self.vehicle_id, seq=self._next_seq(self.health_key), stamp=now_s, role=Role.VEHICLE,
                     status=status, uptime_s=max(0.0, now_s - self.start_s),
                     rates_hz={"control": self._ctrl_steps / period, "state": self._states_in_period / period},
                     latency_ms={"control_step": mean_ms}, rejected=dict(list(rejected.items())[:64]),
                     drops={"rejected_fixes": core.estimator.rejected_fixes},
                     detail=f"{core.mode.value}: {core.detail}"[:250])
        self.transport.publish(self.health_key, msg)
        self._latest[self.health_key] = msg
        self._ctrl_time_ns, self._ctrl_steps, self._states_in_period = 0, 0, 0
        self._last_health_s = now_s

    # ------------------------------------------------------------------ the step
    def _drain(self, now_s: float) -> None:
        core = self.sim.core
        while self._inbox:
            kind, msg, _ = self._inbox.popleft()
            if kind == "cmd":
                assert isinstance(msg, PathSwitchCommand)
                try:
                    self.gate.admit(self.cmd_key, msg, now_s)
                except AuthError as exc:
                    self._refuse(msg, exc, now_s)
                    continue
                for decision in core.on_command(msg, now_s):
                    self._ack(decision, now_s)
                    if self.record is not None and decision.status.value == "accepted":
                        st = self.sim.truth
                        self.record.events.append({
                            "t_s": now_s - self.start_s, "event": "command", "command_id": msg.command_id,
                            "x_m": st.x_m, "y_m": st.y_m,
                            "stop_point": list(msg.stop_point) if msg.stop_point else None})
            elif kind == "link":
                if self._authentic_heartbeat(msg, now_s):
                    core.on_link(now_s)
            elif kind == "alert":
                self._hear_alert(*msg, now_s)
            elif kind == "rsu":
                core.on_picture(now_s, [(o.pos_x_m, o.pos_y_m, o.length_m, o.width_m, o.vel_x_mps, o.vel_y_mps)
                                        for o in msg.objects], msg.rsu_id)
                if self.localisation in ("rsu", "both"):
                    self._rsu_fix(msg)

    def _authentic_heartbeat(self, msg: Health, now_s: float) -> bool:
        """Whether a DDM Health feeds the link watchdog: any in an unsigned corridor; in a signed one (the
        trust list names DDM keys) only one signed by a trusted DDM key, in time, on the DDM's key."""
        verifier = self.gate.verifier
        if verifier is None:
            return True
        try:
            verifier.check(ddm_health_key(self.corridor.corridor_id), msg, now_s)
        except AuthError as exc:
            self.heartbeats_refused[f"auth_{exc.reason}"] += 1
            self.rejected[f"heartbeat_auth_{exc.reason}"] += 1
            return False
        return True

    def _hear_alert(self, key: str, msg: EvAlert, now_s: float) -> None:
        """Keep an active EvAlert that verifies against the trust list's RSU keys (the others are counted)."""
        assert self.alert_verifier is not None
        try:
            self.alert_verifier.check(key, msg, now_s)
        except AuthError as exc:
            self.rejected[f"alert_auth_{exc.reason}"] += 1
            return
        if msg.state != AlertState.ACTIVE:
            return
        prev = self.heard_alert
        if prev is None or now_s - prev.stamp_s > self.direct_alerts.episode_gap_s or self._first_alert_s is None:
            self._first_alert_s = now_s  # a new approach: its command deadline starts now
        if prev is None or msg.stamp >= prev.stamp_s:
            self.heard_alert = HeardAlert(msg.stamp, msg.pos_x_m, msg.pos_y_m, msg.vel_x_mps, msg.vel_y_mps, msg.rsu_id)

    def _consider_direct_alert(self, now_s: float) -> None:
        """Pull over on the car's own authority when a signed alert says so and the command is late."""
        alert, core = self.heard_alert, self.sim.core
        if alert is None or self._first_alert_s is None:
            return
        if now_s - alert.stamp_s > self.direct_alerts.episode_gap_s:
            self.heard_alert = self._first_alert_s = None
            return
        why = act_on_alert(alert, now_s, self.corridor.road, core.estimator.pose, max(core.speed_mps, 0.0),
                           self.vehicle_config.length_m, self._first_alert_s, core.watchdog.last_link_s,
                           core.mode == VehicleMode.DRIVING, self.direct_alerts)
        if why is None:
            return
        if core.direct_pull_over(why, now_s, self.direct_alerts.lat_accel_mps2, self.direct_alerts.curb_check_behind_m):
            self.direct_pull_overs += 1
            log.warning("%s: pulling over on its own: %s", self.vehicle_id, why)
        else:
            self.direct_held_back += 1  # control steps the curb side was occupied: the car drives on

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
        self._consider_direct_alert(now_s)
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
            ctrl_ns = time.perf_counter_ns() - t0
            self._ctrl_time_ns += ctrl_ns
            metrics.observe_stages({"control": ctrl_ns * 1e-9})
            self._ctrl_steps += 1
            self._ctrl_steps_total += 1
            for decision in out.decisions:
                self._ack(decision, now_s)
            if self.record is not None:
                record_step(self.record, self.sim, out, t - self.start_s)
            self._next_control_s = t + dt
            steps += 1
        if self._state_timer.due(now_s):
            state = self.state_message(now_s)
            self.transport.publish(self.state_key, state)
            self._latest[self.state_key] = state
            self.states_sent += 1
            self._states_in_period += 1
        if self._health_timer.due(now_s):
            self._health(now_s)

    # ------------------------------------------------------------------ real-time loop
    def run(self, duration_s: float | None = None) -> None:
        freeze_startup_heap()  # full GC passes scan only what the service makes from now on
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
        presence.close_all(self._handles)
        for sub in self._subs:
            sub.close()
        self._subs.clear()
