"""Decider: from the DDM's picture to commands, for every autonomous vehicle. Pure: no I/O, no clock.

The service (:mod:`ddm.service`, the imperative shell) feeds it the time and the inputs that concern
commands, and publishes what ``due_commands`` returns; everything between an EvAlert in the picture and a
command issued happens here:

- ``decide(now)``: per vehicle (all, or those within the EV look-behind + ``ALERT_RADIUS_MARGIN_M`` of
  an alert): the EV policy (:func:`ddm.policy.decide`); while it has nothing to do (no EV to yield to,
  not yielding), the hazard policy (:func:`ddm.hazard.decide_hazard`). EV over hazard: an EV command
  resets the vehicle's hazard memory.
- Issuing: a decision with a manoeuvre is planned (hazard decisions carry their path), issued through the
  :class:`ddm.commands.CommandManager` and committed to the vehicle's memory (:class:`VehicleMemory`:
  one :class:`ddm.decision.Response` per concern); the memory as it was is kept by command id.
- Rollback: a command rejected or expired restores that memory and delays the vehicle's next decision by
  ``replan_backoff_s``; a vehicle heard again after ``relink_gap_s`` of silence with its command still
  unacknowledged has it rolled back and planned again at once (``check_relink``).
- Adoption after a restart (``adopt``): a vehicle executing a command this DDM never issued (a
  predecessor did) is treated as yielding; no RESUME before the RSUs' alerts have had
  ``ev_alert_timeout_s`` to reach the new DDM.

The world (:class:`ddm.world.CorridorWorld`) and the hazards (:class:`ddm.hazard.HazardBook`) are read
through their public API only.
"""

from __future__ import annotations

import copy
import logging
import math
from collections import Counter
from collections.abc import Collection
from dataclasses import dataclass, field

from ddm.commands import CommandManager, CommandState
from ddm.config import DdmConfig
from ddm.decision import Concern, Decision, Ego, Response
from ddm.geometry import RoadFrame
from ddm.hazard import HazardBook, HazardConfig, decide_hazard
from ddm.policy import decide, plan
from ddm.tracks import Track
from ddm.world import CorridorWorld
from protocol.corridor import Corridor
from protocol.enums import VehicleMode
from protocol.messages import CommandAck, PathSwitchCommand, VehicleState

log = logging.getLogger("ddm")

NEIGHBOUR_RADIUS_M = 150.0
"""Tracks within this distance of an AV are considered for its gap checks."""
ALERT_RADIUS_MARGIN_M = 50.0
"""An EV alert is decided at once for vehicles within the EV look-behind + this of it (it may be passing)."""


@dataclass
class VehicleMemory:
    """What the decider remembers of one vehicle between decisions."""

    ev: Response = field(default_factory=Response)
    hazard: Response = field(default_factory=Response)
    replan_after_s: float = -1.0
    """No decision before this time (after a rejected or expired command)."""
    logged: dict[Concern, tuple[str, int | None]] = field(default_factory=dict)
    """Per concern, the (action, cause) last logged: a decision is logged when it changes."""

    def response(self, concern: Concern) -> Response:
        return self.ev if concern == "ev" else self.hazard

    def restore(self, concern: Concern, before: Response) -> None:
        if concern == "ev":
            self.ev = before
        else:
            self.hazard = before


