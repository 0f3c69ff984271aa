"""SUMO traffic benchmark: the cost of SUMO beside the project's own traffic, and the corridor on SUMO traffic.

    python bench/sumo_bench.py [--parts step,lockstep,process,large] [--seeds 10] [--large-seeds 10]
                               [--cache DIR] [--quick] [--json]

- **step** (``sumo_step_ms_N`` / ``own_step_ms_N``, ``world_snapshot_ms_N`` / ``own_snapshot_ms_N``): one world
  step (SUMO through libsumo, reading every vehicle back: ``sim.sumo.traffic.SumoTraffic``; the project's IDM/MOBIL:
  ``sim.traffic.IdmTraffic``) and the ``WorldSnapshot`` built from it, mean CPU ms over 100 steps of 0.05 s after 20
  of warm-up, with N = 50, 200 and 1,000 vehicles on a straight 4-lane road of 8 km (the same seeded population for
  both; SUMO's flows off, so the counts match), in one run (``sumo_over_own_step_N``: the ratio);
- **lockstep** (``lockstep_runs`` / ``lockstep_runs_yielded``): ``rellis_ev_yield`` with ``--traffic sumo`` on the
  whole corridor in one process (``scenario/lockstep.py``: simulator, 4 RSUs rendering and processing pixels, DDM,
  vehicle), seeds 1..N, judged by the one strict yield judge (``scenario/outcome.py``);
- **process** (``process_runs`` / ``process_runs_yielded``, ``rsu_fps_min``): the same as real processes over Zenoh
  (``iea up --traffic sumo``), seeds 1..N; ``rsu_fps_min``: of each camera's 15 fps, the fewest processed in any
  1 s Health period of any RSU of any run (``bench/e2e_rsu_load.py``);
- **faults** (not in the default parts; ``fault_rows`` / ``fault_rows_passed``): the corridor fault table
  (``scenario/corridor_faults.py``: latency, loss, outages, an RSU killed, the DDM restarted) on SUMO traffic;
- **large** (``large_runs`` / ``large_runs_yielded``, ``large_ev_delay_s``): ``motorway_ev_ramp`` (3.4 km, three
  lanes, on-ramp, 8 RSUs, 1,500 veh/h, the EV from the ramp) in lockstep, seeds 1..N, with the EV's delay.

``--cache DIR`` keeps each run's metrics there and reuses them (the runs take minutes each on two loaded cores).
The last line of the output is one JSON line with the figures.
"""

from __future__ import annotations

import argparse
import json
import logging
import statistics
import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import bench._setup  # noqa: E402,F401  (one thread per numeric library)
from protocol.road import Road, Segment  # noqa: E402
from sim.scenario import TrafficSpec, load_scenario  # noqa: E402

COUNTS = (50, 200, 1000)
ROAD_M = 8000.0
LANES = 4
WARMUP_STEPS = 20
STEPS = 100
DT_S = 0.05


def step_scenario(n: int):
    """rellis_ev_yield's corridor stretched to an 8 km 4-lane road with ~n background vehicles (no AV, EV)."""
    sc = load_scenario("rellis_ev_yield")
    road = Road(0.0, 0.0, 0.0, (Segment("straight", ROAD_M),), lanes=LANES, lane_width_m=3.7, speed_limit_mps=25.0)
    span = 6000.0
    density = n * 1000.0 / (span * LANES)
    traffic = replace(TrafficSpec(), density_veh_per_km_lane=density, speed_mps=20.0, spawn_s_min_m=0.0,
                      spawn_s_max_m=span)
    return replace(sc, corridor=replace(sc.corridor, road=road), traffic=traffic, av=None, ev=None, distractors=(),
                   hazards=(), name=f"bench_{n}")


def time_world(world, steps: int = STEPS) -> tuple[float, float, int]:
    """(mean step ms, mean snapshot ms, vehicles) over ``steps`` after the warm-up: CPU time of this process
    (libsumo runs SUMO in it), so other processes on a shared machine do not count."""
    for _ in range(WARMUP_STEPS):
        world.step(DT_S)
    step_s = snap_s = 0.0
    for _ in range(steps):
        t0 = time.process_time()
        world.step(DT_S)
        t1 = time.process_time()
        snap = world.snapshot()
        snap_s += time.process_time() - t1
        step_s += t1 - t0
    return step_s / steps * 1e3, snap_s / steps * 1e3, len(snap.actors)


