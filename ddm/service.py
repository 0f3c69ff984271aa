"""DDM service: the imperative shell around the world model, the EV policy and the command manager.

Subscribes to every RSU topic (``iea/{c}/rsu/*/objects``, ``ev``, ``hazard``, ``health``; the bulk object lists apart) and to every vehicle's
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
- Security (issue 9): with a ``signer`` every ``PathSwitchCommand`` is signed on publication
  (``protocol.security.SecureTransport``; deterministic, so retransmissions are identical); when the
  corridor trusts RSU keys, EvAlerts/HazardAlerts must carry a valid RSU signature (refusals counted
  as ``decode_auth_<reason>``). Whatever a peer sends, the picture stays bounded: at most
  ``MAX_VEHICLES`` vehicles, ``MAX_RSUS`` RSUs, ``MAX_ALERTS`` alerts and about ``MAX_TRACKS`` tracks
  (refusals counted as ``*_limit``), and numbers nothing physical produces (``MAX_ABS_POSITION_M``...)
  are kept from the fusion: such alerts and vehicle states are refused (``implausible``), such
  objects dropped from their list (``implausible_object``).
- Rejected or expired commands are logged with their reason, the vehicle's response memory is
  rolled back, and the decision is re-planned after ``replan_backoff_s``.
- Hazards (issue 10): ``HazardAlert``s of every RSU are fused in a :class:`ddm.hazard.HazardBook`; while
  the EV policy has nothing to do for a vehicle (no EV to yield to, not yielding), the hazard policy
  (:func:`ddm.hazard.decide_hazard`) may command a lane change around a hazard, a stop before it, or a
  resume. An EV command supersedes a hazard command (EV > hazard).
- Presence and state (issue 21, ``protocol.presence``, ``ddm.catchup``): the service declares its
  liveliness token and watches the RSUs' and vehicles'; an RSU whose token is lost is stale at once
  (not after ``rsu_stale_s`` of silence), a vehicle whose token is lost gets no decisions. It answers
  ``iea/{c}/ddm/state`` (its picture, JSON) and ``iea/{c}/ddm/health`` (its latest Health). At start it
  queries the RSUs' latest object lists and active alerts and the vehicles' states; once every RSU of
  the corridor has answered, the listen period ends and it decides at once (EV-aware without waiting
  for the next alert repeat).
"""

from __future__ import annotations

import copy
import logging
import math
import threading
import time
from collections import Counter, deque

import numpy as np

from ddm.catchup import CorridorPresence
from ddm.commands import CommandManager, CommandState
from ddm.config import DdmConfig
from ddm.geometry import RoadFrame
from ddm.hazard import HazardBook, HazardConfig, HazardDecision, HazardResponse, decide_hazard
from ddm.policy import Decision, Ego, Response, decide, plan
from ddm.world import CorridorWorld
from protocol import metrics, presence
from protocol.clock import Clock, RateTimer
from protocol.corridor import Corridor
from protocol.keys import (
    RSU_TOPICS,
    KeyError_,
    all_vehicles_expr,
    ddm_health_key,
    ddm_state_key,
    parse_key,
    rsu_topic_expr,
    vehicle_key,
)
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
from protocol.ranges import MAX_RATE_HZ
from protocol.runtime import freeze_startup_heap
from protocol.security import SecureTransport, Signer, TrustList, Verifier
from protocol.transport import Transport

log = logging.getLogger("ddm")

NEIGHBOUR_RADIUS_M = 150.0
"""Tracks within this distance of an AV are considered for its gap checks."""
ALERT_RADIUS_MARGIN_M = 50.0
"""An EV alert is decided at once for vehicles within the EV look-behind + this of it (it may be passing)."""
MAX_VEHICLES = 64
MAX_RSUS = 64
MAX_ALERTS = 256
MAX_TRACKS = 4096
"""Caps on what a peer can make the DDM remember (a corridor has a handful of RSUs and AVs, tens of
cars; a peer inventing ids gets refused beyond these)."""
MIN_RATE_PERIOD_S = 1e-3
"""Health reports no rates over a shorter period (published again at once, e.g. an RSU went stale)."""
MAX_ABS_POSITION_M = 1e6
MAX_SPEED_MPS = 1000.0
MAX_SIZE_M = 1000.0
MAX_POS_VAR_M2 = 1e8
"""Plausibility limits, far outside anything physical: the codec lets any finite number through, and
a 1e16 m/s velocity overflowed the fusion's arithmetic (found by fuzzing: the KD-tree of the
duplicate merge then raised on every step). The limits are loose on purpose: a SORT track running
away at 110 m/s, which real RSU output contains, still passes as before."""


