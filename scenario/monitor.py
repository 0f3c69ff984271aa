"""The run monitor of every runner: a client of the corridor that records the events and figures of a run.

``RunMonitor`` listens to every key of a corridor (the demo, ``iea up``, the process faults and the lockstep
runner feed it) and keeps the latencies, commands, acks, lost messages and the AV's and the EV's ground truth
from the simulator for the one yield judge (``scenario/outcome.py``); ``metrics()`` is the run's figures
(``metrics.json``), ``print_summary`` prints them as a table. Evaluation only: perception never reads it.
"""

from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass, field
from typing import Any

from scenario.outcome import YieldTrace


@dataclass
class RunMonitor:
    """Listens to every key of the corridor and records the events and figures of a run."""

    corridor_id: str
    vehicle_id: str = "av1"
    events: dict[str, float] = field(default_factory=dict)
    facts: dict[str, Any] = field(default_factory=dict)
    sim_time_s: float = 0.0
    av: Any = None
    ev: Any = None
    vehicle_state: Any = None
    alerts: list[tuple[float, str, int]] = field(default_factory=list)
    commands: list[tuple[float, str, str]] = field(default_factory=list)
    acks: list[tuple[float, str, str]] = field(default_factory=list)
    min_gap_m: float = math.inf
    min_ttc_s: float = math.inf
    ev_min_speed_mps: float = math.inf
    ev_max_speed_mps: float = 0.0
    counts: dict[str, int] = field(default_factory=dict)
    last_seq: dict[str, int] = field(default_factory=dict)
    lost: dict[str, int] = field(default_factory=dict)
    """Per link (key topic): messages missing from the per-key sequence numbers (gaps seen here)."""
    ev_lit_speeds: list[tuple[float, float]] = field(default_factory=list)
    """(sim time, EV speed) while its lights are on: how much the EV had to slow."""
    road: Any = None
    """The corridor road (protocol.corridor.Road): lanes in road coordinates; None: y is the lateral offset."""
    trace: YieldTrace | None = None
    """The AV's and the EV's ground truth for the one yield judge (``scenario.outcome.judge_yield``)."""
    lock: threading.Lock = field(default_factory=threading.Lock)

    def __post_init__(self) -> None:
        if self.road is not None:
            self.road.prepare()  # not at the first world snapshot, beside every service's first frames

    def mark(self, name: str, t: float) -> None:
        self.events.setdefault(name, t)

    def on_message(self, key: str, msg: Any) -> None:
        now = time.time()
        kind = msg.KIND
        with self.lock:
            self.counts[kind] = self.counts.get(kind, 0) + 1
            last = self.last_seq.get(key)
            if last is not None and msg.seq > last + 1:
                link = key.rsplit("/", 1)[-1]
                self.lost[link] = self.lost.get(link, 0) + (msg.seq - last - 1)
            if last is None or msg.seq > last:
                self.last_seq[key] = msg.seq
            if kind == "WorldSnapshot":
                self._on_world(msg)
            elif kind == "EvAlert" and msg.state.value == "active":
                self.facts["alerts_signed"] = self.facts.get("alerts_signed", True) and msg.auth is not None
                if not self.alerts:
                    self.mark("first_ev_alert", msg.stamp)
                    self.facts["first_alert_rsu"] = msg.rsu_id
                    self.facts["first_alert_received"] = now
                self.alerts.append((msg.stamp, msg.rsu_id, msg.object_id))
            elif kind == "PathSwitchCommand":
                self.facts["commands_signed"] = self.facts.get("commands_signed", True) and msg.auth is not None
                if not any(c[1] == msg.command_id for c in self.commands):
                    self.commands.append((msg.stamp, msg.command_id, msg.manoeuvre.value))
                    if msg.manoeuvre.value != "resume":
                        self.mark("command_published", msg.issued_at)
                        self.facts.setdefault("command", f"{msg.manoeuvre.value}: {msg.reason}")
            elif kind == "CommandAck":
                self.acks.append((msg.stamp, msg.command_id, msg.status.value))
                if msg.status.value == "accepted" and self.commands:
                    self.mark("command_acked", msg.stamp)
            elif kind == "VehicleState" and msg.vehicle_id == self.vehicle_id:
                self.vehicle_state = msg
                if msg.mode.value == "manoeuvre":
                    self.mark("manoeuvre_start", msg.stamp)
                if msg.mode.value in ("stopped", "minimal_risk") and msg.speed_mps < 0.05 and "stopped" not in self.events:
                    self.mark("stopped", msg.stamp)
                    self.facts["stop_position_m"] = (round(msg.pos_x_m, 2), round(msg.pos_y_m, 2))
                    self.facts["stop_lane"] = msg.lane
                    self.facts["stop_mode"] = msg.mode.value
                self.facts["max_abs_lateral_error_m"] = max(self.facts.get("max_abs_lateral_error_m", 0.0),
                                                            abs(msg.lateral_error_m))

    def _on_world(self, snap: Any) -> None:
        self.sim_time_s = snap.sim_time_s
        av = next((a for a in snap.actors if a.kind.value == "av"), None)
        ev = next((a for a in snap.actors if a.kind.value == "ev"), None)
        self.av, self.ev = av, ev
        if ev is not None:
            self.ev_min_speed_mps = min(self.ev_min_speed_mps, ev.speed_mps)
            self.ev_max_speed_mps = max(self.ev_max_speed_mps, ev.speed_mps)
            if ev.light_bar is not None and ev.light_bar.on:
                self.mark("lights_on", snap.stamp)
                self.ev_lit_speeds.append((snap.sim_time_s, ev.speed_mps))
        if av is None:
            return
        if ev is not None and ev.pos_x_m > av.pos_x_m + av.length_m / 2 + ev.length_m / 2:
            self.mark("ev_passed_av", snap.stamp)
        if self.road is not None:  # the yield judge reads the EV's lane from its own path (scenario/outcome.py)
            if self.trace is None:
                self.trace = YieldTrace(road=self.road)
            self.trace.on_snapshot(snap, self.road)
        for other in snap.actors:
            if other is av or other.kind.value == "debris":
                continue
            dx, dy = other.pos_x_m - av.pos_x_m, other.pos_y_m - av.pos_y_m
            lateral_clear = abs(dy) - (av.width_m + other.width_m) / 2
            longitudinal_clear = abs(dx) - (av.length_m + other.length_m) / 2
            gap = max(lateral_clear, longitudinal_clear)
            if gap < self.min_gap_m:
                self.min_gap_m = gap
                self.facts["min_gap_with"] = f"{other.actor_id} at t={snap.sim_time_s:.2f} s"
            if lateral_clear < 0 and longitudinal_clear > 0:  # same lane: time to collision
                closing = av.speed_mps - other.speed_mps if dx > 0 else other.speed_mps - av.speed_mps
                if closing > 0.1:
                    self.min_ttc_s = min(self.min_ttc_s, longitudinal_clear / closing)

    def _ev_delay(self) -> dict[str, Any]:
        """How much the EV had to slow with its lights on: its lowest speed, and the time it lost against
        driving at the highest speed it reached (sum of (1 - v / v_max) dt)."""
        if len(self.ev_lit_speeds) < 2:
            return {"ev_min_speed_lights_on_mps": None, "ev_delay_s": None}
        t = [a for a, _ in self.ev_lit_speeds]
        v = [b for _, b in self.ev_lit_speeds]
        vmax = max(max(v), 1e-3)
        lost = sum((1.0 - v[i] / vmax) * (t[i + 1] - t[i]) for i in range(len(t) - 1))
        return {"ev_min_speed_lights_on_mps": round(min(v), 2), "ev_delay_s": round(lost, 2)}

    def progress_line(self) -> str:
        with self.lock:
            v = self.vehicle_state
            parts = [f"t={self.sim_time_s:5.1f}s"]
            if self.ev is not None:
                lit = self.ev.light_bar is not None and self.ev.light_bar.on
                parts.append(f"EV x={self.ev.pos_x_m:6.1f} {self.ev.speed_mps:4.1f}m/s lights {'ON ' if lit else 'off'}")
            if v is not None:
                parts.append(f"AV x={v.pos_x_m:6.1f} lane={v.lane if v.lane is not None else '-'} "
                             f"{v.speed_mps:4.1f}m/s {v.mode.value}")
            parts.append(f"alerts={len(self.alerts)} cmds={len(self.commands)} acks={len(self.acks)}")
            return " | ".join(parts)

    def metrics(self) -> dict[str, Any]:
        with self.lock:
            ev = dict(self.events)
            base = ev.get("lights_on")
            rel = {k: (round(t - base, 3) if base is not None else None) for k, t in ev.items()}
            hop = {}
            pairs = [("lights_on", "first_ev_alert", "lights_on_to_alert_s"),
                     ("first_ev_alert", "command_published", "alert_to_command_s"),
                     ("command_published", "command_acked", "command_to_ack_s"),
                     ("lights_on", "manoeuvre_start", "lights_on_to_manoeuvre_s"),
                     ("lights_on", "stopped", "lights_on_to_stop_s")]
            for a, b, name in pairs:
                if a in ev and b in ev:
                    hop[name] = round(ev[b] - ev[a], 3)
            stopped_before_pass = "stopped" in ev and ("ev_passed_av" not in ev or ev["stopped"] <= ev["ev_passed_av"])
            verdict = None if self.trace is None else self.trace.verdict(collision=self.min_gap_m < 0.0)
            moved_over = verdict is not None and verdict.status == "yielded"
            out_s = None
            if verdict is not None and verdict.lane_clear_s is not None and verdict.lights_on_s is not None:
                out_s = round(verdict.lane_clear_s - verdict.lights_on_s, 3)
            return {
                "corridor_id": self.corridor_id,
                "events_since_lights_on_s": rel,
                "latency_s": hop,
                "first_alert_rsu": self.facts.get("first_alert_rsu"),
                "command": self.facts.get("command"),
                "stop_position_m": self.facts.get("stop_position_m"),
                "stop_lane": self.facts.get("stop_lane"),
                "stop_mode": self.facts.get("stop_mode"),
                "stopped_before_ev_passed": stopped_before_pass,
                "moved_over_before_ev_passed": moved_over,
                "ev_passed_av_s": rel.get("ev_passed_av"),
                "out_of_ev_lane_s": out_s,
                "yield": None if verdict is None or verdict.status == "no_lights" else verdict.to_dict(),
                "max_abs_lateral_error_m": self.facts.get("max_abs_lateral_error_m"),
                "min_gap_to_any_vehicle_m": None if math.isinf(self.min_gap_m) else round(self.min_gap_m, 2),
                "min_gap_with": self.facts.get("min_gap_with"),
                "min_time_to_collision_s": None if math.isinf(self.min_ttc_s) else round(self.min_ttc_s, 2),
                "collision": self.min_gap_m < 0.0,
                "ev_speed_min_max_mps": (None if math.isinf(self.ev_min_speed_mps)
                                         else [round(self.ev_min_speed_mps, 2), round(self.ev_max_speed_mps, 2)]),
                "commands_signed": self.facts.get("commands_signed"),
                "alerts_signed": self.facts.get("alerts_signed"),
                "messages_seen": dict(self.counts),
                "messages_lost_per_link": dict(self.lost),
                **self._ev_delay(),
                "alerts": len(self.alerts),
                "commands": [{"id": c[1], "manoeuvre": c[2]} for c in self.commands],
                "acks": [{"id": a[1], "status": a[2]} for a in self.acks],
            }


