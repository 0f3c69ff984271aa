"""One fault row on the network lab: the corridor in namespaces, one link broken around the EV's lights-on.

``run_row`` starts a ``Lab`` (the ``iea up`` services, each on its own host, playing ``rellis_ev_yield``),
waits for the row's trigger (what the lab's own session hears: the simulator's lights-on, the first EvAlert,
the AV's first manoeuvre), breaks the link, restores it after the row's length, lets the EV pass, removes the
lab and judges what it heard (``deploy.netlab.schedule``). A failed row whose fault alone delays the command past
the rig's bound (``scenario.faults``) is marked beyond it.
"""

from __future__ import annotations

import dataclasses
import json
import time
import uuid
from pathlib import Path
from typing import Any

from deploy.netlab.lab import Lab, lab_guard, run_dir_for
from deploy.netlab.schedule import (
    ANSWER_WAIT_S,
    EVERY_RSU,
    FIRST_ALERT_RSU,
    SEGMENT_OF_FIRST_ALERT,
    NetFault,
    RowSeen,
    command_delay_s,
    judge_row,
    message_figures,
    unanswered_commands,
)
from deploy.process_faults import Recorder
from deploy.procs import wait_until
from scenario.fault_judges import FaultOutcome

RUNNER = "network lab (iea up, a namespace per host)"


class NetRecorder(Recorder):
    """``deploy.process_faults.Recorder`` plus the DDM's expired commands and each RSU's object lists."""

    def __init__(self) -> None:
        super().__init__()
        self.cmd_expired = 0
        self.objects: dict[str, list[float]] = {}

    def on_message(self, key: str, msg: Any) -> None:
        super().on_message(key, msg)
        if msg.KIND == "Health" and msg.role.value == "ddm":
            self.cmd_expired = max(self.cmd_expired, int(msg.drops.get("cmd_expired", 0)))
        elif msg.KIND == "ObjectList":
            with self.lock:
                self.objects.setdefault(msg.rsu_id, []).append(time.time())


def _unanswered(rec: NetRecorder) -> int:
    with rec.lock:
        return unanswered_commands({c: t for c, (t, *_) in rec.commands.items()}, {cid for _, cid, _ in rec.acks},
                                   rec.cmd_expired)


def _trigger(at: str, lab: Lab, rec: NetRecorder) -> bool:
    if at == "start":
        return True
    if at == "lights_on":
        with lab.monitor.lock:
            return "lights_on" in lab.monitor.events
    if at == "first_alert":
        with rec.lock:
            return any(kind == "alert" for _, _, kind in rec.ev_reports)
    with rec.lock:  # first_manoeuvre
        return any(m == "manoeuvre" for _, m, _ in rec.modes)


def _victims(fault: NetFault, lab: Lab, rec: NetRecorder) -> tuple[str, ...]:
    rsus = [s.name for s in lab.specs if "--rsu" in s.args]
    first = next((r for _, r, kind in rec.ev_reports if kind == "alert"), None)
    if fault.target == FIRST_ALERT_RSU:
        return (first,) if first else ()
    if fault.target == EVERY_RSU:
        return tuple(rsus)
    if fault.target == SEGMENT_OF_FIRST_ALERT:
        seg = lab.plan.link(first).hub if first else None
        return tuple([first, *(r for r in lab.plan.hosts_of(seg) if r != first)]) if seg else ()
    if fault.action == "hub_cut":
        return tuple(s.name for s in lab.specs)
    return (fault.target,)


def _apply(fault: NetFault, lab: Lab, victims: tuple[str, ...]) -> None:
    if fault.action == "loss":
        for v in victims:
            lab.net.drop(v, fault.value)
    elif fault.action == "cut":
        for v in victims:
            lab.net.drop(v, 1.0)
    elif fault.action == "cap":
        for v in victims:
            lab.net.cap(v, fault.value)
    elif fault.action == "hub_cut":
        lab.net.cut_hub(fault.target)
    elif fault.action == "hub_lost":  # the segment router's process and its link, gone for good
        seg = lab.plan.link(victims[0]).hub
        lab.group.kill(f"router-{seg}")
        lab.net.cut_hub(seg)


def _restore(fault: NetFault, lab: Lab, victims: tuple[str, ...]) -> None:
    if fault.action == "cap":
        for v in victims:
            lab.net.uncap(v)
    else:
        lab.net.restore()


def run_row(fault: NetFault, run_root: Path | None = None, duration_s: float = 20.0, timeout_s: float = 60.0,
            detector: str = "project", pass_wait_s: float = 25.0, rsu_ids: list[str] | None = None,
            sysctls: dict[str, str] | None = None) -> FaultOutcome:
    """One row on a fresh lab (``rsu_ids``: only these RSUs; ``sysctls``: every host's kernel settings);
    everything the lab made is removed before it returns (or raises)."""
    with lab_guard():
        return _run(fault, run_root, duration_s, timeout_s, detector, pass_wait_s, rsu_ids, sysctls)


