"""One judge per fault kind (docs/faults.md: each kind's criteria and the yield outcome), shared by every fault runner. Pure.

A runner (the rig ``scenario/faults.py``, the lockstep corridor ``scenario/corridor_faults.py``, the processes
``deploy/process_faults.py``) breaks one thing, records what it saw in the kind's ``*Seen`` record (times in
seconds on one clock) and hands it to the kind's judge with the one yield judge's verdict of the run
(``scenario.outcome.YieldVerdict.to_dict()``; None: no AV/EV ground truth). A row passes only on its kind's own
criterion AND that verdict:

- ``latency``: the yield verdict alone (margin: the yield's);
- ``dropout``: every command acked (a command counts as delivered when it or a later one was acked), none
  executed twice, none expired at the DDM (margin: the yield's);
- ``rsu_kill``: the DDM's Health names the killed RSU stale (status degraded) within ``stale_limit_s``; a
  neighbouring RSU reports the EV afterwards and the killed one does not (where the runner saw the RSUs'
  reports); no RESUME before the EV has passed the AV (margin: the limit - the time to the stale report);
- ``ddm_restart``: on its own (from the kill until it accepts the restarted DDM's first command, or the EV
  has passed) the AV keeps its command or is in its fail-safe stop (driving on only once that command is
  completed); the restarted DDM is heard again; it sends no RESUME before the EV has passed (margin: the EV
  passed -> the restarted DDM's first RESUME, or the end of the run);
- ``router_restart``: every service heard again within ``reconnect_limit_s`` of the router's return, and a
  command accepted afterwards (margin: the limit - the slowest reconnection).
"""

from __future__ import annotations

from collections.abc import Collection, Sequence
from dataclasses import dataclass, field
from typing import Any

DDM_ALONE_OK_MODES = ("manoeuvre", "stopped", "minimal_risk")
"""The AV's modes that keep the DDM's last command (or its fail-safe) while the DDM is away."""


@dataclass(frozen=True)
class FaultOutcome:
    """One row of the fault table."""

    name: str
    kind: str
    passed: bool
    outcome: str
    margin_s: float | None
    """How much earlier than needed the AV was safe (negative: how late); None where not applicable."""
    runner: str
    details: dict[str, Any] = field(default_factory=dict)
    beyond_bound: str | None = None
    """Set (to the bound, in words) when the case is physically impossible: listed, never passed."""

    @property
    def verdict(self) -> str:
        return "BEYOND" if self.beyond_bound else ("PASS" if self.passed else "FAIL")

    def row(self) -> str:
        m = "-" if self.margin_s is None else f"{self.margin_s:+.2f} s"
        extra = f" [beyond the bound: {self.beyond_bound}]" if self.beyond_bound else ""
        return f"{self.name:<34} {self.verdict:<6} {m:>9}  {self.outcome}{extra}"


@dataclass(frozen=True)
class Judgement:
    """A fault kind's own criterion on what a run saw, with the yield verdict of the same run."""

    own_passed: bool
    own: str
    """The own criterion in words ("" where the yield verdict is the whole criterion)."""
    margin_s: float | None
    details: dict[str, Any]
    yield_verdict: dict[str, Any] | None

    @property
    def passed(self) -> bool:
        return self.own_passed and bool(self.yield_verdict and self.yield_verdict["passed"])

    def outcome(self, yield_note: str = "") -> str:
        """The row's outcome in words: the own criterion, then the yield verdict (``yield_note`` appended)."""
        v = self.yield_verdict
        y = "no verdict (no AV/EV ground truth)" if not v else f"{v['status']}: {v['reason']}{yield_note}"
        return f"{self.own}; yield {y}" if self.own else y

    def row(self, name: str, kind: str, runner: str, details: dict[str, Any], yield_note: str = "") -> FaultOutcome:
        margin = None if self.margin_s is None else round(self.margin_s, 3)
        return FaultOutcome(name, kind, self.passed, self.outcome(yield_note), margin, runner,
                            {**details, **self.details})


def _yield_margin(verdict: dict[str, Any] | None) -> float | None:
    return None if not verdict else verdict.get("margin_s")


def lost_commands(issued: Sequence[str], acked: Collection[str]) -> list[str]:
    """Commands (in issue order) neither acked themselves nor superseded by a later acked one."""
    return [cid for i, cid in enumerate(issued) if cid not in acked and not any(x in acked for x in issued[i + 1:])]


