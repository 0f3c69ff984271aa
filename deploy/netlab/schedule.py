"""The fault rows of the network lab and the judging of a row. Pure.

Each row breaks one link (or host) of the lab, timed around the EV's lights-on, and is judged by its kind's
judge (``scenario/fault_judges.py``) AND the one yield judge's verdict of the run (``scenario/outcome.py``), as
every fault table of the project is. A failed row is *beyond the bound* when the fault alone delays the command
past the latest first EvAlert from which the AV still clears the EV's lane (``scenario.faults`` rig bound).

Kinds: ``dropout`` (every command acked, none expired at the DDM), ``rsu_kill`` (an RSU, or a segment's RSUs,
gone: named stale within the limit, a neighbour keeps the EV, no early RESUME), ``ddm_restart`` (the DDM away:
the AV keeps its command or fails safe, the DDM is heard again, no early RESUME), ``router_restart`` (every
service heard again within the limit after the router's return, a command accepted afterwards).

On the messages, a command counts as lost when it was neither acked (itself, or a later one of the DDM) nor
explicitly expired by the DDM (its Health's ``cmd_expired``); commands issued in the last ``IN_FLIGHT_S`` of the
observation are in flight, neither.
"""

from __future__ import annotations

import dataclasses
import statistics
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

from scenario.fault_judges import (
    DdmRestartSeen,
    DeliverySeen,
    Judgement,
    RouterRestartSeen,
    RsuKillSeen,
    judge_ddm_restart,
    judge_dropout,
    judge_router_restart,
    judge_rsu_kill,
    lost_commands,
)

TRIGGERS = ("start", "lights_on", "first_alert", "first_manoeuvre")
ACTIONS = ("loss", "cut", "cap", "hub_cut", "hub_lost")
FIRST_ALERT_RSU = "first_alert_rsu"
"""Target: the RSU that raised the first EvAlert (the EV is in its view)."""
EVERY_RSU = "every_rsu"
SEGMENT_OF_FIRST_ALERT = "segment_of_first_alert"
IN_FLIGHT_S = 1.0
ANSWER_WAIT_S = 6.0
"""After the EV has passed, a row is observed until every command has its answer (acked, itself or by a later
one, or expired at the DDM), for at most this long: over a lossy link a command still retransmitted is not lost
yet, and one issued as the EV passes may take seconds to be acked."""
STALE_LIMIT_S = 2.0
RECONNECT_LIMIT_S = 10.0


@dataclass(frozen=True)
class NetFault:
    """One row: ``action`` on ``target``'s link from ``at`` for ``length_s`` (None: to the end of the run).

    ``value``: the dropped fraction (loss), the rate in bit/s (cap); ``fault_delay_s``: how long after its
    trigger the fault lets the first command through at the earliest (the bound; None: the row is never beyond
    it); ``segments``: segment routers (``iea deploy mesh`` layout; 0: one router)."""

    name: str
    kind: str
    action: str
    target: str
    at: str
    length_s: float | None = None
    value: float = 1.0
    fault_delay_s: float | None = 0.0
    segments: int = 0
    min_duration_s: float = 0.0
    """The simulator runs at least this long (a fault that delays the yield delays the EV's pass too)."""

    def __post_init__(self) -> None:
        if self.action not in ACTIONS:
            raise ValueError(f"action {self.action!r} is not one of {ACTIONS}")
        if self.at not in TRIGGERS:
            raise ValueError(f"trigger {self.at!r} is not one of {TRIGGERS}")
        if self.action == "loss" and not 0.0 < self.value < 1.0:
            raise ValueError(f"a loss is a fraction in (0, 1), got {self.value}")
        if self.length_s is not None and self.length_s <= 0:
            raise ValueError(f"length_s must be positive or None, got {self.length_s}")

    @property
    def restored(self) -> bool:
        return self.length_s is not None


