"""The fault table on the whole corridor in lockstep, each row judged by docs/faults.md's rules.

``scenario/lockstep.py`` runs the simulator, 4 RSUs rendering and processing pixels, the DDM and the vehicle
on one SimClock; one fault per run. Slower than the rig of ``scenario/faults.py`` (every camera frame is
rendered: ~2-3x the scenario time on a loaded 2-core machine) but end to end. Every row passes only on
its own criterion (its kind's judge, ``scenario/fault_judges.py``) AND the one yield judge's verdict
(``scenario/outcome.py``, from the run monitor's ground truth). A row that failed is *beyond the bound* when the fault alone delays the command by more than the
perfect-link run of the same seed had to spare (its margin): a shift of that run's manoeuvre (the same EV
speed and lane change) by the fault's delay could not clear the lane in time. A perfect-link run that
fails itself gives no bound: its rows fail.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Any

from protocol.radio import ChannelModel
from scenario.fault_judges import (
    DdmRestartSeen,
    DeliverySeen,
    FaultOutcome,
    Judgement,
    RsuKillSeen,
    judge_ddm_restart,
    judge_dropout,
    judge_latency,
    judge_rsu_kill,
    lost_commands,
)
from scenario.faults import LATENCIES_S, LOSSES, OUTAGES_S, latency_channel, latency_fault_delay_s

LOCKSTEP_RUNNER = "lockstep corridor (sim + 4 RSUs + DDM + vehicle)"
CORRIDOR_KINDS = ("latency", "dropout", "rsu_kill", "ddm_restart")


def run_corridor_fault(name: str, kind: str, *, channel: ChannelModel | None = None, seed: int | None = None,
                       duration_s: float = 14.0, outage_s: tuple[float, float] | None = None,
                       kill_first_alerting_rsu: bool = False, restart_ddm_after_s: float | None = None,
                       traffic: str | None = None) -> tuple[FaultOutcome, dict[str, Any]]:
    """One lockstep run of a scenario with one fault; the outcome is judged on the simulator's ground truth.

    ``outage_s`` = (start, length): total loss on the vehicle link in that window of scenario time (the
    run is deterministic: ``corridor_faults`` starts it when the same run without it sent its first command);
    ``kill_first_alerting_rsu``: the RSU that raised the first EvAlert stops at once;
    ``restart_ddm_after_s``: the DDM dies when the AV starts its first manoeuvre and a fresh one starts
    this long after. ``traffic``: ``project`` or ``sumo`` (who drives the traffic; None: the scenario's).
    """
    if kind not in CORRIDOR_KINDS or (kind == "rsu_kill") != kill_first_alerting_rsu \
            or (kind == "ddm_restart") != (restart_ddm_after_s is not None):
        raise ValueError(f"run_corridor_fault: kind {kind!r} with kill_first_alerting_rsu={kill_first_alerting_rsu}, "
                         f"restart_ddm_after_s={restart_ddm_after_s}: the kind must be one of {CORRIDOR_KINDS} and "
                         "rsu_kill goes with kill_first_alerting_rsu=True, ddm_restart with restart_ddm_after_s")
    from protocol import keys
    from scenario.lockstep import CorridorLockstep, LockstepConfig

    base = channel or ChannelModel()
    if outage_s is not None:
        base = dataclasses.replace(base, outages=((outage_s[0], outage_s[0] + outage_s[1]),))
    runner = CorridorLockstep(LockstepConfig(duration_s=duration_s, seed=seed, vehicle_channel=base, traffic=traffic))
    sent: dict[str, tuple[float, str]] = {}
    acks: list[tuple[float, str, str]] = []
    facts: dict[str, Any] = {}
    c = runner.corridor_id

    def on_alert(_k: str, msg) -> None:
        if msg.state.value != "active" or "first_alert" in facts:
            return
        now = runner.clock.now()
        facts["first_alert"], facts["first_alert_rsu"] = now, msg.rsu_id
        if kill_first_alerting_rsu:
            runner.at(now, lambda: runner.kill_rsu(msg.rsu_id))

    def on_state(_k: str, msg) -> None:
        if restart_ddm_after_s is not None and msg.mode.value == "manoeuvre" and "ddm_killed" not in facts:
            now = runner.clock.now()
            facts["ddm_killed"] = now
            facts["old_commands"] = set(sent)
            facts["active_at_kill"] = msg.active_command_id
            runner.at(now, runner.kill_ddm)
            facts["ddm_started"] = now + restart_ddm_after_s
            runner.at(now + restart_ddm_after_s, runner.start_ddm)
        if "ddm_killed" in facts:
            facts.setdefault("modes_after_kill", []).append((runner.clock.now(), msg.mode.value))

    ddm_health: list[tuple[float, str, tuple[str, ...]]] = []
    runner.bus.subscribe(keys.all_rsus_expr(c).replace("/*/*", "/*/ev"), on_alert)
    runner.bus.subscribe(keys.all_vehicles_expr(c, "state"), on_state)
    runner.bus.subscribe(keys.all_vehicles_expr(c, "cmd"),
                         lambda k, m: sent.setdefault(m.command_id, (runner.clock.now(), m.manoeuvre.value)))
    runner.bus.subscribe(keys.all_vehicles_expr(c, "ack"),
                         lambda k, m: acks.append((runner.clock.now(), m.command_id, m.status.value)))
    runner.bus.subscribe(keys.ddm_health_key(c), lambda k, m: ddm_health.append((runner.clock.now(), m.status.value,
                                                                                 tuple(m.stale))))
    m = runner.run()

    verdict = m.get("yield")  # the one yield judge (scenario/outcome.py), from the run monitor's ground truth
    lon = None if not verdict else verdict["lights_on_s"]
    passed_at = None if not verdict else verdict["ev_passed_s"]
    issued = sorted(sent, key=lambda i: sent[i][0])
    details: dict[str, Any] = {
        "yield": verdict,
        "commands": [f"{sent[i][1]}@{sent[i][0] - (lon or 0):+.2f}s" for i in issued],
        "lost_commands": lost_commands(issued, {cid for _, cid, _ in acks}), "latency_s": m.get("latency_s"),
        "vehicle_link": m.get("vehicle_link"), "collision": m.get("collision"), "wall_s": m.get("wall_s"),
        "seed": m.get("seed"), "first_command_s": sent[issued[0]][0] if issued else None,
    }
    start = m.get("latency_s", {}).get("lights_on_to_manoeuvre_s")
    note = "" if start is None else f", starts +{start:.2f} s"
    judged = _judge(kind, facts, sent, issued, acks, ddm_health, passed_at, runner.clock.now(), verdict)
    return judged.row(name, kind, LOCKSTEP_RUNNER, details, yield_note=note), m


def _judge(kind: str, facts: dict[str, Any], sent: dict[str, tuple[float, str]], issued: list[str],
           acks: list[tuple[float, str, str]], ddm_health: list[tuple[float, str, tuple[str, ...]]],
           passed_at: float | None, end_s: float, verdict: dict[str, Any] | None) -> Judgement:
    """What the lockstep run saw, in the kind's record, to the kind's judge (``scenario/fault_judges.py``)."""
    if kind == "latency":
        return judge_latency(verdict)
    if kind == "dropout":
        return judge_dropout(DeliverySeen(tuple(issued), frozenset(cid for _, cid, _ in acks)), verdict)
    if kind == "rsu_kill":
        if "first_alert" not in facts:
            return Judgement(False, "no EvAlert at all", None, {}, verdict)
        resumes = tuple(sent[i][0] for i in issued if sent[i][1] == "resume")
        return judge_rsu_kill(RsuKillSeen(facts["first_alert_rsu"], facts["first_alert"], tuple(ddm_health), resumes,
                                          passed_at), verdict)
    t_kill = facts.get("ddm_killed")  # ddm_restart
    if t_kill is None:
        return Judgement(False, "no manoeuvre to interrupt", None, {}, verdict)
    old = facts["old_commands"]
    new = tuple((sent[i][0], sent[i][1], i) for i in issued if i not in old)
    back = next((t for t, _, _ in ddm_health if t > facts["ddm_started"]), None)
    return judge_ddm_restart(DdmRestartSeen(
        t_kill, facts["active_at_kill"], new, tuple(a for a in acks if a[0] > t_kill),
        tuple(facts.get("modes_after_kill", ())), back, passed_at, end_s), verdict)


def _reseeded_row(name: str, kind: str, *, seed: int | None, tries: int = 3, **kw: Any) -> FaultOutcome:
    """One row; a run where the EV never reached the AV tested nothing: run it again on another seed."""
    row = run_corridor_fault(name, kind, seed=seed, **kw)[0]
    k = 0
    while (row.details.get("yield") or {}).get("status") == "not_reached" and k < tries:
        k += 1
        base_seed = row.details.get("seed") if seed is None else seed
        row = run_corridor_fault(name, kind, seed=int(base_seed or 0) + 1000 * k, **kw)[0]
        row.details["reseeded"] = k
    return row


def beyond_corridor_bound(row: FaultOutcome, fault_delay_s: float | None, baseline: FaultOutcome) -> FaultOutcome:
    """``row`` marked beyond the bound when it failed and its fault's own delay exceeds the margin of the
    perfect-link run (``baseline``, which must have yielded); unchanged otherwise."""
    spare = baseline.margin_s if baseline.passed else None
    if row.passed or fault_delay_s is None or spare is None or fault_delay_s <= spare:
        return row
    bound = (f"the perfect-link run cleared the lane {spare:.2f} s before the EV reached the AV; this fault delays "
             f"the command by {fault_delay_s:.2f} s")
    return dataclasses.replace(row, beyond_bound=bound, details={**row.details, "bound_spare_s": spare,
                                                                 "fault_delay_s": round(fault_delay_s, 3)})


def corridor_faults(seed: int | None = None, quick: bool = False, traffic: str | None = None) -> list[FaultOutcome]:
    """The fault table on the whole corridor in lockstep (``quick``: the extreme cases only; ``traffic``: who
    drives the traffic, ``sumo`` for Eclipse SUMO)."""
    lat = (0.0, 0.3) if quick else LATENCIES_S
    _reseeded = functools.partial(_reseeded_row, traffic=traffic)
    base = _reseeded("latency 0 ms +jitter", "latency", channel=latency_channel(0.0), seed=seed)
    out = [base] + [beyond_corridor_bound(_reseeded(f"latency {x * 1000:.0f} ms +jitter", "latency",
                                                    channel=latency_channel(x), seed=seed),
                                          latency_fault_delay_s(x), base) for x in lat if x > 0]
    first_cmd = base.details["first_command_s"]  # the perfect-link run: when the first command went out
    losses = (0.5,) if quick else LOSSES
    out += [_reseeded(f"loss {p:.0%}", "dropout", channel=ChannelModel(latency_s=0.003, loss=p), seed=seed)
            for p in losses]
    if first_cmd is not None:
        for length in ((2.0,) if quick else OUTAGES_S):
            row = _reseeded(f"{length:.0f} s radio outage", "dropout", seed=seed,
                            channel=latency_channel(0.0), outage_s=(first_cmd - 0.005, length))
            out.append(beyond_corridor_bound(row, length, base))
    out.append(_reseeded("RSU killed with the EV in view", "rsu_kill", seed=seed, kill_first_alerting_rsu=True))
    out.append(_reseeded("DDM killed + restarted mid-manoeuvre", "ddm_restart", seed=seed, restart_ddm_after_s=1.0))
    return out