def judge_latency(verdict: dict[str, Any] | None) -> Judgement:
    """``latency``: the yield verdict is the whole criterion."""
    return Judgement(True, "", _yield_margin(verdict), {}, verdict)


@dataclass(frozen=True)
class DeliverySeen:
    """Commands as the DDM issued them and the acks it got back; ``activations``: per command, how often the
    vehicle started it (None where the runner cannot see it); ``expired_at_ddm``: commands the DDM gave up on."""

    issued: tuple[str, ...]
    acked: frozenset[str]
    activations: dict[str, int] | None = None
    expired_at_ddm: int = 0


def judge_dropout(seen: DeliverySeen, verdict: dict[str, Any] | None) -> Judgement:
    """``dropout``: every command delivered once, none expired, AND the yield verdict."""
    lost = lost_commands(seen.issued, seen.acked)
    twice = {cid: n for cid, n in (seen.activations or {}).items() if n > 1}
    if lost:
        own = f"{len(lost)} command(s) lost"
    elif twice:
        own = f"duplicate manoeuvre {sorted(twice)}"
    elif seen.expired_at_ddm:
        own = f"{seen.expired_at_ddm} command(s) expired at the DDM"
    else:
        own = "every command acked" + (", none executed twice" if seen.activations is not None else "")
    ok = not lost and not twice and seen.expired_at_ddm == 0
    return Judgement(ok, own, _yield_margin(verdict), {"lost_commands": lost}, verdict)


@dataclass(frozen=True)
class RsuKillSeen:
    """The killed RSU and what followed: ``ddm_health`` (time, status, stale RSU ids) of the DDM's Health;
    ``resumes_s``: when RESUME commands went out; ``neighbours_reporting``: the other RSUs that reported the
    EV afterwards and ``reports_from_killed`` the killed one's reports (None: the runner did not watch)."""

    victim: str
    killed_at_s: float
    ddm_health: tuple[tuple[float, str, tuple[str, ...]], ...]
    resumes_s: tuple[float, ...]
    ev_passed_at_s: float | None
    neighbours_reporting: tuple[str, ...] | None = None
    reports_from_killed: int | None = None


def judge_rsu_kill(seen: RsuKillSeen, verdict: dict[str, Any] | None, stale_limit_s: float = 2.0) -> Judgement:
    """``rsu_kill``: named stale (degraded) within the limit, the EV kept by a neighbour, no early RESUME."""
    t_kill, victim = seen.killed_at_s, seen.victim
    stale_at = next((t for t, status, stale in seen.ddm_health
                     if t >= t_kill and victim in stale and status == "degraded"), None)
    early = [t for t in seen.resumes_s if t > t_kill and (seen.ev_passed_at_s is None or t < seen.ev_passed_at_s)]
    stale_after = None if stale_at is None else stale_at - t_kill
    no_neighbour = seen.neighbours_reporting is not None and not seen.neighbours_reporting
    ok = (stale_after is not None and stale_after <= stale_limit_s and not no_neighbour and not early
          and not seen.reports_from_killed)
    if stale_after is None:
        own = f"DDM never reported {victim} stale"
    elif no_neighbour:
        own = "no neighbouring RSU reported the EV"
    elif seen.reports_from_killed:
        own = f"{victim} stale after {stale_after:.2f} s but still reported the EV {seen.reports_from_killed} time(s)"
    elif early:
        own = f"{victim} stale after {stale_after:.2f} s; DDM resumed before the EV passed ({len(early)} RESUME)"
    else:
        kept = f"; EV kept by {','.join(seen.neighbours_reporting)}" if seen.neighbours_reporting else ""
        own = f"{victim} stale after {stale_after:.2f} s{kept}"
    details = {"killed": victim, "stale_after_s": None if stale_after is None else round(stale_after, 3),
               "resume_before_ev_passed": len(early)}
    return Judgement(ok, own, None if stale_after is None else stale_limit_s - stale_after, details, verdict)