RATE_NAMES = ("object_lists", "object_updates", "ev_alerts", "vehicle_states", "commands_published")


def period_rates(counts: Counter, before: Counter, period_s: float, names: tuple[str, ...]) -> dict[str, float]:
    """Per-second rates of ``names`` over the last health period; none over a period under 1 ms (a Health
    published at once after another: its count over ~0 s is no rate, and 1,920 updates / 1 us broke the
    RateHz range, which made every ddm_bench run fail at its first step)."""
    if period_s < MIN_RATE_PERIOD_S:
        return {}
    return {k: min((counts[k] - before[k]) / period_s, MAX_RATE_HZ) for k in names}


def implausible(msg) -> str | None:
    """Why an alert's or a vehicle state's numbers cannot be real (None: plausible)."""
    pos = (msg.pos_x_m, msg.pos_y_m)
    if any(abs(v) > MAX_ABS_POSITION_M for v in pos):
        return f"position {pos} beyond {MAX_ABS_POSITION_M:g} m"
    speeds = [getattr(msg, n, 0.0) for n in ("vel_x_mps", "vel_y_mps", "speed_mps")]
    if any(abs(v) > MAX_SPEED_MPS for v in speeds):
        return f"speed {max(abs(v) for v in speeds):.3g} m/s beyond {MAX_SPEED_MPS:g}"
    if max(getattr(msg, "length_m", 0.0), getattr(msg, "width_m", 0.0)) > MAX_SIZE_M:
        return f"size beyond {MAX_SIZE_M:g} m"
    return None


def implausible_objects(msg: ObjectList) -> list[int]:
    """Indexes of the objects whose numbers cannot be real (a plain loop: ~5 us for 30 objects)."""
    p, v, z, c = MAX_ABS_POSITION_M, MAX_SPEED_MPS, MAX_SIZE_M, MAX_POS_VAR_M2
    bad = []
    for i, o in enumerate(msg.objects):
        cov = o.pos_cov_m2
        if (abs(o.pos_x_m) > p or abs(o.pos_y_m) > p or abs(o.vel_x_mps) > v or abs(o.vel_y_mps) > v
                or o.length_m > z or o.width_m > z or cov[0] > c or cov[2] > c or abs(cov[1]) > c):
            bad.append(i)
    return bad


