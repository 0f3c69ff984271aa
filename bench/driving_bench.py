"""The Clemson comparison: the on-board end-to-end steering CNN, cases 1-3, against the
infrastructure-guided controller, on the same held-out hazard episodes.

    python bench/driving_bench.py [--quick] [--json] [--seeds 2000 2001 ...] [--plots DIR] [--models DIR]

Every episode (``studies.clemson.driving.make_scenario``; the held-out seeds 2000.. are never trained on) is driven
five times in lockstep on the same road: the **teacher** (the thesis controller under the DDM's hazard rule
with perfect knowledge, the reference, like the report's manually driven ground truth), the
**infrastructure-guided controller** ``iea`` (the same rule on the RSUs' noisy debris position, the AV's own
position estimate, 0.25 s command latency) and the learned steering of **case 1** (camera image), **case 2**
(fused image, radar threat value eq. 2-3) and **case 3** (fused image, image threat value eq. 4), each
steering from its dashcam at 10 Hz through ONNX Runtime with the thesis core's fail-safe in charge.

Figures, per driver, over all episodes:

- ``*_traj_rmse_m``: RMSE of the lateral position d(s) against the teacher's, from 70 m before the debris to
  20 m past it (report fig. 14: lateral movement against the ground truth's);
- ``*_steer_rmse_n`` / ``*_steer_mae_n``: eq. 6-7 on the steering angle normalised by eq. 5 (the report's
  units, [-0.5, 0.5] over +-0.2 rad), closed loop, against the teacher's at the same station;
- ``case*_open_steer_rmse_n`` / ``_mae_n``: eq. 6-7 open loop, the report's own test: each net's angle on
  the centre-camera frames of the teacher's held-out drives (every 0.2 s) against the teacher's;
- ``*_min_clearance_m`` (smallest gap between the car's and the debris' boxes) and ``*_collisions``;
  ``learned_collisions`` sums cases 1-3;
- ``case2/3_improvement_pct`` (eq. 8, trajectory RMSE against case 1) and ``*_open_improvement_pct`` (eq. 8 on
  the open-loop steering RMSE, the report's use of it).

``--plots DIR`` writes figures like the report's 12-14 (cv2 drawings): ``fig12_errors.png``,
``fig13_steering_SEED.png``, ``fig14_trajectory_SEED.png``. With ``--json`` the last line is one JSON object.
"""

from __future__ import annotations

from bench._setup import ROOT  # noqa: F401  first: one thread per numeric library, before numpy loads

# isort: split
import argparse  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from studies.clemson.dashcam import DashCamera  # noqa: E402
from studies.clemson.driving import camera_driver, clearance_m, make_scenario, run, simulated_radar  # noqa: E402
from studies.clemson.learned_steering import (  # noqa: E402
    CASES,
    MODELS_DIR,
    LearnedSteering,
    LearnedVehicle,
    normalise_steer,
)

cv2.setNumThreads(1)
DRIVERS = ("teacher", "iea", "case1", "case2", "case3")
WINDOW_BEFORE_M, WINDOW_AFTER_M = 70.0, 20.0
REPORT_TRAJ_RMSE = {"case1": 0.52, "case2": 0.07, "case3": 0.23}
COLOURS = {"teacher": (0, 0, 0), "iea": (0, 140, 0), "case1": (40, 40, 220), "case2": (200, 90, 0),
           "case3": (0, 160, 230)}


def drive(seed: int, driver: str, nets: dict[int, LearnedSteering]):
    sc = make_scenario(seed)
    if driver in ("teacher", "iea"):
        return sc, run(sc, driver, seed=seed)
    case = int(driver[-1])
    sim = LearnedVehicle(sc.road, "av1", sc.start_s_m, sc.start_lane, sc.speed_mps, seed=seed)
    return sc, run(sc, "camera", camera_driver(sc, nets[case], seed), seed=seed, sim=sim)


def on_grid(sc, trace, key: str) -> tuple[np.ndarray, np.ndarray]:
    """(s grid, ``key`` interpolated on it) over the comparison window (1 m steps)."""
    a = trace.arrays()
    d = sc.debris[0]
    s = np.arange(max(sc.start_s_m + 5.0, d.s_m - WINDOW_BEFORE_M), d.s_m + WINDOW_AFTER_M, 1.0)
    order = np.argsort(a["s_m"])
    return s, np.interp(s, a["s_m"][order], a[key][order])


