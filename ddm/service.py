"""DDM service: the imperative shell around the world model and the decider (transport, clock, checks).

Subscribes to every RSU topic (``iea/{c}/rsu/*/objects``, ``ev``, ``hazard``, ``health``; the bulk object
lists apart) and to every vehicle's ``state`` and ``ack``; publishes ``PathSwitchCommand`` on
``iea/{c}/vehicle/{v}/cmd`` and ``Health`` on ``iea/{c}/ddm/health`` at 1 Hz.

One direction: inputs update the world (:class:`ddm.world.CorridorWorld`: tracks, EVs,
hazards, vehicles); a decision step takes its immutable picture (``world.snapshot``) and hands it to the
decider (:class:`ddm.decider.Decider`: policies -> intents -> command manager); the service publishes the
commands due.

- ``step(now)`` is one loop iteration (maintain the world, decide for every AV, retransmit, health); a
  lockstep test calls it with a ``SimClock`` + ``LocalBus``, ``run()`` calls it at ``rate_hz``.
- An EvAlert is acted on in its callback (not at the next tick): the decision latency is the time
  from the alert's arrival to the command's publication, measured and reported in ``Health``.
- Boundary checks beyond the codec: the RSU / vehicle id inside a message must match its key, and
  object lists stamped in the future are refused; each refusal is counted by reason.
- Restart: for ``startup_listen_s`` after start the service only listens. A vehicle that reports an
  active command the service does not know (issued by its predecessor) has it adopted by the decider.
- Security: with a ``signer`` every ``PathSwitchCommand`` is signed on publication
  (``protocol.security.SecureTransport``; deterministic, so retransmissions are identical); when the
  corridor trusts RSU keys, EvAlerts/HazardAlerts must carry a valid RSU signature (refusals counted
  as ``decode_auth_<reason>``). Whatever a peer sends, the picture stays bounded: at most
  ``MAX_VEHICLES`` vehicles, ``MAX_RSUS`` RSUs, ``MAX_ALERTS`` alerts and about ``MAX_TRACKS`` tracks
  (refusals counted as ``*_limit``), and numbers nothing physical produces (``MAX_ABS_POSITION_M``...)
  are kept from the fusion: such alerts and vehicle states are refused (``implausible``), such
  objects dropped from their list (``implausible_object``).
- Presence and state (``protocol.presence``, ``ddm.catchup``): the service declares its liveliness token
  and watches the RSUs' and vehicles'; an RSU whose token is lost is stale at once (not after
  ``rsu_stale_s`` of silence), a vehicle whose token is lost gets no decisions. It answers
  ``iea/{c}/ddm/state`` (its picture, JSON) and ``iea/{c}/ddm/health`` (its latest Health). At start it
  queries the RSUs' latest object lists and active alerts and the vehicles' states; once every RSU of
  the corridor has answered, the listen period ends and it decides at once (EV-aware without waiting
  for the next alert repeat).
"""

from __future__ import annotations

import logging
import threading
import time
from collections import Counter, deque

import numpy as np

from ddm.catchup import CorridorPresence
from ddm.commands import CommandState
from ddm.config import DdmConfig, HazardConfig
from ddm.decider import Decider
from ddm.geometry import RoadFrame
from ddm.v2x import V2xInput
from ddm.world import CorridorWorld
from protocol import metrics, presence
from protocol.clock import Clock, RateTimer
from protocol.corridor import Corridor
from protocol.enums import HealthStatus, Role
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
from protocol.messages import CommandAck, EvAlert, HazardAlert, Health, ObjectList, VehicleState
from protocol.ranges import MAX_RATE_HZ
from protocol.runtime import freeze_startup_heap
from protocol.security import SecureTransport, Signer, TrustList, Verifier
from protocol.transport import Transport

