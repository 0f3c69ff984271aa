"""Decider: one decision step, from the world's picture to commands, for every autonomous vehicle. Pure:
no I/O, no clock.

One direction (docs/architecture.md §DDM): the service takes the world's immutable picture
(:meth:`ddm.world.CorridorWorld.snapshot`) and hands it to :meth:`Decider.decide`, which

1. picks the vehicles to decide for: all, or those within the EV look-behind + ``ALERT_RADIUS_MARGIN_M``
   of an EV alert (``near``); none whose state is older than ``vehicle_state_timeout_s``, whose session
   is gone (``unreachable``) or who waits out ``replan_backoff_s`` after a rejected or expired command;
2. asks the EV policy (:func:`ddm.policy.ev.ev_intents`), then the hazard policy
   (:func:`ddm.policy.hazard.hazard_intents`) for the vehicles the EV policy leaves alone (no EV to
   yield to, not yielding): EV over hazard;
3. turns each intent with a manoeuvre into a command through the :class:`ddm.commands.CommandManager`
   and commits it to the vehicle's memory (:class:`VehicleMemory`: one :class:`ddm.intent.Response` per
   concern; an EV command resets the hazard one); the memory as it was is kept by command id.

The policies read the picture and the memory; only this module writes the memory, only the command
manager makes commands, and nothing here reads or writes the world.

- Rollback: a command rejected or expired restores that memory and delays the vehicle's next decision by
  ``replan_backoff_s``; a vehicle heard again after ``relink_gap_s`` of silence with its command still
  unacknowledged has it rolled back and planned again at once (``check_relink``); so has a command still
  unacknowledged when the car has driven ``in_flight_replan_behind_m`` past its path's start
  (``_refresh_in_flight``: a stalled link, the vehicle's state still arriving).
- Adoption after a restart (``adopt``): a vehicle executing a command this DDM never issued (a
  predecessor did) is treated as yielding; no RESUME before the RSUs' alerts have had
  ``ev_alert_timeout_s`` to reach the new DDM.
"""

from __future__ import annotations

import copy
import logging
import math
from collections import Counter
from collections.abc import Collection
from dataclasses import dataclass, field

from ddm.commands import CommandManager, CommandState
from ddm.config import DdmConfig, HazardConfig
from ddm.geometry import RoadFrame
from ddm.intent import Concern, Ego, Intent, Response
from ddm.picture import Picture
from ddm.policy import NEIGHBOUR_RADIUS_M, PolicyContext
from ddm.policy.ev import ev_intents
from ddm.policy.hazard import hazard_intents
from protocol.corridor import Corridor
from protocol.enums import VehicleMode
from protocol.messages import CommandAck, PathSwitchCommand, VehicleState

log = logging.getLogger("ddm")

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
    """Per concern, the (action, cause) last logged: an intent is logged when it changes."""

    def response(self, concern: Concern) -> Response:
        return self.ev if concern == "ev" else self.hazard

    def restore(self, concern: Concern, before: Response) -> None:
        if concern == "ev":
            self.ev = before
        else:
            self.hazard = before


