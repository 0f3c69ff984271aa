"""Reference paths the vehicle follows: commanded waypoints or the centre of a lane.

A ``ReferencePath`` resamples its waypoints at a fixed spacing along a smooth interpolant
(``scipy.interpolate.make_interp_spline`` on chord length) so that the curve fit of thesis 4.2.1
always sees N points spread over the same distance, whatever the spacing of the command's
waypoints. It also carries a speed profile and an optional stop point, both indexed by the
distance ``s`` along the path.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.interpolate import make_interp_spline

from vehicle.geometry import LINE_TOLERANCE_M, PathFit, fit_path

RESAMPLE_STEP_M = 0.5
FIT_POINTS = 13
"""N of thesis 4.2.1: 13 points 0.5 m apart span 6 m of path."""


@dataclass(frozen=True, slots=True)
class PathProjection:
    index: int
    """Index of the resampled point nearest the query."""
    s_m: float
    """Distance along the path of the projection of the query."""
    distance_m: float
    """Distance from the query to the path (unsigned)."""


class ReferencePath:
    """A directed path in the corridor frame with speeds, resampled every ``step_m``."""

    def __init__(self, waypoints: np.ndarray | list, speeds_mps: np.ndarray | list | None = None,
                 stop_point: tuple[float, float] | None = None, step_m: float = RESAMPLE_STEP_M,
                 extend_m: float = 0.0) -> None:
        wp = np.asarray(waypoints, dtype=float)
        if wp.ndim != 2 or wp.shape[1] != 2 or len(wp) < 2:
            raise ValueError(f"a path needs at least 2 (x, y) waypoints, got shape {wp.shape}")
        if not np.all(np.isfinite(wp)):
            raise ValueError("waypoints must be finite")
        seg = np.hypot(*np.diff(wp, axis=0).T)
        keep = np.concatenate([[True], seg > 1e-6])  # drop repeated points
        wp = wp[keep]
        if len(wp) < 2:
            raise ValueError("waypoints collapse to a single point")
        if extend_m > 0:  # straight run-out past the last waypoint (room for the fit window)
            d = wp[-1] - wp[-2]
            wp = np.vstack([wp, wp[-1] + d / np.hypot(*d) * extend_m])
        chord = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(wp, axis=0).T))])
        k = min(3, len(wp) - 1)
        spline = make_interp_spline(chord, wp, k=k)
        n = max(2, int(math.ceil(chord[-1] / step_m)) + 1)
        u = np.linspace(0.0, chord[-1], n)
        pts = spline(u)
        self.points = pts
        self.s = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(pts, axis=0).T))])
        self.length_m = float(self.s[-1])
        d = np.gradient(pts, axis=0)
        self.headings = np.arctan2(d[:, 1], d[:, 0])
        if speeds_mps is None or len(speeds_mps) == 0:
            self.speeds = None
        else:
            sp = np.asarray(speeds_mps, dtype=float)
            if sp.shape != (len(keep),):
                raise ValueError("speeds_mps needs one entry per waypoint")
            sp = sp[keep]
            if extend_m > 0:
                sp = np.append(sp, sp[-1])
            self.speeds = np.interp(u, chord, sp)
        self.stop_s_m: float | None = None
        self.stop_offset_m = 0.0
        if stop_point is not None:
            proj = self.project(*stop_point)
            self.stop_s_m = proj.s_m
            self.stop_offset_m = proj.distance_m
        self._hint = 0
        self._fits: dict[tuple[int, int, float], PathFit] = {}

    # ------------------------------------------------------------------ queries
    def project(self, x_m: float, y_m: float, hint: int | None = None, window: int = 40) -> PathProjection:
        """Nearest point of the path; searches near ``hint`` first (O(window)), globally otherwise."""
        pts = self.points
        if hint is not None and 0 <= hint < len(pts):  # a hint from another (longer) path is ignored
            lo, hi = max(0, hint - window), min(len(pts), hint + window + 1)
            d2 = (pts[lo:hi, 0] - x_m) ** 2 + (pts[lo:hi, 1] - y_m) ** 2
            i = lo + int(np.argmin(d2))
            if lo < i < hi - 1 or i in (0, len(pts) - 1):
                return self._refine(i, x_m, y_m)
        d2 = (pts[:, 0] - x_m) ** 2 + (pts[:, 1] - y_m) ** 2
        return self._refine(int(np.argmin(d2)), x_m, y_m)

    def _refine(self, i: int, x_m: float, y_m: float) -> PathProjection:
        """Project onto the polyline pieces either side of point i."""
        best = (math.inf, self.s[i], i)
        for j in (i - 1, i):
            if 0 <= j < len(self.points) - 1:
                ax, ay = self.points[j]
                bx, by = self.points[j + 1] - self.points[j]
                l2 = bx * bx + by * by
                t = min(1.0, max(0.0, ((x_m - ax) * bx + (y_m - ay) * by) / l2)) if l2 > 0 else 0.0
                dist = math.hypot(x_m - ax - t * bx, y_m - ay - t * by)
                if dist < best[0]:
                    best = (dist, self.s[j] + t * (self.s[j + 1] - self.s[j]), i)
        return PathProjection(best[2], float(best[1]), float(best[0]))

    def _window_start(self, s_m: float, n: int, behind: int | None) -> int:
        i = int(np.searchsorted(self.s, s_m))
        start = i - (n // 2 if behind is None else behind)
        return min(max(0, start), len(self.points) - n)

    def window(self, s_m: float, n: int = FIT_POINTS, behind: int | None = None) -> np.ndarray:
        """The n resampled points around distance s (``behind`` of them before it; default n//2, centred)."""
        n = min(n, len(self.points))
        start = self._window_start(s_m, n, behind)
        return self.points[start:start + n]

    def fit_at(self, s_m: float, n: int = FIT_POINTS,
               line_tolerance_m: float = LINE_TOLERANCE_M) -> PathFit:
        """``fit_path`` of the window around s; a window fitted before is not fitted again (the car's 100 Hz steps
        call this two or three times each, and the window moves one resampled point every few steps)."""
        n = min(n, len(self.points))
        key = (self._window_start(s_m, n, None), n, line_tolerance_m)
        fit = self._fits.get(key)
        if fit is None:
            if len(self._fits) >= 64:
                self._fits.clear()
            fit = self._fits[key] = fit_path(self.points[key[0]:key[0] + n], line_tolerance_m)
        return fit

    def speed_at(self, s_m: float, default_mps: float) -> float:
        if self.speeds is None:
            return default_mps
        return float(np.interp(s_m, self.s, self.speeds))

    def heading_at(self, s_m: float) -> float:
        i = int(np.clip(np.searchsorted(self.s, s_m), 0, len(self.s) - 1))
        return float(self.headings[i])

    def point_at(self, s_m: float) -> tuple[float, float]:
        return (float(np.interp(s_m, self.s, self.points[:, 0])),
                float(np.interp(s_m, self.s, self.points[:, 1])))

    def max_curvature_1pm(self) -> float:
        """Largest |curvature| along the path (from headings of the resampled points)."""
        if len(self.points) < 3:
            return 0.0
        dh = np.abs(np.angle(np.exp(1j * np.diff(self.headings))))
        ds = np.diff(self.s)
        return float(np.max(dh / np.maximum(ds, 1e-9)))


# ---------------------------------------------------------------------- path builders
def lane_centre_waypoints(road, lane: int, s_from_m: float, s_to_m: float, step_m: float = 2.0) -> np.ndarray:
    """Waypoints along the centre of ``lane`` of a corridor ``Road`` between two stations."""
    s_to_m = min(s_to_m, road.length_m)
    n = max(2, int(math.ceil((s_to_m - s_from_m) / step_m)) + 1)
    s = np.linspace(s_from_m, s_to_m, n)
    x, y, _ = road.pose_at(s, np.full_like(s, road.lane_centre_offset_m(lane)))
    return np.column_stack([x, y])


def lane_change_waypoints(road, s_start_m: float, from_lane: int, to_lane: int, change_length_m: float,
                          total_length_m: float, step_m: float = 2.0, lead_m: float = 0.0) -> np.ndarray:
    """A one-lane change on a ``Road``: the lateral offset follows a quintic over ``change_length_m``.

    The path starts ``lead_m`` before ``s_start_m`` (still in ``from_lane``) and ends
    ``total_length_m`` after it. d(u) = d0 + (d1 - d0)(10u^3 - 15u^4 + 6u^5), u in [0, 1], has zero
    slope and zero curvature at both ends (no steering step) and a peak curvature of
    5.77 |d1 - d0| / L^2 (0.0133 1/m for 3.7 m over 40 m).
    """
    d0, d1 = road.lane_centre_offset_m(from_lane), road.lane_centre_offset_m(to_lane)
    s_end = min(s_start_m + total_length_m, road.length_m)
    n = max(2, int(math.ceil((s_end - s_start_m) / step_m)) + 1)
    s = np.linspace(s_start_m - lead_m, s_end, n + int(math.ceil(lead_m / step_m)))
    u = np.clip((s - s_start_m) / change_length_m, 0.0, 1.0)
    d = d0 + (d1 - d0) * u ** 3 * (10.0 - 15.0 * u + 6.0 * u * u)
    x, y, _ = road.pose_at(s, d)
    return np.column_stack([x, y])


def offset_change_waypoints(road, s_start_m: float, d_from_m: float, d_to_m: float, change_length_m: float,
                            total_length_m: float, step_m: float = 2.0) -> np.ndarray:
    """From offset ``d_from_m`` to ``d_to_m`` (any offsets, e.g. onto the shoulder) on a ``Road``: the same
    quintic as ``lane_change_waypoints`` over ``change_length_m``, then straight on to ``total_length_m``."""
    s_end = min(s_start_m + total_length_m, road.length_m)
    n = max(2, int(math.ceil((s_end - s_start_m) / step_m)) + 1)
    s = np.linspace(s_start_m, s_end, n)
    u = np.clip((s - s_start_m) / max(change_length_m, 1e-6), 0.0, 1.0)
    d = d_from_m + (d_to_m - d_from_m) * u ** 3 * (10.0 - 15.0 * u + 6.0 * u * u)
    x, y, _ = road.pose_at(s, d)
    return np.column_stack([x, y])
