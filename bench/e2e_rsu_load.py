"""What each RSU kept up with in a process run of ``bench/e2e_bench.py``, from the run's recording
(``iea up`` records every key of the corridor into ``<run folder>/run.mcap``, ``deploy/record.py``):

- per RSU, from its 1 Hz ``Health``: of the camera's frames per second (``rates_hz.camera``), those processed
  (``fps``: camera fps x processed / (processed + passed over) in the period) and the raw count of frames
  processed per second (``rate_hz``: ``rates_hz.frames``), the camera frames it passed over because it came late
  (``drops.source``: it processes the newest frames, not a queue), the frames' age when their ObjectList went
  out (``latency_ms.frame_age``) and the CPU milliseconds per frame of each stage (``latency_ms.{stage}_cpu``:
  render, detect, track, classify, localize, hazard, publish). Only the periods wholly inside the simulator's
  run count (``WARMUP_PERIODS`` at the start excepted: none);
- the split of lights on -> EvAlert at the first processed frame with the lamps lit: the first ObjectList of the
  RSU that raised the first alert whose frame was captured after lights on (its ``measurement_time``, the
  snapshot's stamp), published at its stamp.

Pure functions of the recording; stamps are the publishers' wall clocks on one host.
"""

from __future__ import annotations

import statistics
from pathlib import Path
from typing import Any

WARMUP_PERIODS = 0
"""Health periods of an RSU not counted at the start of a run (none: its simulated camera renders the static scenes
before its first frame, and the share of the camera's frames processed needs no whole period)."""
STAGES = ("render", "detect", "track", "classify", "localize", "hazard", "publish")


def _messages(path: Path, kinds: set[str]) -> list[tuple[str, Any]]:
    from deploy.record import read_recording
    from protocol.codec import decode

    return [(m.key, decode(m.payload)) for m in read_recording(path) if m.kind in kinds]


def rsu_load(path: str | Path) -> dict[str, dict[str, Any]]:
    """Per RSU id: fps_min / fps_median (processed), camera_fps, frames_dropped (last count), frame_age_ms_median,
    frame_age_ms_max and cpu_ms_per_frame {stage: mean over the periods}; {} when ``path`` is missing."""
    path = Path(path)
    if not path.is_file():
        return {}
    msgs = _messages(path, {"Health", "WorldSnapshot"})
    snaps = [m.stamp for _k, m in msgs if m.KIND == "WorldSnapshot"]
    if not snaps:
        return {}
    t0, t1 = min(snaps), max(snaps)
    health: dict[str, list[Any]] = {}
    for _key, m in msgs:
        if m.KIND == "Health" and m.role.value == "rsu":
            health.setdefault(m.src, []).append(m)
    out = {}
    for rsu_id, hs in sorted(health.items()):
        # periods ending inside the simulator's run (one that runs past the last snapshot counts frames that
        # never came), the first WARMUP_PERIODS excepted
        idx = [i for i, h in enumerate(hs) if t0 < h.stamp <= t1][WARMUP_PERIODS:]
        running = [hs[i] for i in idx]
        if not running:
            continue
        # the raw count of the first period is partial (the RSU started within it, before the simulator)
        rates = [h.rates_hz.get("frames", 0.0) for h in (running[1:] or running)]
        per_period = [(f, hs[i].latency_ms.get("detect_cpu")) for i in idx
                      if (f := _camera_frames_processed_hz(hs[i - 1] if i > 0 else None, hs[i])) is not None]
        fps = [f for f, _d in per_period] or [0.0]
        ages = [h.latency_ms["frame_age"] for h in running if "frame_age" in h.latency_ms]
        # CPU per frame in steady state: the first period also holds the one-off costs of the first frames (body
        # models, lamp sprites and lookup tables built on first use)
        steady = running[1:] or running
        cpu = {s: round(statistics.fmean(h.latency_ms[f"{s}_cpu"] for h in steady if f"{s}_cpu" in h.latency_ms), 2)
               for s in STAGES if any(f"{s}_cpu" in h.latency_ms for h in steady)}
        out[rsu_id] = {
            "fps_min": round(min(fps), 2), "fps_median": round(statistics.median(fps), 2),
            "rate_min_hz": round(min(rates), 2), "rate_median_hz": round(statistics.median(rates), 2),
            "camera_fps": running[-1].rates_hz.get("camera"), "frames_dropped": hs[-1].drops.get("source", 0),
            "frames_dropped_running": running[-1].drops.get("source", 0)
            - (hs[idx[0] - 1].drops.get("source", 0) if idx[0] > 0 else 0),
            "frame_age_ms_median": round(statistics.median(ages), 1) if ages else None,
            "frame_age_ms_max": round(max(h.latency_ms.get("frame_age_max", 0.0) for h in running), 1) if ages else None,
            "cpu_ms_per_frame": cpu, "cpu_ms_per_frame_total": round(sum(cpu.values()), 2), "periods": len(running),
            "fps_detect_cpu_ms": [(round(f, 2), d) for f, d in per_period if d is not None]}
    return out


