"""Process-level faults over real Zenoh on loopback (issue 8): the `iea up` topology, one thing broken.

Each function starts the corridor as ``iea up`` does (a router on a free loopback port, the vehicle, the
DDM, the RSUs with ``--source sim`` and the simulator running ``rellis_ev_yield``, all as processes),
breaks one thing, and returns a ``FaultOutcome`` measured from what a client of the router heard
(the simulator's ground truth only scores the run). Every row passes only on its own criterion below AND
the one yield judge's verdict of the run (``scenario/outcome.py``: out of the EV's lane before it reached
the AV):

- ``rsu_killed``: the RSU that raised the first EvAlert is SIGKILLed at once (the EV is in its view).
  Pass: the DDM's Health names it stale (status degraded) within ``stale_limit_s``; a neighbouring
  RSU reports the EV afterwards; the DDM does not withdraw the AV's yield (no RESUME) before the EV
  has passed it. Margin: ``stale_limit_s`` - time to the stale report.
- ``ddm_restarted``: the DDM is SIGKILLed once the AV executes its first command and started again
  after ``down_s``. Pass: on its own (until it accepts the restarted DDM's first command, or the EV
  has passed) the AV keeps its command (manoeuvre / stopped, or driving on only once that command is
  completed) or is in its fail-safe stop; the restarted DDM is heard again; and the restarted DDM
  sends no RESUME before the EV has passed the AV (both checked until the end of the run if the EV has
  not passed by then). Margin: the EV passed -> the restarted DDM's first RESUME (or the end of the
  run when it sent none).
- ``router_restarted``: the router is stopped and started again on the same port once every service
  has been heard (shortly after the scenario starts). Pass: every service is heard again within ``reconnect_limit_s`` of the router's
  return, with no manual action, and the AV still gets an accepted command. Margin: the limit - the
  slowest reconnection.
"""

from __future__ import annotations

import threading
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from deploy.up import Up
from scenario.faults import FaultOutcome, with_yield

RUNNER = "processes over Zenoh (iea up)"


@dataclass
class Recorder:
    """What a client of the router hears: per-service arrival times and the messages that score a fault."""

    t0: float = field(default_factory=time.time)
    heard: dict[str, list[float]] = field(default_factory=dict)
    ddm_health: list[tuple[float, str, list[str]]] = field(default_factory=list)
    ddm_fused: list[tuple[float, int, int]] = field(default_factory=list)
    """(time, tracks in the DDM's picture, object lists it dropped as too old so far), from its Health."""
    ev_reports: list[tuple[float, str, str]] = field(default_factory=list)
    commands: dict[str, tuple[float, str, int]] = field(default_factory=dict)
    acks: list[tuple[float, str, str]] = field(default_factory=list)
    modes: list[tuple[float, str, str | None]] = field(default_factory=list)
    lock: threading.Lock = field(default_factory=threading.Lock)

    def on_message(self, key: str, msg: Any) -> None:
        from protocol.keys import parse_key

        now = time.time()
        pk = parse_key(key)
        service = pk.node if pk.domain == "rsu" else pk.domain
        if pk.domain == "vehicle" and pk.topic == "cmd":
            service = "ddm"  # commands come from the DDM
        kind = msg.KIND
        with self.lock:
            self.heard.setdefault(service, []).append(now)
            if kind == "Health" and pk.domain == "ddm":
                self.ddm_health.append((now, msg.status.value, list(msg.stale)))
                self.ddm_fused.append((now, int(msg.counts.get("tracks", -1)),
                                       int(msg.drops.get("old_measurements", 0))))
            elif kind == "EvAlert" and msg.state.value == "active":
                self.ev_reports.append((now, msg.rsu_id, "alert"))
            elif kind == "ObjectList":
                if any(o.ev_state.value == "confirmed" or o.obj_type.value == "ev" for o in msg.objects):
                    self.ev_reports.append((now, msg.rsu_id, "object"))
            elif kind == "PathSwitchCommand":
                self.commands.setdefault(msg.command_id, (now, msg.manoeuvre.value, msg.command_seq))
            elif kind == "CommandAck":
                self.acks.append((now, msg.command_id, msg.status.value))
            elif kind == "VehicleState":
                self.modes.append((now, msg.mode.value, msg.active_command_id))

    def first_after(self, service: str, t: float) -> float | None:
        with self.lock:
            return next((x for x in self.heard.get(service, []) if x > t), None)


def _start(name: str, run_root: Path | None, duration_s: float, **kw: Any) -> tuple[Up, Recorder]:
    run_dir = (run_root or Path("runs")) / f"fault-{name}-{time.strftime('%H%M%S')}-{uuid.uuid4().hex[:4]}"
    up = Up(corridor_id=f"f{uuid.uuid4().hex[:8]}", port=0, run_dir=run_dir, duration_s=duration_s, **kw)
    rec = Recorder()
    up.start(extra_subscribers=[rec.on_message])
    return up, rec