def open_loop(seed: int, teacher, nets: dict[int, LearnedSteering]) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """Each case's angle on the teacher's centre-camera frames every 0.2 s: {case: (predicted, teacher)} (rad)."""
    sc = make_scenario(seed)
    a = teacher.arrays()
    cam, actors = DashCamera(sc.road, seed=sc.seed), sc.actors()
    rng = np.random.default_rng([23, seed, 3])
    pred: dict[int, list[float]] = {c: [] for c in nets}
    truth = []
    for i in range(0, len(a["t_s"]), 2):
        x, y, yaw, t = (float(a[k][i]) for k in ("x_m", "y_m", "yaw_rad", "t_s"))
        img = cam.render(x, y, yaw, actors, t, frame_index=int(round(t * 10)))
        radar = simulated_radar(x, y, yaw, actors, rng)
        for c, net in nets.items():
            pred[c].append(net(img, radar)[0])
        truth.append(float(a["steer_cmd_rad"][i]))
    return {c: (np.array(p), np.array(truth)) for c, p in pred.items()}


def rmse_mae(p: np.ndarray, g: np.ndarray) -> tuple[float, float]:
    """Eq. 6 and eq. 7."""
    e = np.asarray(g) - np.asarray(p)
    return float(np.sqrt(np.mean(e * e))), float(np.mean(np.abs(e)))


def improvement_pct(rmse: float, rmse_case1: float) -> float:
    """Eq. 8: |RMSE - RMSE_case1| / RMSE_case1 x 100 (signed here: > 0 better than case 1, < 0 worse)."""
    return float((rmse_case1 - rmse) / rmse_case1 * 100.0) if rmse_case1 > 0 else math.nan