class DdmService(CorridorPresence):
    def __init__(self, transport: Transport, clock: Clock, corridor: Corridor, config: DdmConfig | None = None,
                 *, corridor_id: str | None = None, ddm_id: str = "ddm",
                 hazard_config: HazardConfig | None = None, signer: Signer | None = None,
                 verify_alerts: bool | None = None, catch_up: bool = True) -> None:
        """``signer``: signs every command. ``verify_alerts``: refuse alerts without a valid RSU signature
        (default: when the corridor's trust list names RSU keys). ``catch_up``: query the corridor's state
        at start (False: learn it from the streams only, as before issue 21; for comparisons)."""
        self.config = cfg = config or DdmConfig()
        trust = TrustList.from_corridor(corridor)
        if verify_alerts is None:
            verify_alerts = trust.has_role("rsu")
        if signer is not None or verify_alerts:
            transport = SecureTransport(transport, clock, signer=signer,
                                        verifier=Verifier(trust) if verify_alerts else None)
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
        self.hazard_config = hazard_config or HazardConfig()
        self.hazards = HazardBook(self.frame, self.hazard_config)
        self.hazard_responses: dict[str, HazardResponse] = {}
        self._hazard_rollback: dict[str, HazardResponse] = {}
        self._last_hazard_reason: dict[str, tuple[str, int | None]] = {}
        self.listen_until_s = now + cfg.startup_listen_s
        self.presence = presence.PresenceBook()
        self.stale_now: set[str] = set()
        self.last_health: Health | None = None
        self.ev_aware_s: float | None = None
        """Clock time of the first decision made with an EV in the picture (restart -> EV-aware)."""
        self.catch_up_replies: dict[str, int] = {}
        self._last_seq: dict[str, int] = {}
        # subscribe last: a Zenoh callback may run (on its own thread) as soon as this returns
        self._subs = [
            *(transport.subscribe(rsu_topic_expr(c, topic), self._on_rsu) for topic in RSU_TOPICS),
            transport.subscribe(all_vehicles_expr(c, "state"), self._on_vehicle_state),
            transport.subscribe(all_vehicles_expr(c, "ack"), self._on_ack),
        ]
        self._handles = [
            presence.watch(transport, c, self._on_presence),
            presence.serve(transport, ddm_state_key(c), self._answer_state),
            presence.serve(transport, self._health_key, self._answer_health),
            presence.announce(transport, c, "ddm", ddm_id),
        ]
        if catch_up:
            self.catch_up()

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
        if isinstance(msg, ObjectList):  # drop the impossible objects, keep the rest of the frame
            bad = implausible_objects(msg)
            if bad:
                self.rejected["implausible_object"] += len(bad)
                log.debug("%s: dropped %d implausible objects (first: %s)", key, len(bad), msg.objects[bad[0]])
                drop = set(bad)
                msg = msg.model_copy(update={"objects": [o for i, o in enumerate(msg.objects) if i not in drop]})
        elif not isinstance(msg, Health):
            why = implausible(msg)
            if why is not None:
                self._reject("implausible", f"{key}: {why}")
                return
        with self._lock:
            if node not in self.world._rsu_index and len(self.world.rsu_ids) >= MAX_RSUS:
                self._reject("rsu_limit", f"{key}: already {MAX_RSUS} RSUs")
                return
            if isinstance(msg, ObjectList):
                if msg.rsu_id != node:
                    self._reject("rsu_mismatch", f"{key} carries rsu_id {msg.rsu_id}")
                    return
                if msg.measurement_time > now + self.config.max_future_s:
                    self._reject("future_stamp", f"{key} measurement_time {msg.measurement_time} > now {now}")
                    return
                if self.world.track_count >= MAX_TRACKS:
                    self._reject("track_limit", f"{key}: already {MAX_TRACKS} tracks")
                    return
                self.world.ingest_objects(msg, now)
                self.counters["object_lists"] += 1
                self.counters["object_updates"] += len(msg.objects)
            elif isinstance(msg, EvAlert):
                if msg.rsu_id != node:
                    self._reject("rsu_mismatch", f"{key} carries rsu_id {msg.rsu_id}")
                    return
                if msg.alert_id not in self.world.alerts and len(self.world.alerts) >= MAX_ALERTS:
                    self._reject("alert_limit", f"{key}: already {MAX_ALERTS} alerts")
                    return
                self._count_missed(key, msg.seq)
                self.world.ingest_ev_alert(msg, now)
                self.counters["ev_alerts"] += 1
                # decide at once for the vehicles this EV can concern; the others at the next loop step
                self._decide_all(now, t0=t0, near=(msg.pos_x_m, msg.pos_y_m))
            elif isinstance(msg, Health):
                self.world.ingest_rsu_health(node, now)
            elif isinstance(msg, HazardAlert):
                if msg.rsu_id != node:
                    self._reject("rsu_mismatch", f"{key} carries rsu_id {msg.rsu_id}")
                    return
                self._count_missed(key, msg.seq)
                self.hazards.ingest(msg, now)
                self.counters["hazard_alerts"] += 1

    def _on_vehicle_state(self, key: str, msg: VehicleState) -> None:
        node = parse_key(key).node
        if msg.vehicle_id != node:
            self._reject("vehicle_mismatch", f"{key} carries vehicle_id {msg.vehicle_id}")
            return
        why = implausible(msg)
        if why is not None:
            self._reject("implausible", f"{key}: {why}")
            return
        now = self.clock.now()
        with self._lock:
            first = msg.vehicle_id not in self.world.vehicles
            if first and len(self.world.vehicles) >= MAX_VEHICLES:
                self._reject("vehicle_limit", f"{key}: already {MAX_VEHICLES} vehicles")
                return
            if not first:
                self._check_relink(msg.vehicle_id, now - self.world.vehicles[msg.vehicle_id].received_s, now)
            self.world.ingest_vehicle_state(msg, now)
            self.counters["vehicle_states"] += 1
            if first:
                self._maybe_adopt(msg, now)

    def _check_relink(self, vid: str, silent_s: float, now: float) -> None:
        """The vehicle is heard again after ``silent_s`` without state (a radio outage) while its command is
        still unacknowledged: the retransmissions carry a path planned from where the car was, which it
        has driven past (it rejects a path that starts behind it). Plan again from its fresh state now,
        instead of waiting for the next retransmission, the rejection and the re-plan backoff."""
        if silent_s < self.config.relink_gap_s:
            return
        cur = self.commands.state_of(vid)
        if cur is None or cur.state != CommandState.SENT:
            return
        before = self._rollback.pop(cur.command_id, None)
        if before is not None:
            self.responses[vid] = before
        before_hz = self._hazard_rollback.pop(cur.command_id, None)
        if before_hz is not None:
            self.hazard_responses[vid] = before_hz
        self._replan_after.pop(vid, None)
        self.counters["cmd_replanned_after_outage"] += 1
        log.warning("%s heard again after %.1f s with command %s unacknowledged: planning it again from the "
                    "car's fresh state", vid, silent_s, cur.command_id)

    def _maybe_adopt(self, vs: VehicleState, now: float) -> None:
        """A vehicle executing a command this DDM never issued (a predecessor did): adopt it."""
        cid = vs.active_command_id
        if cid is None or self.commands.state_of(vs.vehicle_id) is not None:
            return
        self.commands.adopt(vs.vehicle_id, cid)
        resp = self.responses.setdefault(vs.vehicle_id, Response())
        if vs.mode in (VehicleMode.MANOEUVRE, VehicleMode.STOPPED):
            resp.phase, resp.manoeuvre, resp.since_s = "yielding", None, now
            # a restarted DDM has not heard the EV yet: no RESUME before the RSUs' alerts (2 Hz) have
            # had ev_alert_timeout_s to reach it
            resp.ev_near_s = now + self.config.ev_alert_timeout_s
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
            self._count_missed(key, msg.seq)
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
                before_hz = self._hazard_rollback.pop(ev.command_id, None)
                if before_hz is not None:
                    self.hazard_responses[ev.vehicle_id] = before_hz
                self._replan_after[ev.vehicle_id] = now + self.config.replan_backoff_s
                log.log(level, "command %s to %s %s: %s; re-planning", ev.command_id, ev.vehicle_id, ev.kind, ev.detail)
            elif ev.kind in ("issued", "superseded", "accepted", "completed", "adopted"):
                if ev.kind != "issued":
                    self._rollback.pop(ev.command_id, None)
                    self._hazard_rollback.pop(ev.command_id, None)
                log.info("command %s to %s %s%s", ev.command_id, ev.vehicle_id, ev.kind,
                         f": {ev.detail}" if ev.detail else "")

    def _ego(self, vid: str) -> Ego | None:
        rec = self.world.vehicles.get(vid)
        if rec is None or self.clock.now() - rec.received_s > self.config.vehicle_state_timeout_s:
            return None
        if not self.presence.is_alive("vehicle", vid) and vid in self.presence.lost("vehicle"):
            return None  # its session is gone: nothing it would receive
        s = rec.state
        return Ego(vid, s.pos_x_m, s.pos_y_m, s.heading_rad, s.speed_mps, s.length_m, s.width_m, s.mode,
                   s.active_command_id, rec.track_id)

    def _decide_all(self, now: float, t0: float | None = None, near: tuple[float, float] | None = None) -> None:
        """Decide for every vehicle; ``near`` (an EV alert's position): only for the vehicles within
        ``ev_lookbehind_m`` + ``ALERT_RADIUS_MARGIN_M`` of it (the alert path stays short with many vehicles)."""
        if now < self.listen_until_s:
            return
        evs = None
        radius = self.config.ev_lookbehind_m + ALERT_RADIUS_MARGIN_M
        for vid in list(self.world.vehicles):
            if now < self._replan_after.get(vid, -1.0):
                continue
            ego = self._ego(vid)
            if ego is None:
                continue
            if near is not None and math.hypot(ego.x_m - near[0], ego.y_m - near[1]) > radius:
                continue
            if evs is None:
                evs = self.world.ev_tracks(now)
            resp = self.responses.setdefault(vid, Response())
            if not evs and resp.phase == "normal":
                self._decide_hazard(vid, ego, now)  # nothing to yield to, nothing to resume from
                continue
            others = self.world.tracks_near(ego.x_m, ego.y_m, NEIGHBOUR_RADIUS_M, now)
            decision = decide(ego, evs, others, self.frame, self.config, resp, now)
            if evs and self.ev_aware_s is None:
                self.ev_aware_s = now
                log.info("first EV-aware decision %.3f s after start (%s)", now - self.started_s, decision.action)
            if decision.ev_near:
                resp.ev_near_s = now
            if decision.ev_s_m is not None and decision.ev_speed_mps is not None:
                resp.ev_last = (decision.ev_s_m, decision.ev_speed_mps, now)
            what = (str(decision.action), decision.ev_track_id)
            if what != self._last_reason.get(vid):
                log.info("%s: %s (%s)", vid, decision.action, decision.reason)
                if log.isEnabledFor(logging.DEBUG):
                    log.debug("%s at (%.1f, %.1f), track %s; tracks near: %s", vid, ego.x_m, ego.y_m, ego.track_id,
                              ", ".join(f"{o.track_id}:({o.x_m:.1f}, {o.y_m:.1f}) {o.obj_type} lane {o.lane}"
                                        for o in others) or "none")
            self._last_reason[vid] = what
            if decision.manoeuvre is not None:
                self._command(vid, decision, resp, now)
                self.counters["decisions"] += 1
                self.hazard_responses.pop(vid, None)  # the EV command supersedes any hazard command
            elif resp.phase == "normal" and decision.action == "none":
                self._decide_hazard(vid, ego, now, others)
        self._send_due(now)
        if t0 is not None and self._issued_in_call:
            ms = (time.perf_counter() - t0) * 1000.0
            self.decision_latency_ms.append(ms)
            metrics.observe_stages({"decision": ms / 1000.0})
            self._period_latency.append(ms)
        self._issued_in_call = False

    def _command(self, vid: str, decision: Decision, resp: Response, now: float) -> None:
        path = plan(decision, self.frame, self.config, self.vehicle_width.get(vid, 1.9),
                    self.cruise_speed.get(vid, self.corridor.road.speed_limit_mps))
        self._issued_in_call = True
        self._issue(vid, decision, path, resp, self._rollback, now)
        resp.note_stop(decision, path.stop_distance_m)  # where the pull-over counts on an empty lane

    def _issue(self, vid: str, decision: Decision | HazardDecision, path, memory: Response | HazardResponse,
               rollback: dict, now: float) -> None:
        """Issue a decision's command and commit it to the vehicle's policy memory; the memory as it was
        is kept in ``rollback`` (by command id) to restore if the command is rejected or expires."""
        target_lane = decision.target_lane if decision.target_lane is not None else 0
        cmd = self.commands.issue(
            vid, now, manoeuvre=decision.manoeuvre, reason=decision.reason, target_lane=target_lane,
            waypoints=path.waypoints, speed_profile_mps=path.speeds_mps, target_speed_mps=path.target_speed_mps,
            stop_point=path.stop_point,
        )
        rollback[cmd.command_id] = copy.deepcopy(memory)
        memory.commit(decision, now)
        self._process_events(now)

    def _decide_hazard(self, vid: str, ego: Ego, now: float, others: list | None = None) -> None:
        """The hazard policy for one vehicle the EV policy leaves alone (``others``: the tracks near it,
        when the EV policy already looked them up)."""
        active = self.hazards.active()
        hresp = self.hazard_responses.setdefault(vid, HazardResponse())
        if not active and hresp.phase == "normal":
            return
        if others is None:
            others = self.world.tracks_near(ego.x_m, ego.y_m, NEIGHBOUR_RADIUS_M, now)
        d = decide_hazard(ego, active, others, self.frame, self.config, self.hazard_config, hresp,
                          self.cruise_speed.get(vid, self.corridor.road.speed_limit_mps))
        what = (str(d.action), d.hazard_id)
        if what != self._last_hazard_reason.get(vid):
            log.info("%s: hazard %s (%s)", vid, d.action, d.reason)
        self._last_hazard_reason[vid] = what
        if d.manoeuvre is not None:
            self._command_hazard(vid, d, hresp, now)
            self.counters["hazard_decisions"] += 1

    def _command_hazard(self, vid: str, d: HazardDecision, hresp: HazardResponse, now: float) -> None:
        assert d.path is not None
        self._issue(vid, d, d.path, hresp, self._hazard_rollback, now)

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
            changed = self._refresh_stale(now, publish=False)
            self.hazards.maintain(now)
            for what, hid in self.hazards.drain():
                log.info("hazard %d %s", hid, what)
            self._decide_all(now)
            self._step_time_s = time.perf_counter() - t0
            metrics.observe_stages({"step": self._step_time_s})
            if self._health_timer.due(now) or changed:
                self.publish_health(now)  # at 1 Hz, and at once when an RSU goes stale or comes back

    def health(self, now: float) -> Health:
        rates = period_rates(self.counters, self._last_counts, now - self._last_health_s, RATE_NAMES)
        lat = {}
        if self.decision_latency_ms:
            arr = np.fromiter(self.decision_latency_ms, float)
            lat["decision_p50"] = float(np.percentile(arr, 50))
            lat["decision_p99"] = float(np.percentile(arr, 99))
        if self._period_latency:
            lat["decision_mean"] = float(np.mean(self._period_latency))
        lat["step"] = self._step_time_s * 1000.0
        if self.ev_aware_s is not None:
            lat["ev_aware_after_start"] = (self.ev_aware_s - self.started_s) * 1000.0
        rejected = dict(self.rejected)
        for reason, n in self.transport.stats.rejected.items():
            rejected[f"decode_{reason}"] = int(n)
        stale = sorted(self._stale_reported)
        n_rsu = len(self.world.rsu_ids)
        counts = {"tracks": self.world.track_count, "vehicles": len(self.world.vehicles),
                  "outstanding": self.commands.outstanding(), "hazards": len(self.hazards.hazards),
                  "rsus_lost": len(self.presence.lost("rsu")), "vehicles_lost": len(self.presence.lost("vehicle"))}
        return Health(
            src=self.ddm_id, seq=self._health_seq, stamp=now, role=Role.DDM,
            status=HealthStatus.DEGRADED if stale else HealthStatus.OK, uptime_s=max(0.0, now - self.started_s),
            rates_hz=rates, latency_ms=lat,
            drops={"old_measurements": self.world.stats.dropped_old, "cmd_expired": self.counters["cmd_expired"],
                   "cmd_rejected": self.counters["cmd_rejected"],
                   "missed_alert_samples": self.counters["missed_alert_samples"],
                   "missed_ack_samples": self.counters["missed_ack_samples"]},
            rejected=rejected, stale=stale[:64], counts=counts,
            detail=f"rsus_alive={n_rsu - len(stale)}/{n_rsu} " + " ".join(f"{k}={v}" for k, v in counts.items()),
        )

    def publish_health(self, now: float) -> Health:
        h = self.health(now)
        self.last_health = h
        self.transport.publish(self._health_key, h)
        self._health_seq += 1
        self._last_health_s = now
        self._last_counts = Counter(self.counters)
        self._period_latency = []
        return h

    def run(self, stop: threading.Event) -> None:
        """The real-time loop at ``rate_hz`` until ``stop`` is set."""
        freeze_startup_heap()  # full GC passes scan only what the service makes from now on
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
        presence.close_all(self._handles)
        for s in self._subs:
            s.close()
        self._subs = []

    # convenience for tests
    def command_state(self, vehicle_id: str) -> CommandState | None:
        cur = self.commands.state_of(vehicle_id)
        return None if cur is None else cur.state
