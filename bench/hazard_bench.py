"""Road-hazard benchmark on simulator renders: detection recall / false alarms and, end to end,
the AV's clearance from the hazard.

    python bench/hazard_bench.py [--quick] [--json] [--seeds 101 102] [--scenarios ...] [--clean ...]

Lockstep, one process, on a simulated clock: ``scenario.lockstep.CorridorLockstep`` runs the sim
``World``, every RSU (``SimCamera`` renders its view at 15 fps; MotionDetector -> SORT -> EV classifier
-> localiser -> ``rsu.hazard.HazardDetector``; ``RsuService`` publishes), the ``DdmService`` (fusion,
EV and hazard policies, command manager) and the AV's ``VehicleService`` (controller on the bicycle
plant; its true pose drives the sim AV) over a ``LocalBus``. Each RSU has been running before the
scenario starts: its motion and hazard background models learnt the road from its own frames (``sim.warmup``).

- **hazard scenarios** (``--scenarios``, default hazard_in_lane and hazard_falls) run end to end;
- **hazard-free scenarios** (``--clean``, default rellis_ev_yield and ev_lights_never_on) run with the
  scripted AV (no vehicle process; the RSUs and the DDM run) and count false alarms.

Scoring uses ground truth (snapshots), never shown to the pipeline:

- a **hazard instance** is one debris object in a lane as watched by one RSU (its centre projects into
  the image within the RSU's watched road, ``HazardConfig.max_range_m``) for at least ``--min-visible-s``;
  it is **found** if that RSU raises ``appear`` for a position within ``--match-m`` of it while it lies
  there. ``hazard_recall`` = found / instances; ``detect_latency_median_s`` from the later of the object
  landing and it coming into view to the ``appear``;
- a **false alarm** is an ``appear`` that matches no debris in a lane (``hazard_false_alarms``, summed
  over all runs, hazard and hazard-free);
- **clearance** (end to end): while the AV's and a hazard's extents along the road overlap, the lateral
  gap between the AV's side and the hazard's side; ``min_clearance_m`` is the smallest over the runs
  (>= 1 m asked). A hazard the AV did not pass counts through its stop: ``stopped_before`` and the gap
  from the AV's front bumper to it (``min_stop_gap_m``); a collision is a negative clearance while
  overlapping.

With ``--json`` the last line is one JSON object of the figures.
"""

from __future__ import annotations

from bench._setup import ROOT  # noqa: F401  first: one thread per numeric library, before numpy loads

# isort: split
import argparse  # noqa: E402
import dataclasses  # noqa: E402
import json  # noqa: E402
import logging  # noqa: E402
import math  # noqa: E402
import statistics  # noqa: E402
import time  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from protocol.keys import corridor_expr  # noqa: E402
from protocol.messages import HazardAlert  # noqa: E402
from rsu.hazard import HazardConfig, road_mask  # noqa: E402
from scenario.lockstep import CorridorLockstep, LockstepConfig  # noqa: E402
from sim.scenario import load_scenario  # noqa: E402

cv2.setNumThreads(1)
HAZARD_SCENARIOS = ("hazard_in_lane", "hazard_falls")
CLEAN_SCENARIOS = ("rellis_ev_yield", "ev_lights_never_on")


def _in_lane(road, actor) -> bool:
    _s, d = road.to_frenet(actor.pos_x_m, actor.pos_y_m)
    return d + actor.width_m / 2 > 0.0 and d - actor.width_m / 2 < road.lanes * road.lane_width_m


def _project(rsu_cfg, x: float, y: float) -> tuple[float, float] | None:
    cam = rsu_cfg.camera
    pc = cam.rotation_world_to_camera @ (np.array([x, y, 0.0]) - cam.centre_world)
    if pc[2] <= 1.0:
        return None
    uv = cam.intrinsic_matrix @ pc
    return float(uv[0] / uv[2]), float(uv[1] / uv[2])


