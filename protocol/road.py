"""Road geometry of a corridor (docs/architecture.md §Corridor file): the reference line and its lanes.

Road frame: the reference line is the right edge of lane 0 (the curb line), in the direction of travel, made of
straight and arc segments; ``s`` is the distance along it and ``d`` the signed offset, positive to the left. Lane
``i`` spans ``d`` in [i*w, (i+1)*w] (lane 0 = rightmost); the shoulder is d in [-shoulder, 0]. ``pose_at`` maps
(s, d) to world (x, y, heading) exactly on lines and arcs; ``to_frenet`` is its inverse (nearest point).
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np


@dataclass(frozen=True)
class Segment:
    kind: str  # "straight" | "arc"
    length_m: float
    radius_m: float | None = None
    """Arc radius; positive turns left (counter-clockwise), negative turns right."""


@dataclass(frozen=True)
class Road:
    start_x_m: float
    start_y_m: float
    start_heading_rad: float
    segments: tuple[Segment, ...]
    lanes: int = 2
    lane_width_m: float = 3.7
    shoulder_width_m: float = 2.5
    opposite_lanes: int = 0
    speed_limit_mps: float = 13.4
    sample_step_m: float = 0.25

    @property
    def length_m(self) -> float:
        return sum(s.length_m for s in self.segments)

    @property
    def width_m(self) -> float:
        return self.lanes * self.lane_width_m

    @cached_property
    def _samples(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Reference line sampled every ``sample_step_m``: s, x, y, heading (exact per segment)."""
        ss, xs, ys, hs = [0.0], [self.start_x_m], [self.start_y_m], [self.start_heading_rad]
        s0, x0, y0, h0 = 0.0, self.start_x_m, self.start_y_m, self.start_heading_rad
        for seg in self.segments:
            n = max(1, int(math.ceil(seg.length_m / self.sample_step_m)))
            u = np.linspace(0.0, seg.length_m, n + 1)[1:]
            if seg.kind == "straight":
                x = x0 + u * math.cos(h0)
                y = y0 + u * math.sin(h0)
                h = np.full_like(u, h0)
            else:
                k = 1.0 / seg.radius_m  # type: ignore[operator]
                h = h0 + k * u
                x = x0 + (np.sin(h) - math.sin(h0)) / k
                y = y0 - (np.cos(h) - math.cos(h0)) / k
            ss.extend(s0 + u), xs.extend(x), ys.extend(y), hs.extend(h)
            s0, x0, y0, h0 = s0 + seg.length_m, float(x[-1]), float(y[-1]), float(h[-1])
        return np.array(ss), np.array(xs), np.array(ys), np.array(hs)

    def pose_at(self, s_m: float | np.ndarray, d_m: float | np.ndarray = 0.0):
        """World (x, y, heading) of the road point at distance s and lateral offset d (left +)."""
        if isinstance(s_m, (float, int)) and isinstance(d_m, (float, int)):
            return self._pose_scalar(float(s_m), float(d_m))
        s_arr, x_arr, y_arr, h_arr = self._samples
        s = np.clip(np.asarray(s_m, dtype=float), s_arr[0], s_arr[-1])
        i = np.clip(np.searchsorted(s_arr, s, side="right") - 1, 0, len(s_arr) - 2)
        # exact within a sample interval: the heading is linear in s on lines and arcs
        ds = s - s_arr[i]
        h0, h1 = h_arr[i], h_arr[i + 1]
        seg_len = s_arr[i + 1] - s_arr[i]
        dh = h1 - h0
        k = np.where(seg_len > 0, dh / np.where(seg_len > 0, seg_len, 1.0), 0.0)
        h = h0 + k * ds
        small = np.abs(k) < 1e-12
        kk = np.where(small, 1.0, k)
        x = np.where(small, x_arr[i] + ds * np.cos(h0), x_arr[i] + (np.sin(h) - np.sin(h0)) / kk)
        y = np.where(small, y_arr[i] + ds * np.sin(h0), y_arr[i] - (np.cos(h) - np.cos(h0)) / kk)
        d = np.asarray(d_m, dtype=float)
        x = x - d * np.sin(h)
        y = y + d * np.cos(h)
        if np.ndim(x) == 0:
            return float(x), float(y), float(h)
        return x, y, h

    def prepare(self) -> Road:
        """Build now what the first ``to_frenet`` / ``pose_at`` would build (the samples, the k-d tree and the
        scipy.spatial import under it: 0.4 s of CPU). A service calls it at start-up, before the scenario: several
        processes paying it together at the first world snapshot stalled every RSU of a two-core corridor for about
        a second."""
        _ = self._sample_tree, self._pieces, self._samples_list
        return self

    @cached_property
    def _sample_tree(self):
        from scipy.spatial import cKDTree

        _, x_arr, y_arr, _ = self._samples
        return cKDTree(np.column_stack([x_arr, y_arr]))

    @cached_property
    def _pieces(self) -> list[tuple[float, float, float, float, float]]:
        """Per piece of the sampled reference line: start x, y, direction x, y (to the next sample), length^2."""
        _, x_arr, y_arr, _ = self._samples
        ax, ay = x_arr[:-1], y_arr[:-1]
        bx, by = x_arr[1:] - ax, y_arr[1:] - ay
        return list(zip(ax.tolist(), ay.tolist(), bx.tolist(), by.tolist(), (bx * bx + by * by).tolist(), strict=True))

    @cached_property
    def _samples_list(self) -> tuple[list[float], list[float], list[float], list[float]]:
        return tuple(a.tolist() for a in self._samples)  # type: ignore[return-value]

    def _pose_scalar(self, s_m: float, d_m: float) -> tuple[float, float, float]:
        """``pose_at`` of one point in plain floats: the same arithmetic, without numpy's per-call cost (the
        localiser, the DDM and the vehicle call it per object, per frame; 80 us -> a few us)."""
        s_arr, x_arr, y_arr, h_arr = self._samples_list
        s = min(max(s_m, s_arr[0]), s_arr[-1])
        i = min(max(bisect.bisect_right(s_arr, s) - 1, 0), len(s_arr) - 2)
        ds = s - s_arr[i]
        h0 = h_arr[i]
        seg_len = s_arr[i + 1] - s_arr[i]
        k = (h_arr[i + 1] - h0) / seg_len if seg_len > 0 else 0.0
        h = h0 + k * ds
        if abs(k) < 1e-12:
            x, y = x_arr[i] + ds * math.cos(h0), y_arr[i] + ds * math.sin(h0)
        else:
            x, y = x_arr[i] + (math.sin(h) - math.sin(h0)) / k, y_arr[i] - (math.cos(h) - math.cos(h0)) / k
        return x - d_m * math.sin(h), y + d_m * math.cos(h), h

    def curvature_at(self, s_m: float) -> float:
        s = 0.0
        for seg in self.segments:
            if s_m <= s + seg.length_m:
                return 0.0 if seg.kind == "straight" else 1.0 / seg.radius_m  # type: ignore[operator]
            s += seg.length_m
        return 0.0

    def to_frenet(self, x_m: float | np.ndarray, y_m: float | np.ndarray):
        """(s, d) of world points: nearest point on the reference line, d positive to the left."""
        px = np.atleast_1d(np.asarray(x_m, dtype=float))
        py = np.atleast_1d(np.asarray(y_m, dtype=float))
        out_s = np.empty_like(px)
        out_d = np.empty_like(px)
        # the nearest sample of each point (a k-d tree), then the two pieces that meet there: the nearest point of
        # a line sampled every sample_step_m lies on one of them (compared against every piece in the tests)
        _, near = self._sample_tree.query(np.column_stack([px, py]))
        pieces, (s_arr, *_) = self._pieces, self._samples_list
        for j, (x, y, n) in enumerate(zip(px.tolist(), py.tolist(), np.atleast_1d(near).tolist(), strict=True)):
            best = None
            for i in (n - 1, n):
                if not 0 <= i < len(pieces):
                    continue
                ax, ay, bx, by, len2 = pieces[i]
                t = min(max(((x - ax) * bx + (y - ay) * by) / len2, 0.0), 1.0)
                dist2 = (x - ax - t * bx) ** 2 + (y - ay - t * by) ** 2
                if best is None or dist2 < best[0]:
                    best = (dist2, i, t)
            _, i, t = best
            s_j = s_arr[i] + t * (s_arr[i + 1] - s_arr[i])
            # refine on the exact curve: move s along the tangent until the offset is normal to it
            for _ in range(2):
                rx, ry, rh = self._pose_scalar(s_j, 0.0)
                s_j = min(max(s_j + (x - rx) * math.cos(rh) + (y - ry) * math.sin(rh), s_arr[0]), s_arr[-1])
            rx, ry, rh = self._pose_scalar(s_j, 0.0)
            out_s[j] = s_j
            out_d[j] = -(x - rx) * math.sin(rh) + (y - ry) * math.cos(rh)
        if np.ndim(x_m) == 0:
            return float(out_s[0]), float(out_d[0])
        return out_s, out_d

    def lane_centre_offset_m(self, lane: int) -> float:
        if not 0 <= lane < self.lanes:
            raise ValueError(f"lane {lane} does not exist (the road has lanes 0..{self.lanes - 1})")
        return (lane + 0.5) * self.lane_width_m

    def lane_of_offset(self, d_m: float) -> int | None:
        """Lane index at lateral offset d, None on the shoulder or off the road."""
        if d_m < 0 or d_m >= self.lanes * self.lane_width_m:
            return None
        return int(d_m // self.lane_width_m)

    def lane_at(self, x_m: float, y_m: float) -> int | None:
        return self.lane_of_offset(self.to_frenet(x_m, y_m)[1])