NET_FAULTS: tuple[NetFault, ...] = (
    *(NetFault(f"vehicle link loss {p:.0%}", "dropout", "loss", "vehicle", "lights_on", value=p)
      for p in (0.1, 0.3, 0.5)),
    *(NetFault(f"vehicle link cut {s:.0f} s", "dropout", "cut", "vehicle", "lights_on", length_s=s,
               fault_delay_s=s) for s in (1.0, 3.0, 10.0)),
    NetFault("RSU host cut, EV in its view", "rsu_kill", "cut", FIRST_ALERT_RSU, "first_alert", fault_delay_s=None),
    NetFault("DDM host cut 2 s", "ddm_restart", "cut", "ddm", "first_manoeuvre", length_s=2.0, fault_delay_s=None),
    *(NetFault(f"RSU uplinks capped {name}", "dropout", "cap", EVERY_RSU, "start", value=rate)
      for name, rate in (("1 Mbit/s", 1e6), ("256 kbit/s", 256e3), ("16 kbit/s", 16e3))),
    NetFault("router host cut 2 s, restored", "router_restart", "hub_cut", "router", "lights_on", length_s=2.0,
             fault_delay_s=2.0),
    NetFault("segment router lost (mesh)", "rsu_kill", "hub_lost", SEGMENT_OF_FIRST_ALERT, "first_alert",
             fault_delay_s=None, segments=2, min_duration_s=32.0),
)
"""The network lab's fault table (``bench/netfault_bench.py`` runs it; the tests one or two short rows)."""


def command_delay_s(fault: NetFault, alert_delay_s: float) -> float | None:
    """The least delay the fault adds to a command that would go out ``alert_delay_s`` after lights-on: a fault
    from lights-on costs what is left of it at the alert; one from the alert on, its whole delay."""
    if fault.fault_delay_s is None:
        return None
    if fault.at in ("start", "lights_on"):
        return max(0.0, fault.fault_delay_s - alert_delay_s)
    return fault.fault_delay_s


def fault_by_name(name: str) -> NetFault:
    for f in NET_FAULTS:
        if f.name == name:
            return f
    raise KeyError(f"no fault row {name!r}: one of {[f.name for f in NET_FAULTS]}")


@dataclass(frozen=True)
class RowSeen:
    """What the lab's own session heard in one row (times in seconds, wall clock of the one host).

    ``commands``: id -> (first heard, manoeuvre) in issue order; ``acks``: (time, id, status); ``modes``:
    (time, vehicle mode, active command); ``ddm_health``: (time, status, stale ids); ``ev_reports``: (time,
    rsu, 'alert'|'object'); ``heard``: service -> arrival times; ``cmd_expired``: the DDM's count at the end;
    ``victims``: the hosts the fault cut off (an RSU, a segment's RSUs); ``lights_on_s``: from the simulator."""

    fault_at_s: float
    restored_at_s: float | None
    end_s: float
    commands: dict[str, tuple[float, str]]
    acks: tuple[tuple[float, str, str], ...]
    modes: tuple[tuple[float, str, str | None], ...] = ()
    ddm_health: tuple[tuple[float, str, tuple[str, ...]], ...] = ()
    ev_reports: tuple[tuple[float, str, str], ...] = ()
    heard: dict[str, tuple[float, ...]] = field(default_factory=dict)
    cmd_expired: int = 0
    victims: tuple[str, ...] = ()
    ev_passed_at_s: float | None = None
    lights_on_s: float | None = None
    active_at_fault: str | None = None


def _pct(xs: Sequence[float], q: float) -> float | None:
    if not xs:
        return None
    s = sorted(xs)
    return s[min(len(s) - 1, round(q / 100 * (len(s) - 1)))]


def unanswered_commands(issued_at_s: dict[str, float], acked: set[str] | frozenset[str], expired: int) -> int:
    """How many commands still wait for their answer: neither acked (itself, or a later one) nor among the
    ``expired`` the DDM gave up on (``issued_at_s``: command id -> when it was issued)."""
    issued = sorted(issued_at_s, key=issued_at_s.__getitem__)
    return max(0, len(lost_commands(issued, acked)) - expired)


def message_figures(seen: RowSeen) -> dict[str, Any]:
    """Command delivery and ack latency, what was lost (neither acked nor expired), recovery after the link's
    return (first message of every cut-off host after it), stale detection (the DDM naming a victim stale, counted
    from the fault, or from lights-on for a fault in force before it)."""
    issued = [cid for cid, (t, _) in seen.commands.items() if t <= seen.end_s - IN_FLIGHT_S]
    acked = {cid for _, cid, _ in seen.acks}
    unacked = lost_commands(issued, acked)
    first_ack = {}
    for t, cid, _ in seen.acks:
        first_ack.setdefault(cid, t)
    ack_lat = [first_ack[c] - seen.commands[c][0] for c in issued if c in first_ack]
    out: dict[str, Any] = {
        "commands_issued": len(issued), "commands_acked": len([c for c in issued if c in acked]),
        "commands_unacked": len(unacked), "commands_expired_at_ddm": seen.cmd_expired,
        "commands_lost": unanswered_commands({c: seen.commands[c][0] for c in issued}, acked, seen.cmd_expired),
        "ack_latency_p50_s": None if not ack_lat else round(statistics.median(ack_lat), 3),
        "ack_latency_max_s": None if not ack_lat else round(max(ack_lat), 3),
    }
    if seen.restored_at_s is not None:
        backs = {h: next((t for t in seen.heard.get(h, ()) if t > seen.restored_at_s), None) for h in seen.victims}
        out["recovered_after_s"] = {h: None if t is None else round(t - seen.restored_at_s, 3) for h, t in backs.items()}
        out["recovery_s"] = (None if not backs or any(t is None for t in backs.values())
                             else round(max(backs.values()) - seen.restored_at_s, 3))
    since = max(seen.fault_at_s, seen.lights_on_s or seen.fault_at_s)
    stale = [t for t, _, ids in seen.ddm_health if t >= since and any(v in ids for v in seen.victims)]
    out["stale_detected_after_s"] = None if not stale else round(stale[0] - since, 3)
    return out


