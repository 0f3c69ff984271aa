"""Ground-truth labels of a rendered frame (``sim.render.renderer.Renderer.labels``; ``sim.dataset`` writes them out): the
visible part of each vehicle's silhouette in a per-vehicle id buffer, drawn from the same geometry as the frame, as a
box with the visible fraction; a vehicle below ``MIN_VISIBLE_FRACTION`` is dropped. For scoring and training only:
no perception code reads them."""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from protocol.messages import WorldSnapshot
from sim.camera import NEAR_M

MIN_VISIBLE_FRACTION = 0.3
CLASS_VEHICLE = 0
CLASS_EV = 1
CLASS_NAMES = ("vehicle", "ev")


@dataclass
class Label:
    actor_id: str
    kind: str
    class_id: int
    bbox_px: tuple[float, float, float, float]  # x1, y1, x2, y2 of the visible part, in the image
    visible_fraction: float
    full_bbox_px: tuple[float, float, float, float]


def visible_labels(renderer, snapshot: WorldSnapshot, min_visible_fraction: float = MIN_VISIBLE_FRACTION,
               include_dropped: bool = False) -> list[Label]:
    """Visible boxes of vehicles as ``renderer`` (a ``sim.render.renderer.Renderer``) draws ``snapshot``: the silhouette (parts)
    of each vehicle is drawn into an id buffer back to front; the label box is the bbox of the pixels each vehicle keeps
    and the visible fraction is kept pixels / full silhouette pixels (in or out of the image)."""
    ids = np.zeros((renderer.h, renderer.w), np.uint16)
    entries = []
    for k, a in enumerate(renderer._ordered(snapshot), start=1):
        kind = a.kind.value if hasattr(a.kind, "value") else str(a.kind)
        parts, _decals, _corners, uv, depth, _rot = renderer._actor_geometry(a)
        if np.any(depth <= NEAR_M):
            continue
        x1, y1 = uv[..., 0].min(), uv[..., 1].min()
        x2, y2 = uv[..., 0].max(), uv[..., 1].max()
        if x2 < 0 or y2 < 0 or x1 >= renderer.w or y1 >= renderer.h:
            continue
        hulls = [cv2.convexHull(np.round(uv[p] * 16).astype(np.int32)) for p in range(len(parts))
                 if parts[p].silhouette]
        for hull in hulls:
            cv2.fillConvexPoly(ids, hull, k, cv2.LINE_8, 4)
        # full silhouette area, unclipped, on an ROI canvas
        ox, oy = int(math.floor(x1)) - 1, int(math.floor(y1)) - 1
        cw, ch = int(math.ceil(x2)) - ox + 2, int(math.ceil(y2)) - oy + 2
        if cw * ch > 4_000_000:
            continue
        canvas = np.zeros((ch, cw), np.uint8)
        for hull in hulls:
            cv2.fillConvexPoly(canvas, hull - np.array([ox * 16, oy * 16], np.int32), 1, cv2.LINE_8, 4)
        full_px = int(np.count_nonzero(canvas))
        if kind == "debris":
            continue  # drawn as an occluder, not a label class
        cls = CLASS_EV if kind == "ev" and a.light_bar is not None and a.light_bar.on else CLASS_VEHICLE
        entries.append((k, a, kind, cls, full_px, (float(x1), float(y1), float(x2), float(y2))))
    out = []
    for k, a, kind, cls, full_px, full_box in entries:
        sel = ids == k
        rows = np.flatnonzero(sel.any(axis=1))
        if len(rows) == 0:
            vis, box = 0.0, (0.0, 0.0, 0.0, 0.0)
        else:
            cols = np.flatnonzero(sel[rows[0]:rows[-1] + 1].any(axis=0))
            vis = float(np.count_nonzero(sel[rows[0]:rows[-1] + 1, cols[0]:cols[-1] + 1])) / max(1, full_px)
            box = (float(cols[0]), float(rows[0]), float(cols[-1] + 1), float(rows[-1] + 1))
        if vis < min_visible_fraction and not include_dropped:
            continue
        out.append(Label(a.actor_id, kind, cls, box, min(1.0, vis), full_box))
    return out
