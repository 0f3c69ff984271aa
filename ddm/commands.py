"""Command manager: turns intents into path-switch commands that are never lost. Pure state machine,
explicit clock. The only place a ``PathSwitchCommand`` is made (docs/architecture.md §DDM).

``issue_intent`` makes the command of an intent with a manoeuvre and a planned path (the policies'
output, :class:`ddm.intent.Intent`). One outstanding command per vehicle. Each command has a unique id
and a per-vehicle ``command_seq`` (the vehicle never lets a lower value override a higher one). Life cycle of one command:

    issue -> SENT --ack accepted--> ACCEPTED --ack completed--> COMPLETED
               |  \\--ack rejected--> REJECTED (reason logged; the caller re-plans)
               |---- no ack after max_attempts sends / past valid_until --> EXPIRED (explicit event)
               \\--- a newer command for the vehicle ---> SUPERSEDED (the new one names it in ``supersedes``)

Retransmission (like CARMA's response message, repeated until acknowledged): after
``retransmit_initial_s``, doubling up to ``retransmit_max_s``, at most ``max_attempts`` sends.
``on_tick(now)`` returns the commands to (re)send now; acks come in through ``on_ack``. Every state
change is returned as an ``Event`` for the caller to log and count.

Sequence numbers start at ``seq_base`` (the service passes its start time in ms), so that a restarted
DDM's commands still outrank the ones its predecessor sent.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import StrEnum

from ddm.config import DdmConfig
from ddm.intent import Intent
from protocol.enums import AckStatus, Manoeuvre
from protocol.messages import CommandAck, PathSwitchCommand


class CommandState(StrEnum):
    SENT = "sent"
    ACCEPTED = "accepted"
    COMPLETED = "completed"
    REJECTED = "rejected"
    EXPIRED = "expired"
    SUPERSEDED = "superseded"
    ADOPTED = "adopted"
    """Found active on the vehicle after a restart (its content is unknown to this DDM)."""


@dataclass
class Outstanding:
    """A vehicle's latest command, its state and its retransmission schedule."""

    command: PathSwitchCommand | None
    command_id: str
    state: CommandState
    attempts: int = 0
    first_sent_s: float = 0.0
    next_send_s: float = 0.0
    interval_s: float = 0.0


@dataclass(frozen=True)
class Event:
    """A change in a command's life (for the caller to log, count and roll back on)."""

    kind: str  # "issued" | "accepted" | "completed" | "rejected" | "expired" | "superseded" | "retransmit" | "ignored_ack" | "adopted"
    vehicle_id: str
    command_id: str
    detail: str = ""
    manoeuvre: Manoeuvre | None = None


