"""Where an RSU's detector looks: only the part of the frame where its zone of responsibility lies.

An RSU reports nothing farther than ``max_range_m`` from its mast (the next RSU covers it), and vehicles drive on
the road; from an elevated camera the road within that range is about half of the 1280x720 frame (the sky, the far
road and the verges are the rest). So the project detector letterboxes only that part, at the pixel scale it runs
at on the whole frame (0.5, its training scale: the same vehicles in the same pixels), and its input shrinks with it:
288x448 instead of 384x640 on the RELLIS corridor's cameras, about 45 % less CPU per frame on two cores, where four
RSUs, the simulator, the DDM and the vehicle share one machine; cheaper than the whole frame at 0.4 (288x512), which
missed falling debris (``models.resize_detector.RSU_INPUT_HW``).

:func:`zone_box_px` is the image box of the road (its lanes and shoulders, 1 m beyond) within a range of the mast,
from the ground up to the top of a tall vehicle, projected with the RSU's own calibration (no ground truth);
:func:`detection_roi` fits the detector's window around it. Pure functions: the RSU builds its detector with them
(``rsu.build.build_detector``).
"""

from __future__ import annotations

import math

import numpy as np

from protocol.corridor import CameraConfig
from protocol.road import Road
from rsu.calibration.camera_geometry import project

ROI_MARGIN_M = 15.0
"""The detector looks this far beyond the zone of responsibility, so that a vehicle entering the zone is already
tracked (SORT reports a track after 3 hits) and the benches' 100 m scoring zone (``ZONE_M``) is covered."""
VEHICLE_TOP_M = 4.5
"""The top of the tallest vehicle (a truck or a bus with its light bar) above the road."""
PROJECT_SCALE = 0.5
"""The letterbox scale the project detector runs at (a 1280x720 frame in its 384x640 input, the training scale)."""


def zone_box_px(camera: CameraConfig, road: Road, mast_xy: tuple[float, float], range_m: float, *,
                top_m: float = VEHICLE_TOP_M, step_m: float = 0.5) -> tuple[int, int, int, int] | None:
    """The image box (x1, y1, x2, y2 whole pixels, cut to the frame) of the road within ``range_m`` of the mast:
    points every ``step_m`` along it across its lanes and shoulders (1 m beyond each edge), on the road and
    ``top_m`` above it, projected with ``camera`` (points behind the camera left out); None when none is in view."""
    if range_m <= 0 or step_m <= 0:
        raise ValueError(f"range_m and step_m must be > 0, got {range_m}, {step_m}")
    s = np.arange(0.0, road.length_m + step_m, step_m)
    right = -road.shoulder_width_m - 1.0 - road.opposite_lanes * road.lane_width_m
    left = road.width_m + road.shoulder_width_m + 1.0
    d = np.linspace(right, left, max(3, int(math.ceil((left - right) / 1.0)) + 1))
    ss, dd = np.meshgrid(s, d)
    x, y, _ = road.pose_at(ss.ravel(), dd.ravel())
    near = np.hypot(x - mast_xy[0], y - mast_xy[1]) <= range_m
    if not near.any():
        return None
    n = int(near.sum())
    pts = np.concatenate([np.column_stack([x[near], y[near], np.full(n, z)]) for z in (0.0, top_m)])
    uv, depth = project(camera, pts)
    uv = np.asarray(uv, float).reshape(-1, 2)[np.asarray(depth).reshape(-1) > 0.5]
    w, h = camera.width_px, camera.height_px
    inside = (uv[:, 0] >= 0) & (uv[:, 0] < w) & (uv[:, 1] >= 0) & (uv[:, 1] < h)
    if not inside.any():
        return None
    # the box of the points, cut to the frame (points outside it still widen the box up to the border)
    x1, y1 = np.clip(np.floor(uv.min(axis=0)), 0, [w, h]).astype(int).tolist()
    x2, y2 = np.clip(np.ceil(uv.max(axis=0)) + 1, 0, [w, h]).astype(int).tolist()
    return (x1, y1, x2, y2) if x2 > x1 and y2 > y1 else None


def detection_roi(box: tuple[int, int, int, int] | None, frame_wh: tuple[int, int], scale: float = PROJECT_SCALE,
                  multiple: int = 32) -> tuple[tuple[int, int, int, int], tuple[int, int]]:
    """The detector's window (x1, y1, x2, y2) and input (h, w) for a zone ``box``: per side, the input is the box
    side times ``scale`` rounded up to ``multiple`` (the network's largest stride), and the window is that input
    divided by ``scale``, centred on the box and shifted into the frame, so the letterbox keeps exactly ``scale``;
    a side whose window would not fit in the frame takes the whole frame side (the letterbox then pads). No box:
    the whole frame."""
    w, h = frame_wh
    if not 0.05 <= scale <= 1.0:
        raise ValueError(f"scale must be in [0.05, 1], got {scale}")
    x1, y1, x2, y2 = box if box is not None else (0, 0, w, h)

    def side(lo: int, hi: int, full: int) -> tuple[int, int, int]:
        n_in = int(math.ceil((hi - lo) * scale / multiple - 1e-9)) * multiple
        span = int(round(n_in / scale))
        if span >= full:
            return 0, full, int(math.ceil(full * scale / multiple - 1e-9)) * multiple
        start = int(round((lo + hi - span) / 2))
        start = min(max(start, 0), full - span)
        return start, start + span, n_in

    ax, bx, in_w = side(x1, x2, w)
    ay, by, in_h = side(y1, y2, h)
    return (ax, ay, bx, by), (in_h, in_w)
