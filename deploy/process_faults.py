"""Process-level faults over real Zenoh on loopback: the `iea up` topology, one thing broken.

Each function starts the corridor as ``iea up`` does (a router on a free loopback port, the vehicle, the
DDM, the RSUs with ``--source sim`` and the simulator running ``rellis_ev_yield``, all as processes),
breaks one thing, and returns a ``FaultOutcome`` measured from what a client of the router heard
(the simulator's ground truth only scores the run). Every row passes only on its own criterion below AND
the one yield judge's verdict of the run (``scenario/outcome.py``: out of the EV's lane before it reached
the AV); each kind is judged by its judge in ``scenario/fault_judges.py``:

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

from deploy.procs import wait_until
from deploy.up import Up
from scenario.fault_judges import (
    DdmRestartSeen,
    FaultOutcome,
    RouterRestartSeen,
    RsuKillSeen,
    judge_ddm_restart,
    judge_router_restart,
    judge_rsu_kill,
)

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


def _ev_passed(up: Up) -> float | None:
    with up.monitor.lock:
        return up.monitor.events.get("ev_passed_av")


def rsu_killed(run_root: Path | None = None, stale_limit_s: float = 2.0, timeout_s: float = 60.0,
               duration_s: float = 18.0) -> FaultOutcome:
    up, rec = _start("rsu", run_root, duration_s=duration_s, restart="no")
    details: dict[str, Any] = {"run_dir": str(up.run_dir)}
    try:
        if not wait_until(lambda: bool(rec.ev_reports and any(r[2] == "alert" for r in rec.ev_reports)), timeout_s):
            return FaultOutcome("RSU killed with the EV in view", "rsu_kill", False, "no EvAlert at all", None,
                                RUNNER, details)
        victim = next(r[1] for r in rec.ev_reports if r[2] == "alert")
        up.group.kill(victim)
        t_kill = time.time()
        details["killed"] = victim
        wait_until(lambda: _ev_passed(up) is not None, 25.0, 0.2)
        time.sleep(1.0)
    finally:
        up.stop()
    with rec.lock:
        later_ev = tuple(sorted({rsu for t, rsu, _ in rec.ev_reports if t > t_kill + 0.5 and rsu != victim}))
        seen = RsuKillSeen(victim, t_kill, tuple((t, st, tuple(stale)) for t, st, stale in rec.ddm_health),
                           tuple(t for t, m, _ in rec.commands.values() if m == "resume"), _ev_passed(up), later_ev,
                           len([t for t, rsu, _ in rec.ev_reports if t > t_kill + 0.5 and rsu == victim]))
        details.update(ddm_max_tracks=max((n for _, n, _ in rec.ddm_fused), default=None),
                       ddm_old_measurements=max((d for _, _, d in rec.ddm_fused), default=None))
    details.update(ev_reported_after_kill_by=list(later_ev), reports_from_killed=seen.reports_from_killed,
                   ev_passed=seen.ev_passed_at_s is not None, metrics=up.metrics())
    judged = judge_rsu_kill(seen, details["metrics"].get("yield"), stale_limit_s)
    return judged.row("RSU killed with the EV in view", "rsu_kill", RUNNER, details)


def ddm_restarted(run_root: Path | None = None, down_s: float = 0.5, timeout_s: float = 60.0,
                  duration_s: float = 18.0) -> FaultOutcome:
    up, rec = _start("ddm", run_root, duration_s=duration_s, restart="no")
    details: dict[str, Any] = {"run_dir": str(up.run_dir), "down_s": down_s}
    try:
        if not wait_until(lambda: any(m == "manoeuvre" for _, m, _ in rec.modes), timeout_s):
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
        wait_until(lambda: _ev_passed(up) is not None, 25.0, 0.2)
        time.sleep(2.0)
    finally:
        up.stop()
    with rec.lock:
        seen = DdmRestartSeen(
            t_kill, active_at_kill,
            tuple(sorted((t, m, cid) for cid, (t, m, _) in rec.commands.items() if cid not in old_ids)),
            tuple(rec.acks), tuple((t, m) for t, m, _ in rec.modes if t > t_kill),
            next((t for t, _, _ in rec.ddm_health if t > t_restart), None), _ev_passed(up), time.time())
        kept = any(a == active_at_kill for t, m, a in rec.modes if t_kill < t < (seen.ev_passed_at_s or seen.end_s))
    details.update(kept_active_command=kept, metrics=up.metrics())
    judged = judge_ddm_restart(seen, details["metrics"].get("yield"))
    return judged.row("DDM killed + restarted mid-manoeuvre", "ddm_restart", RUNNER, details)


SERVICES = ("vehicle", "ddm", "rsu1", "rsu2", "rsu3", "rsu4", "sim")


def router_restarted(run_root: Path | None = None, at_s: float = 0.5, down_s: float = 0.5,
                     reconnect_limit_s: float = 10.0, timeout_s: float = 60.0,
                     duration_s: float = 20.0) -> FaultOutcome:
    up, rec = _start("router", run_root, duration_s=duration_s, restart="no")
    details: dict[str, Any] = {"run_dir": str(up.run_dir), "down_s": down_s}
    try:
        if not wait_until(lambda: all(s in rec.heard for s in SERVICES), timeout_s, 0.1):
            details["never_heard"] = [s for s in SERVICES if s not in rec.heard]
        time.sleep(at_s)  # every service is connected and publishing: now take the router away
        up.restart_router(down_s)
        t_back = time.time()
        wait_until(lambda: all(rec.first_after(s, t_back) is not None for s in SERVICES), reconnect_limit_s, 0.1)
        wait_until(lambda: any(s == "accepted" and t > t_back for t, _, s in rec.acks), timeout_s / 2, 0.2)
        wait_until(lambda: _ev_passed(up) is not None, 25.0, 0.2)  # the yield outcome is judged too
        time.sleep(0.5)
    finally:
        up.stop()
    back = {s: rec.first_after(s, t_back) for s in SERVICES}
    seen = RouterRestartSeen({s: (None if t is None else round(t - t_back, 2)) for s, t in back.items()},
                             any(s == "accepted" and t > t_back for t, _, s in rec.acks))
    details.update(reconnect_s=seen.back_after_s, command_accepted_after_restart=seen.command_accepted_after,
                   metrics=up.metrics())
    judged = judge_router_restart(seen, details["metrics"].get("yield"), reconnect_limit_s)
    return judged.row("router restarted (iea up)", "router_restart", RUNNER, details)


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
