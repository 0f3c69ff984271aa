"""`iea demo`: the main scenario end to end, every service a separate process over Zenoh on loopback.

Starts the vehicle (av1), the DDM, one RSU per camera of the corridor (frames rendered from the
simulator's ground truth by each RSU's SimCamera; perception sees pixels only) and the simulator
running ``rellis_ev_yield`` in real time, all in Zenoh peer mode (no router). While it runs it prints
the scenario time, what each service is doing, and the EV alert and the command when they happen;
then a summary table. The run folder (``runs/demo-<time>/``) holds ``metrics.json``, each service's
log, the vehicle's run and its plots, and the annotated video of the RSU that saw the EV first.

Signatures are on by default: the demo makes throwaway Ed25519 keys in the run folder
(``keys/``: one for the DDM, one per RSU), writes ``corridor.toml`` there (the default corridor plus
their ``[[trust]]`` entries) and starts every service on it, so the vehicle refuses any command the
DDM did not sign and the DDM refuses unsigned EV alerts. ``--unsigned`` runs without them.

Evaluation (this module, not the services) reads the simulator's ground truth to score the run.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
import uuid
from pathlib import Path
from typing import Any

from deploy.procs import ServiceGroup, child_env, corridor_services, start_when_rsus_up
from scenario.monitor import RunMonitor, print_summary

ROOT = Path(__file__).resolve().parent.parent


def make_demo_keys(run_dir: Path, corridor: Any) -> tuple[Path, dict[str, Path]]:
    """Throwaway keys (DDM + one per RSU) and the corridor file trusting them, in ``run_dir/keys``."""
    from deploy.signing import write_key_bundle
    from protocol.corridor import DEFAULT_CORRIDOR

    return write_key_bundle(DEFAULT_CORRIDOR, run_dir / "keys", key_id_suffix="demo", overwrite=True,
                            note="throwaway keys of this run")


def run_demo(scenario: str = "rellis_ev_yield", duration_s: float = 30.0, run_root: Path | None = None,
             corridor_id: str | None = None, quiet: bool = False, detector: str = "project",
             seed: int | None = None, signed: bool = True, record: bool = True,
             traffic: str | None = None) -> dict[str, Any]:
    from protocol import keys
    from protocol.zenoh_transport import ZenohTransport
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
    recorder = ddm_poll = None
    if record:  # every key as it went on the wire, for `iea replay` and log viewers
        from deploy.foxglove_scene import CorridorScene, DdmStatePoll
        from deploy.record import McapRecorder

        scene = CorridorScene(corridor)  # the Foxglove scene, map and log, with the DDM's fused tracks
        recorder = McapRecorder(run_dir / "run.mcap", metadata={"corridor_id": cid, "scenario": scenario},
                                derive=scene.feed)
        ddm_poll = DdmStatePoll(transport, cid, scene).start()
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
                              detector=detector, seed=seed, zenoh_args=common, keys=key_args, traffic=traffic)
    try:
        # DDM and RSUs; once every RSU is up (its token) and discovery settled, the vehicle and the world
        start_when_rsus_up(group, specs, transport, cid, say=lambda line: say(f"[demo] {line}"))
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
        if ddm_poll is not None:
            ddm_poll.close()
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
