"""Curve fit and tracking errors of the lateral controller (thesis 4.2.1; report "Curve Fitting").

The N reference points nearest the vehicle are classified as a straight line when every point lies
within ``line_tolerance_m`` of the chord from the first to the last point; otherwise a circle is
fitted by least squares on the algebraic error of eq. 4.1, which is linear in the unknowns
(x_c, y_c, R^2 - x_c^2 - y_c^2) and solved in one ``numpy.linalg.lstsq`` call (eq. 4.2).

Sign convention (the thesis fixes none; docs/architecture.md §Vehicle controller): the path has a direction (the order
of its points). ``lateral_error_m`` is positive when the vehicle is to the LEFT of the path,
``curvature_1pm`` is positive for a left (counter-clockwise) turn, the yaw error is
theta - theta_R wrapped to (-pi, pi] (eq. 4.6), and the yaw-rate error is
theta_dot - v_x * curvature (eq. 4.7 with a signed 1/R). With these, eq. 4.3 reads
e_lat = sign(kappa) * (R - |p - c|) and eq. 4.4 e_lat = cross(t, p - p0) for the unit tangent t,
which equals (y_v - m x_v - c) / sqrt(1 + m^2) for a line heading towards +x.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

LINE_TOLERANCE_M = 0.002
"""Default chord-deviation threshold below which the points are a straight line (2 mm: the reference
points are exact, and over a 6 m window a 1 cm threshold would call R < 450 m arcs straight)."""


def wrap_angle(angle_rad: float) -> float:
    """Wrap to (-pi, pi]."""
    a = math.fmod(angle_rad + math.pi, 2.0 * math.pi)
    if a <= 0.0:
        a += 2.0 * math.pi
    return a - math.pi


@dataclass(frozen=True, slots=True)
class PathFit:
    """Local model of the reference near the vehicle: a directed line or a directed circular arc."""

    is_line: bool
    point_x_m: float
    point_y_m: float
    """Line: a point on it (the first reference point). Arc: the centre (x_c, y_c)."""
    dir_x: float
    dir_y: float
    """Line: unit direction of travel. Arc: unused (0, 0)."""
    radius_m: float
    """Arc radius R (inf for a line)."""
    turn: int
    """+1 counter-clockwise (left turn), -1 clockwise, 0 for a line."""

    @property
    def curvature_1pm(self) -> float:
        """Signed curvature: +1/R for a left turn, -1/R for a right turn, 0 on a line."""
        return 0.0 if self.is_line else self.turn / self.radius_m

    def lateral_error_m(self, x_m: float, y_m: float) -> float:
        """Signed lateral error, positive left of the path (eq. 4.3 on an arc, eq. 4.4 on a line)."""
        if self.is_line:
            return self.dir_x * (y_m - self.point_y_m) - self.dir_y * (x_m - self.point_x_m)
        dist = math.hypot(x_m - self.point_x_m, y_m - self.point_y_m)
        return self.turn * (self.radius_m - dist)

    def heading_at(self, x_m: float, y_m: float) -> float:
        """Path heading theta_R (rad) at the point of the path nearest (x, y)."""
        if self.is_line:
            return math.atan2(self.dir_y, self.dir_x)
        rx, ry = x_m - self.point_x_m, y_m - self.point_y_m
        # tangent of a CCW circle is the radius vector turned +90 deg; CW turns it -90 deg
        return math.atan2(self.turn * rx, -self.turn * ry)

    def errors(self, x_m: float, y_m: float, yaw_rad: float, yaw_rate_rps: float,
               speed_mps: float) -> tuple[float, float, float]:
        """(e_lat, yaw error, yaw-rate error) of a vehicle pose (eqs. 4.3/4.4, 4.6, 4.7)."""
        e_lat = self.lateral_error_m(x_m, y_m)
        yaw_err = wrap_angle(yaw_rad - self.heading_at(x_m, y_m))
        yaw_rate_err = yaw_rate_rps - speed_mps * self.curvature_1pm
        return e_lat, yaw_err, yaw_rate_err


def chord_deviation_m(points: np.ndarray) -> float:
    """Largest distance of the points from the chord joining the first and the last one."""
    p0, p1 = points[0], points[-1]
    chord = p1 - p0
    length = math.hypot(chord[0], chord[1])
    if length == 0.0:
        raise ValueError("the first and last reference points coincide; cannot define a chord")
    rel = points - p0
    return float(np.max(np.abs(chord[0] * rel[:, 1] - chord[1] * rel[:, 0])) / length)


def fit_circle(points: np.ndarray) -> tuple[float, float, float]:
    """Least-squares circle (x_c, y_c, R) minimising the algebraic error of eq. 4.1.

    x^2 + y^2 = 2 x_c x + 2 y_c y + (R^2 - x_c^2 - y_c^2) is linear in the three unknowns (eq. 4.2);
    points are centred first so that the solve is well conditioned far from the origin.
    """
    pts = np.asarray(points, dtype=float)
    if pts.ndim != 2 or pts.shape[1] != 2 or len(pts) < 3:
        raise ValueError(f"fit_circle needs an (N>=3, 2) array of points, got shape {pts.shape}")
    mean = pts.mean(axis=0)
    q = pts - mean
    a = np.column_stack([2.0 * q[:, 0], 2.0 * q[:, 1], np.ones(len(q))])
    rhs = q[:, 0] ** 2 + q[:, 1] ** 2
    sol, *_ = np.linalg.lstsq(a, rhs, rcond=None)
    xc, yc, k = float(sol[0]), float(sol[1]), float(sol[2])
    r2 = k + xc * xc + yc * yc
    if not r2 > 0.0 or not math.isfinite(r2):
        raise ValueError("degenerate circle fit (collinear or repeated points)")
    return xc + float(mean[0]), yc + float(mean[1]), math.sqrt(r2)


def fit_line(points: np.ndarray) -> tuple[float, float, float, float]:
    """Total-least-squares line through the points: (x0, y0, ux, uy), direction of travel first->last."""
    pts = np.asarray(points, dtype=float)
    mean = pts.mean(axis=0)
    _, _, vt = np.linalg.svd(pts - mean, full_matrices=False)
    u = vt[0]
    if np.dot(u, pts[-1] - pts[0]) < 0:
        u = -u
    return float(mean[0]), float(mean[1]), float(u[0]), float(u[1])


def fit_path(points: np.ndarray, line_tolerance_m: float = LINE_TOLERANCE_M) -> PathFit:
    """Thesis 4.2.1: a line when all points are within ``line_tolerance_m`` of the chord, else an arc.

    ``points`` are the N reference points nearest the vehicle, in driving order.
    """
    pts = np.asarray(points, dtype=float)
    if pts.ndim != 2 or pts.shape[1] != 2 or len(pts) < 2:
        raise ValueError(f"fit_path needs an (N>=2, 2) array of points, got shape {pts.shape}")
    if not np.all(np.isfinite(pts)):
        raise ValueError("reference points must be finite")
    if len(pts) == 2 or chord_deviation_m(pts) <= line_tolerance_m:
        x0, y0, ux, uy = fit_line(pts)
        return PathFit(True, x0, y0, ux, uy, math.inf, 0)
    xc, yc, r = fit_circle(pts)
    # turn direction from the travel direction around the centre (cross of radius and motion)
    rx, ry = pts[0, 0] - xc, pts[0, 1] - yc
    mx, my = pts[-1, 0] - pts[0, 0], pts[-1, 1] - pts[0, 1]
    turn = 1 if rx * my - ry * mx > 0 else -1
    return PathFit(False, xc, yc, 0.0, 0.0, r, turn)