def _camera_frames_processed_hz(prev: Any | None, h: Any) -> float | None:
    """Of the camera's frames in the period ending at Health ``h``, those processed, per second of camera time:
    camera fps x processed / (processed + passed over) (``drops.source`` is cumulative: its rise since ``prev``,
    the RSU's previous Health; None: ``h`` is its first, the period its uptime).
    The raw count per 1 s period (``rates_hz.frames``) moves +-1 frame with the period's phase even when no frame
    is dropped (snapshots come at 20 Hz, frames of a 15 fps camera 50 or 100 ms apart)."""
    camera = h.rates_hz.get("camera") or 0.0
    period_s = h.uptime_s if prev is None else h.stamp - prev.stamp
    n = h.rates_hz.get("frames", 0.0) * max(period_s, 0.0)
    d = max(h.drops.get("source", 0) - (0 if prev is None else prev.drops.get("source", 0)), 0)
    return camera * n / (n + d) if n + d > 0 else None  # None: no camera frame in the period


def first_lit_frame_s(path: str | Path, rsu_id: str | None, lights_on_s: float | None) -> float | None:
    """Publication stamp of ``rsu_id``'s first ObjectList whose frame was captured at or after ``lights_on_s``."""
    path = Path(path)
    if rsu_id is None or lights_on_s is None or not path.is_file():
        return None
    stamps = [m.stamp for _k, m in _messages(path, {"ObjectList"})
              if m.rsu_id == rsu_id and m.measurement_time >= lights_on_s]
    return min(stamps) if stamps else None


def print_load(runs: list[dict[str, Any]]) -> None:
    """One line per RSU over the runs: processed fps (min of the periods, min over runs), drops, frame age, CPU."""
    by_rsu: dict[str, list[dict[str, Any]]] = {}
    for r in runs:
        for rsu_id, load in (r.get("rsu_load") or {}).items():
            by_rsu.setdefault(rsu_id, []).append(load)
    if not by_rsu:
        print(" per-RSU load: no recording")
        return
    print(f"\n per RSU over {len(runs)} process runs (Health, 1 s periods ending inside the simulator's run; fps: of "
          "the camera's frames, those processed; raw: frames counted per period, the first one excepted)")
    print(f" {'rsu':<6} {'fps min':>7} {'median':>7} {'raw min':>7} {'camera':>6} {'dropped':>8} {'age ms':>7} {'age max':>8}  "
          "CPU ms per frame by stage")
    for rsu_id, loads in sorted(by_rsu.items()):
        cpu = {s: statistics.fmean(ld["cpu_ms_per_frame"].get(s, 0.0) for ld in loads) for s in STAGES}
        ages = [ld["frame_age_ms_median"] for ld in loads if ld["frame_age_ms_median"] is not None]
        age_max = max((ld["frame_age_ms_max"] for ld in loads if ld["frame_age_ms_max"] is not None), default=None)
        print(f" {rsu_id:<6} {min(ld['fps_min'] for ld in loads):7.1f} "
              f"{statistics.median(ld['fps_median'] for ld in loads):7.1f} {min(ld['rate_min_hz'] for ld in loads):7.1f} "
              f"{loads[0]['camera_fps'] or 0:6.1f} {sum(ld['frames_dropped_running'] for ld in loads):8d} "
              f"{statistics.median(ages) if ages else float('nan'):7.0f} {age_max or float('nan'):8.0f}  "
              + " ".join(f"{s} {v:.1f}" for s, v in cpu.items()) + f" = {sum(cpu.values()):.1f}")


def load_figures(runs: list[dict[str, Any]]) -> dict[str, Any]:
    """The JSON figures: rsu_fps_min (every RSU, every period, every run), per RSU the median CPU ms per stage."""
    loads = [(rsu_id, ld) for r in runs for rsu_id, ld in (r.get("rsu_load") or {}).items()]
    if not loads:
        return {"rsu_fps_min": None}
    cpu: dict[str, dict[str, float]] = {}
    for rsu_id in sorted({rid for rid, _ in loads}):
        mine = [ld for rid, ld in loads if rid == rsu_id]
        cpu[rsu_id] = {s: round(statistics.median(ld["cpu_ms_per_frame"].get(s, 0.0) for ld in mine), 2)
                       for s in STAGES}
        cpu[rsu_id]["fps_min"] = min(ld["fps_min"] for ld in mine)
        cpu[rsu_id]["rate_min_hz"] = min(ld["rate_min_hz"] for ld in mine)
        cpu[rsu_id]["frames_dropped"] = sum(ld["frames_dropped"] for ld in mine)
        cpu[rsu_id]["frames_dropped_running"] = sum(ld["frames_dropped_running"] for ld in mine)
    ages = [ld["frame_age_ms_max"] for _r, ld in loads if ld["frame_age_ms_max"] is not None]
    return {"rsu_fps_min": min(ld["fps_min"] for _r, ld in loads),
            "rsu_rate_min_hz": min(ld["rate_min_hz"] for _r, ld in loads), "rsu_load": cpu,
            "rsu_frame_age_ms_max": max(ages) if ages else None}