# ------------------------------------------------------------------ plots (cv2)
def _plot(series: dict[str, tuple[np.ndarray, np.ndarray]], title: str, xlabel: str, ylabel: str,
          boxes: list[tuple[float, float, float, float]] = ()) -> np.ndarray:
    W, H, m = 900, 420, 70
    img = np.full((H, W, 3), 255, np.uint8)
    xs = np.concatenate([v[0] for v in series.values()])
    ys = np.concatenate([v[1] for v in series.values()] + [np.array([b[1], b[3]]) for b in boxes])
    x0, x1 = float(xs.min()), float(xs.max())
    y0, y1 = float(ys.min()), float(ys.max())
    pad = 0.08 * (y1 - y0 or 1.0)
    y0, y1 = y0 - pad, y1 + pad

    def px(x, y):
        return (np.round(m + (np.asarray(x) - x0) / (x1 - x0 or 1) * (W - 2 * m)).astype(int),
                np.round(H - m + (np.asarray(y) - y0) / (y1 - y0) * -(H - 2 * m)).astype(int))

    cv2.rectangle(img, (m, m), (W - m, H - m), (120, 120, 120), 1)
    for b in boxes:
        (bx0, bx1), (by0, by1) = px([b[0], b[2]], [b[1], b[3]])
        cv2.rectangle(img, (int(bx0), int(by1)), (int(bx1), int(by0)), (60, 75, 150), -1)
    for frac in np.linspace(0, 1, 5):
        yv = y0 + frac * (y1 - y0)
        _, yp = px(x0, yv)
        cv2.putText(img, f"{yv:.2f}", (4, int(yp) + 4), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 0, 0), 1)
        xv = x0 + frac * (x1 - x0)
        xp, _ = px(xv, y0)
        cv2.putText(img, f"{xv:.0f}", (int(xp) - 10, H - m + 16), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 0, 0), 1)
    for k, (name, (x, y)) in enumerate(series.items()):
        u, v = px(x, y)
        cv2.polylines(img, [np.column_stack([u, v]).astype(np.int32)], False, COLOURS.get(name, (0, 0, 0)), 2,
                      cv2.LINE_AA)
        cv2.putText(img, name, (W - m + 4, m + 16 * k + 10), cv2.FONT_HERSHEY_SIMPLEX, 0.45,
                    COLOURS.get(name, (0, 0, 0)), 1)
    cv2.putText(img, title, (m, 30), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (0, 0, 0), 1)
    cv2.putText(img, xlabel, (W // 2 - 40, H - 20), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1)
    cv2.putText(img, ylabel, (4, m - 12), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1)
    return img


def _bars(values: dict[str, tuple[float, float]], title: str) -> np.ndarray:
    W, H, m = 700, 380, 60
    img = np.full((H, W, 3), 255, np.uint8)
    top = max(max(v) for v in values.values()) * 1.15 or 1.0
    bw = (W - 2 * m) / (len(values) * 3)
    for k, (name, (r, a)) in enumerate(values.items()):
        for j, (val, col) in enumerate(((r, (200, 90, 0)), (a, (0, 160, 230)))):
            x = int(m + (3 * k + j + 0.5) * bw)
            y = int(H - m - val / top * (H - 2 * m))
            cv2.rectangle(img, (x, y), (int(x + bw), H - m), col, -1)
            cv2.putText(img, f"{val:.3f}", (x - 4, y - 4), cv2.FONT_HERSHEY_SIMPLEX, 0.35, (0, 0, 0), 1)
        cv2.putText(img, name, (int(m + (3 * k + 0.6) * bw), H - m + 18), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1)
    cv2.putText(img, title + "  (blue: RMSE, orange: MAE)", (m, 30), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1)
    cv2.line(img, (m, H - m), (W - m, H - m), (0, 0, 0), 1)
    return img


def write_plots(out: Path, runs: dict, errors: dict[str, tuple[float, float]]) -> list[Path]:
    out.mkdir(parents=True, exist_ok=True)
    paths = [out / "fig12_errors.png"]
    cv2.imwrite(str(paths[0]), _bars(errors, "Fig. 12: open-loop steering error on the held-out frames (eq. 5 units)"))
    for seed, (sc, traces) in runs.items():
        steer = {n: (tr.arrays()["t_s"], np.degrees(tr.arrays()["steer_cmd_rad"])) for n, tr in traces.items()}
        p = out / f"fig13_steering_{seed}.png"
        cv2.imwrite(str(p), _plot(steer, f"Fig. 13: steering, episode {seed}", "time (s)", "road-wheel angle (deg)"))
        paths.append(p)
        traj = {n: (tr.arrays()["s_m"], tr.arrays()["d_m"]) for n, tr in traces.items()}
        d = sc.debris[0]
        box = (d.s_m - d.length_m / 2, d.d_m - d.width_m / 2, d.s_m + d.length_m / 2, d.d_m + d.width_m / 2)
        p = out / f"fig14_trajectory_{seed}.png"
        cv2.imwrite(str(p), _plot(traj, f"Fig. 14: trajectory, episode {seed} (box: the debris)",
                                  "distance along the road (m)", "lateral position d (m)", [box]))
        paths.append(p)
    return paths


def bench(seeds: list[int], models: Path, plots: Path | None, progress: bool = True) -> dict:
    nets = {c: LearnedSteering(c, models) for c in CASES}
    t0 = time.perf_counter()
    per: dict[str, dict[str, list]] = {n: {"d_err": [], "s_err": [], "clear": []} for n in DRIVERS}
    open_err: dict[int, list] = {c: [] for c in CASES}
    runs, rows = {}, []
    for k, seed in enumerate(seeds):
        traces = {n: drive(seed, n, nets)[1] for n in DRIVERS}
        sc = make_scenario(seed)
        runs[seed] = (sc, traces)
        _, d_ref = on_grid(sc, traces["teacher"], "d_m")
        _, st_ref = on_grid(sc, traces["teacher"], "steer_cmd_rad")
        row = {"seed": seed, "debris": sc.debris[0].kind, "lane": sc.start_lane}
        for n, tr in traces.items():
            _, d = on_grid(sc, tr, "d_m")
            _, st = on_grid(sc, tr, "steer_cmd_rad")
            per[n]["d_err"].append(d - d_ref)
            per[n]["s_err"].append(normalise_steer(st) - normalise_steer(st_ref))
            c = clearance_m(sc, tr)
            per[n]["clear"].append(c)
            row[f"{n}_clearance_m"] = round(c, 3)
            row[f"{n}_traj_rmse_m"] = round(float(np.sqrt(np.mean((d - d_ref) ** 2))), 3)
        for c, (p, g) in open_loop(seed, traces["teacher"], nets).items():
            open_err[c].append((normalise_steer(p), normalise_steer(g)))
        rows.append(row)
        if progress:
            print(f"[{time.perf_counter() - t0:5.0f} s] episode {seed} ({k + 1}/{len(seeds)}): "
                  + " ".join(f"{n} rmse {row[f'{n}_traj_rmse_m']:.2f} m clr {row[f'{n}_clearance_m']:.2f} m"
                             for n in DRIVERS[1:]), file=sys.stderr, flush=True)
    fig: dict = {"episodes": len(seeds), "seeds": seeds}
    for n in DRIVERS[1:]:
        de, se = np.concatenate(per[n]["d_err"]), np.concatenate(per[n]["s_err"])
        fig[f"{n}_traj_rmse_m"] = round(float(np.sqrt(np.mean(de ** 2))), 4)
        fig[f"{n}_steer_rmse_n"] = round(float(np.sqrt(np.mean(se ** 2))), 4)
        fig[f"{n}_steer_mae_n"] = round(float(np.mean(np.abs(se))), 4)
        fig[f"{n}_min_clearance_m"] = round(float(min(per[n]["clear"])), 3)
        fig[f"{n}_collisions"] = int(sum(c < 0 for c in per[n]["clear"]))
    fig["teacher_min_clearance_m"] = round(float(min(per["teacher"]["clear"])), 3)
    errors = {}
    for c in CASES:
        p = np.concatenate([e[0] for e in open_err[c]])
        g = np.concatenate([e[1] for e in open_err[c]])
        r, a = rmse_mae(p, g)
        fig[f"case{c}_open_steer_rmse_n"], fig[f"case{c}_open_steer_mae_n"] = round(r, 4), round(a, 4)
        errors[f"case{c}"] = (r, a)
    fig["open_loop_frames"] = int(sum(len(e[0]) for e in open_err[1]))
    for c in (2, 3):
        fig[f"case{c}_improvement_pct"] = round(improvement_pct(fig[f"case{c}_traj_rmse_m"], fig["case1_traj_rmse_m"]), 1)
        fig[f"case{c}_open_improvement_pct"] = round(
            improvement_pct(fig[f"case{c}_open_steer_rmse_n"], fig["case1_open_steer_rmse_n"]), 1)
    fig["learned_collisions"] = sum(fig[f"case{c}_collisions"] for c in CASES)
    fig["learned_failures"] = [{"seed": r["seed"], "case": c, "clearance_m": r[f"case{c}_clearance_m"]}
                               for r in rows for c in CASES if r[f"case{c}_clearance_m"] < 0]
    fig["per_episode"] = rows
    fig["wall_s"] = round(time.perf_counter() - t0, 1)
    if plots is not None:
        fig["plots"] = [str(p) for p in write_plots(plots, runs, errors)]
    return fig


def table(fig: dict) -> str:
    lines = [f"{'driver':8} {'traj RMSE m':>11} {'report':>7} {'steer RMSE':>10} {'steer MAE':>9} "
             f"{'open RMSE':>9} {'open MAE':>8} {'min clr m':>9} {'coll':>4} {'eq.8 %':>7}"]
    for n in DRIVERS[1:]:
        rep = REPORT_TRAJ_RMSE.get(n)
        op = (f"{fig[f'{n}_open_steer_rmse_n']:9.4f} {fig[f'{n}_open_steer_mae_n']:8.4f}" if n != "iea"
              else f"{'-':>9} {'-':>8}")
        imp = fig.get(f"{n}_improvement_pct")
        lines.append(f"{n:8} {fig[f'{n}_traj_rmse_m']:11.3f} {'-' if rep is None else f'{rep:.2f}':>7} "
                     f"{fig[f'{n}_steer_rmse_n']:10.4f} {fig[f'{n}_steer_mae_n']:9.4f} {op} "
                     f"{fig[f'{n}_min_clearance_m']:9.2f} {fig[f'{n}_collisions']:4d} "
                     f"{'-' if imp is None else f'{imp:+.1f}':>7}")
    lines.append(f"teacher min clearance {fig['teacher_min_clearance_m']:.2f} m; {fig['episodes']} held-out episodes; "
                 f"{fig['open_loop_frames']} open-loop frames")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, nargs="+", default=None, help="held-out episode seeds (default 2000..2007)")
    ap.add_argument("--quick", action="store_true", help="one episode, 2000 (a smoke run)")
    ap.add_argument("--models", default=str(MODELS_DIR), help="folder of driving_*.onnx")
    ap.add_argument("--plots", default=None, metavar="DIR", help="write figures like the report's 12-14 here")
    ap.add_argument("--json", action="store_true", help="end with one JSON line of the figures")
    args = ap.parse_args(argv)
    seeds = args.seeds or ([2000] if args.quick else list(range(2000, 2008)))
    if any(s < 2000 for s in seeds):
        print("driving_bench: seeds below 2000 are training or validation episodes, not held out", file=sys.stderr)
        return 2
    try:
        fig = bench(seeds, Path(args.models), None if args.plots is None else Path(args.plots))
    except FileNotFoundError as exc:
        print(f"driving_bench: {exc}", file=sys.stderr)
        return 2
    print(table(fig))
    if fig["learned_failures"]:
        print("learned-mode collisions: " + ", ".join(f"episode {f['seed']} case {f['case']} "
                                                      f"({f['clearance_m']:+.2f} m)" for f in fig["learned_failures"]))
    if args.json:
        print(json.dumps(fig))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
