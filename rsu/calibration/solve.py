"""Commissioning a camera: its pose (and focal length, radial distortion) from surveyed points.

Input: pairs pixel (u, v) -> world point (x, y, z) in the corridor frame (x east, y north, z up, metres;
lat/lon/height are converted by the caller, :func:`read_points_csv`). Model: the corridor's pinhole camera
(``protocol.corridor.CameraConfig``: p_cam = R (p_world - C), [u v 1]' ~ K p_cam) plus, when asked for,
OpenCV's radial term k1 (u = K * (1 + k1 r^2) * x_n).

Solution (:func:`solve_camera`):
1. checks: at least ``MIN_POINTS`` pairs, the world points not on one line, pixels inside the image;
2. focal length: the given guess, else the best of a sweep of guesses (the lowest robust reprojection error);
3. ``cv2.solvePnPRansac`` (robust to wrong pairs) then ``cv2.solvePnPRefineLM`` on its inliers (intrinsics
   fixed), or ``cv2.calibrateCameraExtended`` from that guess when the focal length / k1 are solved too
   (principal point fixed at the given one, square pixels, no tangential terms);
4. per-point reprojection errors; the worst point beyond ``flag_px`` (3 x the inlier RMS, at least 2 px)
   is dropped and the solve repeated; dropped points are flagged by name; too many dropped: inconsistent;
5. the parameter covariance ``s^2 (J'J)^-1`` (J: ``cv2.projectPoints`` Jacobian of the residuals,
   s: the residual RMS, at least ``pixel_sigma_px``), the basis of :mod:`rsu.calibration.error`.

"When the pairs allow" (``solve_focal`` / ``solve_distortion`` ``"auto"``): the focal length is solved
from >= ``MIN_POINTS_FOCAL`` inliers when its 1-sigma is under 2 % (a camera looking along a flat road
may leave it poorly fixed: then the given one stays, or the solve fails without one); k1 from
>= ``MIN_POINTS_DISTORTION`` inliers when it is 3 sigma from zero. Pure core: no I/O.
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from protocol.corridor import CameraConfig
from rsu.calibration.camera_geometry import camera_from_rvec_tvec, dist5, project

MIN_POINTS = 6
MIN_POINTS_FOCAL = 8
MIN_POINTS_DISTORTION = 12
WORLD_COLUMNS = (("x_m", "y_m", "z_m"), ("lat_deg", "lon_deg", "height_m"))


class CalibrationError(ValueError):
    """Pairs that give no trustworthy camera; the message says what was wrong and what to do."""


@dataclass(frozen=True)
class SurveyPoint:
    name: str
    u_px: float
    v_px: float
    x_m: float
    y_m: float
    z_m: float = 0.0


def read_points_csv(text: str, to_xy: Callable[[float, float], tuple[float, float]] | None = None,
                    source: str = "points") -> list[SurveyPoint]:
    """Pairs from CSV text: header ``name,u_px,v_px,x_m,y_m[,z_m]`` or ``name,u_px,v_px,lat_deg,lon_deg[,height_m]``
    (``name`` optional; ``#`` lines are comments). ``to_xy(lat, lon) -> (x, y)`` converts lat/lon (the corridor's)."""
    lines = [ln for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    if not lines:
        raise CalibrationError(f"{source}: no pairs (expected a header line such as 'name,u_px,v_px,x_m,y_m,z_m')")
    rows = list(csv.reader(io.StringIO("\n".join(lines))))
    header = [h.strip().lower() for h in rows[0]]
    missing = [c for c in ("u_px", "v_px") if c not in header]
    world = next((cols for cols in WORLD_COLUMNS if all(c in header for c in cols[:2])), None)
    if missing or world is None:
        raise CalibrationError(f"{source}: header {rows[0]} needs u_px, v_px and either x_m, y_m[, z_m] (corridor "
                               "frame) or lat_deg, lon_deg[, height_m]")
    if world[0] == "lat_deg" and to_xy is None:
        raise CalibrationError(f"{source}: lat/lon pairs need the corridor's origin (give --corridor)")
    out, seen = [], set()
    for i, row in enumerate(rows[1:], start=2):
        rec = dict(zip(header, (c.strip() for c in row), strict=False))
        name = rec.get("name") or f"p{i - 1}"
        try:
            u, v, a, b = (float(rec[c]) for c in ("u_px", "v_px", world[0], world[1]))
            z = float(rec.get(world[2]) or 0.0)
        except (KeyError, ValueError):
            raise CalibrationError(f"{source}: row {i} ({name}): expected numbers in u_px, v_px, {', '.join(world)}, "
                                   f"got {row}") from None
        if not all(math.isfinite(t) for t in (u, v, a, b, z)):
            raise CalibrationError(f"{source}: row {i} ({name}): values must be finite, got {row}")
        if name in seen:
            raise CalibrationError(f"{source}: row {i}: point name {name!r} is used twice (names must be unique)")
        seen.add(name)
        x, y = to_xy(a, b) if world[0] == "lat_deg" else (a, b)  # type: ignore[misc]
        out.append(SurveyPoint(name, u, v, float(x), float(y), z))
    return out


# ----------------------------------------------------------------------------- result
@dataclass(frozen=True)
class PointResidual:
    name: str
    measured_uv: tuple[float, float]
    reprojected_uv: tuple[float, float]
    error_px: float
    flagged: bool
    """Left out of the solution: it disagrees with the others (RANSAC outlier or beyond ``flag_px``)."""


@dataclass(frozen=True)
class CameraSolution:
    camera: CameraConfig
    dist: np.ndarray
    """OpenCV distortion (k1, k2, p1, p2, k3): only k1 is ever solved."""
    points: tuple[SurveyPoint, ...]
    residuals: tuple[PointResidual, ...]
    rms_px: float
    """Reprojection RMS over the points kept."""
    flag_px: float
    focal_solved: bool
    distortion_solved: bool
    covariance: np.ndarray
    """Covariance of ``params``: rvec (3), tvec (3), then f (when solved), k1 (when solved)."""
    params: np.ndarray
    pose_sigma: dict[str, float]
    """1-sigma of x_m, y_m, height_m, yaw_deg, pitch_deg, roll_deg (and fx_px, k1 when solved)."""
    notes: tuple[str, ...] = ()

    @property
    def flagged(self) -> list[str]:
        return [r.name for r in self.residuals if r.flagged]

    @property
    def kept(self) -> list[SurveyPoint]:
        bad = set(self.flagged)
        return [p for p in self.points if p.name not in bad]

    def camera_at(self, params: np.ndarray) -> tuple[CameraConfig, np.ndarray]:
        """The camera and distortion of a parameter vector in the layout of ``params`` (for sampling)."""
        return _unpack(params, self.camera, self.dist, self.focal_solved, self.distortion_solved)


def _unpack(params: np.ndarray, base: CameraConfig, dist: np.ndarray, focal: bool, distortion: bool
            ) -> tuple[CameraConfig, np.ndarray]:
    k = base.intrinsic_matrix.copy()
    i = 6
    if focal:
        aspect = base.fy_px / base.fx_px
        k[0, 0], k[1, 1] = params[i], params[i] * aspect
        i += 1
    d = dist5(dist)
    if distortion:
        d[0] = params[i]
    cam = camera_from_rvec_tvec(params[:3], params[3:6], k, base.width_px, base.height_px, base.fps)
    return cam, d


# ----------------------------------------------------------------------------- solving
def check_points(points: Sequence[SurveyPoint], width_px: int, height_px: int) -> None:
    """Raise :class:`CalibrationError` on too few, collinear or off-image points."""
    n = len(points)
    if n < MIN_POINTS:
        raise CalibrationError(f"too few points: {n} pairs, the pose needs at least {MIN_POINTS} (8 or more to also "
                               f"solve the focal length, {MIN_POINTS_DISTORTION} for lens distortion); survey more "
                               "points spread over the view")
    xyz = np.array([[p.x_m, p.y_m, p.z_m] for p in points])
    sv = np.linalg.svd(xyz - xyz.mean(axis=0), compute_uv=False)
    spread_m = sv[1] / math.sqrt(n)
    if spread_m < 0.5 or sv[1] < 0.02 * sv[0]:
        raise CalibrationError(f"the points are (nearly) collinear: their RMS distance off the best line is "
                               f"{spread_m:.2f} m; add points across the road (both edges, lane lines) and along it")
    uv = np.array([[p.u_px, p.v_px] for p in points])
    off = [p.name for p, (u, v) in zip(points, uv, strict=True)
           if not (-0.5 <= u <= width_px - 0.5 and -0.5 <= v <= height_px - 0.5)]
    if off:
        raise CalibrationError(f"points outside the {width_px}x{height_px} image: {', '.join(off)} (pixel columns "
                               "swapped, or picked on a resized copy of the frame?)")
    dup = {tuple(r) for r in np.round(uv, 1)}
    if len(dup) < n:
        raise CalibrationError("two points share the same pixel: each surveyed point needs its own pixel")


def solve_camera(points: Sequence[SurveyPoint], width_px: int, height_px: int, *, fx_px: float | None = None,
                 cx_px: float | None = None, cy_px: float | None = None, aspect: float = 1.0,
                 solve_focal: str = "auto", solve_distortion: str = "auto", pixel_sigma_px: float = 1.0,
                 ransac_px: float | None = None, fps: float = 15.0) -> CameraSolution:
    """Camera pose (and focal length, k1 when the pairs allow) from surveyed pairs (module docstring)."""
    for flag, name in ((solve_focal, "solve_focal"), (solve_distortion, "solve_distortion")):
        if flag not in ("auto", "yes", "no"):
            raise ValueError(f"{name} must be auto, yes or no, got {flag!r}")
    if fx_px is None and solve_focal == "no":
        raise CalibrationError("no focal length given and solve_focal='no': give the camera's fx_px")
    check_points(points, width_px, height_px)
    pts = list(points)
    cx = width_px / 2.0 if cx_px is None else float(cx_px)
    cy = height_px / 2.0 if cy_px is None else float(cy_px)
    ransac_px = max(3.0, 0.006 * width_px) if ransac_px is None else float(ransac_px)
    notes: list[str] = []
    if fx_px is None or (solve_focal != "no" and len(pts) >= MIN_POINTS_FOCAL):
        guess = fx_px
        fx_px = _sweep_focal(pts, width_px, cx, cy, aspect, ransac_px, guess)
        notes.append(f"focal length guess from a sweep: {fx_px:.0f} px" + (f" (given {guess:.0f} px)" if guess else ""))
    kept = list(pts)
    flagged: list[str] = []
    max_drop = max(0, len(pts) - max(MIN_POINTS, int(math.ceil(0.6 * len(pts)))))
    while True:
        sol = _solve_once(kept, width_px, height_px, fx_px, cx, cy, aspect, solve_focal, solve_distortion,
                          pixel_sigma_px, ransac_px, fps)
        outliers = [p for p, ok in zip(kept, sol["inlier"], strict=True) if not ok]
        err = sol["errors"]
        flag_px = max(2.0, 3.0 * sol["rms"])
        worst = int(np.argmax(np.where(sol["inlier"], err, -1.0)))
        drop = outliers if outliers else ([kept[worst]] if err[worst] > flag_px else [])
        if not drop:
            break
        if len(flagged) + len(drop) > max_drop or len(kept) - len(drop) < MIN_POINTS:
            bad = ", ".join(f"{p.name} ({e:.1f} px)" for p, e in sorted(zip(kept, err, strict=True), key=lambda t: -t[1])[:5])
            raise CalibrationError(f"the points are inconsistent: no camera fits {len(kept) - len(drop)} of "
                                   f"{len(pts)} within {flag_px:.1f} px (worst: {bad}); check that each pixel belongs "
                                   "to its world point, the world columns (x/y or lat/lon) and heights, and the "
                                   "camera's focal length")
        flagged += [p.name for p in drop]
        bad_names = {p.name for p in drop}
        kept = [p for p in kept if p.name not in bad_names]
    cam, dist = sol["camera"], sol["dist"]
    if not (0.0 <= cam.pitch_rad <= math.pi / 2) or abs(cam.roll_rad) > 0.5 or cam.height_m <= 0.0:
        raise CalibrationError(f"no roadside camera looking down fits the pairs (solved: height {cam.height_m:.1f} m, "
                               f"pitch {math.degrees(cam.pitch_rad):.1f} deg, roll {math.degrees(cam.roll_rad):.1f} "
                               "deg): the pairs are inconsistent (pixel and world rows mismatched?) or the world axes "
                               "mirrored (x/y swapped?)")
    notes += sol["notes"]
    all_uv, _ = project(cam, np.array([[p.x_m, p.y_m, p.z_m] for p in pts]), dist)
    residuals = tuple(
        PointResidual(p.name, (p.u_px, p.v_px), (float(r[0]), float(r[1])),
                      float(math.hypot(p.u_px - r[0], p.v_px - r[1])), p.name in flagged)
        for p, r in zip(pts, all_uv, strict=True))
    return CameraSolution(camera=cam, dist=dist, points=tuple(pts), residuals=residuals, rms_px=sol["rms"],
                          flag_px=max(2.0, 3.0 * sol["rms"]), focal_solved=sol["focal"],
                          distortion_solved=sol["distortion"], covariance=sol["cov"], params=sol["params"],
                          pose_sigma=sol["sigma"], notes=tuple(notes))


def _arrays(points: Sequence[SurveyPoint]) -> tuple[np.ndarray, np.ndarray]:
    obj = np.array([[p.x_m, p.y_m, p.z_m] for p in points], dtype=np.float64)
    img = np.array([[p.u_px, p.v_px] for p in points], dtype=np.float64)
    return obj, img


def _k(fx: float, cx: float, cy: float, aspect: float) -> np.ndarray:
    return np.array([[fx, 0.0, cx], [0.0, fx * aspect, cy], [0.0, 0.0, 1.0]])


def _ransac(obj: np.ndarray, img: np.ndarray, k: np.ndarray, dist: np.ndarray, ransac_px: float):
    ok, rvec, tvec, inl = cv2.solvePnPRansac(obj, img, k, dist, iterationsCount=300, reprojectionError=ransac_px,
                                             confidence=0.999, flags=cv2.SOLVEPNP_SQPNP)
    if not ok or inl is None or len(inl) < MIN_POINTS:
        # no consensus: the globally optimal all-point solution, then its points within reach
        ok, rvec, tvec = cv2.solvePnP(obj, img, k, dist, flags=cv2.SOLVEPNP_SQPNP)
        if not ok:
            return None
        err = np.linalg.norm(cv2.projectPoints(obj, rvec, tvec, k, dist)[0].reshape(-1, 2) - img, axis=1)
        inl = np.flatnonzero(err <= max(ransac_px, np.median(err) * 3))
        if len(inl) < MIN_POINTS:
            return None
    inl = np.asarray(inl).ravel()
    for _ in range(5):  # local optimisation: refine on the consensus, re-test every point (EPnP minimal sets are rough)
        rvec, tvec = cv2.solvePnPRefineLM(obj[inl], img[inl], k, dist, rvec, tvec)
        err = np.linalg.norm(cv2.projectPoints(obj, rvec, tvec, k, dist)[0].reshape(-1, 2) - img, axis=1)
        new = np.flatnonzero(err <= ransac_px)
        if len(new) < MIN_POINTS or np.array_equal(new, inl):
            break
        inl = new
    return rvec.reshape(3), tvec.reshape(3), inl


def _sweep_focal(points: Sequence[SurveyPoint], width_px: int, cx: float, cy: float, aspect: float,
                 ransac_px: float, around_px: float | None = None) -> float:
    """The focal length (px) of the best robust fit (MSAC score: squared errors truncated at ``ransac_px``) over
    guesses 0.5-2 x ``around_px`` (0.3-4 x the image width without one), then a finer sweep about the best."""
    obj, img = _arrays(points)

    def score(f: float) -> float:
        k = _k(f, cx, cy, aspect)
        got = _ransac(obj, img, k, np.zeros(5), ransac_px)
        if got is None:
            return math.inf
        err = np.linalg.norm(cv2.projectPoints(obj, got[0], got[1], k, np.zeros(5))[0].reshape(-1, 2) - img, axis=1)
        return float(np.sum(np.minimum(err, ransac_px) ** 2))

    grid = (around_px * np.geomspace(0.5, 2.0, 25)) if around_px else width_px * np.geomspace(0.3, 4.0, 40)
    best = min(grid, key=score)
    step = grid[1] / grid[0]
    return float(min(best * np.geomspace(1 / step, step, 9), key=score))


def _solve_once(points, width_px, height_px, fx_px, cx, cy, aspect, solve_focal, solve_distortion,
                pixel_sigma_px, ransac_px, fps) -> dict:
    obj, img = _arrays(points)
    n = len(points)
    k = _k(fx_px, cx, cy, aspect)
    got = _ransac(obj, img, k, np.zeros(5), ransac_px)
    if got is None:
        raise CalibrationError(f"no camera pose fits {MIN_POINTS} or more of the {n} points within {ransac_px:.1f} px: "
                               "the pairs are inconsistent (pixel and world rows mismatched, wrong world frame or "
                               "heights) or the focal length is far off (try --solve-focal yes or --fx-px)")
    rvec, tvec, inl = got
    inlier = np.zeros(n, dtype=bool)
    inlier[inl] = True
    dist = np.zeros(5)
    notes: list[str] = []
    focal = distortion = False
    want_f = solve_focal == "yes" or (solve_focal == "auto" and len(inl) >= MIN_POINTS_FOCAL)
    want_k1 = solve_distortion == "yes" or (solve_distortion == "auto" and len(inl) >= MIN_POINTS_DISTORTION)
    if want_f or want_k1:
        fit = _calibrate(obj[inl], img[inl], width_px, height_px, k, want_f, want_k1)
        if fit is not None:
            k_new, d_new, sd_f, sd_k1, rv, tv = fit
            keep_f = want_f and (solve_focal == "yes" or sd_f < 0.02 * k_new[0, 0])
            keep_k1 = want_k1 and (solve_distortion == "yes" or abs(d_new[0]) > 3.0 * sd_k1)
            if want_f and not keep_f:
                notes.append(f"focal length not fixed by these points ({k_new[0, 0]:.0f} +- {sd_f:.0f} px): "
                             f"kept {fx_px:.0f} px")
            if want_k1 and not keep_k1:
                notes.append(f"lens distortion not significant (k1 {d_new[0]:+.3f} +- {sd_k1:.3f}): k1 = 0")
            if keep_f != want_f or keep_k1 != want_k1:
                fit = _calibrate(obj[inl], img[inl], width_px, height_px, k, keep_f, keep_k1) if (keep_f or keep_k1) else None
                if fit is None:
                    rvec, tvec = cv2.solvePnPRefineLM(obj[inl], img[inl], k, dist, rvec, tvec)
                    rvec, tvec = rvec.reshape(3), tvec.reshape(3)
            if fit is not None:
                k, dist, _, _, rvec, tvec = fit
                focal, distortion = keep_f, keep_k1
        else:
            notes.append("the intrinsics fit did not converge: intrinsics kept as given")
    uv = cv2.projectPoints(obj, rvec, tvec, k, dist)[0].reshape(-1, 2)
    errors = np.linalg.norm(uv - img, axis=1)
    cam = camera_from_rvec_tvec(rvec, tvec, k, width_px, height_px, fps)
    params = np.concatenate([rvec, tvec, [k[0, 0]] if focal else [], [dist[0]] if distortion else []])
    n_in = int(inlier.sum())
    rms = float(np.sqrt(np.mean(errors[inlier] ** 2)))
    dof = max(1, 2 * n_in - len(params))
    s2 = max(pixel_sigma_px ** 2, float(np.sum(errors[inlier] ** 2)) / dof)
    jac = _residual_jacobian(obj[inlier], rvec, tvec, k, dist, focal, distortion)
    cov = s2 * np.linalg.pinv(jac.T @ jac)
    sigma = _pose_sigma(params, cov, cam, dist, focal, distortion)
    return {"camera": cam, "dist": dist, "inlier": inlier, "errors": errors, "rms": rms, "cov": cov,
            "params": params, "focal": focal, "distortion": distortion, "sigma": sigma, "notes": notes}


def _calibrate(obj, img, width_px, height_px, k, focal: bool, k1: bool):
    flags = (cv2.CALIB_USE_INTRINSIC_GUESS | cv2.CALIB_FIX_PRINCIPAL_POINT | cv2.CALIB_FIX_ASPECT_RATIO
             | cv2.CALIB_ZERO_TANGENT_DIST | cv2.CALIB_FIX_K2 | cv2.CALIB_FIX_K3)
    if not focal:
        flags |= cv2.CALIB_FIX_FOCAL_LENGTH
    if not k1:
        flags |= cv2.CALIB_FIX_K1
    try:
        out = cv2.calibrateCameraExtended([obj.astype(np.float32)], [img.astype(np.float32)], (width_px, height_px),
                                          k.copy(), np.zeros(5), flags=flags,
                                          criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-12))
    except cv2.error:
        return None
    _, k_new, d_new, rvecs, tvecs, sd_int, _, _ = out
    if not np.isfinite(k_new).all() or k_new[0, 0] <= 0:
        return None
    sd = sd_int.ravel()
    return k_new, d_new.ravel()[:5], float(sd[0]), float(sd[4]), rvecs[0].reshape(3), tvecs[0].reshape(3)


def _residual_jacobian(obj, rvec, tvec, k, dist, focal: bool, distortion: bool) -> np.ndarray:
    """d(reprojected pixels)/d(params): cv2.projectPoints' columns rvec, tvec, fx, fy, cx, cy, k1, ..."""
    _, j = cv2.projectPoints(obj, rvec, tvec, k, dist)
    cols = [j[:, :6]]
    if focal:  # fy = aspect * fx
        cols.append((j[:, 6] + j[:, 7] * k[1, 1] / k[0, 0])[:, None])
    if distortion:
        cols.append(j[:, 10:11])
    return np.hstack(cols)


def _pose_sigma(params, cov, cam, dist, focal, distortion) -> dict[str, float]:
    """1-sigma of the corridor-file pose by first-order propagation (central differences of the mapping)."""
    def pose_of(p):
        c, _ = _unpack(p, cam, dist, focal, distortion)
        return np.array([c.x_m, c.y_m, c.height_m, math.degrees(c.yaw_rad), math.degrees(c.pitch_rad),
                         math.degrees(c.roll_rad)])
    jac = np.empty((6, len(params)))
    for i in range(len(params)):
        h = 1e-6 * max(1.0, abs(params[i]))
        dp = np.zeros(len(params))
        dp[i] = h
        jac[:, i] = (pose_of(params + dp) - pose_of(params - dp)) / (2 * h)
    var = np.diag(jac @ cov @ jac.T)
    names = ("x_m", "y_m", "height_m", "yaw_deg", "pitch_deg", "roll_deg")
    out = {n: float(math.sqrt(max(v, 0.0))) for n, v in zip(names, var, strict=True)}
    i = 6
    if focal:
        out["fx_px"] = float(math.sqrt(max(cov[i, i], 0.0)))
        i += 1
    if distortion:
        out["k1"] = float(math.sqrt(max(cov[i, i], 0.0)))
    return out