@dataclass(frozen=True)
class DdmRestartSeen:
    """The DDM killed at ``killed_at_s`` (while the AV executed ``active_at_kill``) and started again:
    ``new_commands`` (time, manoeuvre, id) of the restarted DDM, ``acks`` (time, id, status) and ``modes``
    (time, mode) of the vehicle after the kill; ``ddm_back_at_s``: the restarted DDM first heard;
    ``end_s``: the end of the run."""

    killed_at_s: float
    active_at_kill: str | None
    new_commands: tuple[tuple[float, str, str], ...]
    acks: tuple[tuple[float, str, str], ...]
    modes: tuple[tuple[float, str], ...]
    ddm_back_at_s: float | None
    ev_passed_at_s: float | None
    end_s: float


def judge_ddm_restart(seen: DdmRestartSeen, verdict: dict[str, Any] | None) -> Judgement:
    """``ddm_restart``: the AV on its own keeps its command (or fails safe); the DDM is back; no early RESUME."""
    t_kill = seen.killed_at_s
    end = seen.ev_passed_at_s if seen.ev_passed_at_s is not None else seen.end_s
    new_ids = {cid for _, _, cid in seen.new_commands}
    own_end = min([end] + [t for t, cid, st in seen.acks if cid in new_ids and st == "accepted"])
    modes = sorted({m for t, m in seen.modes if t_kill < t < own_end})
    completed = any(cid == seen.active_at_kill and st == "completed" for _, cid, st in seen.acks)
    ok_modes = DDM_ALONE_OK_MODES + (("driving",) if completed else ())
    bad_modes = [m for m in modes if m not in ok_modes]  # driving: only once the command was done
    contradicting = [(round(t - t_kill, 2), m) for t, m, _ in seen.new_commands if m == "resume" and t < end]
    if bad_modes:
        own = f"AV went to {bad_modes} on its own while the DDM was away"
    elif contradicting:
        own = f"restarted DDM sent {contradicting[0][1]} before the EV passed"
    elif seen.ddm_back_at_s is None:
        own = "the DDM did not come back"
    else:
        how = "fail-safe stop" if "minimal_risk" in modes else "kept its command"
        own = f"AV {how}; DDM back after {seen.ddm_back_at_s - t_kill:.1f} s"
    if seen.ev_passed_at_s is None:
        own += " (the EV had not passed the AV by the end of the run)"
    first_resume = next((t for t, m, _ in seen.new_commands if m == "resume"), None)
    margin = None if seen.ev_passed_at_s is None else (first_resume or seen.end_s) - seen.ev_passed_at_s
    details = {"modes_on_its_own": modes, "on_its_own_s": round(own_end - t_kill, 2), "command_completed": completed,
               "new_ddm_commands": [(round(t - t_kill, 2), m) for t, m, _ in seen.new_commands],
               "ddm_heard_again_after_s": None if seen.ddm_back_at_s is None else round(seen.ddm_back_at_s - t_kill, 2),
               "ev_passed": seen.ev_passed_at_s is not None}
    ok = not bad_modes and not contradicting and seen.ddm_back_at_s is not None
    return Judgement(ok, own, margin, details, verdict)


@dataclass(frozen=True)
class RouterRestartSeen:
    """Per service, how long after the router's return it was first heard (None: never);
    ``command_accepted_after``: the vehicle accepted a command after the return."""

    back_after_s: dict[str, float | None]
    command_accepted_after: bool


def judge_router_restart(seen: RouterRestartSeen, verdict: dict[str, Any] | None,
                         reconnect_limit_s: float = 10.0) -> Judgement:
    """``router_restart``: every service back within the limit with no manual action, a command accepted after."""
    missing = [s for s, d in seen.back_after_s.items() if d is None]
    slowest = max((d for d in seen.back_after_s.values() if d is not None), default=None)
    ok = not missing and slowest is not None and slowest <= reconnect_limit_s and seen.command_accepted_after
    if missing:
        own = f"not heard again: {', '.join(missing)}"
    elif not seen.command_accepted_after:
        own = "no command accepted after the restart"
    else:
        own = f"all {len(seen.back_after_s)} services back within {slowest:.1f} s"
    margin = None if slowest is None or missing else reconnect_limit_s - slowest
    return Judgement(ok, own, margin, {}, verdict)


JUDGES = {"latency": judge_latency, "dropout": judge_dropout, "rsu_kill": judge_rsu_kill,
          "ddm_restart": judge_ddm_restart, "router_restart": judge_router_restart}
"""The judge of each fault kind (the ``kind`` of a ``FaultOutcome``)."""