def step_figures(counts=COUNTS, steps: int = STEPS) -> dict[str, Any]:
    import numpy as np

    from sim.sumo.traffic import SumoTraffic
    from sim.traffic import build_population
    from sim.world import World

    out: dict[str, Any] = {}
    for n in counts:
        sc = step_scenario(n)
        own = World(sc, seed=1)
        own_ms, own_snap_ms, own_n = time_world(own, steps)
        population = build_population(sc, np.random.default_rng(1))
        sumo = World(sc, seed=1, traffic=SumoTraffic(sc, 1, population=population, flows=False))
        sumo_ms, sumo_snap_ms, sumo_n = time_world(sumo, steps)
        sumo.close()
        out.update({f"sumo_step_ms_{n}": round(sumo_ms, 3), f"own_step_ms_{n}": round(own_ms, 3),
                    f"world_snapshot_ms_{n}": round(sumo_snap_ms, 3), f"own_snapshot_ms_{n}": round(own_snap_ms, 3),
                    f"sumo_over_own_step_{n}": round(sumo_ms / own_ms, 2) if own_ms > 0 else None,
                    f"vehicles_sumo_{n}": sumo_n, f"vehicles_own_{n}": own_n})
        print(f" {n:>5} vehicles: SUMO step {sumo_ms:7.2f} ms + snapshot {sumo_snap_ms:6.2f} ms ({sumo_n} actors) | "
              f"own step {own_ms:7.2f} ms + snapshot {own_snap_ms:6.2f} ms ({own_n} actors)", flush=True)
    return out


def cached(cache: Path | None, name: str, fn) -> dict[str, Any]:
    if cache is not None and (cache / f"{name}.json").is_file():
        return json.loads((cache / f"{name}.json").read_text())
    m = fn()
    if cache is not None:
        cache.mkdir(parents=True, exist_ok=True)
        (cache / f"{name}.json").write_text(json.dumps(m, default=str))
    return m


def lockstep_run(scenario: str, seed: int, duration_s: float | None = None) -> dict[str, Any]:
    from scenario.lockstep import CorridorLockstep, LockstepConfig, ev_lights_on
    from scenario.outcome import judge_run

    runner = CorridorLockstep(LockstepConfig(scenario=scenario, seed=seed, traffic="sumo", duration_s=duration_s))
    m = runner.run()
    ok, why = judge_run(m, ev_lights_on=ev_lights_on(runner.scenario, duration_s))
    keep = ("yield", "collision", "min_gap_to_any_vehicle_m", "min_gap_with", "ev_delay_s", "wall_s", "frames", "first_alert_rsu",
            "commands", "traffic", "seed")
    return {**{k: m.get(k) for k in keep}, "passed": ok, "verdict": why}


def process_run(seed: int, run_root: Path, duration_s: float) -> dict[str, Any]:
    from bench.e2e_rsu_load import rsu_load
    from deploy.up import Up
    from scenario.outcome import judge_run

    up = Up(scenario="rellis_ev_yield", port=0, run_dir=run_root / f"sumo-seed{seed}", duration_s=duration_s,
            seed=seed, restart="no", record=True, traffic="sumo")
    try:
        up.start()
        deadline = time.monotonic() + duration_s + 40
        while up.group.running("sim") and time.monotonic() < deadline:
            time.sleep(0.2)
        time.sleep(0.5)
    finally:
        up.stop()
    m = up.metrics()
    ok, why = judge_run(m, ev_lights_on=True)
    load = rsu_load(up.run_dir / "run.mcap")
    return {"seed": seed, "yield": m.get("yield"), "passed": ok, "verdict": why, "collision": m.get("collision"),
            "min_gap_to_any_vehicle_m": m.get("min_gap_to_any_vehicle_m"), "min_gap_with": m.get("min_gap_with"),
            "rsu_fps_min": min((ld["fps_min"] for ld in load.values()), default=None), "exit_codes": m.get("exit_codes")}