SPEED_BANDS = (1.15, 1.3, 1.5)
"""Bands of a period's detector CPU per frame over the detector's uncontended time (``detector_reference_ms``). The
detector's work per frame is fixed (one inference on the RSU's window, a few boxes decoded), so the ratio is how much
slower the machine ran that work in the period. The corridor's own contention alone: 7.22 -> 7.88 ms with ``iea up``
running beside the reference loop (1.09 x on a 2-core Xeon), hence the first band's 1.15."""


def fps_by_machine_speed(runs: list[dict[str, Any]], reference_ms: dict[str, float]) -> list[dict[str, Any]]:
    """Every RSU's periods of every run, by ``SPEED_BANDS`` of their detector CPU per frame over that RSU's
    ``reference_ms``: per band the periods, those under 14 of the camera's 15 fps, and their minimum fps ([] without
    a reference)."""
    pairs = [(f, d / reference_ms[rsu_id]) for r in runs for rsu_id, ld in (r.get("rsu_load") or {}).items()
             if reference_ms.get(rsu_id, 0.0) > 0 for f, d in ld.get("fps_detect_cpu_ms", [])]
    if not pairs:
        return []
    edges = (0.0, *SPEED_BANDS, float("inf"))
    out = []
    for lo, hi in zip(edges[:-1], edges[1:], strict=True):
        fps = [f for f, x in pairs if lo < x <= hi]
        out.append({"slowdown_from": lo, "slowdown_to": None if hi == float("inf") else hi, "periods": len(fps),
                    "periods_under_14": sum(f < 14.0 for f in fps), "fps_min": min(fps) if fps else None})
    return out


def print_machine_speed(bands: list[dict[str, Any]], before: dict[str, float], after: dict[str, float]) -> None:
    """The processed fps by how fast the machine ran the detector's fixed work (``fps_by_machine_speed``)."""
    if not bands:
        print(" machine speed: no detector reference measured")
        return
    ms = " ".join(f"{k} {before[k]:.2f}/{after.get(k, float('nan')):.2f}" for k in sorted(before))
    print(f"\n machine speed: each RSU's detector alone on the machine, CPU ms per frame before/after the runs: {ms};"
          "\n per 1 s period of every RSU, its detector CPU per frame over the faster of the two:")
    print(f" {'slowdown':<12} {'periods':>8} {'< 14 fps':>9} {'fps min':>8}")
    for b in bands:
        band = (f"<= {b['slowdown_to']:.2f} x" if b["slowdown_from"] == 0.0 else
                f"> {b['slowdown_from']:.2f} x" if b["slowdown_to"] is None else
                f"{b['slowdown_from']:.2f}-{b['slowdown_to']:.2f} x")
        fmin = "-" if b["fps_min"] is None else f"{b['fps_min']:.1f}"
        print(f" {band:<12} {b['periods']:8d} {b['periods_under_14']:9d} {fmin:>8}")


def detector_reference_ms(frames: int = 20, repeats: int = 3) -> dict[str, float]:
    """Per RSU of the corridor, CPU ms per frame of its detector (its own search window, one thread, as ``iea-rsu``
    runs it) on renders of its camera in ``rellis_ev_yield``, best of ``repeats`` passes: the machine's speed at the
    detector's fixed work, nothing else running (~3 s)."""
    import time

    import cv2

    from protocol.corridor import load_corridor
    from rsu.build import PipelineConfig, build_detector
    from sim.render.renderer import Renderer
    from sim.scenario import load_scenario
    from sim.world import World

    cv2.setNumThreads(1)  # as the RSU runs it (rsu.build): the letterbox's resize on this thread
    corridor = load_corridor()
    world = World(load_scenario("rellis_ev_yield"), seed=1)
    snapshots = []
    for k in range(frames):
        world.run_until(2.0 + 0.3 * k)
        snapshots.append(world.snapshot())
    out = {}
    for rsu in corridor.rsus:
        renderer = Renderer(rsu.camera, corridor.road, seed=1)
        images = [renderer.render(s, k) for k, s in enumerate(snapshots)]
        detector = build_detector(PipelineConfig(detector="project", threads=1), corridor, rsu.rsu_id)
        detector.detect(images[0])
        best = float("inf")
        for _ in range(repeats):
            t0 = time.thread_time()
            for image in images:
                detector.detect(image)
            best = min(best, (time.thread_time() - t0) * 1000.0 / len(images))
        out[rsu.rsu_id] = round(best, 3)
    return out
