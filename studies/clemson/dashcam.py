"""Dashboard cameras of the AV (the Clemson comparison; Clemson hazard navigation report, section 4.1, figs. 7-8).

A front camera at the centre of the windscreen, and for training data a left and a right camera offset
sideways by ``SIDE_CAMERA_OFFSET_M`` (the report's three cameras, DAVE-2's recovery views), all rendered
by the project's renderer (``sim.render.renderer.Renderer``) at DAVE-2's input size, 66 x 200 px (the report used
400 x 600 and cropped its top 200 rows; here the horizon sits near the top row, so nothing is cropped).

The renderer draws its static scene once per camera; a camera that moves with the car would redraw the
whole road every frame, so the scene is drawn over a window of the road (``road_window``: from a little
behind the camera to ``WINDOW_AHEAD_M`` ahead). The window starts on a multiple of the lane-marking
period, so dashes stay where they are on the ground from frame to frame.

``hazard_mask`` is the label of the debris in a dashcam image (projected box faces): training labels
and evaluation only; the car's own segmentation (``studies.clemson.learned_steering``) never reads it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from protocol.corridor import CameraConfig
from protocol.enums import ActorKind, Lighting
from protocol.messages import Actor, WorldSnapshot
from protocol.road import Road, Segment
from sim.camera import PinholeCamera, box_corners
from sim.render.renderer import Renderer
from sim.scenario import DEBRIS_KINDS
from sim.traffic import DEBRIS_COLOURS
from sim.vehicles import make_style

WIDTH_PX, HEIGHT_PX = 200, 66
"""DAVE-2's input size (the report: 600 x 400, top 200 rows cropped)."""
HFOV_DEG = 60.0
MOUNT_HEIGHT_M = 1.4
MOUNT_AHEAD_M = 1.5
"""Camera ahead of the car's centre (windscreen)."""
PITCH_DEG = 4.0
HORIZON_ROW_PX = 10.0
"""Principal point row: with the pitch, the horizon lies near the top rows (sky is of no use to steer)."""
SIDE_CAMERA_OFFSET_M = 0.8
"""Left and right cameras, this far either side of the centre camera (training data only)."""
WINDOW_BEHIND_M = 6.0
WINDOW_AHEAD_M = 130.0
MARKING_PERIOD_M = 12.0
"""Period of the dashed lane lines in ``sim.scenery`` (the window starts on a multiple of it)."""


def road_window(road: Road, s_from_m: float, length_m: float) -> tuple[Road, float]:
    """The part of ``road`` from ``s_from_m`` (clipped to the road) over ``length_m``, as a road of its own,
    and the station where it starts on ``road``."""
    s0 = max(0.0, min(float(s_from_m), road.length_m - 1.0))
    s1 = min(road.length_m, s0 + length_m)
    segs, s = [], 0.0
    for seg in road.segments:
        a, b = max(s, s0), min(s + seg.length_m, s1)
        if b - a > 1e-6:
            segs.append(Segment(seg.kind, b - a, seg.radius_m))
        s += seg.length_m
    x, y, h = road.pose_at(s0, 0.0)
    win = Road(float(x), float(y), float(h), tuple(segs), lanes=road.lanes, lane_width_m=road.lane_width_m,
               shoulder_width_m=road.shoulder_width_m, opposite_lanes=road.opposite_lanes,
               speed_limit_mps=road.speed_limit_mps)
    return win, s0