log = logging.getLogger("ddm")

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
a 1e16 m/s velocity overflows the fusion's arithmetic (the KD-tree of the duplicate merge then raises
on every step). The limits are loose on purpose: a SORT track running away at 110 m/s, which real RSU
output contains, still passes."""


RATE_NAMES = ("object_lists", "object_updates", "ev_alerts", "vehicle_states", "commands_published")


def period_rates(counts: Counter, before: Counter, period_s: float, names: tuple[str, ...]) -> dict[str, float]:
    """Per-second rates of ``names`` over the last health period; none over a period under 1 ms (a Health
    published at once after another: its count over ~0 s is no rate, and would overflow the RateHz range)."""
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
        at start (False: learn it from the streams only; for comparisons)."""
        self.config = cfg = config or DdmConfig()
        corridor.road.prepare()  # its first road query would otherwise cost 0.4 s at the scenario's start
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
        self.hazard_config = hazard_config or HazardConfig()
        self.world = CorridorWorld(cfg, rsu_ids=tuple(r.rsu_id for r in corridor.rsus), frame=self.frame,
                                   hazard_config=self.hazard_config)
        now = clock.now()
        self.started_s = now
        self.rejected: Counter = Counter()
        self.counters: Counter = Counter()
        self.decider = Decider(corridor, self.frame, cfg, self.hazard_config, ddm_id=ddm_id, started_s=now,
                               counters=self.counters)
        self.commands = self.decider.commands
        """The decider's command manager (read by Health, the state answer and the runners)."""
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
        self.listen_until_s = now + cfg.startup_listen_s
        self.presence = presence.PresenceBook()
        self.stale_now: set[str] = set()
        self.last_health: Health | None = None
        self.catch_up_replies: dict[str, int] = {}
        self._last_seq: dict[str, int] = {}
        # subscribe last: a Zenoh callback may run (on its own thread) as soon as this returns
        self._subs = [
            *(transport.subscribe(rsu_topic_expr(c, topic), self._on_rsu) for topic in RSU_TOPICS),
            transport.subscribe(all_vehicles_expr(c, "state"), self._on_vehicle_state),
            transport.subscribe(all_vehicles_expr(c, "ack"), self._on_ack),
        ]
        self.v2x = V2xInput(self).start()  # EV CAMs passed on by the RSU radios (ddm/v2x.py)
        self._subs.append(self.v2x)
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
        """An RSU's message: checked at the boundary, then routed (EvAlerts decided at once)."""
        t0 = time.perf_counter()
        try:
            node = parse_key(key).node
        except KeyError_:
            self._reject("key", key)
            return
        now = self.clock.now()
        msg = self._plausible(key, msg)
        if msg is None:
            return
        with self._lock:
            if not self.world.knows_rsu(node) and len(self.world.rsu_ids) >= MAX_RSUS:
                self._reject("rsu_limit", f"{key}: already {MAX_RSUS} RSUs")
            elif isinstance(msg, Health):
                self.world.ingest_rsu_health(node, now)
            elif isinstance(msg, ObjectList | EvAlert | HazardAlert) and msg.rsu_id != node:
                self._reject("rsu_mismatch", f"{key} carries rsu_id {msg.rsu_id}")
            elif isinstance(msg, ObjectList):
                self._on_objects(key, msg, now)
            elif isinstance(msg, EvAlert):
                self._on_ev_alert(key, msg, now, t0)
            elif isinstance(msg, HazardAlert):
                self._count_missed(key, msg.seq)
                self.world.ingest_hazard_alert(msg, now)
                self.counters["hazard_alerts"] += 1

    def _plausible(self, key: str, msg):
        """The message without the objects whose numbers cannot be real; None (refused) for an alert whose
        numbers cannot be."""
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
                return None
        return msg

    def _on_objects(self, key: str, msg: ObjectList, now: float) -> None:
        if msg.measurement_time > now + self.config.max_future_s:
            self._reject("future_stamp", f"{key} measurement_time {msg.measurement_time} > now {now}")
        elif self.world.track_count >= MAX_TRACKS:
            self._reject("track_limit", f"{key}: already {MAX_TRACKS} tracks")
        else:
            self.world.ingest_objects(msg, now)
            self.counters["object_lists"] += 1
            self.counters["object_updates"] += len(msg.objects)

    def _on_ev_alert(self, key: str, msg: EvAlert, now: float, t0: float) -> None:
        """Into the world, then decided at once for the vehicles this EV can concern (the others at the
        next loop step); ``t0``: the callback's entry, for the decision latency."""
        if msg.alert_id not in self.world.alerts and len(self.world.alerts) >= MAX_ALERTS:
            self._reject("alert_limit", f"{key}: already {MAX_ALERTS} alerts")
            return
        self._count_missed(key, msg.seq)
        self.world.ingest_ev_alert(msg, now)
        self.counters["ev_alerts"] += 1
        self._decide_all(now, t0=t0, near=(msg.pos_x_m, msg.pos_y_m))

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
                self.decider.check_relink(msg.vehicle_id, now - self.world.vehicles[msg.vehicle_id].received_s)
            self.world.ingest_vehicle_state(msg, now)
            self.counters["vehicle_states"] += 1
            if first:
                self.decider.adopt(msg, now)

    def _on_ack(self, key: str, msg: CommandAck) -> None:
        node = parse_key(key).node
        if msg.vehicle_id != node:
            self._reject("vehicle_mismatch", f"{key} carries vehicle_id {msg.vehicle_id}")
            return
        now = self.clock.now()
        with self._lock:
            self.counters["acks"] += 1
            self._count_missed(key, msg.seq)
            self.decider.on_ack(msg, now)

    # ------------------------------------------------------------------ decisions
    @property
    def ev_aware_s(self) -> float | None:
        """Clock time of the first decision made with an EV in the picture (restart -> EV-aware)."""
        return self.decider.ev_aware_s

    def unreachable_vehicles(self) -> set[str]:
        """Vehicles whose session is gone (liveliness token lost): nothing they would receive."""
        return {v for v in self.presence.lost("vehicle") if not self.presence.is_alive("vehicle", v)}

    def _decide_all(self, now: float, t0: float | None = None, near: tuple[float, float] | None = None) -> None:
        """The decider decides on the world's picture at ``now`` (``near``: an EV alert's position, for the
        vehicles it can concern), then the due commands are published; an alert's decision latency (``t0``:
        its callback's entry) is measured to the publication."""
        if now < self.listen_until_s:
            return
        issued = self.decider.decide(self.world.snapshot(now), self.unreachable_vehicles(), near)
        self._send_due(now)
        if t0 is not None and issued:
            ms = (time.perf_counter() - t0) * 1000.0
            self.decision_latency_ms.append(ms)
            metrics.observe_stages({"decision": ms / 1000.0})
            self._period_latency.append(ms)

    def _send_due(self, now: float) -> None:
        for cmd in self.decider.due_commands(now):
            key = self._cmd_keys.get(cmd.vehicle_id)
            if key is None:
                key = self._cmd_keys[cmd.vehicle_id] = vehicle_key(self.corridor_id, cmd.vehicle_id, "cmd")
            self.transport.publish(key, cmd)
            self.counters["commands_published"] += 1

    # ------------------------------------------------------------------ loop
    def step(self, now: float | None = None) -> None:
        """One loop iteration: maintain the picture, decide, retransmit, publish health when due."""
        now = self.clock.now() if now is None else now
        with self._lock:
            t0 = time.perf_counter()
            self.world.maintain(now)
            changed = self._refresh_stale(now, publish=False)
            for what, hid in self.world.drain_hazard_events():
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
                  "outstanding": self.commands.outstanding(), "hazards": len(self.world.hazards.hazards),
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
