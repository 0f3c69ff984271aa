"""Foxglove's well-known message types as JSON-ready data (the ``foxglove.*`` JSON Schemas of
``@foxglove/schemas``, kept in ``deploy/foxglove_schema``): pure builders, every field filled in.

Times are ``{"sec", "nsec"}`` (``foxglove.Time``), durations likewise; poses are in metres with a
quaternion about z for a yaw (REP 103: x forward/east, y left/north, z up); colours are RGBA in 0..1.
"""

from __future__ import annotations

import base64
import math
from collections.abc import Iterable, Sequence
from typing import Any

RGBA = tuple[float, float, float, float]

LOG_LEVEL = {"debug": 1, "info": 2, "warning": 3, "error": 4, "fatal": 5}
"""``foxglove.LogLevel``."""
LINE_STRIP, LINE_LOOP, LINE_LIST = 0, 1, 2
"""``foxglove.LineType``."""
DELETE_ALL = 1
"""``foxglove.SceneEntityDeletionType.ALL``."""


def time_of(t_s: float) -> dict[str, int]:
    """``foxglove.Time`` of ``t_s`` seconds (clamped at 0: the type is unsigned)."""
    ns = max(0, int(round(t_s * 1e9)))
    return {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000}


def color(rgba: RGBA) -> dict[str, float]:
    r, g, b, a = rgba
    return {"r": float(r), "g": float(g), "b": float(b), "a": float(a)}


def quat_yaw(yaw_rad: float) -> dict[str, float]:
    """Rotation by ``yaw_rad`` about z."""
    return {"x": 0.0, "y": 0.0, "z": math.sin(yaw_rad / 2.0), "w": math.cos(yaw_rad / 2.0)}


def pose(x_m: float, y_m: float, z_m: float = 0.0, yaw_rad: float = 0.0) -> dict[str, Any]:
    return {"position": {"x": float(x_m), "y": float(y_m), "z": float(z_m)}, "orientation": quat_yaw(yaw_rad)}


def point(x_m: float, y_m: float, z_m: float = 0.0) -> dict[str, float]:
    return {"x": float(x_m), "y": float(y_m), "z": float(z_m)}


def line(points_xy: Iterable[Sequence[float]], rgba: RGBA, *, thickness_m: float = 0.15, z_m: float = 0.02,
         kind: int = LINE_STRIP) -> dict[str, Any]:
    """``foxglove.LinePrimitive`` through ``points_xy`` (metres, in the entity's frame)."""
    return {"type": kind, "pose": pose(0.0, 0.0), "thickness": float(thickness_m), "scale_invariant": False,
            "points": [point(p[0], p[1], z_m) for p in points_xy], "color": color(rgba), "colors": [],
            "indices": []}


def cube(x_m: float, y_m: float, yaw_rad: float, size_m: Sequence[float], rgba: RGBA) -> dict[str, Any]:
    """``foxglove.CubePrimitive`` of ``size_m`` (length, width, height) standing on the ground at (x, y)."""
    length, width, height = (float(v) for v in size_m)
    return {"pose": pose(x_m, y_m, height / 2.0, yaw_rad), "size": {"x": length, "y": width, "z": height},
            "color": color(rgba)}


def text(x_m: float, y_m: float, z_m: float, label: str, rgba: RGBA = (1, 1, 1, 1),
         font_size_px: float = 14.0) -> dict[str, Any]:
    """``foxglove.TextPrimitive``: a label that faces the viewer, of constant size on screen."""
    return {"pose": pose(x_m, y_m, z_m), "billboard": True, "font_size": float(font_size_px),
            "scale_invariant": True, "color": color(rgba), "text": label}


def entity(entity_id: str, frame_id: str, t_s: float, *, lines: list | None = None, cubes: list | None = None,
           texts: list | None = None, lifetime_s: float = 0.0, metadata: dict[str, str] | None = None) -> dict[str, Any]:
    """``foxglove.SceneEntity`` (lifetime 0: until replaced or deleted)."""
    return {"timestamp": time_of(t_s), "frame_id": frame_id, "id": entity_id, "lifetime": time_of(lifetime_s),
            "frame_locked": False, "metadata": [{"key": k, "value": str(v)} for k, v in (metadata or {}).items()],
            "arrows": [], "cubes": cubes or [], "spheres": [], "cylinders": [], "lines": lines or [],
            "triangles": [], "texts": texts or [], "models": []}


def scene_update(entities: list[dict[str, Any]], t_s: float | None = None, *,
                 replace_all: bool = False) -> dict[str, Any]:
    """``foxglove.SceneUpdate``; ``replace_all``: delete the topic's earlier entities first (at ``t_s``)."""
    deletions = [{"timestamp": time_of(t_s or 0.0), "type": DELETE_ALL, "id": ""}] if replace_all else []
    return {"deletions": deletions, "entities": entities}


def frame_transform(parent: str, child: str, t_s: float, x_m: float, y_m: float, z_m: float = 0.0,
                    yaw_rad: float = 0.0) -> dict[str, Any]:
    """``foxglove.FrameTransform``: ``child``'s pose in ``parent``."""
    p = pose(x_m, y_m, z_m, yaw_rad)
    return {"timestamp": time_of(t_s), "parent_frame_id": parent, "child_frame_id": child,
            "translation": p["position"], "rotation": p["orientation"]}


def frame_transforms(transforms: list[dict[str, Any]]) -> dict[str, Any]:
    return {"transforms": transforms}


def location_fix(t_s: float, frame_id: str, lat_deg: float, lon_deg: float, *, altitude_m: float = 0.0,
                 sigma_m: float | None = None, rgba: RGBA | None = None) -> dict[str, Any]:
    """``foxglove.LocationFix`` (WGS84); ``sigma_m``: a diagonal horizontal covariance of that deviation."""
    cov = [0.0] * 9
    cov_type = 0
    if sigma_m is not None:
        cov[0] = cov[4] = float(sigma_m) ** 2
        cov_type = 2  # DIAGONAL_KNOWN
    out = {"timestamp": time_of(t_s), "frame_id": frame_id, "latitude": float(lat_deg),
           "longitude": float(lon_deg), "altitude": float(altitude_m), "position_covariance": cov,
           "position_covariance_type": cov_type}
    if rgba is not None:
        out["color"] = color(rgba)
    return out


def compressed_image(t_s: float, frame_id: str, data: bytes, fmt: str = "jpeg") -> dict[str, Any]:
    """``foxglove.CompressedImage``: ``data`` is the encoded image (base64 in JSON, as the schema states)."""
    return {"timestamp": time_of(t_s), "frame_id": frame_id, "data": base64.b64encode(data).decode("ascii"),
            "format": fmt}


def log_line(t_s: float, level: str, name: str, message: str) -> dict[str, Any]:
    """``foxglove.Log``: one line of the alert and command log."""
    return {"timestamp": time_of(t_s), "level": LOG_LEVEL[level], "message": message, "name": name,
            "file": "", "line": 0}