def _wait(pred, timeout_s: float, poll_s: float = 0.05) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if pred():
            return True
        time.sleep(poll_s)
    return bool(pred())


def _ev_passed(up: Up) -> float | None:
    with up.monitor.lock:
        return up.monitor.events.get("ev_passed_av")


def rsu_killed(run_root: Path | None = None, stale_limit_s: float = 2.0, timeout_s: float = 60.0,
               duration_s: float = 18.0) -> FaultOutcome:
    up, rec = _start("rsu", run_root, duration_s=duration_s, restart="no")
    details: dict[str, Any] = {"run_dir": str(up.run_dir)}
    try:
        if not _wait(lambda: bool(rec.ev_reports and any(r[2] == "alert" for r in rec.ev_reports)), timeout_s):
            return FaultOutcome("RSU killed with the EV in view", "rsu_kill", False, "no EvAlert at all", None,
                                RUNNER, details)
        victim = next(r[1] for r in rec.ev_reports if r[2] == "alert")
        up.group.kill(victim)
        t_kill = time.time()
        details["killed"] = victim
        _wait(lambda: _ev_passed(up) is not None, 25.0, 0.2)
        time.sleep(1.0)
    finally:
        up.stop()
    with rec.lock:
        stale_at = next((t for t, status, stale in rec.ddm_health
                         if t > t_kill and victim in stale and status == "degraded"), None)
        later_ev = sorted({rsu for t, rsu, _ in rec.ev_reports if t > t_kill + 0.5 and rsu != victim})
        victim_after = [t for t, rsu, _ in rec.ev_reports if t > t_kill + 0.5 and rsu == victim]
        resumes = [t for t, m, _ in rec.commands.values() if m == "resume" and t > t_kill]
    passed_at = _ev_passed(up)
    early_resume = [t for t in resumes if passed_at is None or t < passed_at]
    details.update(stale_after_s=None if stale_at is None else round(stale_at - t_kill, 3),
                   ev_reported_after_kill_by=later_ev, reports_from_killed=len(victim_after),
                   resume_before_ev_passed=len(early_resume), ev_passed=passed_at is not None,
                   ddm_max_tracks=max((n for _, n, _ in rec.ddm_fused), default=None),
                   ddm_old_measurements=max((d for _, _, d in rec.ddm_fused), default=None),
                   metrics=up.metrics())
    ok = stale_at is not None and stale_at - t_kill <= stale_limit_s and bool(later_ev) and not early_resume \
        and not victim_after
    if stale_at is None:
        outcome = f"DDM never reported {victim} stale"
    elif not later_ev:
        outcome = "no neighbouring RSU reported the EV"
    elif early_resume:
        outcome = "DDM resumed before the EV passed"
    else:
        outcome = f"{victim} stale after {stale_at - t_kill:.2f} s; EV kept by {','.join(later_ev)}"
    ok, outcome = with_yield(ok, outcome, details["metrics"].get("yield"))
    margin = None if stale_at is None else round(stale_limit_s - (stale_at - t_kill), 3)
    return FaultOutcome("RSU killed with the EV in view", "rsu_kill", ok, outcome, margin, RUNNER, details)


def ddm_restarted(run_root: Path | None = None, down_s: float = 0.5, timeout_s: float = 60.0,
                  duration_s: float = 18.0) -> FaultOutcome:
    up, rec = _start("ddm", run_root, duration_s=duration_s, restart="no")
    details: dict[str, Any] = {"run_dir": str(up.run_dir), "down_s": down_s}
    try:
        if not _wait(lambda: any(m == "manoeuvre" for _, m, _ in rec.modes), timeout_s):
            return FaultOutcome("DDM killed + restarted mid-manoeuvre", "ddm_restart", False,
                                "the AV never started a manoeuvre", None, RUNNER, details)
        up.group.kill("ddm")
        t_kill = time.time()
        with rec.lock:
            old_ids = set(rec.commands)
            active_at_kill = next((a for _, m, a in reversed(rec.modes) if m == "manoeuvre"), None)
        time.sleep(down_s)
        up.group.restart("ddm")
        t_restart = time.time()
        _wait(lambda: _ev_passed(up) is not None, 25.0, 0.2)
        time.sleep(2.0)
    finally:
        up.stop()
    passed_at = _ev_passed(up)
    end = passed_at if passed_at is not None else time.time()
    with rec.lock:
        new_cmds = sorted((t, m, cid) for cid, (t, m, _) in rec.commands.items() if cid not in old_ids)
        new_ids = {cid for _, _, cid in new_cmds}
        # the vehicle on its own: from the kill until it accepts the restarted DDM's first command
        own_end = min([end] + [t for t, cid, st in rec.acks if cid in new_ids and st == "accepted"])
        modes_between = sorted({m for t, m, _ in rec.modes if t_kill < t < own_end})
        ddm_back = next((t for t, _, _ in rec.ddm_health if t > t_restart), None)
        kept = any(a == active_at_kill for t, m, a in rec.modes if t_kill < t < end)
    contradicting = [(round(t - t_kill, 2), m) for t, m, _ in new_cmds if m == "resume" and t < end]
    with rec.lock:
        completed = any(cid == active_at_kill and st == "completed" for _, cid, st in rec.acks)
    ok_modes = ("manoeuvre", "stopped", "minimal_risk") + (("driving",) if completed else ())
    bad_modes = [m for m in modes_between if m not in ok_modes]  # driving: only after the command was done
    first_resume = next((t for t, m, _ in new_cmds if m == "resume"), None)
    details.update(modes_on_its_own=modes_between, on_its_own_s=round(own_end - t_kill, 2), kept_active_command=kept,
                   command_completed=completed,
                   new_ddm_commands=[(round(t - t_kill, 2), m) for t, m, _ in new_cmds],
                   ddm_heard_again_after_s=None if ddm_back is None else round(ddm_back - t_kill, 2),
                   ev_passed=passed_at is not None, metrics=up.metrics())
    ok = not bad_modes and not contradicting and ddm_back is not None
    if bad_modes:
        outcome = f"AV went to {bad_modes} on its own while the DDM was away"
    elif contradicting:
        outcome = f"restarted DDM sent {contradicting[0][1]} before the EV passed"
    elif ddm_back is None:
        outcome = "the DDM did not come back"
    else:
        how = "fail-safe stop" if "minimal_risk" in modes_between else "kept its command"
        outcome = f"AV {how}; DDM back after {ddm_back - t_kill:.1f} s"
    if passed_at is None:
        outcome += " (the EV had not passed the AV by the end of the run)"
    ok, outcome = with_yield(ok, outcome, details["metrics"].get("yield"))
    margin = None if passed_at is None else round((first_resume or time.time()) - passed_at, 3)
    return FaultOutcome("DDM killed + restarted mid-manoeuvre", "ddm_restart", ok, outcome, margin, RUNNER, details)


