"""Check image of a camera calibration: the corridor drawn through the camera onto its frame.

Drawn: the 10 m ground grid of the corridor frame (grey, labelled with the distance from the camera's
foot along the road), the lane lines (cyan), the road edges (orange), the RSU's coverage limit
(``max_range_m`` from the mast, red), and the surveyed points: measured pixel (green circle),
reprojection of its world point (magenta cross), a line between them, its name; points the solution
left out are red. A camera that has moved shows lines off the painted lanes: the same layer is drawn by
``iea-rsu --annotate`` under the boxes (:class:`CalibrationOverlay`, computed once, composited per frame).
Pure: numpy/OpenCV drawing on arrays, no I/O.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import cv2
import numpy as np

from protocol.corridor import CameraConfig
from protocol.road import Road
from rsu.calibration.camera_geometry import project

GRID = (110, 110, 110)
LANE = (255, 255, 0)
EDGE = (0, 140, 255)
LIMIT = (40, 40, 230)
MEASURED = (60, 220, 60)
REPROJECTED = (255, 0, 255)
FLAGGED = (0, 0, 255)


@dataclass(frozen=True)
class OverlayPoint:
    name: str
    measured_uv: tuple[float, float]
    reprojected_uv: tuple[float, float] | None
    flagged: bool = False


def _polyline(img: np.ndarray, cam: CameraConfig, dist: np.ndarray | None, xyz: np.ndarray, colour, thickness: int,
              dash_samples: int | None = None) -> None:
    """Draw a world polyline (N, 3) through the camera: the runs in front of it and near the image (dashed: runs
    of ``dash_samples`` points on, as many off)."""
    uv, depth = project(cam, xyz, dist)
    h, w = img.shape[:2]
    ok = (depth > 1.0) & (np.abs(uv[:, 0] - w / 2) < 2 * w) & (np.abs(uv[:, 1] - h / 2) < 2 * h)
    if dash_samples:
        ok &= (np.arange(len(ok)) // dash_samples) % 2 == 0
    pts = np.round(np.where(ok[:, None], uv, 0.0) * 16).astype(np.int32)  # 4 fractional bits: smooth lines
    edges = np.flatnonzero(np.diff(np.concatenate([[0], ok.astype(np.int8), [0]])))
    runs = [pts[a:b] for a, b in zip(edges[::2], edges[1::2], strict=True) if b - a >= 2]
    if runs:
        cv2.polylines(img, runs, False, colour, thickness, cv2.LINE_AA, shift=4)


def _label(img: np.ndarray, text: str, uv, colour, scale: float = 0.4) -> None:
    h, w = img.shape[:2]
    u, v = int(round(uv[0])), int(round(uv[1]))
    if 0 <= u < w and 0 <= v < h:
        for du, dv in ((-1, 0), (1, 0), (0, -1), (0, 1)):  # a dark outline (thicker text is also wider)
            cv2.putText(img, text, (u + 4 + du, v - 4 + dv), cv2.FONT_HERSHEY_SIMPLEX, scale, (0, 0, 0), 1,
                        cv2.LINE_AA)
        cv2.putText(img, text, (u + 4, v - 4), cv2.FONT_HERSHEY_SIMPLEX, scale, colour, 1, cv2.LINE_AA)


def draw_corridor(img: np.ndarray, cam: CameraConfig, road: Road, *, dist: np.ndarray | None = None,
                  max_range_m: float | None = None, grid_step_m: float = 10.0, grid_extent_m: float = 150.0,
                  step_m: float = 0.5) -> np.ndarray:
    """Grid, lanes, road edges and coverage limit drawn onto ``img`` (in place; returned)."""
    scale = max(0.3, img.shape[1] / 1600.0)
    thick = max(1, int(round(img.shape[1] / 1280)))
    cx, cy = cam.x_m, cam.y_m
    lo_x, lo_y = (np.floor((np.array([cx, cy]) - grid_extent_m) / grid_step_m) * grid_step_m)
    line = np.arange(-grid_extent_m, grid_extent_m + 1e-9, step_m)
    for k in np.arange(0, 2 * grid_extent_m + 1e-9, grid_step_m):
        gx = np.column_stack([np.full_like(line, lo_x + k), cy + line, np.zeros_like(line)])
        gy = np.column_stack([cx + line, np.full_like(line, lo_y + k), np.zeros_like(line)])
        _polyline(img, cam, dist, gx, GRID, 1)
        _polyline(img, cam, dist, gy, GRID, 1)
    s = np.arange(0.0, road.length_m + 1e-9, step_m)
    total = road.lanes + road.opposite_lanes
    for i in range(total + 1):
        d = i * road.lane_width_m
        x, y, _ = road.pose_at(s, d)
        edge = i in (0, total)
        _polyline(img, cam, dist, np.column_stack([x, y, np.zeros_like(x)]), EDGE if (edge and i == total) else LANE,
                  thick, None if edge else 6)
    x, y, _ = road.pose_at(s, -road.shoulder_width_m)
    _polyline(img, cam, dist, np.column_stack([x, y, np.zeros_like(x)]), EDGE, thick)
    s_cam, _ = road.to_frenet(cx, cy)
    label_to_m = min(grid_extent_m, max_range_m or 100.0)
    for k in range(1, int(label_to_m // grid_step_m) + 1):  # distance labels along the road, every 2 grid steps
        for sign in (1, -1):
            if k % 2:
                continue
            x, y, _ = road.pose_at(s_cam + sign * k * grid_step_m, road.lanes * road.lane_width_m)
            uv, depth = project(cam, np.array([[x, y, 0.0]]), dist)
            if depth[0] > 1.0:
                _label(img, f"{k * grid_step_m:.0f} m", uv[0], GRID, scale)
    if max_range_m is not None:
        a = np.linspace(0.0, 2 * np.pi, 1441)
        ring = np.column_stack([cx + max_range_m * np.cos(a), cy + max_range_m * np.sin(a), np.zeros_like(a)])
        _polyline(img, cam, dist, ring, LIMIT, thick)
        uv, depth = project(cam, ring, dist)
        h, w = img.shape[:2]
        inside = np.flatnonzero((depth > 1) & (uv[:, 0] >= 0) & (uv[:, 0] < w) & (uv[:, 1] >= 0) & (uv[:, 1] < h))
        if len(inside):
            _label(img, f"coverage limit {max_range_m:.0f} m", uv[inside[len(inside) // 2]], LIMIT, scale)
    return img


def draw_points(img: np.ndarray, points: Sequence[OverlayPoint]) -> np.ndarray:
    """Surveyed points: measured (circle), reprojected (cross), the line between, the name (in place; returned)."""
    scale = max(0.3, img.shape[1] / 1600.0)
    r = max(3, int(round(img.shape[1] / 320)))
    for p in points:
        colour = FLAGGED if p.flagged else MEASURED
        m = tuple(int(round(v)) for v in p.measured_uv)
        if p.reprojected_uv is not None and np.isfinite(p.reprojected_uv).all():
            q = tuple(int(round(v)) for v in p.reprojected_uv)
            cv2.line(img, m, q, colour, 1, cv2.LINE_AA)
            cv2.drawMarker(img, q, REPROJECTED, cv2.MARKER_CROSS, 2 * r + 2, 1, cv2.LINE_AA)
        cv2.circle(img, m, r, colour, 1, cv2.LINE_AA)
        _label(img, p.name + (" (left out)" if p.flagged else ""), p.measured_uv, colour, scale)
    return img


def draw_legend(img: np.ndarray, lines: Sequence[tuple[str, tuple[int, int, int]]]) -> np.ndarray:
    scale = max(0.3, img.shape[1] / 1600.0)
    step = int(22 * scale / 0.5)
    for i, (text, colour) in enumerate(lines):
        _label(img, text, (2, step * (i + 1)), colour, scale)
    return img


def check_image(frame: np.ndarray, cam: CameraConfig, road: Road, *, dist: np.ndarray | None = None,
                max_range_m: float | None = None, points: Sequence[OverlayPoint] = (),
                title: str = "", min_width_px: int = 960) -> np.ndarray:
    """The check image (module docstring) on a copy of ``frame``, enlarged by a whole factor to at
    least ``min_width_px`` wide so that labels stay legible on small frames."""
    k = max(1, int(np.ceil(min_width_px / frame.shape[1])))
    img = cv2.resize(frame, None, fx=k, fy=k, interpolation=cv2.INTER_CUBIC) if k > 1 else frame.copy()
    if k > 1:
        cam = replace(cam, width_px=cam.width_px * k, height_px=cam.height_px * k, fx_px=cam.fx_px * k,
                      fy_px=cam.fy_px * k, cx_px=(cam.cx_px + 0.5) * k - 0.5, cy_px=(cam.cy_px + 0.5) * k - 0.5)

        def up(uv):
            return None if uv is None else tuple((np.asarray(uv, dtype=float) + 0.5) * k - 0.5)
        points = [replace(p, measured_uv=up(p.measured_uv), reprojected_uv=up(p.reprojected_uv)) for p in points]
    draw_corridor(img, cam, road, dist=dist, max_range_m=max_range_m)
    draw_points(img, points)
    legend = [(title, (255, 255, 255))] if title else []
    legend += [("grid 10 m", GRID), ("lanes", LANE), ("road edge", EDGE), ("coverage limit", LIMIT),
               ("surveyed (o) / reprojected (+)", MEASURED)]
    return draw_legend(img, legend)


class CalibrationOverlay:
    """The corridor layer of :func:`check_image` drawn once and composited on every annotated frame."""

    def __init__(self, cam: CameraConfig, road: Road, *, max_range_m: float | None = None,
                 calibration: Sequence[Sequence[float]] = ()) -> None:
        self.shape = (cam.height_px, cam.width_px, 3)
        layer = np.zeros(self.shape, np.uint8)
        draw_corridor(layer, cam, road, max_range_m=max_range_m)
        pts = []
        for i, (u, v, x, y) in enumerate(calibration):
            uv, depth = project(cam, np.array([[x, y, 0.0]]))
            pts.append(OverlayPoint(f"c{i}", (u, v), tuple(uv[0]) if depth[0] > 1 else None))
        draw_points(layer, pts) if len(pts) <= 40 else None  # a dense simulated survey would hide the road
        self.layer = layer
        self.mask = layer.any(axis=2)

    def apply(self, image: np.ndarray) -> np.ndarray:
        """``image`` with the layer drawn on it (a copy); unchanged when its size is not the camera's."""
        if image.shape != self.shape:
            return image
        out = image.copy()
        out[self.mask] = self.layer[self.mask]
        return out
