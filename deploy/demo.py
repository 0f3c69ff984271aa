"""`iea demo`: the main scenario end to end, every service a separate process over Zenoh on loopback.

Starts the vehicle (av1), the DDM, one RSU per camera of the corridor (frames rendered from the
simulator's ground truth by each RSU's SimCamera; perception sees pixels only) and the simulator
running ``rellis_ev_yield`` in real time, all in Zenoh peer mode (no router). While it runs it prints
the scenario time, what each service is doing, and the EV alert and the command when they happen;
then a summary table. The run folder (``runs/demo-<time>/``) holds ``metrics.json``, each service's
log, the vehicle's run and its plots, and the annotated video of the RSU that saw the EV first.

Signatures (issue 9) are on by default: the demo makes throwaway Ed25519 keys in the run folder
(``keys/``: one for the DDM, one per RSU), writes ``corridor.toml`` there (the default corridor plus
their ``[[trust]]`` entries) and starts every service on it, so the vehicle refuses any command the
DDM did not sign and the DDM refuses unsigned EV alerts. ``--unsigned`` runs without them.

Evaluation (this module, not the services) reads the simulator's ground truth to score the run.
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import threading
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from scenario.outcome import YieldTrace
from deploy.procs import ServiceGroup, child_env, corridor_services

ROOT = Path(__file__).resolve().parent.parent


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


def make_demo_keys(run_dir: Path, corridor: Any) -> tuple[Path, dict[str, Path]]:
    """Throwaway keys (DDM + one per RSU) and the corridor file trusting them, in ``run_dir/keys``."""
    from deploy.signing import write_key_bundle
    from protocol.corridor import DEFAULT_CORRIDOR

    return write_key_bundle(DEFAULT_CORRIDOR, run_dir / "keys", key_id_suffix="demo", overwrite=True,
                            note="throwaway keys of this run")


def run_demo(scenario: str = "rellis_ev_yield", duration_s: float = 30.0, run_root: Path | None = None,
             corridor_id: str | None = None, quiet: bool = False, detector: str = "project",
             seed: int | None = None, signed: bool = True, record: bool = True) -> dict[str, Any]:
    from protocol import keys
    from protocol.transport import ZenohTransport
    from sim.scenario import load_scenario

    sc = load_scenario(scenario)
    corridor = sc.corridor
    cid = corridor_id or f"rellis-{uuid.uuid4().hex[:6]}"
    run_dir = (run_root or ROOT / "runs") / f"demo-{time.strftime('%Y%m%d-%H%M%S')}"
    (run_dir / "logs").mkdir(parents=True, exist_ok=True)
    env = child_env()
    say = (lambda *a: None) if quiet else (lambda *a: print(*a, flush=True))
    say(f"[demo] corridor {cid}, scenario {scenario}, {duration_s:.0f} s; run folder {run_dir}")

    monitor = RunMonitor(cid, road=corridor.road)
    transport = ZenohTransport()
    transport.subscribe(keys.corridor_expr(cid), monitor.on_message)
    recorder = None
    if record:  # every key as it went on the wire, for `iea replay` and log viewers (issue 22)
        from deploy.record import McapRecorder

        recorder = McapRecorder(run_dir / "run.mcap", metadata={"corridor_id": cid, "scenario": scenario})
        transport.subscribe_bytes(keys.corridor_expr(cid), recorder.on_bytes)
        say(f"[demo] recording every key to {run_dir / 'run.mcap'} (--no-record: off)")
    common: list[str] = []
    key_args: dict[str, list[str]] = {}
    if signed:
        corridor_file, key_paths = make_demo_keys(run_dir, corridor)
        common = ["--corridor", str(corridor_file)]
        key_args = {name: ["--key", str(path)] for name, path in key_paths.items()}
        say(f"[demo] signed messages: throwaway keys in {run_dir / 'keys'}, trust list in {corridor_file}")
    else:
        say("[demo] UNSIGNED: commands and alerts carry no signatures (--unsigned)")
    group = ServiceGroup(run_dir, env)
    procs = group.procs
    # DDM, RSUs, then (after discovery) the vehicle and the simulator together: the AV starts where the
    # scenario puts it when the world starts
    specs = corridor_services(corridor, cid, scenario=scenario, duration_s=duration_s, run_dir=run_dir,
                              detector=detector, seed=seed, zenoh_args=common, keys=key_args)
    try:
        for spec in specs[:-2]:
            group.start(spec.name, spec.args)
        time.sleep(2.0)  # let every session discover the others before the world starts
        for spec in specs[-2:]:
            group.start(spec.name, spec.args)
        say("[demo] started: " + ", ".join(f"{k} (pid {p.pid})" for k, p in procs.items()))
        deadline = time.monotonic() + duration_s + 30
        last_alerts = last_cmds = 0
        reported: set[str] = set()
        while procs["sim"].poll() is None and time.monotonic() < deadline:
            time.sleep(1.0)
            say("  " + monitor.progress_line())
            with monitor.lock:
                if len(monitor.alerts) > last_alerts and last_alerts == 0:
                    say(f"  >> EV alert from {monitor.facts.get('first_alert_rsu')}")
                if len(monitor.commands) > last_cmds:
                    say(f"  >> command {monitor.commands[-1][1]}: {monitor.commands[-1][2]}")
                last_alerts, last_cmds = len(monitor.alerts), len(monitor.commands)
            for name, p in procs.items():
                if name != "sim" and name not in reported and p.poll() is not None and p.returncode != 0:
                    reported.add(name)
                    say(f"  !! {name} exited with code {p.returncode}; see {run_dir / 'logs' / (name + '.log')}")
        time.sleep(1.0)
    finally:
        group.stop_all()
        transport.close()
        if recorder is not None:
            recorder.close()

    metrics = monitor.metrics()
    first = metrics.get("first_alert_rsu")
    for rsu in corridor.rsus:  # keep the video of the RSU that saw the EV first
        video = run_dir / f"{rsu.rsu_id}.mp4"
        if video.exists() and first is not None and rsu.rsu_id != first:
            video.unlink()
    if (run_dir / "vehicle").exists():
        subprocess.run([sys.executable, "-m", "vehicle", "plot", str(run_dir / "vehicle")], env=env, cwd=ROOT,
                       capture_output=True, timeout=120)
    (run_dir / "metrics.json").write_text(json.dumps(metrics, indent=2) + "\n")
    metrics["run_dir"] = str(run_dir)
    return metrics


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


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="iea demo", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenario", default="rellis_ev_yield", help="scenario name (iea-sim list)")
    ap.add_argument("--duration-s", type=float, default=30.0, help="scenario time to run")
    ap.add_argument("--detector", default="project",
                    help="RSU detector: 'project' (models/iea_det_tiny.onnx, default), 'motion' (MOG2) or an ONNX path")
    ap.add_argument("--runs", default=str(ROOT / "runs"), help="where run folders go")
    ap.add_argument("--unsigned", action="store_true", help="no signatures (default: throwaway keys, signed)")
    ap.add_argument("--no-record", action="store_true",
                    help="do not record the run (default: every key to <run folder>/run.mcap; `iea replay` it)")
    args = ap.parse_args(argv)
    m = run_demo(args.scenario, args.duration_s, Path(args.runs), detector=args.detector, signed=not args.unsigned,
                 record=not args.no_record)
    print_summary(m)
    from scenario.outcome import judge_run
    from sim.scenario import load_scenario

    sc = load_scenario(args.scenario)
    lit = None if sc.ev is None else sc.ev.lights_on_at_s is not None and sc.ev.lights_on_at_s < args.duration_s
    ok, why = judge_run(m, ev_lights_on=lit)
    print(f"\n[demo] {'PASS' if ok else 'FAIL'}: {why}")
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
