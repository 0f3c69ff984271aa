"""Road-hazard benchmark on simulator renders (issue 10): detection recall / false alarms and, end to end,
the AV's clearance from the hazard.

    python bench/hazard_bench.py [--quick] [--json] [--seeds 101 102] [--scenarios ...] [--clean ...]

Lockstep, one process, on a simulated clock: the sim ``World`` is stepped at 60 Hz; every RSU's view is
rendered with ``SimCamera.render`` at its 15 fps and run through the RSU's own pipeline (MotionDetector
-> SORT -> localiser -> ``rsu.hazard.HazardDetector``) and published by its ``RsuService`` over a
``LocalBus``. Each RSU has been running before the scenario starts: its motion and hazard background
models have learnt the empty road (as in ``bench/ev_bench.py``).

- **hazard scenarios** (``--scenarios``, default hazard_in_lane and hazard_falls) run end to end: a
  ``DdmService`` (fusion, hazard policy, command manager) and the AV's ``VehicleService`` (controller on
  the bicycle plant, GNSS localisation) on the same bus; the AV's true pose drives the sim AV, so the
  cameras see the car the controller moves;
- **hazard-free scenarios** (``--clean``, default rellis_ev_yield and ev_lights_never_on) run the RSUs
  only (the scripted AV and traffic) and count false alarms.

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

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import dataclasses  # noqa: E402
import json  # noqa: E402
import logging  # noqa: E402
import math  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from ddm.service import DdmService  # noqa: E402
from protocol.clock import SimClock  # noqa: E402
from protocol.corridor import VehicleConfig  # noqa: E402
from protocol.keys import all_rsus_expr, all_vehicles_expr  # noqa: E402
from protocol.messages import HazardAlert, PathSwitchCommand  # noqa: E402
from protocol.transport import LocalBus  # noqa: E402
from rsu.detect import MotionDetector  # noqa: E402
from rsu.frames import Frame  # noqa: E402
from rsu.hazard import HazardDetector, road_mask  # noqa: E402
from rsu.localize import Localizer  # noqa: E402
from rsu.service import RsuPipeline, RsuService  # noqa: E402
from rsu.track import FrameworkTracker  # noqa: E402
from sim.camera_source import SimCamera  # noqa: E402
from sim.scenario import load_scenario  # noqa: E402
from sim.world import World  # noqa: E402
from vehicle.service import VehicleService  # noqa: E402

cv2.setNumThreads(1)
HAZARD_SCENARIOS = ("hazard_in_lane", "hazard_falls")
CLEAN_SCENARIOS = ("rellis_ev_yield", "ev_lights_never_on")
TICK_S = 1.0 / 60.0
MOTION_WARMUP_FRAMES = 30


class _NullSource:
    """RsuService wants a source; the lockstep hands it frames directly."""

    source_id = "lockstep"
    fps = 15.0
    drops = 0

    def read(self, timeout_s=None):
        return None

    def close(self) -> None:
        pass


@dataclasses.dataclass
class _Rsu:
    rsu_id: str
    camera: SimCamera
    service: RsuService
    watched: np.ndarray  # road mask at full scale (bool)


def _make_rsus(scenario, world, bus, clock, rsu_ids, seed) -> list[_Rsu]:
    corridor = scenario.corridor
    empty = world.snapshot().model_copy(update={"actors": []})
    out = []
    for r in corridor.rsus:
        if rsu_ids and r.rsu_id not in rsu_ids:
            continue
        cam = SimCamera(corridor, r.rsu_id, seed=seed)
        det = MotionDetector()
        loc = Localizer(corridor, r)
        hz = HazardDetector(corridor.road, loc.mapper.to_ground, camera=r.camera)
        empty_img = cam.render(empty).image
        for _ in range(MOTION_WARMUP_FRAMES):  # an RSU that has been running: it has learnt the empty road
            det.detect(empty_img)
        hz.prime(empty_img)
        pipe = RsuPipeline(det, FrameworkTracker("B", 1, 3, 0.3), loc, hazards=hz)
        svc = RsuService(corridor, r.rsu_id, _NullSource(), pipe, bus, clock)
        watched = road_mask(r.camera, corridor.road, 1.0, right_margin_m=0.0, left_margin_m=0.0,
                            max_range_m=hz.cfg.max_range_m)
        out.append(_Rsu(r.rsu_id, cam, svc, watched))
    return out


def _project(rsu_cfg, x: float, y: float) -> tuple[float, float] | None:
    cam = rsu_cfg.camera
    pc = cam.rotation_world_to_camera @ (np.array([x, y, 0.0]) - cam.centre_world)
    if pc[2] <= 1.0:
        return None
    uv = cam.intrinsic_matrix @ pc
    return float(uv[0] / uv[2]), float(uv[1] / uv[2])


def _in_lane(road, actor) -> bool:
    _s, d = road.to_frenet(actor.pos_x_m, actor.pos_y_m)
    return d + actor.width_m / 2 > 0.0 and d - actor.width_m / 2 < road.lanes * road.lane_width_m


def run_one(name: str, seed: int, *, end_to_end: bool, duration_s: float | None, rsu_ids: list[str] | None,
            min_visible_s: float, match_m: float) -> dict:
    sc = load_scenario(name).with_overrides(seed=seed)
    if end_to_end and sc.av is not None:  # the AV's vehicle process starts where the scenario puts the AV
        vcs = tuple(dataclasses.replace(v, start_s_m=sc.av.start_s_m, start_lane=sc.av.lane,
                                        cruise_speed_mps=sc.av.speed_mps) if v.vehicle_id == sc.av.vehicle_id
                    else v for v in sc.corridor.vehicles)
        if not any(v.vehicle_id == sc.av.vehicle_id for v in vcs):
            vcs += (VehicleConfig(sc.av.vehicle_id, sc.av.start_s_m, sc.av.lane, sc.av.speed_mps),)
        sc = dataclasses.replace(sc, corridor=dataclasses.replace(sc.corridor, vehicles=vcs))
    corridor, road = sc.corridor, sc.corridor.road
    world = World(sc, seed=seed)
    clock = SimClock(0.0)
    bus = LocalBus()
    rsus = _make_rsus(sc, world, bus, clock, rsu_ids, seed)
    alerts: list[tuple[float, HazardAlert]] = []
    bus.subscribe(all_rsus_expr(corridor.corridor_id), lambda _k, m: alerts.append((clock.now(), m))
                  if isinstance(m, HazardAlert) else None)
    commands: list[PathSwitchCommand] = []
    ddm = veh = None
    av_id = sc.av.vehicle_id if sc.av is not None else None
    if end_to_end and av_id is not None:
        ddm = DdmService(bus, clock, corridor)
        veh = VehicleService(bus, clock, corridor, av_id, seed=seed)
        bus.subscribe(all_vehicles_expr(corridor.corridor_id, "cmd"), lambda _k, m: commands.append(m))
    end_s = min(sc.duration_s, duration_s) if duration_s else sc.duration_s
    fps = corridor.rsus[0].camera.fps
    frame_period = 1.0 / fps
    next_frame = frame_period
    next_ddm = 0.0
    visible_s: dict[tuple[str, str], float] = {}
    first_visible: dict[tuple[str, str], float] = {}
    min_clear = math.inf
    collisions = 0
    overlapped: set[str] = set()
    debris_seen: dict[str, object] = {}
    t_pipe = 0.0
    frames = 0
    while world.t_s < end_s - 1e-9:
        now = world.step(TICK_S)
        clock.advance(now - clock.now())
        if veh is not None:
            veh.step(now)
            st = veh.sim.truth
            world.traffic.set_external_pose(av_id, st.x_m, st.y_m, st.yaw_rad, max(st.vx_mps, 0.0))
        if ddm is not None and now >= next_ddm - 1e-9:
            ddm.step(now)
            next_ddm += 0.05
        if now < next_frame - 1e-9:
            continue
        next_frame += frame_period
        snap = world.snapshot()
        debris = [a for a in snap.actors if a.kind.value == "debris"]
        for a in debris:
            debris_seen[a.actor_id] = a
        for r in rsus:
            f = r.camera.render(snap)
            t0 = time.perf_counter()
            r.service._process(Frame(f.image, f.timestamp_s, f.frame_number, r.rsu_id))
            t_pipe += time.perf_counter() - t0
            frames += 1
            for a in debris:
                if not _in_lane(road, a):
                    continue
                uv = _project(corridor.rsu(r.rsu_id), a.pos_x_m, a.pos_y_m)
                if uv is None:
                    continue
                u, v = int(uv[0]), int(uv[1])
                if 0 <= v < r.watched.shape[0] and 0 <= u < r.watched.shape[1] and r.watched[v, u]:
                    key = (r.rsu_id, a.actor_id)
                    visible_s[key] = visible_s.get(key, 0.0) + frame_period
                    first_visible.setdefault(key, now)
        if veh is not None:  # clearance between the AV (true pose) and every hazard in a lane
            st = veh.sim.truth
            s_av, d_av = road.to_frenet(st.x_m, st.y_m)
            vc = corridor.vehicle(av_id)
            for a in debris:
                if not _in_lane(road, a):
                    continue
                s_h, d_h = road.to_frenet(a.pos_x_m, a.pos_y_m)
                if abs(s_av - s_h) < (vc.length_m + a.length_m) / 2:
                    overlapped.add(a.actor_id)
                    # footprint half-width across the road grows with the heading error
                    h_err = st.yaw_rad - road.pose_at(s_av, 0.0)[2]
                    half = (vc.width_m * abs(math.cos(h_err)) + vc.length_m * abs(math.sin(h_err))) / 2
                    gap = abs(d_av - d_h) - half - a.width_m / 2
                    min_clear = min(min_clear, gap)
                    if gap < 0:
                        collisions += 1
    # ---------------------------------------------------------------- scoring
    present_at: dict[str, tuple[float, float]] = {}
    for k, h in enumerate(sc.hazards):
        present_at[f"hz{k}"] = (h.appear_s, h.remove_s if h.remove_s is not None else math.inf)
    instances = {key for key, s in visible_s.items() if s >= min_visible_s}
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
        for aid, a in debris_seen.items():
            t0_, t1_ = present_at.get(aid, (0.0, math.inf))
            if t0_ <= t <= t1_ + 0.5 and _in_lane(road, a) and math.hypot(a.pos_x_m - m.pos_x_m,
                                                                             a.pos_y_m - m.pos_y_m) <= match_m:
                match = aid
                break
        if match is None:
            false_alarms.append([m.rsu_id, round(t, 2), round(m.pos_x_m, 1), round(m.pos_y_m, 1)])
            continue
        hazard_of_alert[m.hazard_id] = match
        key = (m.rsu_id, match)
        if key not in found:
            found[key] = t
    latencies = [found[k] - max(first_visible[k], present_at[k[1]][0]) for k in found if k in first_visible]
    out = dict(scenario=name, seed=seed, end_to_end=ddm is not None, instances=len(instances),
               found=len(instances & set(found)), missed=sorted(map(list, instances - set(found))),
               false_alarms=len(false_alarms), false_detail=false_alarms, detect_latency_s=latencies,
               clear_latency_s=clear_latency, frames=frames, pipeline_ms_per_frame=1000 * t_pipe / max(frames, 1))
    if veh is not None:
        st = veh.sim.truth
        s_av, _ = road.to_frenet(st.x_m, st.y_m)
        vc = corridor.vehicle(av_id)
        stop_gaps = []
        for aid, a in debris_seen.items():
            if aid in overlapped or not _in_lane(road, a):
                continue
            s_h, d_h = road.to_frenet(a.pos_x_m, a.pos_y_m)
            _s, d_av = road.to_frenet(st.x_m, st.y_m)
            in_path = abs(d_av - d_h) - (vc.width_m + a.width_m) / 2 < 1.0
            if in_path and s_av < s_h:
                stop_gaps.append(s_h - a.length_m / 2 - (s_av + vc.length_m / 2))
        out.update(min_clearance_m=None if math.isinf(min_clear) else round(min_clear, 3),
                   passed=len(overlapped), stopped_before=len(stop_gaps),
                   min_stop_gap_m=round(min(stop_gaps), 2) if stop_gaps else None, collisions=collisions,
                   av_final_x_m=round(st.x_m, 1), av_final_speed_mps=round(st.vx_mps, 2),
                   commands=sorted({(c.command_id, c.manoeuvre.value) for c in commands}),
                   ddm_hazard_decisions=ddm.counters["hazard_decisions"])
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
                        f"{r['false_alarms']}  {r['pipeline_ms_per_frame']:.0f} ms/frame")
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
        "pipeline_ms_per_frame": round(float(np.mean([r["pipeline_ms_per_frame"] for r in runs])), 1),
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
