"""Camera commissioning on simulator renders: pose and ground error from 8 surveyed points, 1-px noise.

The simulator's rsu1 camera (deploy/corridors/rellis.toml) is the truth. Per seed: 8 ground points spread
over its view (two per image row at about 22, 35, 62 and 95 m, left and right: the layout the `iea calibrate`
help asks a surveyor for), their pixels perturbed by N(0, 1 px) per axis and their world positions by the RTK
error N(0, 2 cm); the camera is solved with the corridor's intrinsics given (``rsu.calibration.solve.solve_camera``,
solve_focal="no"). Figures, over the seeds (named in the JSON):
- pose_position_error_m: the largest |C_solved - C_true| (m); pose_angle_error_deg: the largest of
  |yaw|, |pitch|, |roll| errors (deg); the medians beside them;
- ground_error_60m_median_m: median horizontal error of lane-centre points 55-65 m from the mast, their exact
  pixels back-projected through the solved camera (the calibration's share of the localisation error);
  ..._with_1px_detection_m: the same with N(0, 1 px) on the detection pixel;
- predicted_ground_error_60m_median_m: what the error table (rsu.calibration.error) predicted for the 50-70 m band;
- the same pose figures with the focal length solved too, and for 8 points on the road edges only.
The error table of the first seed is printed. ``--out DIR`` writes the render and its check image.

    python bench/calibration_bench.py [--quick] [--json] [--out DIR]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from protocol.corridor import load_corridor  # noqa: E402
from rsu.calibration.camera_geometry import ground_points, project  # noqa: E402
from rsu.calibration.error import error_table, format_error_table  # noqa: E402
from rsu.calibration.solve import SurveyPoint, solve_camera  # noqa: E402

SPREAD_PX = [(100, 660), (1180, 660), (250, 450), (1030, 450), (400, 300), (880, 300), (560, 230), (720, 230)]
"""Pixels of the 8 surveyed points on the 1280x720 rsu1 view (their ground points are the truth)."""
ROAD_EDGES = [(22, -2.5), (22, 7.4), (30, 0.0), (35, 7.4), (50, -2.5), (60, 3.7), (80, 0.0), (100, 7.4)]
"""(distance ahead of the mast m, road offset d m) of 8 points on the road only: a poorer layout."""


def survey(cam, world_xy: np.ndarray, rng: np.random.Generator, pixel_sigma_px: float, rtk_sigma_m: float):
    uv, _ = project(cam, np.column_stack([world_xy, np.zeros(len(world_xy))]))
    uv = uv + rng.normal(0.0, pixel_sigma_px, uv.shape)
    xy = world_xy + rng.normal(0.0, rtk_sigma_m, world_xy.shape)
    return [SurveyPoint(f"p{i}", float(u), float(v), float(x), float(y), 0.0) for i, ((u, v), (x, y))
            in enumerate(zip(uv, xy, strict=True))]


def pose_errors(sol_cam, cam) -> tuple[float, float]:
    pos = float(np.linalg.norm(sol_cam.centre_world - cam.centre_world))
    ang = max(abs(math.degrees(math.remainder(a - b, 2 * math.pi))) for a, b in (
        (sol_cam.yaw_rad, cam.yaw_rad), (sol_cam.pitch_rad, cam.pitch_rad), (sol_cam.roll_rad, cam.roll_rad)))
    return pos, ang


def lane_points_at(corridor, cam, lo_m: float, hi_m: float) -> np.ndarray:
    road = corridor.road
    s = np.arange(0.0, road.length_m, 0.5)
    ss, dd = np.meshgrid(s, (np.arange(road.lanes) + 0.5) * road.lane_width_m)
    x, y, _ = road.pose_at(ss.ravel(), dd.ravel())
    d = np.hypot(x - cam.x_m, y - cam.y_m)
    keep = (d >= lo_m) & (d < hi_m) & (x > cam.x_m)
    return np.column_stack([x[keep], y[keep]])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="3 seeds instead of 20")
    ap.add_argument("--json", action="store_true", help="end with one JSON line of the figures")
    ap.add_argument("--out", default=None, help="folder for the render and its check image")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    corridor = load_corridor()
    cam = corridor.rsu("rsu1").camera
    seeds = list(range(3 if args.quick else 20))
    spread_xy = ground_points(cam, np.array(SPREAD_PX, dtype=float))
    road = corridor.road
    edges_xy = np.array([road.pose_at(cam.x_m - road.start_x_m + a, d)[:2] for a, d in ROAD_EDGES])
    at60 = lane_points_at(corridor, cam, 55.0, 65.0)
    true_uv, _ = project(cam, np.column_stack([at60, np.zeros(len(at60))]))
    res: dict[str, list[float]] = {k: [] for k in ("pos", "ang", "pos_f", "ang_f", "pos_e", "ang_e", "g60", "g60_1px",
                                                   "pred60")}
    for seed in seeds:
        rng = np.random.default_rng(seed)
        pts = survey(cam, spread_xy, rng, 1.0, 0.02)
        sol = solve_camera(pts, cam.width_px, cam.height_px, fx_px=cam.fx_px, solve_focal="no", solve_distortion="no")
        pos, ang = pose_errors(sol.camera, cam)
        res["pos"].append(pos)
        res["ang"].append(ang)
        got = ground_points(sol.camera, true_uv)
        res["g60"] += np.hypot(*(got - at60).T).tolist()
        got = ground_points(sol.camera, true_uv + rng.normal(0.0, 1.0, true_uv.shape))
        res["g60_1px"] += np.hypot(*(got - at60).T).tolist()
        rows = error_table(sol, road, 100.0, 1.0, draws=100 if args.quick else 200, seed=seed)
        res["pred60"].append(next(r.predicted_median_m for r in rows if r.centre_m == 60.0))
        if seed == seeds[0]:
            print(f"seed {seed}: 8 points spread over the view, 1 px noise, intrinsics given: position error "
                  f"{pos:.3f} m, angle error {ang:.3f} deg, reprojection {sol.rms_px:.2f} px RMS")
            print(format_error_table(rows))
            if args.out:
                write_check(args.out, corridor, cam, sol)
        sol_f = solve_camera(pts, cam.width_px, cam.height_px, fx_px=cam.fx_px, solve_focal="yes",
                             solve_distortion="no")
        pos_f, ang_f = pose_errors(sol_f.camera, cam)
        res["pos_f"].append(pos_f)
        res["ang_f"].append(ang_f)
        pts_e = survey(cam, edges_xy, rng, 1.0, 0.02)
        sol_e = solve_camera(pts_e, cam.width_px, cam.height_px, fx_px=cam.fx_px, solve_focal="no",
                             solve_distortion="no")
        pos_e, ang_e = pose_errors(sol_e.camera, cam)
        res["pos_e"].append(pos_e)
        res["ang_e"].append(ang_e)
        print(f"seed {seed}: position {pos:.3f} m, angles {ang:.3f} deg | focal solved: {pos_f:.3f} m, {ang_f:.3f} deg "
              f"| road edges only: {pos_e:.3f} m, {ang_e:.3f} deg", flush=True)
    fig = {
        "seeds": seeds, "points": 8, "pixel_noise_px": 1.0, "rtk_noise_m": 0.02, "camera": "rellis rsu1 (sim)",
        "pose_position_error_m": max(res["pos"]), "pose_position_error_median_m": float(np.median(res["pos"])),
        "pose_angle_error_deg": max(res["ang"]), "pose_angle_error_median_deg": float(np.median(res["ang"])),
        "ground_error_60m_median_m": float(np.median(res["g60"])),
        "ground_error_60m_median_with_1px_detection_m": float(np.median(res["g60_1px"])),
        "predicted_ground_error_60m_median_m": float(np.median(res["pred60"])),
        "focal_solved_pose_position_error_m": max(res["pos_f"]), "focal_solved_pose_angle_error_deg": max(res["ang_f"]),
        "road_edges_only_pose_position_error_m": max(res["pos_e"]),
        "road_edges_only_pose_angle_error_deg": max(res["ang_e"]),
        "wall_s": time.perf_counter() - t0,
    }
    ok = fig["pose_position_error_m"] <= 0.2 and fig["pose_angle_error_deg"] <= 0.2 and fig["ground_error_60m_median_m"] <= 0.3
    print(f"over {len(seeds)} seeds: position error max {fig['pose_position_error_m']:.3f} m (median "
          f"{fig['pose_position_error_median_m']:.3f}), angle error max {fig['pose_angle_error_deg']:.3f} deg (median "
          f"{fig['pose_angle_error_median_deg']:.3f}), ground error at 60 m median {fig['ground_error_60m_median_m']:.3f} m "
          f"({fig['ground_error_60m_median_with_1px_detection_m']:.3f} m with 1 px detection noise; predicted "
          f"{fig['predicted_ground_error_60m_median_m']:.3f} m); targets 0.2 m / 0.2 deg / 0.3 m: "
          f"{'met' if ok else 'NOT met'}")
    if args.json:
        print(json.dumps({k: (round(v, 4) if isinstance(v, float) else v) for k, v in fig.items()}))
    return 0


def write_check(out: str, corridor, cam, sol) -> None:
    import cv2

    from rsu.calibration.overlay import OverlayPoint, check_image
    from sim.render.renderer import Renderer

    folder = Path(out)
    folder.mkdir(parents=True, exist_ok=True)
    frame = Renderer(cam, corridor.road, seed=0).background("day")
    pts = [OverlayPoint(r.name, r.measured_uv, r.reprojected_uv, r.flagged) for r in sol.residuals]
    img = check_image(frame, sol.camera, corridor.road, max_range_m=85.0, points=pts, title="rsu1 (sim), 8 points")
    cv2.imwrite(str(folder / "render.png"), frame)
    cv2.imwrite(str(folder / "check.jpg"), img, [cv2.IMWRITE_JPEG_QUALITY, 85])
    print(f"wrote {folder / 'render.png'} and {folder / 'check.jpg'}")


if __name__ == "__main__":
    raise SystemExit(main())
