"""``iea scenario list | run NAME``: a scenario end to end, judged by the yield judge: as separate processes over
Zenoh (``deploy.demo``) or in one process in lockstep on a simulated clock (``scenario.lockstep``), with its run
folder (metrics, the vehicle's run and plots, the first alerting RSU's video, an MCAP recording)."""

from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import Any

from deploy.record import scene_recorder
from scenario.lockstep import CorridorLockstep, LockstepConfig, ev_lights_on
from sim.scenario import load_scenario


def main(argv: list[str] | None = None) -> int:
    """``iea scenario list | run NAME [--inprocess [--fast]]``."""
    import argparse
    import json

    from scenario.outcome import judge_run
    from sim.scenario import ScenarioError, list_scenarios

    ap = argparse.ArgumentParser(
        prog="iea scenario", description="Run a scenario end to end and judge it: as separate processes over Zenoh "
        "(like `iea demo`), or in one process in lockstep on a simulated clock (--inprocess).")
    sub = ap.add_subparsers(dest="action", required=True)
    sub.add_parser("list", help="list the scenarios")
    run = sub.add_parser("run", help="run one scenario and print its summary")
    run.add_argument("name", help="scenario name (`iea scenario list`) or a scenario TOML file")
    run.add_argument("--inprocess", action="store_true",
                     help="all services in this process on a simulated clock (deterministic; no Zenoh)")
    run.add_argument("--fast", action="store_true",
                     help="with --inprocess: run as fast as the CPU allows instead of in real time")
    run.add_argument("--seed", type=int, default=None, help="scenario seed (default: the scenario file's)")
    run.add_argument("--duration-s", type=float, default=None, help="scenario time to run (default: the scenario's)")
    run.add_argument("--detector", default="project",
                     help="RSU detector: 'project' (models/iea_det_tiny.onnx), 'motion' (MOG2) or an ONNX model path")
    run.add_argument("--runs", default=None, help="where the run folder goes (default ./runs)")
    run.add_argument("--json", action="store_true", help="print the metrics as one JSON line at the end")
    run.add_argument("--traffic", choices=("project", "sumo"), default=None,
                     help="who drives the traffic: the simulator's own model or Eclipse SUMO (default: the scenario's)")
    args = ap.parse_args(argv)
    if args.action == "list":
        for name in list_scenarios():
            print(name)
        return 0
    try:
        sc = load_scenario(args.name)
    except ScenarioError as exc:
        print(f"iea scenario: {exc}", file=sys.stderr)
        return 2
    if args.seed is not None or args.traffic is not None:
        sc = sc.with_overrides(seed=args.seed, traffic=args.traffic)
    if sc.traffic_model == "sumo":
        from sim.sumo import sumo_missing

        why = sumo_missing()
        if why is not None:
            print(f"iea scenario: --traffic sumo: {why}", file=sys.stderr)
            return 2
    from deploy.demo import ROOT, run_demo
    from scenario.monitor import print_summary

    runs = Path(args.runs) if args.runs else ROOT / "runs"
    if args.inprocess:
        run_dir = runs / f"scenario-{sc.name}-{time.strftime('%Y%m%d-%H%M%S')}"
        cfg = LockstepConfig(scenario=sc.name, seed=args.seed, duration_s=args.duration_s, detector=args.detector,
                             record_vehicle=True, annotate_dir=run_dir, realtime=not args.fast,
                             traffic=sc.traffic_model)
        print(f"[scenario] {sc.name} seed {sc.seed} in lockstep ({'fast' if args.fast else 'real time'}); "
              f"run folder {run_dir}", flush=True)
        mcap_path = run_dir / "run.mcap"
        mcap_path.parent.mkdir(parents=True, exist_ok=True)
        # every key, and the Foxglove scene, map and log (deploy.foxglove_scene)
        runner = CorridorLockstep(cfg, scenario=sc, recorder=scene_recorder(mcap_path, sc.corridor))
        m = runner.run(progress=lambda line: print("  " + line, flush=True))
        write_run_folder(runner, m, run_dir)
        m["run_dir"] = str(run_dir)
    else:
        m = run_demo(sc.name, args.duration_s or sc.duration_s, runs, seed=args.seed, detector=args.detector,
                     traffic=sc.traffic_model)
    print_summary(m)
    ok, why = judge_run(m, ev_lights_on=ev_lights_on(sc, args.duration_s))
    print(f"\n[scenario] {sc.name}: {'PASS' if ok else 'FAIL'}: {why}")
    if args.json:
        print(json.dumps({**m, "passed": ok, "verdict": why}, default=str))
    return 0 if ok else 1


def write_run_folder(runner: CorridorLockstep, metrics: dict[str, Any], run_dir: Path) -> None:
    """metrics.json, the vehicle's run (and its plots), and keep only the video of the first alerting RSU."""
    import json

    run_dir.mkdir(parents=True, exist_ok=True)
    first = metrics.get("first_alert_rsu")
    for rsu_id in [r.rsu_id for r in runner.corridor.rsus]:
        video = run_dir / f"{rsu_id}.mp4"
        if video.exists() and first is not None and rsu_id != first:
            video.unlink()
    if runner.vehicle is not None and runner.vehicle.record is not None:
        from vehicle.plot import plot_run
        from vehicle.record import write_run

        write_run(run_dir / "vehicle", runner.vehicle.record)
        try:
            plot_run(run_dir / "vehicle")
        except Exception as exc:  # plots are a convenience: the run's data is written
            print(f"[scenario] plots not written: {exc}", file=sys.stderr)
    (run_dir / "metrics.json").write_text(json.dumps(metrics, indent=2, default=str) + "\n")