class Decider:
    """Per-vehicle decisions, response memory, rollback and adoption over one corridor's pictures."""

    def __init__(self, corridor: Corridor, frame: RoadFrame, config: DdmConfig, hazard_config: HazardConfig, *,
                 ddm_id: str, started_s: float, counters: Counter | None = None) -> None:
        """``counters``: where decisions (``decisions``, ``hazard_decisions``) and command events
        (``cmd_<kind>``) are counted (the service's, for its Health)."""
        self.config = config
        self.started_s = started_s
        self.commands = CommandManager(config, source_id=ddm_id, seq_base=int(started_s * 1000))
        self.counters = Counter() if counters is None else counters
        self.memory: dict[str, VehicleMemory] = {}
        self._rollback: dict[str, tuple[Concern, Response]] = {}  # command id -> memory before it
        self.context = PolicyContext(frame, config, hazard_config, corridor.road.speed_limit_mps,
                                     {v.vehicle_id: v.cruise_speed_mps for v in corridor.vehicles},
                                     {v.vehicle_id: v.width_m for v in corridor.vehicles})
        self.ev_aware_s: float | None = None
        """Time of the first decision made with an EV in the picture (restart -> EV-aware)."""

    # ------------------------------------------------------------------ reading
    def egos(self, picture: Picture, unreachable: Collection[str] = ()) -> list[Ego]:
        """The vehicles of the picture the policies may decide for: state no older than
        ``vehicle_state_timeout_s``, session not gone (``unreachable``)."""
        timeout = self.config.vehicle_state_timeout_s
        return [v for v in picture.vehicles
                if picture.now - v.received_s <= timeout and v.vehicle_id not in unreachable]

    def sizes(self) -> dict[str, int]:
        """How much the decider remembers (bounded by the vehicles and the outstanding commands)."""
        return {"responses": len(self.memory), "rollback": len(self._rollback),
                "commands_current": len(self.commands.current), "command_events": len(self.commands.events)}

    # ------------------------------------------------------------------ deciding
    def decide(self, picture: Picture, unreachable: Collection[str] = (), near: tuple[float, float] | None = None
               ) -> int:
        """One decision step over ``picture`` (``near``: an EV alert's position, to decide only for the vehicles
        within ``ev_lookbehind_m`` + ``ALERT_RADIUS_MARGIN_M`` of it). Returns how many EV commands were issued."""
        now = picture.now
        self._refresh_in_flight(picture)
        egos = self._due(picture, unreachable, near)
        ev = {i.vehicle_id: i for i in ev_intents(picture, egos, self._responses(egos, "ev"), self.context)}
        # EV over hazard: the hazard policy decides for the vehicles the EV policy leaves alone
        left = [e for e in egos if (i := ev.get(e.vehicle_id)) is None
                or (i.action == "none" and self.memory[e.vehicle_id].ev.phase == "normal")]
        hazard = {i.vehicle_id: i for i in hazard_intents(picture, left, self._responses(left, "hazard"),
                                                            self.context)}
        issued = 0
        for ego in egos:
            mem = self.memory[ego.vehicle_id]
            intent = ev.get(ego.vehicle_id)
            if intent is not None:
                self._note_ev(picture, ego, mem, intent)
                if intent.manoeuvre is not None:
                    self._issue(intent, mem, now)
                    self.counters["decisions"] += 1
                    mem.hazard = Response()  # the EV command supersedes any hazard command
                    issued += 1
                    continue
            intent = hazard.get(ego.vehicle_id)
            if intent is not None:
                self._log_change(picture, ego, mem, intent)
                if intent.manoeuvre is not None:
                    self._issue(intent, mem, now)
                    self.counters["hazard_decisions"] += 1
        return issued

    def _due(self, picture: Picture, unreachable: Collection[str], near: tuple[float, float] | None) -> list[Ego]:
        """The vehicles to decide for now, each with its memory (made on its first decision)."""
        radius = self.config.ev_lookbehind_m + ALERT_RADIUS_MARGIN_M
        out = []
        for ego in self.egos(picture, unreachable):
            mem = self.memory.get(ego.vehicle_id)
            if mem is not None and picture.now < mem.replan_after_s:
                continue
            if near is not None and math.hypot(ego.x_m - near[0], ego.y_m - near[1]) > radius:
                continue
            self.memory.setdefault(ego.vehicle_id, VehicleMemory())
            out.append(ego)
        return out

    def _responses(self, egos: list[Ego], concern: Concern) -> dict[str, Response]:
        """Each vehicle's memory of what it was commanded about ``concern`` (what the policies read)."""
        return {e.vehicle_id: self.memory[e.vehicle_id].response(concern) for e in egos}

    def _note_ev(self, picture: Picture, ego: Ego, mem: VehicleMemory, intent: Intent) -> None:
        """What an EV intent tells the memory whatever it commands: an EV near, and where the EV was."""
        now = picture.now
        if picture.evs and self.ev_aware_s is None:
            self.ev_aware_s = now
            log.info("first EV-aware decision %.3f s after start (%s)", now - self.started_s, intent.action)
        resp = mem.ev
        if intent.ev_near:
            resp.ev_near_s = now
        if intent.ev_s_m is not None and intent.ev_speed_mps is not None:
            resp.ev_last = (intent.ev_s_m, intent.ev_speed_mps, now)
        self._log_change(picture, ego, mem, intent)

    def _log_change(self, picture: Picture, ego: Ego, mem: VehicleMemory, d: Intent) -> None:
        what = (str(d.action), d.cause_id)
        if what != mem.logged.get(d.about):
            log.info("%s: %s%s (%s)", ego.vehicle_id, "hazard " if d.about == "hazard" else "", d.action, d.reason)
            if d.about == "ev" and log.isEnabledFor(logging.DEBUG):
                others = picture.tracks_near(ego.x_m, ego.y_m, NEIGHBOUR_RADIUS_M)
                log.debug("%s at (%.1f, %.1f), track %s; tracks near: %s", ego.vehicle_id, ego.x_m, ego.y_m,
                          ego.track_id, ", ".join(f"{o.track_id}:({o.x_m:.1f}, {o.y_m:.1f}) {o.obj_type} lane "
                                                  f"{o.lane}" for o in others) or "none")
        mem.logged[d.about] = what

    def _issue(self, intent: Intent, mem: VehicleMemory, now: float) -> None:
        """Issue the intent's command and commit it to the vehicle's memory; the memory as it was is kept by
        command id, to restore if the command is rejected or expires."""
        memory = mem.response(intent.about)
        cmd = self.commands.issue_intent(intent, now)
        self._rollback[cmd.command_id] = (intent.about, copy.deepcopy(memory))
        memory.commit(intent, now)
        self._process_events(now)
        memory.note_stop(intent, intent.path.stop_distance_m)  # where a pull-over counts on an empty lane

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

    def _plan_again(self, vid: str, command_id: str, counter: str) -> None:
        """Roll the vehicle's memory back to before ``command_id`` and decide for it at the next step (no backoff);
        the new command supersedes that one. Counted under ``counter``."""
        mem = self.memory.setdefault(vid, VehicleMemory())
        self._roll_back(command_id, mem)
        mem.replan_after_s = -1.0
        self.counters[counter] += 1

    def _refresh_in_flight(self, picture: Picture) -> None:
        """Plan again, from where the car is now, each unacknowledged command that the car's state does not name
        as active and whose path starts more than ``in_flight_replan_behind_m`` behind the car (along its
        heading): the retransmissions of a command stalled on its link carry a path the car is driving past, and
        the car rejects one that starts 15 m behind it. The next decision supersedes the command with a path
        from the car's position."""
        limit_m = self.config.in_flight_replan_behind_m
        for ego in picture.vehicles:
            cur = self.commands.state_of(ego.vehicle_id)
            if cur is None or cur.state != CommandState.SENT or cur.command is None or not cur.command.waypoints:
                continue
            if ego.active_command_id == cur.command_id:
                continue  # the car executes it: only its ack is late
            x0, y0 = cur.command.waypoints[0]
            behind_m = (ego.x_m - x0) * math.cos(ego.heading_rad) + (ego.y_m - y0) * math.sin(ego.heading_rad)
            if behind_m <= limit_m or cur.command_id not in self._rollback:
                continue  # short of the limit, or already planned again (the next command supersedes it)
            self._plan_again(ego.vehicle_id, cur.command_id, "cmd_replanned_in_flight")
            log.warning("%s: command %s unacknowledged after %.1f s, its path now starts %.1f m behind the car: "
                        "planning it again from the car's position", ego.vehicle_id, cur.command_id,
                        picture.now - cur.first_sent_s, behind_m)

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
        self._plan_again(vid, cur.command_id, "cmd_replanned_after_outage")
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
