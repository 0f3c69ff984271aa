"""Command validation and the command state machine (pure: no I/O, no clocks).

Every ``PathSwitchCommand`` gets exactly one decision, sent as a ``CommandAck``:

- ``rejected`` with a reason: another vehicle's command, expired (received after ``valid_until``),
  older than the newest accepted one (``command_seq`` lower: an older command never overrides a
  newer one), a reused ``command_seq``, or a path that is malformed or not reachable from where the
  car is (first waypoint too far or too far behind, heading inconsistent with the car's, curvature
  above what the car can drive at the speed it can have there, stop point off the path);
- ``accepted``: the car switches to the command's path now;
- ``completed`` later: stopped at the stop point, end of the path reached, or superseded by a newer
  accepted command (reason ``superseded by <id>``); or ``rejected`` with reason ``aborted: ...`` when
  the fail-safe takes over before it is done.

A duplicate (same ``command_id``) changes nothing and gets the same decision again, so a DDM that
retries until it hears an ack is answered every time. ``valid_until`` is the acceptance deadline: a
command already being executed is carried out to the end (a half-done pull-over is not abandoned);
lost contact during it is the fail-safe's job (``vehicle/failsafe.py``).

Before any of that, ``CommandGate`` authenticates the command (after IEEE 1609.2): with a
trust list it refuses unsigned, unknown-key, wrongly signed, expired, not-yet-valid, out-of-scope and
replayed commands (``protocol.security.AuthError`` with the reason); a refused command never reaches
the book, so the car keeps driving on its last valid command.
"""

from __future__ import annotations

import math
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from protocol.enums import AckStatus, Manoeuvre
from protocol.messages import PathSwitchCommand
from protocol.security import ReplayGuard, TrustList, Verifier
from vehicle.geometry import wrap_angle
from vehicle.reference import ReferencePath


@dataclass(frozen=True)
class CommandLimits:
    max_start_distance_m: float = 30.0
    """The first waypoint must be this close to the car."""
    max_start_behind_m: float = 15.0
    """... and not further behind it than this (a DDM path starts where the RSU last saw the car)."""
    max_offset_from_path_m: float = 6.0
    """The car must be this close to the path (about a lane and a half)."""
    max_heading_error_rad: float = 0.6
    max_lateral_accel_mps2: float = 4.0
    comfort_decel_mps2: float = 3.0
    max_speed_mps: float = 45.0
    max_waypoint_gap_m: float = 25.0
    max_stop_offset_m: float = 3.0
    """The stop point must lie this close to the path."""
    max_steer_rad: float = 0.5
    wheelbase_m: float = 2.8448


@dataclass(frozen=True, slots=True)
class Decision:
    command_id: str
    status: AckStatus
    reason: str = ""