class _Score:
    """Ground-truth bookkeeping of one run, fed with the simulator's snapshots (evaluation only)."""

    def __init__(self, corridor, rsu_ids: list[str], av_id: str | None, end_to_end: bool) -> None:
        self.corridor, self.road = corridor, corridor.road
        self.rsus = [corridor.rsu(r) for r in rsu_ids]
        self.watched = {r.rsu_id: road_mask(r.camera, self.road, 1.0, right_margin_m=0.0, left_margin_m=0.0,
                                            max_range_m=HazardConfig().max_range_m) for r in self.rsus}
        self.av_id, self.end_to_end = av_id, end_to_end
        self.visible_s: dict[tuple[str, str], float] = {}
        self.first_visible: dict[tuple[str, str], float] = {}
        self.debris: dict[str, object] = {}
        self.min_clear = math.inf
        self.collisions = 0
        self.overlapped: set[str] = set()
        self.last_t: float | None = None
        self.av = None

    def on_snapshot(self, snap) -> None:
        t = snap.sim_time_s
        dt = 0.0 if self.last_t is None else t - self.last_t
        self.last_t = t
        debris = [a for a in snap.actors if a.kind.value == "debris" and _in_lane(self.road, a)]
        for a in debris:
            self.debris[a.actor_id] = a
            for r in self.rsus:
                uv = _project(r, a.pos_x_m, a.pos_y_m)
                if uv is None:
                    continue
                u, v = int(uv[0]), int(uv[1])
                m = self.watched[r.rsu_id]
                if 0 <= v < m.shape[0] and 0 <= u < m.shape[1] and m[v, u]:
                    key = (r.rsu_id, a.actor_id)
                    self.visible_s[key] = self.visible_s.get(key, 0.0) + dt
                    self.first_visible.setdefault(key, t)
        av = next((a for a in snap.actors if a.actor_id == self.av_id), None)
        if av is None or not self.end_to_end:
            return
        self.av = av
        s_av, d_av = self.road.to_frenet(av.pos_x_m, av.pos_y_m)
        h_err = av.heading_rad - self.road.pose_at(s_av, 0.0)[2]
        half = (av.width_m * abs(math.cos(h_err)) + av.length_m * abs(math.sin(h_err))) / 2
        half_len = (av.length_m * abs(math.cos(h_err)) + av.width_m * abs(math.sin(h_err))) / 2
        for a in debris:
            s_h, d_h = self.road.to_frenet(a.pos_x_m, a.pos_y_m)
            if abs(s_av - s_h) < half_len + a.length_m / 2:
                self.overlapped.add(a.actor_id)
                gap = abs(d_av - d_h) - half - a.width_m / 2
                self.min_clear = min(self.min_clear, gap)
                if gap < 0:
                    self.collisions += 1