def dashcam_config(x_m: float, y_m: float, yaw_rad: float, lateral_offset_m: float = 0.0) -> CameraConfig:
    """Camera on a car whose centre is at (x, y) heading ``yaw_rad``; ``lateral_offset_m`` > 0 moves it left."""
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    f = WIDTH_PX / 2.0 / math.tan(math.radians(HFOV_DEG) / 2.0)
    return CameraConfig(x_m=float(x_m + MOUNT_AHEAD_M * c - lateral_offset_m * s),
                        y_m=float(y_m + MOUNT_AHEAD_M * s + lateral_offset_m * c), height_m=MOUNT_HEIGHT_M,
                        yaw_rad=float(yaw_rad), pitch_rad=math.radians(PITCH_DEG), roll_rad=0.0,
                        width_px=WIDTH_PX, height_px=HEIGHT_PX, fx_px=f, fy_px=f, cx_px=WIDTH_PX / 2.0,
                        cy_px=HORIZON_ROW_PX, fps=10.0)


def debris_actor(road: Road, actor_id: str, s_m: float, d_m: float, kind: str, length_m: float, width_m: float,
                 height_m: float, detail: int = 0) -> Actor:
    """A static debris actor on ``road`` as the simulator makes it (``sim.traffic``)."""
    if kind not in DEBRIS_KINDS:
        raise ValueError(f"debris kind must be one of {DEBRIS_KINDS}, got {kind!r}")
    x, y, h = road.pose_at(s_m, d_m)
    return Actor(actor_id=actor_id, kind=ActorKind.DEBRIS, pos_x_m=float(x), pos_y_m=float(y),
                 heading_rad=float(h), length_m=length_m, width_m=width_m, height_m=height_m,
                 colour_bgr=DEBRIS_COLOURS[kind], style=make_style(DEBRIS_KINDS.index(kind), detail))


@dataclass
class DashCamera:
    """Renders the AV's dashboard views of one road (scene seed ``seed``, ``lighting``)."""

    road: Road
    seed: int = 0
    lighting: str = "day"
    noise: bool = True

    def render(self, x_m: float, y_m: float, yaw_rad: float, actors: list[Actor], t_s: float,
               lateral_offset_m: float = 0.0, frame_index: int = 0) -> np.ndarray:
        """BGR image (HEIGHT_PX, WIDTH_PX, 3) from the car's pose (true pose: the camera is on the car)."""
        s_cam, _ = self.road.to_frenet(x_m, y_m)
        s_from = math.floor((float(np.atleast_1d(s_cam)[0]) - WINDOW_BEHIND_M) / MARKING_PERIOD_M) * MARKING_PERIOD_M
        win, s0 = road_window(self.road, s_from, WINDOW_AHEAD_M + WINDOW_BEHIND_M + MARKING_PERIOD_M)
        cfg = dashcam_config(x_m, y_m, yaw_rad, lateral_offset_m)
        # the scene's own randomness (patches, tree line) keyed by the window: the same ground each visit
        r = Renderer(cfg, win, seed=self.seed * 1000 + int(s0 // MARKING_PERIOD_M), noise=self.noise)
        snap = WorldSnapshot(src="dashcam", stamp=float(t_s), scenario="dashcam", sim_time_s=float(t_s),
                             lighting=Lighting(self.lighting), actors=actors)
        return r.render(snap, frame_index)


def hazard_mask(x_m: float, y_m: float, yaw_rad: float, actors: list[Actor],
                lateral_offset_m: float = 0.0) -> np.ndarray:
    """Label mask (HEIGHT_PX, WIDTH_PX) uint8, 1 on debris pixels: the projected convex hull of each debris box."""
    cam = PinholeCamera.from_config(dashcam_config(x_m, y_m, yaw_rad, lateral_offset_m))
    mask = np.zeros((HEIGHT_PX, WIDTH_PX), np.uint8)
    for a in actors:
        if a.kind != ActorKind.DEBRIS:
            continue
        corners = box_corners(a.pos_x_m, a.pos_y_m, a.heading_rad, a.length_m, a.width_m, a.height_m)
        uv, depth = cam.project(corners)
        if np.any(depth <= 1.0):
            continue
        hull = cv2.convexHull(np.round(uv * 16).astype(np.int32))
        cv2.fillConvexPoly(mask, hull, 1, lineType=cv2.LINE_8, shift=4)
    return mask