@dataclass
class CommandManager:
    """Every vehicle's latest command (ids, sequence numbers, retransmission, acks, expiry)."""

    config: DdmConfig = field(default_factory=DdmConfig)
    source_id: str = "ddm"
    seq_base: int = 0
    current: dict[str, Outstanding] = field(default_factory=dict)
    """The latest command per vehicle (outstanding or finished)."""
    events: list[Event] = field(default_factory=list)
    _seq: int = 0
    history_limit: int = 1000

    def _emit(self, ev: Event) -> Event:
        self.events.append(ev)
        if len(self.events) > self.history_limit:
            del self.events[: len(self.events) - self.history_limit]
        return ev

    def next_seq(self) -> int:
        self._seq += 1
        return self.seq_base + self._seq

    def issue(self, vehicle_id: str, now: float, *, manoeuvre: Manoeuvre, reason: str, target_lane: int,
              waypoints: list[tuple[float, float]], speed_profile_mps: list[float], target_speed_mps: float,
              stop_point: tuple[float, float] | None = None, validity_s: float | None = None) -> PathSwitchCommand:
        """Create a command, supersede the vehicle's previous one explicitly, and mark it to send now."""
        seq = self.next_seq()
        cid = f"{self.source_id}-{vehicle_id}-{seq}"
        prev = self.current.get(vehicle_id)
        supersedes = None
        if prev is not None and prev.state in (CommandState.SENT, CommandState.ACCEPTED, CommandState.ADOPTED):
            supersedes = prev.command_id
        cmd = PathSwitchCommand(
            src=self.source_id, seq=seq, stamp=now, command_id=cid, command_seq=seq, vehicle_id=vehicle_id,
            manoeuvre=manoeuvre, reason=reason[:256], target_lane=target_lane, waypoints=waypoints,
            speed_profile_mps=speed_profile_mps, target_speed_mps=target_speed_mps, stop_point=stop_point,
            issued_at=now, valid_until=now + (validity_s or self.config.command_validity_s), supersedes=supersedes,
        )
        if supersedes is not None:
            prev.state = CommandState.SUPERSEDED  # type: ignore[union-attr]
            self._emit(Event("superseded", vehicle_id, supersedes, f"by {cid}"))
        self.current[vehicle_id] = Outstanding(cmd, cid, CommandState.SENT, attempts=0, first_sent_s=now,
                                               next_send_s=now, interval_s=self.config.retransmit_initial_s)
        self._emit(Event("issued", vehicle_id, cid, reason, manoeuvre))
        return cmd

    def issue_intent(self, intent: Intent, now: float) -> PathSwitchCommand:
        """The command of ``intent`` (a manoeuvre with its planned path, for ``intent.vehicle_id``), issued
        as ``issue`` does; ValueError for an intent that is no command."""
        path = intent.path
        if intent.manoeuvre is None or path is None or not intent.vehicle_id:
            raise ValueError(f"intent {intent.action!r} for vehicle {intent.vehicle_id!r} is no command: it needs a "
                             "manoeuvre, a planned path and a vehicle id")
        return self.issue(intent.vehicle_id, now, manoeuvre=intent.manoeuvre, reason=intent.reason,
                          target_lane=intent.target_lane if intent.target_lane is not None else 0,
                          waypoints=path.waypoints, speed_profile_mps=path.speeds_mps,
                          target_speed_mps=path.target_speed_mps, stop_point=path.stop_point)

    def adopt(self, vehicle_id: str, command_id: str) -> None:
        """After a restart: the vehicle executes ``command_id``; the next command will supersede it."""
        cur = self.current.get(vehicle_id)
        if cur is not None and cur.command_id == command_id:
            return
        self.current[vehicle_id] = Outstanding(None, command_id, CommandState.ADOPTED)
        self._emit(Event("adopted", vehicle_id, command_id))

    def on_ack(self, ack: CommandAck, now: float) -> Event:
        cur = self.current.get(ack.vehicle_id)
        if cur is None or cur.command_id != ack.command_id:
            return self._emit(Event("ignored_ack", ack.vehicle_id, ack.command_id,
                                    f"{ack.status.value} for a command that is not the current one"))
        m = cur.command.manoeuvre if cur.command is not None else None
        if ack.status == AckStatus.ACCEPTED:
            if cur.state == CommandState.SENT:
                cur.state = CommandState.ACCEPTED
                return self._emit(Event("accepted", ack.vehicle_id, ack.command_id, ack.reason, m))
            return self._emit(Event("ignored_ack", ack.vehicle_id, ack.command_id, f"duplicate accept ({cur.state})"))
        if ack.status == AckStatus.COMPLETED:
            cur.state = CommandState.COMPLETED
            return self._emit(Event("completed", ack.vehicle_id, ack.command_id, ack.reason, m))
        if cur.state in (CommandState.SENT, CommandState.ACCEPTED):
            cur.state = CommandState.REJECTED
            return self._emit(Event("rejected", ack.vehicle_id, ack.command_id, ack.reason or "no reason given", m))
        return self._emit(Event("ignored_ack", ack.vehicle_id, ack.command_id, f"reject in state {cur.state}"))

    def on_tick(self, now: float) -> list[PathSwitchCommand]:
        """Commands due for (re)transmission now; expires those out of attempts or validity."""
        out = []
        cfg = self.config
        for vid, cur in self.current.items():
            if cur.state != CommandState.SENT or cur.command is None:
                continue
            if now >= cur.command.valid_until or (cur.attempts >= cfg.max_attempts and now >= cur.next_send_s):
                cur.state = CommandState.EXPIRED
                self._emit(Event("expired", vid, cur.command_id,
                                 f"no ack after {cur.attempts} sends over {now - cur.first_sent_s:.1f} s",
                                 cur.command.manoeuvre))
                continue
            if now + 1e-9 >= cur.next_send_s:
                if cur.attempts > 0:
                    self._emit(Event("retransmit", vid, cur.command_id, f"attempt {cur.attempts + 1}"))
                    cur.interval_s = min(cur.interval_s * 2.0, cfg.retransmit_max_s) if cur.attempts > 1 else cur.interval_s
                cur.attempts += 1
                cur.next_send_s = now + cur.interval_s
                out.append(cur.command)
        return out

    def drain_events(self) -> list[Event]:
        """Events since the last drain (the caller logs and counts them)."""
        out, self.events = self.events, []
        return out

    def state_of(self, vehicle_id: str) -> Outstanding | None:
        return self.current.get(vehicle_id)

    def outstanding(self) -> int:
        return sum(1 for c in self.current.values() if c.state == CommandState.SENT)