def _run(fault: NetFault, run_root: Path | None, duration_s: float, timeout_s: float, detector: str,
         pass_wait_s: float, rsu_ids: list[str] | None, sysctls: dict[str, str] | None) -> FaultOutcome:
    lab = Lab(segments=fault.segments, run_dir=run_dir_for(run_root, fault.action),
              corridor_id=f"n{uuid.uuid4().hex[:8]}", duration_s=max(duration_s, fault.min_duration_s), restart="no",
              detector=detector, rsu_ids=rsu_ids, sysctls=sysctls)
    if fault.action == "cap":  # the RSUs are deployed knowing their backhaul's rate (rsu.uplink)
        for spec in lab.specs:
            if "--rsu" in spec.args:
                spec.args += ["--uplink-kbit-s", f"{fault.value / 1000.0:g}"]
    rec = NetRecorder()
    details: dict[str, Any] = {"run_dir": str(lab.run_dir), "prefix": lab.plan.prefix,
                               "sysctls": dict(lab.net.sysctls),
                               "action": fault.action,
                               "target": fault.target, "value": fault.value, "length_s": fault.length_s}
    t_fault = t_restore = None
    victims: tuple[str, ...] = ()
    active = None
    bytes0 = {}
    try:
        lab.start(extra_subscribers=[rec.on_message])
        t_start = time.time()
        if not wait_until(lambda: _trigger(fault.at, lab, rec), timeout_s):
            return FaultOutcome(fault.name, fault.kind, False, f"the trigger ({fault.at}) never came", None, RUNNER,
                                {**details, "metrics": lab.metrics()})
        victims = _victims(fault, lab, rec)
        if not victims:
            raise RuntimeError(f"row {fault.name!r}: nothing to break for target {fault.target!r}")
        with rec.lock:
            active = next((a for _, m, a in reversed(rec.modes) if m == "manoeuvre"), None)
        bytes0 = {v: lab.net.link_bytes(v) for v in victims if fault.action == "cap"}
        _apply(fault, lab, victims)
        t_fault = time.time()
        if fault.length_s is not None:
            time.sleep(fault.length_s)
            _restore(fault, lab, victims)
            t_restore = time.time()
        if fault.kind == "router_restart":
            names = [s.name for s in lab.specs]
            wait_until(lambda: all(rec.first_after(s, t_restore) is not None for s in names), 15.0, 0.1)
        wait_until(lambda: lab.monitor.events.get("ev_passed_av") is not None,
              pass_wait_s + fault.min_duration_s, 0.2)
        time.sleep(1.5)
        wait_until(lambda: _unanswered(rec) == 0, ANSWER_WAIT_S, 0.2)
        if bytes0:
            span = time.time() - t_fault
            details["uplink_bytes_per_s"] = {v: round((lab.net.link_bytes(v)[0] - bytes0[v][0]) / span)
                                             for v in bytes0}
            with rec.lock:
                details["object_lists_hz"] = {v: round(len([t for t in rec.objects.get(v, []) if t > t_fault]) / span, 2)
                                              for v in victims}
        details["startup_s"] = round(t_start - rec.t0, 2)
    finally:
        end = time.time()  # what the lab's session heard ends here
        lab.stop()
    m = lab.metrics()
    with rec.lock:
        seen = RowSeen(
            t_fault, t_restore, end, dict(sorted(((c, (t, mn)) for c, (t, mn, _) in rec.commands.items()),
                                                 key=lambda kv: kv[1][0])),
            tuple(rec.acks), tuple(rec.modes), tuple((t, s, tuple(st)) for t, s, st in rec.ddm_health),
            tuple(rec.ev_reports), {k: tuple(v) for k, v in rec.heard.items()}, rec.cmd_expired, victims,
            lab.monitor.events.get("ev_passed_av"), lab.monitor.events.get("lights_on"), active)
    lon = seen.lights_on_s
    details.update(commands_since_lights_on_s=[(mn, None if lon is None else round(t - lon, 2))
                                               for t, mn in seen.commands.values()],
                   victims=list(victims), metrics=m, alert_latency_s=m["latency_s"].get("lights_on_to_alert_s"),
                   fault_after_lights_on_s=None if seen.lights_on_s is None else round(t_fault - seen.lights_on_s, 3),
                   **message_figures(seen))
    judged = judge_row(fault, seen, m.get("yield"))
    row = beyond_bound(judged.row(fault.name, fault.kind, RUNNER, details), fault, details["alert_latency_s"])
    (lab.run_dir / "row.json").write_text(json.dumps({"row": row.row(), **row.details}, indent=2, default=str) + "\n")
    return row


def beyond_bound(row: FaultOutcome, fault: NetFault, alert_delay_s: float | None) -> FaultOutcome:
    """The row marked beyond the rig's bound (``scenario.faults``) when it failed and its own alert delay plus
    the fault's least delay is past the latest alert that still clears the lane. A run where no EvAlert got
    through at all measured no alert delay: no bound, the failure stands."""
    extra = None if alert_delay_s is None else command_delay_s(fault, alert_delay_s)
    if row.passed or extra is None:
        return row
    from scenario.faults import YieldScenario
    from scenario.faults import _judged as judged_against_rig_bound

    return judged_against_rig_bound(row, extra, YieldScenario(alert_delay_s=alert_delay_s))


def run_table(faults, run_root: Path | None = None, say=print, **kw: Any) -> list[FaultOutcome]:
    """Every row in turn (a fresh lab each); ``say`` gets each judged row's line as it is done."""
    out = []
    for f in faults:
        t = time.monotonic()
        r = run_row(f, run_root, **kw)
        r = dataclasses.replace(r, details={**r.details, "wall_s": round(time.monotonic() - t, 1)})
        say(r.row())
        out.append(r)
    return out
