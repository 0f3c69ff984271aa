"""Vectorised road frame for the DDM's hot paths.

``protocol.corridor.Road.to_frenet`` projects one point at a time over every reference-line piece;
the DDM needs hundreds of points per decision, so this samples the reference line once (with
``Road.pose_at``), finds each point's nearest sample with a k-d tree (scipy.spatial.cKDTree) and
projects onto the neighbouring pieces. Same convention as the Road: s along the reference line
(right edge of lane 0), d positive to the left.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from protocol.road import Road


class RoadFrame:
    def __init__(self, road: Road, step_m: float = 0.5) -> None:
        self.road = road
        n = max(2, int(np.ceil(road.length_m / step_m)) + 1)
        self.s = np.linspace(0.0, road.length_m, n)
        x, y, h = road.pose_at(self.s, 0.0)
        self.x, self.y, self.h = np.asarray(x), np.asarray(y), np.asarray(h)
        self._tree = cKDTree(np.column_stack([self.x, self.y]))
        self.lane_width_m = road.lane_width_m
        self.lanes = road.lanes

    def to_frenet(self, x_m, y_m) -> tuple[np.ndarray, np.ndarray]:
        """(s, d) of world points (arrays in, arrays out)."""
        px = np.atleast_1d(np.asarray(x_m, dtype=float))
        py = np.atleast_1d(np.asarray(y_m, dtype=float))
        _, idx = self._tree.query(np.column_stack([px, py]))
        best_s = np.empty_like(px)
        best_d = np.empty_like(px)
        best_e = np.full_like(px, np.inf)
        last = len(self.s) - 1
        for off in (-1, 0):  # the pieces before and after the nearest sample
            i = np.clip(idx + off, 0, last - 1)
            ax, ay = self.x[i], self.y[i]
            bx, by = self.x[i + 1] - ax, self.y[i + 1] - ay
            ln2 = np.maximum(bx * bx + by * by, 1e-12)
            t = np.clip(((px - ax) * bx + (py - ay) * by) / ln2, 0.0, 1.0)
            qx, qy = ax + t * bx, ay + t * by
            e = (px - qx) ** 2 + (py - qy) ** 2
            cross = bx * (py - ay) - by * (px - ax)
            better = e < best_e
            best_e = np.where(better, e, best_e)
            best_s = np.where(better, self.s[i] + t * (self.s[i + 1] - self.s[i]), best_s)
            best_d = np.where(better, np.copysign(np.sqrt(e), cross), best_d)
        return best_s, best_d

    def heading_at(self, s_m) -> np.ndarray:
        return np.interp(s_m, self.s, self.h)

    def lane_of(self, d_m) -> np.ndarray:
        """Lane index per offset; -1 off the carriageway (shoulder, opposite side)."""
        d = np.asarray(d_m, dtype=float)
        lane = np.floor(d / self.lane_width_m).astype(int)
        return np.where((d < 0) | (lane >= self.lanes), -1, lane)

    def longitudinal_speed(self, s_m, vx, vy) -> np.ndarray:
        """Velocity component along the road direction at s (m/s, + = direction of travel)."""
        h = self.heading_at(s_m)
        return np.asarray(vx) * np.cos(h) + np.asarray(vy) * np.sin(h)

    def lane_centre_offset(self, lane: int) -> float:
        return self.road.lane_centre_offset_m(lane)
