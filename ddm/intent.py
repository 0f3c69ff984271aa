"""What a policy wants for one vehicle, and what the DDM remembers of it: one type each for EV and hazard.

- :class:`Ego`: an autonomous vehicle's own state, as the policies read it (from the world's picture).
- :class:`Intent`: the outcome of one policy for one vehicle, ``about`` an EV (:mod:`ddm.policy.ev`) or a
  hazard (:mod:`ddm.policy.hazard`); an intent whose action is a ``Manoeuvre`` carries its planned path
  and becomes a command (:meth:`ddm.commands.CommandManager.issue_intent`). EV-only and hazard-only
  fields stay at their defaults in the other kind.
- :class:`Response`: the per-vehicle memory of what was commanded about one concern (the decider keeps
  one for EVs and one for hazards per vehicle), updated by ``commit`` when a command is issued; the
  policies read it, never write it.

Pure data: no I/O, no clock.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Literal

from protocol.enums import Manoeuvre, VehicleMode

if TYPE_CHECKING:
    from ddm.paths import PlannedPath

Action = Literal["none", "hold"] | Manoeuvre
"""``none``: nothing to command; ``hold``: keep the manoeuvre under way; a Manoeuvre: command it."""
Concern = Literal["ev", "hazard"]
Phase = Literal["normal", "yielding", "avoiding", "stopping"]
"""``yielding`` to an EV; ``avoiding`` (changing lane around) or ``stopping`` before a hazard."""
SlowBecause = Literal["gap", "too_late", "ev_in_lane0", ""]


@dataclass(frozen=True)
class Ego:
    """An autonomous vehicle as its last VehicleState reported it (``track_id``: the corridor track bound
    to it; ``received_s``: when the DDM received that state)."""

    vehicle_id: str
    x_m: float
    y_m: float
    heading_rad: float
    speed_mps: float
    length_m: float = 4.9
    width_m: float = 1.9
    mode: VehicleMode = VehicleMode.DRIVING
    active_command_id: str | None = None
    track_id: int | None = None
    received_s: float = 0.0


@dataclass(frozen=True)
class Intent:
    """One policy's outcome for one vehicle (the ``ego_*`` fields: its road-frame pose when decided)."""

    action: Action
    reason: str
    about: Concern = "ev"
    target_lane: int | None = None
    ev_track_id: int | None = None
    time_to_pass_s: float | None = None
    ev_gap_m: float | None = None
    slow_because: SlowBecause = ""
    stop_within_m: float | None = None
    """EV PULL_OVER: stop within this distance (room behind a leader in the target lane)."""
    ev_s_m: float | None = None
    """Station of the EV the intent is about (behind the AV)."""
    ev_speed_mps: float | None = None
    ev_near: bool = False
    """An EV is behind the AV (within ``ev_lookbehind_m``) or passing it (ahead by < ``pass_margin_m``)."""
    hazard_id: int | None = None
    threat: float = 0.0
    """Hazard T_f (report eq. 2-3)."""
    stop_s_m: float | None = None
    """Hazard STOP_IN_LANE: road s of the AV centre's stop."""
    path: PlannedPath | None = None
    """The commanded path of an intent with a manoeuvre (None otherwise)."""
    vehicle_id: str = ""
    ego_s_m: float = 0.0
    ego_d_m: float = 0.0
    ego_heading_error_rad: float = 0.0
    ego_speed_mps: float = 0.0

    @property
    def manoeuvre(self) -> Manoeuvre | None:
        return self.action if isinstance(self.action, Manoeuvre) else None

    @property
    def cause_id(self) -> int | None:
        """The EV track or the hazard the intent responds to."""
        return self.ev_track_id if self.about == "ev" else self.hazard_id

    @property
    def phase_after(self) -> Phase:
        """The vehicle's phase once the intent's command is issued."""
        if self.manoeuvre in (None, Manoeuvre.RESUME):
            return "normal"
        if self.about == "ev":
            return "yielding"
        return "avoiding" if self.manoeuvre == Manoeuvre.LANE_CHANGE else "stopping"


@dataclass
class Response:
    """What the DDM has commanded one vehicle about one concern (its memory between decisions)."""

    phase: Phase = "normal"
    manoeuvre: Manoeuvre | None = None
    target_lane: int | None = None
    cause_ids: set[int] = field(default_factory=set)
    """The EV tracks yielded to, or the hazards responded to, since the last RESUME."""
    slow_because: SlowBecause = ""
    since_s: float = 0.0
    ev_near_s: float = 0.0
    """Last time an EV was behind the AV or passing it (the decider updates it from ``Intent.ev_near``)."""
    ev_last: tuple[float, float, float] | None = None
    """(station m, speed along the road m/s, time s) of the nearest EV behind when last seen (the decider
    updates it from ``Intent.ev_s_m``/``ev_speed_mps``): a lost EV is assumed to drive on."""
    stop_s_m: float | None = None
    """EV PULL_OVER: station up to which the command plans for the lane ahead to be free: its stop, or the
    room behind a vehicle ahead it already allowed for (then it creeps). Set with ``note_stop`` once the
    path is planned; a vehicle that turns up in lane 0 later is checked against it."""

    def note_stop(self, intent: Intent, stop_distance_m: float | None) -> None:
        """Remember how far the commanded pull-over counts on an empty lane (station along the road)."""
        if intent.manoeuvre == Manoeuvre.PULL_OVER and stop_distance_m is not None:
            room = stop_distance_m if intent.stop_within_m is None else min(stop_distance_m, intent.stop_within_m)
            self.stop_s_m = intent.ego_s_m + room

    def commit(self, intent: Intent, now: float) -> None:
        """The intent's command was issued: remember it (RESUME forgets what was responded to)."""
        m = intent.manoeuvre
        if m is None:
            return
        self.stop_s_m = None
        self.phase = intent.phase_after
        if m == Manoeuvre.RESUME:
            self.manoeuvre, self.target_lane, self.cause_ids = None, None, set()
            self.slow_because = ""
            self.ev_last = None
        else:
            self.manoeuvre, self.target_lane = m, intent.target_lane
            if intent.cause_id is not None:
                self.cause_ids.add(intent.cause_id)
            self.slow_because = intent.slow_because
            if intent.about == "ev":
                self.ev_near_s = now
        self.since_s = now