def judge_row(fault: NetFault, seen: RowSeen, verdict: dict[str, Any] | None) -> Judgement:
    """The row's kind's judge on what the lab heard, with the yield verdict of the run; every kind also on the
    messages: no command lost (acked, or expired by the DDM)."""
    j = _judge_kind(fault, seen, verdict)
    lost = message_figures(seen)["commands_lost"]
    if fault.kind == "dropout" or not lost:
        return j
    return dataclasses.replace(j, own_passed=False, own=f"{j.own}; {lost} command(s) lost")


def _judge_kind(fault: NetFault, seen: RowSeen, verdict: dict[str, Any] | None) -> Judgement:
    issued = tuple(cid for cid, (t, _) in seen.commands.items() if t <= seen.end_s - IN_FLIGHT_S)
    if fault.kind == "dropout":
        return judge_dropout(DeliverySeen(issued, frozenset(cid for _, cid, _ in seen.acks),
                                          expired_at_ddm=seen.cmd_expired), verdict)
    if fault.kind == "rsu_kill":
        victim = seen.victims[0] if seen.victims else "?"
        later = tuple(sorted({r for t, r, _ in seen.ev_reports if t > seen.fault_at_s + 0.5
                              and r not in seen.victims}))
        from_killed = len([1 for t, r, _ in seen.ev_reports if t > seen.fault_at_s + 0.5 and r in seen.victims])
        resumes = tuple(t for t, m in seen.commands.values() if m == "resume")
        return judge_rsu_kill(RsuKillSeen(victim, seen.fault_at_s, seen.ddm_health, resumes, seen.ev_passed_at_s,
                                          later, from_killed), verdict, STALE_LIMIT_S)
    if fault.kind == "ddm_restart":
        new = tuple(sorted((t, m, cid) for cid, (t, m) in seen.commands.items() if t > seen.fault_at_s))
        back_from = seen.restored_at_s if seen.restored_at_s is not None else seen.fault_at_s
        back = next((t for t, _, _ in seen.ddm_health if t > back_from), None)
        return judge_ddm_restart(DdmRestartSeen(
            seen.fault_at_s, seen.active_at_fault, new, tuple(a for a in seen.acks if a[0] > seen.fault_at_s),
            tuple((t, m) for t, m, _ in seen.modes if t > seen.fault_at_s), back, seen.ev_passed_at_s, seen.end_s),
            verdict)
    if fault.kind == "router_restart":
        t_back = seen.restored_at_s if seen.restored_at_s is not None else seen.fault_at_s
        back = {s: next((round(t - t_back, 3) for t in ts if t > t_back), None) for s, ts in seen.heard.items()}
        accepted = any(st == "accepted" and t > t_back for t, _, st in seen.acks)
        return judge_router_restart(RouterRestartSeen(back, accepted), verdict, RECONNECT_LIMIT_S)
    raise ValueError(f"no judge for kind {fault.kind!r}")


def summary(rows: Sequence[Any]) -> dict[str, Any]:
    """The bench's figures over judged rows (``FaultOutcome`` with ``details`` from ``message_figures``)."""
    return {
        "rows_total": len(rows),
        "rows_passed": sum(1 for r in rows if r.verdict == "PASS"),
        "rows_beyond_bound": sum(1 for r in rows if r.verdict == "BEYOND"),
        "rows_failed": sum(1 for r in rows if r.verdict == "FAIL"),
        "commands_lost": sum(int(r.details.get("commands_lost") or 0) for r in rows),
        "recovery_s": {r.name: r.details.get("recovery_s") for r in rows if "recovery_s" in r.details},
        "bounds": {r.name: r.beyond_bound for r in rows if r.beyond_bound},
    }
