"""Localisation error to expect from a camera calibration, per distance band (thesis App. B).

Two App. B methods map a detection's pixel to the road:
- transformation-based (``rsu.localize.GroundProjector``): the solved camera's ray meets the road plane.
  Its expected error, :func:`predicted_ground_error`: Monte Carlo over the calibration's parameter
  covariance (``CameraSolution.covariance``, first-order from the PnP Jacobian) and a detection pixel
  noise (``pixel_sigma_px``, per axis): each draw back-projects the pixel of a lane-centre point with a
  sampled camera; the error is the horizontal distance to the point. Also measured by leave-one-out
  over the surveyed pairs (:func:`transform_cv`: solve without the pair, back-project its pixel);
- location-reference (``rsu.localize.ReferenceInterpolator``, default ``homography+rbf``): leave-one-out
  cross-validation on the same ground pairs (:func:`reference_cv`).
:func:`error_table` puts them side by side per band and says which to use: the method of the lower
cross-validated median where pairs lie in the band; the transformation elsewhere (the reference method
extrapolates outside its pairs). Distances are horizontal, from the camera's foot. Pure core.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from protocol.road import Road
from rsu.calibration.camera_geometry import ground_points, project
from rsu.calibration.solve import CalibrationError, CameraSolution, SurveyPoint, solve_camera

GROUND_TOLERANCE_M = 0.05
"""Pairs within this height of the road plane count as road-plane pairs (the corridor's calibration)."""


@dataclass(frozen=True)
class BandError:
    centre_m: float
    lo_m: float
    hi_m: float
    n_lane_points: int
    predicted_median_m: float | None
    predicted_p95_m: float | None
    n_pairs: int
    transform_cv_median_m: float | None
    reference_cv_median_m: float | None
    use: str


def bands_for(max_range_m: float, step_m: float = 20.0) -> list[tuple[float, float, float]]:
    """(centre, lo, hi) bands every ``step_m`` from ``step_m`` to ``max_range_m``, each +- step/2."""
    centres = np.arange(step_m, max_range_m + 1e-9, step_m)
    return [(float(c), float(c - step_m / 2), float(c + step_m / 2)) for c in centres]


def lane_points(solution: CameraSolution, road: Road, lo_m: float, hi_m: float, step_m: float = 1.0) -> np.ndarray:
    """(N, 2) lane-centre ground points whose distance from the camera's foot is in [lo, hi) and that are seen."""
    cam = solution.camera
    s = np.arange(0.0, road.length_m, step_m)
    lanes = road.lanes + road.opposite_lanes
    offsets = (np.arange(lanes) + 0.5) * road.lane_width_m
    ss, dd = np.meshgrid(s, offsets)
    x, y, _ = road.pose_at(ss.ravel(), dd.ravel())
    dist = np.hypot(x - cam.x_m, y - cam.y_m)
    keep = (dist >= lo_m) & (dist < hi_m)
    xyz = np.column_stack([x[keep], y[keep], np.zeros(int(keep.sum()))])
    uv, depth = project(cam, xyz, solution.dist)
    seen = (depth > 1.0) & (uv[:, 0] >= 0) & (uv[:, 0] < cam.width_px) & (uv[:, 1] >= 0) & (uv[:, 1] < cam.height_px)
    return xyz[seen, :2]


def predicted_ground_error(solution: CameraSolution, xy: np.ndarray, pixel_sigma_px: float = 1.0, draws: int = 200,
                           seed: int = 0) -> np.ndarray:
    """(draws * N,) horizontal errors (m) of back-projecting the points' pixels (+ pixel noise) with cameras
    drawn from the calibration covariance (module docstring)."""
    xy = np.asarray(xy, dtype=float).reshape(-1, 2)
    if len(xy) == 0:
        return np.zeros(0)
    rng = np.random.default_rng(seed)
    uv, _ = project(solution.camera, np.column_stack([xy, np.zeros(len(xy))]), solution.dist)
    cov = 0.5 * (solution.covariance + solution.covariance.T)
    samples = rng.multivariate_normal(solution.params, cov, size=draws, method="eigh")
    out = []
    for p in samples:
        cam, dist = solution.camera_at(p)
        noisy = uv + rng.normal(0.0, pixel_sigma_px, size=uv.shape)
        got = ground_points(cam, noisy, dist)
        out.append(np.hypot(*(got - xy).T))
    err = np.concatenate(out)
    return err[np.isfinite(err)]


def reference_cv(points: Sequence[SurveyPoint], method: str = "homography+rbf") -> dict[str, float]:
    """Leave-one-out error (m) of the location-reference method per road-plane pair name."""
    from rsu.localize import ReferenceInterpolator

    ground = [p for p in points if abs(p.z_m) <= GROUND_TOLERANCE_M]
    out: dict[str, float] = {}
    if len(ground) < 7:  # the interpolator needs 6 pairs after leaving one out
        return out
    for i, p in enumerate(ground):
        rest = [(q.u_px, q.v_px, q.x_m, q.y_m) for j, q in enumerate(ground) if j != i]
        try:
            got, _ = ReferenceInterpolator(rest, method).to_ground(np.array([[p.u_px, p.v_px]]))
        except ValueError:
            continue
        out[p.name] = float(math.hypot(got[0, 0] - p.x_m, got[0, 1] - p.y_m))
    return out


def transform_cv(solution: CameraSolution) -> dict[str, float]:
    """Leave-one-out error (m) of the transformation method per kept pair: the camera solved without the pair
    (intrinsics as solved), its pixel back-projected to the pair's height."""
    kept = solution.kept
    cam = solution.camera
    out: dict[str, float] = {}
    for i, p in enumerate(kept):
        rest = [q for j, q in enumerate(kept) if j != i]
        try:
            sol = solve_camera(rest, cam.width_px, cam.height_px, fx_px=cam.fx_px, cx_px=cam.cx_px, cy_px=cam.cy_px,
                               aspect=cam.fy_px / cam.fx_px, solve_focal="no",
                               solve_distortion="yes" if solution.distortion_solved else "no")
        except CalibrationError:
            continue
        got = ground_points(sol.camera, np.array([[p.u_px, p.v_px]]), sol.dist, z_m=p.z_m)
        if np.isfinite(got).all():
            out[p.name] = float(math.hypot(got[0, 0] - p.x_m, got[0, 1] - p.y_m))
    return out


def error_table(solution: CameraSolution, road: Road, max_range_m: float = 100.0, pixel_sigma_px: float = 1.0,
                draws: int = 200, seed: int = 0, step_m: float = 20.0) -> list[BandError]:
    """One row per distance band: predicted transformation error, both methods' cross-validated errors, the pick."""
    cam = solution.camera
    dist_of = {p.name: math.hypot(p.x_m - cam.x_m, p.y_m - cam.y_m) for p in solution.kept}
    t_cv, r_cv = transform_cv(solution), reference_cv(solution.kept)
    rows = []
    for centre, lo, hi in bands_for(max_range_m, step_m):
        xy = lane_points(solution, road, lo, hi)
        err = predicted_ground_error(solution, xy, pixel_sigma_px, draws, seed)
        names = [n for n, d in dist_of.items() if lo <= d < hi]
        t = [t_cv[n] for n in names if n in t_cv]
        r = [r_cv[n] for n in names if n in r_cv]
        t_med = float(np.median(t)) if t else None
        r_med = float(np.median(r)) if r else None
        if r_med is not None and t_med is not None and r_med < t_med:
            use = "reference"
        elif not names:
            use = "transform (no pairs here)"
        else:
            use = "transform"
        rows.append(BandError(centre, lo, hi, len(xy), float(np.median(err)) if len(err) else None,
                              float(np.percentile(err, 95)) if len(err) else None, len(names), t_med, r_med, use))
    return rows


def format_error_table(rows: Sequence[BandError], pixel_sigma_px: float = 1.0) -> str:
    def f(v: float | None) -> str:
        return "    -" if v is None else f"{v:5.2f}"
    lines = [f"expected ground error (m) along the road, by distance from the camera's foot; detection pixel noise "
             f"{pixel_sigma_px:g} px:",
             "  distance      transform (predicted)   pairs  leave-one-out median     use",
             "                 median      p95                 transform  reference"]
    for r in rows:
        lines.append(f"  {r.centre_m:5.0f} m ({r.lo_m:3.0f}-{r.hi_m:3.0f})  {f(r.predicted_median_m)}   "
                     f"{f(r.predicted_p95_m)}      {r.n_pairs:3d}     {f(r.transform_cv_median_m)}      "
                     f"{f(r.reference_cv_median_m)}    {r.use}")
    return "\n".join(lines)