def summary_line(kind: str, seed: int, r: dict[str, Any]) -> str:
    y = r.get("yield") or {}
    return (f" {kind} seed {seed:>2}: {'PASS' if r.get('passed') else 'FAIL'} {r.get('verdict', '')[:110]}"
            f" | EV delay {y.get('ev_delay_s')} s" + (f" | fps min {r['rsu_fps_min']}" if "rsu_fps_min" in r else ""))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--parts", default="step,lockstep,process,large")
    ap.add_argument("--seeds", type=int, default=10, help="seeds 1..N of rellis_ev_yield (lockstep and process)")
    ap.add_argument("--large-seeds", type=int, default=10, help="seeds 1..N of motorway_ev_ramp (lockstep)")
    ap.add_argument("--cache", default=None, help="keep and reuse each run's metrics in this folder")
    ap.add_argument("--runs", default=None, help="run folders of the process runs (default: a temporary folder)")
    ap.add_argument("--quick", action="store_true", help="50 and 200 vehicles, 2 seeds of each")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.WARNING)
    from sim.sumo import sumo_missing

    if (why := sumo_missing()) is not None:
        print(f"sumo_bench: {why}", file=sys.stderr)
        return 2
    parts = set(args.parts.split(","))
    seeds = 2 if args.quick else args.seeds
    large_seeds = 2 if args.quick else args.large_seeds
    cache = Path(args.cache) if args.cache else None
    fig: dict[str, Any] = {}
    if "step" in parts:
        print(f"== world step, SUMO vs the project's traffic ({STEPS} steps of {DT_S} s, {LANES}-lane {ROAD_M / 1000:.0f} km road)")
        counts = COUNTS[:2] if args.quick else COUNTS
        fig.update(cached(cache, f"step-{'-'.join(map(str, counts))}", lambda: step_figures(counts)))
    if "lockstep" in parts:
        print(f"== rellis_ev_yield on SUMO traffic, lockstep, seeds 1..{seeds}", flush=True)
        runs = []
        for seed in range(1, seeds + 1):
            r = cached(cache, f"lockstep-{seed}", lambda seed=seed: lockstep_run("rellis_ev_yield", seed))
            print(summary_line("lockstep", seed, r), flush=True)
            runs.append(r)
        fig.update(lockstep_runs=len(runs), lockstep_runs_yielded=sum(r["passed"] for r in runs))
    if "process" in parts:
        import tempfile

        print(f"== rellis_ev_yield on SUMO traffic, processes over Zenoh (iea up --traffic sumo), seeds 1..{seeds}",
              flush=True)
        root = Path(args.runs or tempfile.mkdtemp(prefix="sumo-bench-"))
        runs = []
        for seed in range(1, seeds + 1):
            r = cached(cache, f"process-{seed}", lambda seed=seed: process_run(seed, root, 30.0))
            print(summary_line("process", seed, r), flush=True)
            runs.append(r)
        fps = [r["rsu_fps_min"] for r in runs if r.get("rsu_fps_min") is not None]
        fig.update(process_runs=len(runs), process_runs_yielded=sum(r["passed"] for r in runs),
                   rsu_fps_min=min(fps) if fps else None)
    if "large" in parts:
        print(f"== motorway_ev_ramp (3.4 km, 3 lanes, on-ramp, 8 RSUs, 1500 veh/h), lockstep, seeds 1..{large_seeds}",
              flush=True)
        runs = []
        for seed in range(1, large_seeds + 1):
            r = cached(cache, f"large-{seed}", lambda seed=seed: lockstep_run("motorway_ev_ramp", seed))
            print(summary_line("large", seed, r), flush=True)
            runs.append(r)
        delays = [r["yield"]["ev_delay_s"] for r in runs if (r.get("yield") or {}).get("ev_delay_s") is not None]
        fig.update(large_runs=len(runs), large_runs_yielded=sum(r["passed"] for r in runs),
                   large_ev_delay_s=[round(d, 3) for d in delays],
                   large_ev_delay_s_median=round(statistics.median(delays), 3) if delays else None)
    if "faults" in parts:
        from scenario.corridor_faults import corridor_faults

        print("== the corridor fault table (scenario/corridor_faults.py) on SUMO traffic, lockstep", flush=True)
        rows = corridor_faults(quick=args.quick, traffic="sumo")
        for r in rows:
            print(f" {r.name:<40} {'PASS' if r.passed else 'FAIL'} {r.outcome[:100]}", flush=True)
        fig.update(fault_rows=len(rows), fault_rows_passed=sum(r.passed for r in rows))
    if args.json:
        print(json.dumps(fig))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