class Decider:
    """Per-vehicle decisions, response memory, rollback and adoption over one corridor's picture."""

    def __init__(self, world: CorridorWorld, hazards: HazardBook, corridor: Corridor, frame: RoadFrame,
                 config: DdmConfig, hazard_config: HazardConfig, *, ddm_id: str, started_s: float,
                 counters: Counter | None = None) -> None:
        """``counters``: where decisions (``decisions``, ``hazard_decisions``) and command events
        (``cmd_<kind>``) are counted (the service's, for its Health)."""
        self.world, self.hazards, self.frame = world, hazards, frame
        self.config, self.hazard_config = config, hazard_config
        self.started_s = started_s
        self.commands = CommandManager(config, source_id=ddm_id, seq_base=int(started_s * 1000))
        self.counters = Counter() if counters is None else counters
        self.memory: dict[str, VehicleMemory] = {}
        self._rollback: dict[str, tuple[Concern, Response]] = {}  # command id -> memory before it
        self._speed_limit_mps = corridor.road.speed_limit_mps
        self._cruise_mps = {v.vehicle_id: v.cruise_speed_mps for v in corridor.vehicles}
        self._width_m = {v.vehicle_id: v.width_m for v in corridor.vehicles}
        self.ev_aware_s: float | None = None
        """Time of the first decision made with an EV in the picture (restart -> EV-aware)."""

    # ------------------------------------------------------------------ reading
    def ego(self, vid: str, now: float, unreachable: Collection[str] = ()) -> Ego | None:
        """The vehicle as the policies see it; None when its state is older than
        ``vehicle_state_timeout_s`` or it is ``unreachable`` (its session is gone)."""
        rec = self.world.vehicles.get(vid)
        if rec is None or now - rec.received_s > self.config.vehicle_state_timeout_s or vid in unreachable:
            return None
        s = rec.state
        return Ego(vid, s.pos_x_m, s.pos_y_m, s.heading_rad, s.speed_mps, s.length_m, s.width_m, s.mode,
                   s.active_command_id, rec.track_id)

    def sizes(self) -> dict[str, int]:
        """How much the decider remembers (bounded by the vehicles and the outstanding commands)."""
        return {"responses": len(self.memory), "rollback": len(self._rollback),
                "commands_current": len(self.commands.current), "command_events": len(self.commands.events)}

    # ------------------------------------------------------------------ deciding
    def decide(self, now: float, unreachable: Collection[str] = (), near: tuple[float, float] | None = None) -> int:
        """Decide for every vehicle; ``near`` (an EV alert's position): only for those within
        ``ev_lookbehind_m`` + ``ALERT_RADIUS_MARGIN_M`` of it. Returns how many EV commands were issued."""
        evs: list[Track] | None = None
        radius = self.config.ev_lookbehind_m + ALERT_RADIUS_MARGIN_M
        issued = 0
        for vid in list(self.world.vehicles):
            mem = self.memory.get(vid)
            if mem is not None and now < mem.replan_after_s:
                continue
            ego = self.ego(vid, now, unreachable)
            if ego is None or (near is not None and math.hypot(ego.x_m - near[0], ego.y_m - near[1]) > radius):
                continue
            if evs is None:
                evs = self.world.ev_tracks(now)
            issued += self._decide_vehicle(ego, self.memory.setdefault(vid, VehicleMemory()), evs, now)
        return issued

    def _decide_vehicle(self, ego: Ego, mem: VehicleMemory, evs: list[Track], now: float) -> int:
        """The EV policy, then the hazard policy when the EV policy leaves the vehicle alone."""
        resp = mem.ev
        if not evs and resp.phase == "normal":
            self._decide_hazard(ego, mem, now)  # nothing to yield to, nothing to resume from
            return 0
        others = self.world.tracks_near(ego.x_m, ego.y_m, NEIGHBOUR_RADIUS_M, now)
        decision = decide(ego, evs, others, self.frame, self.config, resp, now)
        if evs and self.ev_aware_s is None:
            self.ev_aware_s = now
            log.info("first EV-aware decision %.3f s after start (%s)", now - self.started_s, decision.action)
        if decision.ev_near:
            resp.ev_near_s = now
        if decision.ev_s_m is not None and decision.ev_speed_mps is not None:
            resp.ev_last = (decision.ev_s_m, decision.ev_speed_mps, now)
        self._log_change(ego, mem, decision, others)
        if decision.manoeuvre is not None:
            self._issue(ego.vehicle_id, decision, mem, now)
            self.counters["decisions"] += 1
            mem.hazard = Response()  # the EV command supersedes any hazard command
            return 1
        if resp.phase == "normal" and decision.action == "none":
            self._decide_hazard(ego, mem, now, others)
        return 0

    def _decide_hazard(self, ego: Ego, mem: VehicleMemory, now: float, others: list[Track] | None = None) -> None:
        """The hazard policy for one vehicle (``others``: the tracks near it, when already looked up)."""
        active = self.hazards.active()
        if not active and mem.hazard.phase == "normal":
            return
        if others is None:
            others = self.world.tracks_near(ego.x_m, ego.y_m, NEIGHBOUR_RADIUS_M, now)
        decision = decide_hazard(ego, active, others, self.frame, self.config, self.hazard_config, mem.hazard,
                                 self._cruise_mps.get(ego.vehicle_id, self._speed_limit_mps))
        self._log_change(ego, mem, decision, others)
        if decision.manoeuvre is not None:
            self._issue(ego.vehicle_id, decision, mem, now)
            self.counters["hazard_decisions"] += 1

    def _log_change(self, ego: Ego, mem: VehicleMemory, d: Decision, others: list[Track]) -> None:
        what = (str(d.action), d.cause_id)
        if what != mem.logged.get(d.about):
            log.info("%s: %s%s (%s)", ego.vehicle_id, "hazard " if d.about == "hazard" else "", d.action, d.reason)
            if d.about == "ev" and log.isEnabledFor(logging.DEBUG):
                log.debug("%s at (%.1f, %.1f), track %s; tracks near: %s", ego.vehicle_id, ego.x_m, ego.y_m,
                          ego.track_id, ", ".join(f"{o.track_id}:({o.x_m:.1f}, {o.y_m:.1f}) {o.obj_type} lane "
                                                  f"{o.lane}" for o in others) or "none")
        mem.logged[d.about] = what

    def _issue(self, vid: str, decision: Decision, mem: VehicleMemory, now: float) -> None:
        """Plan (unless the policy did), issue the command and commit it to the vehicle's memory; the
        memory as it was is kept by command id, to restore if the command is rejected or expires."""
        path = decision.path
        if path is None:
            path = plan(decision, self.frame, self.config, self._width_m.get(vid, 1.9),
                        self._cruise_mps.get(vid, self._speed_limit_mps))
        memory = mem.response(decision.about)
        cmd = self.commands.issue(
            vid, now, manoeuvre=decision.manoeuvre, reason=decision.reason,
            target_lane=decision.target_lane if decision.target_lane is not None else 0,
            waypoints=path.waypoints, speed_profile_mps=path.speeds_mps, target_speed_mps=path.target_speed_mps,
            stop_point=path.stop_point,
        )
        self._rollback[cmd.command_id] = (decision.about, copy.deepcopy(memory))
        memory.commit(decision, now)
        self._process_events(now)
        memory.note_stop(decision, path.stop_distance_m)  # where a pull-over counts on an empty lane

    # ------------------------------------------------------------------ commands' life
    def due_commands(self, now: float) -> list[PathSwitchCommand]:
        """Commands to (re)send now (the service publishes them)."""
        due = self.commands.on_tick(now)
        self._process_events(now)
        return due

    def on_ack(self, ack: CommandAck, now: float) -> None:
        self.commands.on_ack(ack, now)
        self._process_events(now)

    def _process_events(self, now: float) -> None:
        for ev in self.commands.drain_events():
            self.counters[f"cmd_{ev.kind}"] += 1
            if ev.kind in ("rejected", "expired"):
                mem = self.memory.setdefault(ev.vehicle_id, VehicleMemory())
                self._roll_back(ev.command_id, mem)
                mem.replan_after_s = now + self.config.replan_backoff_s
                log.warning("command %s to %s %s: %s; re-planning", ev.command_id, ev.vehicle_id, ev.kind, ev.detail)
            elif ev.kind in ("issued", "superseded", "accepted", "completed", "adopted"):
                if ev.kind != "issued":
                    self._rollback.pop(ev.command_id, None)
                log.info("command %s to %s %s%s", ev.command_id, ev.vehicle_id, ev.kind,
                         f": {ev.detail}" if ev.detail else "")

    def _roll_back(self, command_id: str, mem: VehicleMemory) -> None:
        entry = self._rollback.pop(command_id, None)
        if entry is not None:
            mem.restore(*entry)

    def check_relink(self, vid: str, silent_s: float) -> None:
        """The vehicle is heard again after ``silent_s`` without state (a radio outage) while its command is
        still unacknowledged: the retransmissions carry a path planned from where the car was, which it
        has driven past (it rejects a path that starts behind it). Plan again from its fresh state at the
        next decision, instead of waiting for the next retransmission, the rejection and the backoff."""
        if silent_s < self.config.relink_gap_s:
            return
        cur = self.commands.state_of(vid)
        if cur is None or cur.state != CommandState.SENT:
            return
        mem = self.memory.setdefault(vid, VehicleMemory())
        self._roll_back(cur.command_id, mem)
        mem.replan_after_s = -1.0
        self.counters["cmd_replanned_after_outage"] += 1
        log.warning("%s heard again after %.1f s with command %s unacknowledged: planning it again from the "
                    "car's fresh state", vid, silent_s, cur.command_id)

    def adopt(self, vs: VehicleState, now: float) -> None:
        """A vehicle first heard executing a command this DDM never issued (a predecessor did): adopt it."""
        cid = vs.active_command_id
        if cid is None or self.commands.state_of(vs.vehicle_id) is not None:
            return
        self.commands.adopt(vs.vehicle_id, cid)
        resp = self.memory.setdefault(vs.vehicle_id, VehicleMemory()).ev
        if vs.mode in (VehicleMode.MANOEUVRE, VehicleMode.STOPPED):
            resp.phase, resp.manoeuvre, resp.since_s = "yielding", None, now
            # a restarted DDM has not heard the EV yet: no RESUME before the RSUs' alerts (2 Hz) have
            # had ev_alert_timeout_s to reach it
            resp.ev_near_s = now + self.config.ev_alert_timeout_s
        log.info("vehicle %s executes command %s (mode %s) from a previous DDM: adopted", vs.vehicle_id, cid,
                 vs.mode.value)

    def forget_response(self, vid: str, concern: Concern = "ev") -> None:
        """Forget what the vehicle was commanded about ``concern``, as after its RESUME (benches' rounds)."""
        mem = self.memory.get(vid)
        if mem is not None:
            mem.restore(concern, Response())
