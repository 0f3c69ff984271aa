"""Where a rendered frame's CPU goes: the sim bench's scene (``bench/sim_bench.py``: rsu1, 1280x720, 20
vehicles in view) per lighting, split by stage, and the frame without its per-frame geometry.

    python bench/render_split_bench.py [--frames N] [--rounds R] [--quick] [--json]

Per lighting:
- ``render_ms_<lighting>``: CPU per full frame (process time, best of the rounds), as the sim bench measures it.
- ``stage_ms_<lighting>``: wall time per frame in each stage of ``sim.render.renderer.Renderer.render`` (the pure geometry
  functions of ``sim.render.pose`` and ``sim.render.effects`` and the renderer's drawing methods, each timed around
  its call; ``rest``: the per-actor drawing loop with its polygon fills, and the glue), from the quickest round.
- ``without_geometry_ms_<lighting>``: the same frames with every pure geometry function's answer recorded once and
  handed back instantly (the drawing unchanged): what a frame would cost if the geometry were free, the bound for any
  faster form of it (a compiled one, say). ``geometry_ms_<lighting>``: the median paired difference.

Single-threaded (OpenCV and BLAS on one thread). The host's speed moves every figure (up to 1.5x within the hour on
the 2-core VM): compare figures from the same run only.
"""

from __future__ import annotations

from bench._setup import ROOT  # noqa: F401  first: one thread per numeric library, before numpy loads

# isort: split
import argparse  # noqa: E402
import json  # noqa: E402
import time  # noqa: E402
from collections import Counter  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

import sim.render.renderer as render_module  # noqa: E402
from bench.sim_bench import scene  # noqa: E402
from protocol.corridor import load_corridor  # noqa: E402

GEOMETRY = ("painter_order", "pose_frame", "shadow_outlines", "pool_quads", "blur_vectors", "shade_faces",
            "visible_polygons", "lamp_halos")
"""The pure per-frame functions ``sim.render.renderer`` calls (its module-level names)."""
DRAWING = ("_frame_start", "_draw_shadow", "_draw_headlight_pool", "_motion_blur", "_draw_halos", "_expose_frame")
"""The renderer's drawing methods timed as stages."""


def _timed(fn, stage: str, totals: Counter):
    def wrapper(*args, **kwargs):
        t0 = time.perf_counter()
        out = fn(*args, **kwargs)
        totals[stage] += time.perf_counter() - t0
        return out
    return wrapper


def split_lighting(lighting: str, frames: int, rounds: int) -> dict[str, object]:
    """The figures of one lighting (module docstring)."""
    corridor = load_corridor()
    cam = corridor.rsu("rsu1").camera
    snaps = [scene(k / 15.0, lighting) for k in range(frames)]
    renderer = render_module.Renderer(cam, corridor.road, seed=1)
    renderer.render(snaps[0], 0)  # static scene, noise bank, body models
    original = {name: getattr(render_module, name) for name in GEOMETRY}
    methods = {name: getattr(render_module.Renderer, name) for name in DRAWING}
    answers: dict[str, dict[int, object]] = {name: {} for name in GEOMETRY}
    current = [0]

    def recording(name):
        def wrapper(*args, **kwargs):
            out = answers[name][current[0]] = original[name](*args, **kwargs)
            return out
        return wrapper

    def run() -> float:
        t0 = time.process_time()
        for k, snap in enumerate(snaps):
            current[0] = k
            renderer.render(snap, k)
        return (time.process_time() - t0) * 1000.0 / frames

    try:
        for name in GEOMETRY:
            setattr(render_module, name, recording(name))
        run()
        full, free, stages = [], [], []
        for _ in range(rounds):
            for name in GEOMETRY:
                setattr(render_module, name, original[name])
            full.append(run())
            for name in GEOMETRY:
                setattr(render_module, name, lambda *a, _n=name, **k: answers[_n][current[0]])
            free.append(run())
            totals: Counter = Counter()
            for name in GEOMETRY:
                setattr(render_module, name, _timed(original[name], name, totals))
            for name in DRAWING:
                setattr(render_module.Renderer, name, _timed(methods[name], name, totals))
            t0 = time.perf_counter()
            run()
            wall_ms = (time.perf_counter() - t0) * 1000.0 / frames
            for name in DRAWING:
                setattr(render_module.Renderer, name, methods[name])
            per_frame = {stage: 1000.0 * s / frames for stage, s in totals.items()}
            per_frame["rest"] = wall_ms - sum(per_frame.values())
            stages.append((wall_ms, per_frame))
    finally:
        for name in GEOMETRY:
            setattr(render_module, name, original[name])
        for name in DRAWING:
            setattr(render_module.Renderer, name, methods[name])
    quickest = min(stages, key=lambda s: s[0])[1]
    return {f"render_ms_{lighting}": round(min(full), 3),
            f"without_geometry_ms_{lighting}": round(min(free), 3),
            f"geometry_ms_{lighting}": round(float(np.median(np.array(full) - np.array(free))), 3),
            f"stage_ms_{lighting}": {k: round(v, 3) for k, v in sorted(quickest.items(), key=lambda kv: -kv[1])}}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=60, help="frames a round (default 60)")
    ap.add_argument("--rounds", type=int, default=5, help="rounds, each full, geometry-free and split (default 5)")
    ap.add_argument("--quick", action="store_true", help="4 frames, 1 round (a smoke run)")
    ap.add_argument("--json", action="store_true", help="last line: one JSON object of the figures")
    args = ap.parse_args(argv)
    if args.quick:
        args.frames, args.rounds = 4, 1
    if args.frames < 2 or args.rounds < 1:
        ap.error("--frames must be at least 2 and --rounds at least 1")
    cv2.setNumThreads(1)
    figures: dict[str, object] = {}
    for lighting in ("day", "dusk", "night"):
        f = split_lighting(lighting, args.frames, args.rounds)
        figures.update(f)
        print(f"{lighting:5s}: {f[f'render_ms_{lighting}']:.2f} ms a frame; without its geometry "
              f"{f[f'without_geometry_ms_{lighting}']:.2f} (the geometry {f[f'geometry_ms_{lighting}']:.2f})",
              flush=True)
        print("       " + ", ".join(f"{k} {v:.2f}" for k, v in f[f"stage_ms_{lighting}"].items()), flush=True)
    if args.json:
        print(json.dumps(figures))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