def run_one(name: str, seed: int, *, end_to_end: bool, duration_s: float | None, rsu_ids: list[str] | None,
            min_visible_s: float, match_m: float) -> dict:
    """One scenario run on ``scenario.lockstep.CorridorLockstep`` (hazard detection on in every RSU);
    ``end_to_end`` False: the AV is scripted (no vehicle process), the RSUs and DDM still run."""
    sc = load_scenario(name).with_overrides(seed=seed)
    if not end_to_end:
        sc = dataclasses.replace(sc, av=None)
    cfg = LockstepConfig(scenario=name, seed=seed, duration_s=min(sc.duration_s, duration_s or sc.duration_s))
    runner = CorridorLockstep(cfg, scenario=sc)
    corridor = runner.corridor
    all_rsus = [r.rsu_id for r in corridor.rsus]
    for rid in all_rsus:
        if rsu_ids and rid not in rsu_ids:
            runner.kill_rsu(rid)
    watched = [r for r in all_rsus if not rsu_ids or r in rsu_ids]
    score = _Score(corridor, watched, runner.vehicle_id, end_to_end)
    alerts: list[tuple[float, HazardAlert]] = []
    commands: dict[str, str] = {}

    def on_message(_key, m) -> None:
        kind = m.KIND
        if kind == "HazardAlert":
            alerts.append((runner.clock.now(), m))
        elif kind == "WorldSnapshot":
            score.on_snapshot(m)
        elif kind == "PathSwitchCommand":
            commands.setdefault(m.command_id, m.manoeuvre.value)

    runner.bus.subscribe(corridor_expr(corridor.corridor_id), on_message)
    t0 = time.perf_counter()
    metrics = runner.run()
    wall = time.perf_counter() - t0
    road = corridor.road
    # ---------------------------------------------------------------- scoring
    present_at = {f"hz{k}": (h.appear_s, h.remove_s if h.remove_s is not None else math.inf)
                  for k, h in enumerate(sc.hazards)}
    instances = {key for key, v in score.visible_s.items() if v >= min_visible_s}
    found: dict[tuple[str, str], float] = {}
    false_alarms = []
    clear_latency = []
    hazard_of_alert: dict[str, str] = {}
    for t, m in alerts:
        if m.state.value == "clear":
            aid = hazard_of_alert.get(m.hazard_id)
            if aid is not None and present_at[aid][1] < math.inf:
                clear_latency.append(t - present_at[aid][1])
            continue
        if m.state.value != "appear":
            continue
        match = None
        for aid, a in score.debris.items():
            t0_, t1_ = present_at.get(aid, (0.0, math.inf))
            if t0_ <= t <= t1_ + 0.5 and math.hypot(a.pos_x_m - m.pos_x_m, a.pos_y_m - m.pos_y_m) <= match_m:
                match = aid
                break
        if match is None:
            false_alarms.append([m.rsu_id, round(t, 2), round(m.pos_x_m, 1), round(m.pos_y_m, 1)])
            continue
        hazard_of_alert[m.hazard_id] = match
        found.setdefault((m.rsu_id, match), t)
    latencies = [found[k] - max(score.first_visible[k], present_at[k[1]][0]) for k in found
                 if k in score.first_visible]
    frames = max(1, metrics.get("frames", 0))
    out = dict(scenario=name, seed=seed, end_to_end=end_to_end, instances=len(instances),
               found=len(instances & set(found)), missed=sorted(map(list, instances - set(found))),
               false_alarms=len(false_alarms), false_detail=false_alarms, detect_latency_s=latencies,
               clear_latency_s=clear_latency, frames=frames, ms_per_frame=1000 * wall / frames)
    if end_to_end and score.av is not None:
        av = score.av
        s_av, d_av = road.to_frenet(av.pos_x_m, av.pos_y_m)
        stop_gaps = []
        for aid, a in score.debris.items():
            if aid in score.overlapped:
                continue
            s_h, d_h = road.to_frenet(a.pos_x_m, a.pos_y_m)
            if s_av < s_h and abs(d_av - d_h) - (av.width_m + a.width_m) / 2 < 1.0:
                stop_gaps.append(s_h - a.length_m / 2 - (s_av + av.length_m / 2))
        out.update(min_clearance_m=None if math.isinf(score.min_clear) else round(score.min_clear, 3),
                   passed=len(score.overlapped), stopped_before=len(stop_gaps),
                   min_stop_gap_m=round(min(stop_gaps), 2) if stop_gaps else None, collisions=score.collisions,
                   av_final_x_m=round(av.pos_x_m, 1), av_final_speed_mps=round(av.speed_mps, 2),
                   commands=sorted(commands.items()),
                   ddm_hazard_decisions=runner.ddm.counters["hazard_decisions"] if runner.ddm else 0)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenarios", nargs="*", default=list(HAZARD_SCENARIOS), help="hazard scenarios (end to end)")
    ap.add_argument("--clean", nargs="*", default=list(CLEAN_SCENARIOS), help="hazard-free scenarios (RSUs only)")
    ap.add_argument("--seeds", nargs="+", type=int, default=[101, 102])
    ap.add_argument("--duration-s", type=float, default=20.0, help="simulated seconds per run (scenario cap)")
    ap.add_argument("--rsus", nargs="*", default=None, help="only these RSUs (default all)")
    ap.add_argument("--min-visible-s", type=float, default=2.0)
    ap.add_argument("--match-m", type=float, default=2.5)
    ap.add_argument("--quick", action="store_true",
                    help="hazard_in_lane end to end, 1 seed, 12 s, rsu2+rsu3 only; no hazard-free run")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.WARNING)
    if args.quick:
        args.scenarios, args.clean, args.seeds = ["hazard_in_lane"], [], args.seeds[:1]
        args.duration_s, args.rsus = 12.0, args.rsus or ["rsu2", "rsu3"]
    t0 = time.perf_counter()
    runs = []
    for e2e, names in ((True, args.scenarios), (False, args.clean)):
        for name in names:
            for seed in args.seeds:
                r = run_one(name, seed, end_to_end=e2e, duration_s=args.duration_s, rsu_ids=args.rsus,
                            min_visible_s=args.min_visible_s, match_m=args.match_m)
                runs.append(r)
                line = (f"{name:20s} seed {seed:4d}: found {r['found']}/{r['instances']}  false alarms "
                        f"{r['false_alarms']}  {r['ms_per_frame']:.0f} ms/frame (render + RSU + DDM + vehicle)")
                if r["end_to_end"]:
                    line += (f"  | clearance {r['min_clearance_m']} m, passed {r['passed']}, stopped before "
                             f"{r['stopped_before']} (gap {r['min_stop_gap_m']}), collisions {r['collisions']}, "
                             f"commands {[m for _c, m in r['commands']]}")
                print(line, flush=True)
                if r["false_detail"]:
                    print("    false alarms (rsu, t, x, y):", r["false_detail"])
                if r["missed"]:
                    print("    missed (rsu, debris):", r["missed"])
    inst = sum(r["instances"] for r in runs)
    lat = [x for r in runs for x in r["detect_latency_s"]]
    clr = [x for r in runs for x in r["clear_latency_s"]]
    e2e_runs = [r for r in runs if r["end_to_end"]]
    clearances = [r["min_clearance_m"] for r in e2e_runs if r["min_clearance_m"] is not None]
    stop_gaps = [r["min_stop_gap_m"] for r in e2e_runs if r["min_stop_gap_m"] is not None]
    figures = {
        "hazard_recall": round(sum(r["found"] for r in runs) / inst, 3) if inst else None,
        "hazard_false_alarms": sum(r["false_alarms"] for r in runs),
        "min_clearance_m": round(min(clearances), 3) if clearances else None,
        "hazard_instances": inst,
        "false_alarms_hazard_free": sum(r["false_alarms"] for r in runs if not r["end_to_end"]),
        "detect_latency_median_s": round(statistics.median(lat), 2) if lat else None,
        "clear_latency_median_s": round(statistics.median(clr), 2) if clr else None,
        "passed": sum(r.get("passed", 0) for r in e2e_runs),
        "stopped_before": sum(r.get("stopped_before", 0) for r in e2e_runs),
        "min_stop_gap_m": min(stop_gaps) if stop_gaps else None,
        "collisions": sum(r.get("collisions", 0) for r in e2e_runs),
        "runs": len(runs),
        "seeds": args.seeds,
        "ms_per_frame": round(float(np.mean([r["ms_per_frame"] for r in runs])), 1),
        "wall_s": round(time.perf_counter() - t0, 1),
    }
    print(f"hazard recall {figures['hazard_recall']} over {inst} instances; false alarms "
          f"{figures['hazard_false_alarms']} ({figures['false_alarms_hazard_free']} on hazard-free scenarios); "
          f"detection latency median {figures['detect_latency_median_s']} s; end to end: min clearance "
          f"{figures['min_clearance_m']} m (>= 1 m asked), passed {figures['passed']}, stopped before "
          f"{figures['stopped_before']}, collisions {figures['collisions']}")
    if args.json:
        print(json.dumps(figures))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