def validate_command(cmd: PathSwitchCommand, vehicle_id: str, now_s: float, pose: tuple[float, float, float],
                     speed_mps: float, limits: CommandLimits = CommandLimits()) -> tuple[str | None, ReferencePath | None]:
    """Check one command against the car's id, the clock and its pose; (reason or None, path)."""
    if cmd.vehicle_id != vehicle_id:
        return f"wrong vehicle: command is for {cmd.vehicle_id!r}, this is {vehicle_id!r}", None
    if now_s > cmd.valid_until:
        return f"expired: valid_until {cmd.valid_until:.3f} < now {now_s:.3f}", None
    if cmd.manoeuvre == Manoeuvre.RESUME:
        return None, None
    if cmd.target_speed_mps > limits.max_speed_mps or any(v > limits.max_speed_mps for v in cmd.speed_profile_mps):
        return f"speed above {limits.max_speed_mps} m/s", None
    wp = np.asarray(cmd.waypoints, dtype=float)
    gaps = np.hypot(*np.diff(wp, axis=0).T)
    if np.any(gaps > limits.max_waypoint_gap_m):
        return f"malformed path: waypoints {float(gaps.max()):.1f} m apart (max {limits.max_waypoint_gap_m})", None
    if float(gaps.sum()) < 1.0:
        return "malformed path: shorter than 1 m", None
    try:
        path = ReferencePath(wp, cmd.speed_profile_mps or None, cmd.stop_point, extend_m=10.0)
    except ValueError as exc:
        return f"malformed path: {exc}", None
    x, y, yaw = pose
    first = wp[0]
    dist0 = math.hypot(first[0] - x, first[1] - y)
    if dist0 > limits.max_start_distance_m:
        return f"unreachable: path starts {dist0:.1f} m from the car (max {limits.max_start_distance_m})", None
    ahead0 = (first[0] - x) * math.cos(yaw) + (first[1] - y) * math.sin(yaw)
    if ahead0 < -limits.max_start_behind_m:
        return f"unreachable: path starts {-ahead0:.1f} m behind the car (max {limits.max_start_behind_m})", None
    proj = path.project(x, y)
    if proj.distance_m > limits.max_offset_from_path_m:
        return f"unreachable: car is {proj.distance_m:.1f} m off the path (max {limits.max_offset_from_path_m})", None
    if proj.s_m >= path.length_m - 10.0 - 0.5:
        return "unreachable: the path ends behind the car", None
    dh = abs(wrap_angle(path.heading_at(proj.s_m) - yaw))
    if dh > limits.max_heading_error_rad:
        return f"unreachable: path heading differs from the car's by {dh:.2f} rad", None
    # curvature against the lowest speed the car can have there when braking comfortably
    ahead = path.s >= proj.s_m
    if np.count_nonzero(ahead) >= 3:
        s_ahead = path.s[ahead] - proj.s_m
        dh_ds = np.abs(np.angle(np.exp(1j * np.diff(path.headings[ahead])))) / np.maximum(np.diff(path.s[ahead]), 1e-9)
        kappa = np.convolve(dh_ds, np.ones(3) / 3.0, mode="same")  # resampling noise
        v_min = np.sqrt(np.maximum(0.0, speed_mps ** 2 - 2.0 * limits.comfort_decel_mps2 * s_ahead[1:]))
        a_lat = kappa * v_min ** 2
        steer_kappa = math.tan(limits.max_steer_rad) / limits.wheelbase_m
        if np.any(kappa > steer_kappa):
            return f"unreachable: path curvature {float(kappa.max()):.3f} 1/m above the steering limit", None
        if np.any(a_lat > limits.max_lateral_accel_mps2):
            i = int(np.argmax(a_lat))
            return (f"unreachable: curvature {float(kappa[i]):.4f} 1/m at {float(s_ahead[i + 1]):.0f} m ahead needs "
                    f"{float(a_lat[i]):.1f} m/s^2 lateral (max {limits.max_lateral_accel_mps2})"), None
    if cmd.stop_point is not None:
        if path.stop_offset_m > limits.max_stop_offset_m:
            return f"malformed path: stop point {path.stop_offset_m:.1f} m off the path", None
        if path.stop_s_m is not None and path.stop_s_m < proj.s_m - 1.0:
            return "unreachable: stop point is behind the car", None
    elif cmd.manoeuvre in (Manoeuvre.PULL_OVER, Manoeuvre.STOP_IN_LANE):
        return f"malformed command: {cmd.manoeuvre.value} needs a stop_point", None
    return None, path