def print_summary(m: dict[str, Any]) -> None:
    rows = [
        ("EV lights on -> first EvAlert", m["latency_s"].get("lights_on_to_alert_s"), "s"),
        ("EvAlert -> command published", m["latency_s"].get("alert_to_command_s"), "s"),
        ("command -> accepted by the vehicle", m["latency_s"].get("command_to_ack_s"), "s"),
        ("lights on -> manoeuvre start", m["latency_s"].get("lights_on_to_manoeuvre_s"), "s"),
        ("lights on -> stopped", m["latency_s"].get("lights_on_to_stop_s"), "s"),
        ("first alert from", m.get("first_alert_rsu"), ""),
        ("command", m.get("command"), ""),
        ("stop position (x, y)", m.get("stop_position_m"), "m"),
        ("stop lane (None: shoulder)", m.get("stop_lane"), ""),
        ("AV out of the EV's lane (after lights on)", m.get("out_of_ev_lane_s"), "s"),
        ("EV passed the AV (after lights on)", m.get("ev_passed_av_s"), "s"),
        ("yield (out of the EV's lane before it reached the AV)",
         None if not m.get("yield") else f"{m['yield']['status']}: {m['yield']['reason']}", ""),
        ("EV delay to the AV (yield judge)", None if not m.get("yield") else m["yield"]["ev_delay_s"], "s"),
        ("stopped before the EV passed", m.get("stopped_before_ev_passed"), ""),
        ("max |lateral error|", m.get("max_abs_lateral_error_m"), "m"),
        ("min gap to any vehicle", m.get("min_gap_to_any_vehicle_m"), "m"),
        ("min time to collision", m.get("min_time_to_collision_s"), "s"),
        ("collision", m.get("collision"), ""),
        ("commands / alerts signed", f"{m.get('commands_signed')} / {m.get('alerts_signed')}", ""),
        ("EV speed min / max", m.get("ev_speed_min_max_mps"), "m/s"),
        ("EV lowest speed with lights on", m.get("ev_min_speed_lights_on_mps"), "m/s"),
        ("EV delay (time lost vs its top speed)", m.get("ev_delay_s"), "s"),
        ("messages lost per link", m.get("messages_lost_per_link") or "none", ""),
    ]
    print("\n summary")
    for name, value, unit in rows:
        v = "-" if value is None else (f"{value:.3f}" if isinstance(value, float) else str(value))
        print(f"  {name:<36} {v} {unit}")
    print(f"  run folder: {m.get('run_dir')}")
