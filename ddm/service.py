"""DDM service: the imperative shell around the world model, the EV policy and the command manager.

Subscribes to ``iea/{c}/rsu/*/*`` (objects, EV alerts, hazards, health) and to every vehicle's
``state`` and ``ack``; publishes ``PathSwitchCommand`` on ``iea/{c}/vehicle/{v}/cmd`` and ``Health``
on ``iea/{c}/ddm/health`` at 1 Hz.

- ``step(now)`` is one loop iteration (maintain tracks, decide for every AV, retransmit, health); a
  lockstep test calls it with a ``SimClock`` + ``LocalBus``, ``run()`` calls it at ``rate_hz``.
- An EvAlert is acted on in its callback (not at the next tick): the decision latency is the time
  from the alert's arrival to the command's publication, measured and reported in ``Health``.
- Boundary checks beyond the codec: the RSU / vehicle id inside a message must match its key, and
  object lists stamped in the future are refused; each refusal is counted by reason.
- Restart: for ``startup_listen_s`` after start the service only listens. A vehicle that reports an
  active command the service does not know (issued by its predecessor) has it adopted: the service
  treats the vehicle as yielding, sends nothing that contradicts it while an EV approaches, and
  supersedes it with RESUME once no EV needs yielding to.
- Rejected or expired commands are logged with their reason, the vehicle's response memory is
  rolled back, and the decision is re-planned after ``replan_backoff_s``.
"""

from __future__ import annotations

import copy
import logging
import threading
import time
from collections import Counter, deque

import numpy as np

from ddm.commands import CommandManager, CommandState
from ddm.config import DdmConfig
from ddm.geometry import RoadFrame
from ddm.policy import Decision, Ego, Response, decide, plan
from ddm.world import CorridorWorld
from protocol.clock import Clock, RateTimer
from protocol.corridor import Corridor
from protocol.keys import KeyError_, all_rsus_expr, all_vehicles_expr, ddm_health_key, parse_key, vehicle_key
from protocol.messages import (
    CommandAck,
    EvAlert,
    HazardAlert,
    Health,
    HealthStatus,
    ObjectList,
    Role,
    VehicleMode,
    VehicleState,
)
from protocol.transport import Transport

log = logging.getLogger("ddm")

NEIGHBOUR_RADIUS_M = 150.0
"""Tracks within this distance of an AV are considered for its gap checks."""