class CommandBook:
    """Which commands were seen, what was decided, the newest accepted sequence number."""

    def __init__(self, vehicle_id: str, limits: CommandLimits = CommandLimits(), remember: int = 256) -> None:
        self.vehicle_id = vehicle_id
        self.limits = limits
        self.newest_seq: int | None = None
        self.active: PathSwitchCommand | None = None
        self.active_path: ReferencePath | None = None
        self._decisions: OrderedDict[str, Decision] = OrderedDict()
        self._remember = remember

    def decision(self, command_id: str) -> Decision | None:
        return self._decisions.get(command_id)

    def _record(self, d: Decision) -> Decision:
        self._decisions[d.command_id] = d
        self._decisions.move_to_end(d.command_id)
        while len(self._decisions) > self._remember:
            self._decisions.popitem(last=False)
        return d

    def offer(self, cmd: PathSwitchCommand, now_s: float, pose: tuple[float, float, float], speed_mps: float,
              blocked_reason: str | None = None) -> list[Decision]:
        """Decide on a command. Returns the decisions to acknowledge (in order).

        ``blocked_reason``: the car cannot take commands now (e.g. localisation lost).
        """
        seen = self._decisions.get(cmd.command_id)
        if seen is not None:
            return [seen]  # duplicate: idempotent, answer again
        if cmd.vehicle_id != self.vehicle_id:  # not ours: answer, but remember nothing of its seq
            return [Decision(cmd.command_id, AckStatus.REJECTED,
                             f"wrong vehicle: command is for {cmd.vehicle_id!r}, this is {self.vehicle_id!r}")]
        if self.newest_seq is not None and cmd.command_seq < self.newest_seq:
            return [self._record(Decision(cmd.command_id, AckStatus.REJECTED,
                                          f"stale: command_seq {cmd.command_seq} < newest accepted {self.newest_seq}"))]
        if self.newest_seq is not None and cmd.command_seq == self.newest_seq:
            return [self._record(Decision(cmd.command_id, AckStatus.REJECTED,
                                          f"command_seq {cmd.command_seq} already used by another command"))]
        if blocked_reason is not None and cmd.manoeuvre != Manoeuvre.RESUME:
            return [self._record(Decision(cmd.command_id, AckStatus.REJECTED, blocked_reason))]
        reason, path = validate_command(cmd, self.vehicle_id, now_s, pose, speed_mps, self.limits)
        if reason is not None:
            return [self._record(Decision(cmd.command_id, AckStatus.REJECTED, reason))]
        out = []
        if self.active is not None:
            out.append(self.complete(f"superseded by {cmd.command_id}"))
        self.newest_seq = cmd.command_seq
        self.active, self.active_path = cmd, path
        out.append(self._record(Decision(cmd.command_id, AckStatus.ACCEPTED)))
        return out

    def abort(self, reason: str) -> Decision:
        """The active command will not be carried out (fail-safe); returns its ``rejected`` decision."""
        if self.active is None:
            raise RuntimeError("no active command to abort")
        d = self._record(Decision(self.active.command_id, AckStatus.REJECTED, f"aborted: {reason}"[:250]))
        self.active, self.active_path = None, None
        return d

    def complete(self, reason: str = "") -> Decision:
        """The active command is done; returns its ``completed`` decision."""
        if self.active is None:
            raise RuntimeError("no active command to complete")
        d = self._record(Decision(self.active.command_id, AckStatus.COMPLETED, reason))
        self.active, self.active_path = None, None
        return d


ANSWERED_AUTH_REASONS = frozenset({"expired", "not_yet_valid", "out_of_scope", "replayed"})
"""Refusals acknowledged ``rejected`` to the DDM: the signature verified, so a trusted DDM sent it and
should know why it is refused. Unsigned, unknown-key and forged commands get no answer: an unknown
sender cannot make the car speak (and e.g. reject a command id the real DDM is waiting on)."""


class CommandGate:
    """Authenticates commands against a trust list (pure: the caller passes the time).

    ``verifier`` None: no trust list, every command passes (the pre-signature behaviour).
    ``require_signed`` False: unsigned commands pass, signed ones are still checked.
    """

    def __init__(self, verifier: Verifier | None, require_signed: bool = True, replay_capacity: int = 4096) -> None:
        self.verifier = verifier
        self.require_signed = require_signed
        self.replay = ReplayGuard(replay_capacity)

    @classmethod
    def from_trust(cls, trust: TrustList, require_signed: bool | None = None) -> CommandGate:
        """Verifies when the trust list names DDM keys; then unsigned commands are refused unless
        ``require_signed`` is False."""
        if not trust.has_role("ddm"):
            return cls(None, False)
        return cls(Verifier(trust), True if require_signed is None else require_signed)

    @property
    def active(self) -> bool:
        return self.verifier is not None

    def admit(self, key: str, cmd: PathSwitchCommand, now_s: float) -> None:
        """Raise ``AuthError`` unless ``cmd`` may be offered to the ``CommandBook``."""
        if self.verifier is None or (cmd.auth is None and not self.require_signed):
            return
        self.verifier.check(key, cmd, now_s)
        if self.replay.classify(cmd) == "new":
            self.replay.remember(cmd)