SERVICES = ("vehicle", "ddm", "rsu1", "rsu2", "rsu3", "rsu4", "sim")


def router_restarted(run_root: Path | None = None, at_s: float = 0.5, down_s: float = 0.5,
                     reconnect_limit_s: float = 10.0, timeout_s: float = 60.0,
                     duration_s: float = 20.0) -> FaultOutcome:
    up, rec = _start("router", run_root, duration_s=duration_s, restart="no")
    details: dict[str, Any] = {"run_dir": str(up.run_dir), "down_s": down_s}
    try:
        if not _wait(lambda: all(s in rec.heard for s in SERVICES), timeout_s, 0.1):
            details["never_heard"] = [s for s in SERVICES if s not in rec.heard]
        time.sleep(at_s)  # every service is connected and publishing: now take the router away
        up.restart_router(down_s)
        t_back = time.time()
        _wait(lambda: all(rec.first_after(s, t_back) is not None for s in SERVICES), reconnect_limit_s, 0.1)
        _wait(lambda: any(s == "accepted" and t > t_back for t, _, s in rec.acks), timeout_s / 2, 0.2)
        _wait(lambda: _ev_passed(up) is not None, 25.0, 0.2)  # the yield outcome is judged too (issue 18)
        time.sleep(0.5)
    finally:
        up.stop()
    back = {s: rec.first_after(s, t_back) for s in SERVICES}
    delays = {s: (None if t is None else round(t - t_back, 2)) for s, t in back.items()}
    missing = [s for s, d in delays.items() if d is None]
    accepted = [t for t, _, s in rec.acks if s == "accepted" and t > t_back]
    slowest = max((d for d in delays.values() if d is not None), default=None)
    details.update(reconnect_s=delays, command_accepted_after_restart=bool(accepted), metrics=up.metrics())
    ok = not missing and slowest is not None and slowest <= reconnect_limit_s and bool(accepted)
    if missing:
        outcome = f"not heard again: {', '.join(missing)}"
    elif not accepted:
        outcome = "no command accepted after the restart"
    else:
        outcome = f"all {len(SERVICES)} services back within {slowest:.1f} s"
    ok, outcome = with_yield(ok, outcome, details["metrics"].get("yield"))
    margin = None if slowest is None or missing else round(reconnect_limit_s - slowest, 3)
    return FaultOutcome("router restarted (iea up)", "router_restart", ok, outcome, margin, RUNNER, details)


PROCESS_FAULTS = {"rsu_kill": rsu_killed, "ddm_restart": ddm_restarted, "router_restart": router_restarted}
RETIME_EXTRA_S = 10.0


def run_retimed(fn, run_root: Path | None = None) -> FaultOutcome:
    """A process fault; when its EV never reached the AV (the run tested nothing), once more 10 s longer."""
    out = fn(run_root)
    if ((out.details.get("metrics") or {}).get("yield") or {}).get("status") == "not_reached":
        import inspect

        longer = inspect.signature(fn).parameters["duration_s"].default + RETIME_EXTRA_S
        out = fn(run_root, duration_s=longer)
        out.details["retimed_duration_s"] = longer
    return out