class DdmService:
    def __init__(self, transport: Transport, clock: Clock, corridor: Corridor, config: DdmConfig | None = None,
                 *, corridor_id: str | None = None, ddm_id: str = "ddm") -> None:
        self.config = cfg = config or DdmConfig()
        self.transport = transport
        self.clock = clock
        self.corridor = corridor
        self.corridor_id = corridor_id or corridor.corridor_id
        self.ddm_id = ddm_id
        self.frame = RoadFrame(corridor.road)
        self.world = CorridorWorld(cfg, rsu_ids=tuple(r.rsu_id for r in corridor.rsus))
        now = clock.now()
        self.started_s = now
        self.commands = CommandManager(cfg, source_id=ddm_id, seq_base=int(now * 1000))
        self.responses: dict[str, Response] = {}
        self._rollback: dict[str, Response] = {}  # command id -> response before it was committed
        self._replan_after: dict[str, float] = {}
        self._last_reason: dict[str, tuple[str, int | None]] = {}
        self._issued_in_call = False
        self.cruise_speed = {v.vehicle_id: v.cruise_speed_mps for v in corridor.vehicles}
        self.vehicle_width = {v.vehicle_id: v.width_m for v in corridor.vehicles}
        self.rejected: Counter = Counter()
        self.counters: Counter = Counter()
        self.decision_latency_ms: deque[float] = deque(maxlen=20000)
        self._period_latency: list[float] = []
        self._health_timer = RateTimer(cfg.health_period_s)
        self._health_seq = 0
        self._last_health_s = now
        self._last_counts = Counter()
        self._stale_reported: set[str] = set()
        self._lock = threading.RLock()
        c = self.corridor_id
        self._cmd_keys: dict[str, str] = {}
        self._health_key = ddm_health_key(c)
        self._step_time_s = 0.0
        # subscribe last: a Zenoh callback may run (on its own thread) as soon as this returns
        self._subs = [
            transport.subscribe(all_rsus_expr(c), self._on_rsu),
            transport.subscribe(all_vehicles_expr(c, "state"), self._on_vehicle_state),
            transport.subscribe(all_vehicles_expr(c, "ack"), self._on_ack),
        ]

    # ------------------------------------------------------------------ inputs
    def _reject(self, reason: str, detail: str) -> None:
        self.rejected[reason] += 1
        log.debug("rejected input (%s): %s", reason, detail)

    def _on_rsu(self, key: str, msg) -> None:
        t0 = time.perf_counter()
        try:
            node = parse_key(key).node
        except KeyError_:
            self._reject("key", key)
            return
        now = self.clock.now()
        with self._lock:
            if isinstance(msg, ObjectList):
                if msg.rsu_id != node:
                    self._reject("rsu_mismatch", f"{key} carries rsu_id {msg.rsu_id}")
                    return
                if msg.measurement_time > now + self.config.max_future_s:
                    self._reject("future_stamp", f"{key} measurement_time {msg.measurement_time} > now {now}")
                    return
                self.world.ingest_objects(msg, now)
                self.counters["object_lists"] += 1
                self.counters["object_updates"] += len(msg.objects)
            elif isinstance(msg, EvAlert):
                if msg.rsu_id != node:
                    self._reject("rsu_mismatch", f"{key} carries rsu_id {msg.rsu_id}")
                    return
                self.world.ingest_ev_alert(msg, now)
                self.counters["ev_alerts"] += 1
                self._decide_all(now, t0=t0)
            elif isinstance(msg, Health):
                self.world.ingest_rsu_health(node, now)
            elif isinstance(msg, HazardAlert):
                self.counters["hazard_alerts"] += 1  # hazard policy: not part of this service yet

    def _on_vehicle_state(self, key: str, msg: VehicleState) -> None:
        node = parse_key(key).node
        if msg.vehicle_id != node:
            self._reject("vehicle_mismatch", f"{key} carries vehicle_id {msg.vehicle_id}")
            return
        now = self.clock.now()
        with self._lock:
            first = msg.vehicle_id not in self.world.vehicles
            self.world.ingest_vehicle_state(msg, now)
            self.counters["vehicle_states"] += 1
            if first:
                self._maybe_adopt(msg, now)

    def _maybe_adopt(self, vs: VehicleState, now: float) -> None:
        """A vehicle executing a command this DDM never issued (a predecessor did): adopt it."""
        cid = vs.active_command_id
        if cid is None or self.commands.state_of(vs.vehicle_id) is not None:
            return
        self.commands.adopt(vs.vehicle_id, cid)
        resp = self.responses.setdefault(vs.vehicle_id, Response())
        if vs.mode in (VehicleMode.MANOEUVRE, VehicleMode.STOPPED):
            resp.phase, resp.manoeuvre, resp.since_s = "yielding", None, now
        log.info("vehicle %s executes command %s (mode %s) from a previous DDM: adopted", vs.vehicle_id, cid,
                 vs.mode.value)

    def _on_ack(self, key: str, msg: CommandAck) -> None:
        node = parse_key(key).node
        if msg.vehicle_id != node:
            self._reject("vehicle_mismatch", f"{key} carries vehicle_id {msg.vehicle_id}")
            return
        now = self.clock.now()
        with self._lock:
            self.counters["acks"] += 1
            self.commands.on_ack(msg, now)
            self._process_events(now)

    # ------------------------------------------------------------------ decisions
    def _process_events(self, now: float) -> None:
        for ev in self.commands.drain_events():
            self.counters[f"cmd_{ev.kind}"] += 1
            if ev.kind in ("rejected", "expired"):
                level = logging.WARNING
                before = self._rollback.pop(ev.command_id, None)
                if before is not None:
                    self.responses[ev.vehicle_id] = before
                self._replan_after[ev.vehicle_id] = now + self.config.replan_backoff_s
                log.log(level, "command %s to %s %s: %s; re-planning", ev.command_id, ev.vehicle_id, ev.kind, ev.detail)
            elif ev.kind in ("issued", "superseded", "accepted", "completed", "adopted"):
                if ev.kind != "issued":
                    self._rollback.pop(ev.command_id, None)
                log.info("command %s to %s %s%s", ev.command_id, ev.vehicle_id, ev.kind,
                         f": {ev.detail}" if ev.detail else "")

    def _ego(self, vid: str) -> Ego | None:
        rec = self.world.vehicles.get(vid)
        if rec is None or self.clock.now() - rec.received_s > self.config.vehicle_state_timeout_s:
            return None
        s = rec.state
        return Ego(vid, s.pos_x_m, s.pos_y_m, s.heading_rad, s.speed_mps, s.length_m, s.width_m, s.mode,
                   s.active_command_id, rec.track_id)

    def _decide_all(self, now: float, t0: float | None = None) -> None:
        if now - self.started_s < self.config.startup_listen_s:
            return
        evs = None
        for vid in list(self.world.vehicles):
            if now < self._replan_after.get(vid, -1.0):
                continue
            ego = self._ego(vid)
            if ego is None:
                continue
            if evs is None:
                evs = self.world.ev_tracks(now)
            resp = self.responses.setdefault(vid, Response())
            if not evs and resp.phase == "normal":
                continue  # nothing to yield to, nothing to resume from
            others = self.world.tracks_near(ego.x_m, ego.y_m, NEIGHBOUR_RADIUS_M, now)
            decision = decide(ego, evs, others, self.frame, self.config, resp, now)
            if decision.ev_near:
                resp.ev_near_s = now
            what = (str(decision.action), decision.ev_track_id)
            if what != self._last_reason.get(vid):
                log.info("%s: %s (%s)", vid, decision.action, decision.reason)
            self._last_reason[vid] = what
            if decision.manoeuvre is not None:
                self._command(vid, decision, resp, now)
                self.counters["decisions"] += 1
        self._send_due(now)
        if t0 is not None and self._issued_in_call:
            ms = (time.perf_counter() - t0) * 1000.0
            self.decision_latency_ms.append(ms)
            self._period_latency.append(ms)
        self._issued_in_call = False

    def _command(self, vid: str, decision: Decision, resp: Response, now: float) -> None:
        path = plan(decision, self.frame, self.config, self.vehicle_width.get(vid, 1.9),
                    self.cruise_speed.get(vid, self.corridor.road.speed_limit_mps))
        target_lane = decision.target_lane if decision.target_lane is not None else 0
        cmd = self.commands.issue(
            vid, now, manoeuvre=decision.manoeuvre, reason=decision.reason, target_lane=target_lane,
            waypoints=path.waypoints, speed_profile_mps=path.speeds_mps, target_speed_mps=path.target_speed_mps,
            stop_point=path.stop_point,
        )
        self._rollback[cmd.command_id] = copy.deepcopy(resp)
        resp.commit(decision, now)
        self._issued_in_call = True
        self._process_events(now)

    def _send_due(self, now: float) -> None:
        for cmd in self.commands.on_tick(now):
            key = self._cmd_keys.get(cmd.vehicle_id)
            if key is None:
                key = self._cmd_keys[cmd.vehicle_id] = vehicle_key(self.corridor_id, cmd.vehicle_id, "cmd")
            self.transport.publish(key, cmd)
            self.counters["commands_published"] += 1
        self._process_events(now)

    # ------------------------------------------------------------------ loop
    def step(self, now: float | None = None) -> None:
        """One loop iteration: maintain the picture, decide, retransmit, publish health when due."""
        now = self.clock.now() if now is None else now
        with self._lock:
            t0 = time.perf_counter()
            self.world.maintain(now)
            stale = set(self.world.stale_rsus(now))
            for r in sorted(stale - self._stale_reported):
                log.warning("RSU %s is stale (no objects for > %.2f s)", r, self.config.rsu_stale_s)
            for r in sorted(self._stale_reported - stale):
                log.info("RSU %s is alive again", r)
            changed = stale != self._stale_reported
            self._stale_reported = stale
            self._decide_all(now)
            self._step_time_s = time.perf_counter() - t0
            if self._health_timer.due(now) or changed:
                self.publish_health(now)  # at 1 Hz, and at once when an RSU goes stale or comes back

    def health(self, now: float) -> Health:
        period = max(now - self._last_health_s, 1e-6)
        rates = {k: (self.counters[k] - self._last_counts[k]) / period
                 for k in ("object_lists", "object_updates", "ev_alerts", "vehicle_states", "commands_published")}
        lat = {}
        if self.decision_latency_ms:
            arr = np.fromiter(self.decision_latency_ms, float)
            lat["decision_p50"] = float(np.percentile(arr, 50))
            lat["decision_p99"] = float(np.percentile(arr, 99))
        if self._period_latency:
            lat["decision_mean"] = float(np.mean(self._period_latency))
        lat["step"] = self._step_time_s * 1000.0
        rejected = dict(self.rejected)
        for reason, n in self.transport.stats.rejected.items():
            rejected[f"decode_{reason}"] = int(n)
        stale = sorted(self._stale_reported)
        n_rsu = len(self.world.rsu_ids)
        return Health(
            src=self.ddm_id, seq=self._health_seq, stamp=now, role=Role.DDM,
            status=HealthStatus.DEGRADED if stale else HealthStatus.OK, uptime_s=max(0.0, now - self.started_s),
            rates_hz=rates, latency_ms=lat,
            drops={"old_measurements": self.world.stats.dropped_old, "cmd_expired": self.counters["cmd_expired"],
                   "cmd_rejected": self.counters["cmd_rejected"]},
            rejected=rejected, stale=stale[:64],
            detail=(f"tracks={self.world.track_count} rsus_alive={n_rsu - len(stale)}/{n_rsu} "
                    f"vehicles={len(self.world.vehicles)} outstanding={self.commands.outstanding()}"),
        )

    def publish_health(self, now: float) -> Health:
        h = self.health(now)
        self.transport.publish(self._health_key, h)
        self._health_seq += 1
        self._last_health_s = now
        self._last_counts = Counter(self.counters)
        self._period_latency = []
        return h

    def run(self, stop: threading.Event) -> None:
        """The real-time loop at ``rate_hz`` until ``stop`` is set."""
        period = 1.0 / self.config.rate_hz
        log.info("DDM %s on corridor %s: %d RSUs, %d vehicles, %.0f Hz", self.ddm_id, self.corridor_id,
                 len(self.corridor.rsus), len(self.corridor.vehicles), self.config.rate_hz)
        next_t = time.monotonic()
        while not stop.is_set():
            try:
                self.step()
            except Exception:  # the loop must survive a bug in one iteration
                log.exception("DDM step failed")
                self.counters["step_errors"] += 1
            next_t += period
            delay = next_t - time.monotonic()
            if delay < 0:
                next_t = time.monotonic()
                delay = 0.0
            stop.wait(delay)

    def close(self) -> None:
        for s in self._subs:
            s.close()
        self._subs = []

    # convenience for tests
    def command_state(self, vehicle_id: str) -> CommandState | None:
        cur = self.commands.state_of(vehicle_id)
        return None if cur is None else cur.state
