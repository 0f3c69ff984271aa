"""Pinhole camera model of an RSU camera (docs/architecture.md §Coordinates; thesis App. B).

p_cam = R (p_world - C), [u v 1]^T ~ K p_cam, OpenCV axes (x right, y down, z forward). The pose and
intrinsics come from the corridor file (``protocol.corridor.CameraConfig``). Ground-plane
back-projection intersects the pixel ray with the plane z = z0 (the "transformation-based" localiser
of App. B, used here for tests and labels).
"""

from __future__ import annotations

import math

import numpy as np

from protocol.corridor import CameraConfig

NEAR_M = 0.5
"""Points closer than this along the optical axis count as not projectable."""


def box_corners(x_m: float, y_m: float, heading_rad: float, length_m: float, width_m: float,
                height_m: float, z0_m: float = 0.0) -> np.ndarray:
    """(8, 3) world corners of an oriented box whose footprint centre is (x, y) on z = z0.

    Order: bottom rear-right, rear-left, front-left, front-right, then the same four on top."""
    c, s = math.cos(heading_rad), math.sin(heading_rad)
    hl, hw = length_m / 2.0, width_m / 2.0
    local = np.array([[-hl, -hw], [-hl, hw], [hl, hw], [hl, -hw]])
    xy = local @ np.array([[c, s], [-s, c]]) + (x_m, y_m)
    bottom = np.column_stack([xy, np.full(4, z0_m)])
    top = np.column_stack([xy, np.full(4, z0_m + height_m)])
    return np.vstack([bottom, top])


class PinholeCamera:
    """Projection and back-projection for one camera."""

    def __init__(self, intrinsic: np.ndarray, rotation_world_to_camera: np.ndarray, centre_world: np.ndarray,
                 width_px: int, height_px: int) -> None:
        self.K = np.asarray(intrinsic, dtype=float)
        self.R = np.asarray(rotation_world_to_camera, dtype=float)
        self.C = np.asarray(centre_world, dtype=float).reshape(3)
        if self.K.shape != (3, 3) or self.R.shape != (3, 3):
            raise ValueError("intrinsic and rotation must be 3x3")
        self.width_px, self.height_px = int(width_px), int(height_px)
        self.K_inv = np.linalg.inv(self.K)
        self.KR = self.K @ self.R

    @classmethod
    def from_config(cls, cam: CameraConfig) -> PinholeCamera:
        return cls(cam.intrinsic_matrix, cam.rotation_world_to_camera, cam.centre_world, cam.width_px, cam.height_px)

    def to_camera(self, xyz: np.ndarray) -> np.ndarray:
        """World points (N, 3) -> camera-frame points (N, 3)."""
        return (np.asarray(xyz, dtype=float) - self.C) @ self.R.T

    def project(self, xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixels (N, 2) and depths (N,) of world points (N, 3); depth <= NEAR_M means not projectable."""
        pts = np.atleast_2d(np.asarray(xyz, dtype=float))
        h = (pts - self.C) @ self.KR.T
        depth = h[:, 2]
        safe = np.where(depth > NEAR_M, depth, 1.0)
        return h[:, :2] / safe[:, None], depth

    def ray(self, uv: np.ndarray) -> np.ndarray:
        """Unit world-frame ray directions (N, 3) through pixels (N, 2)."""
        uv = np.atleast_2d(np.asarray(uv, dtype=float))
        hom = np.column_stack([uv, np.ones(len(uv))])
        d = (hom @ self.K_inv.T) @ self.R  # R^T d_cam
        return d / np.linalg.norm(d, axis=1, keepdims=True)

    def backproject_to_ground(self, uv: np.ndarray, z_m: float = 0.0) -> np.ndarray:
        """World points (N, 3) where pixel rays meet the plane z = z_m; NaN where a ray misses it."""
        d = self.ray(uv)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (z_m - self.C[2]) / d[:, 2]
        t = np.where(t > 0, t, np.nan)
        return self.C + t[:, None] * d

    def horizon_v_px(self) -> float:
        """Image row of the horizon at the image centre column (roll-free cameras: the whole row)."""
        # a point far ahead at camera height projects onto the horizon
        fwd = self.R[2].copy()
        fwd[2] = 0.0
        fwd /= np.linalg.norm(fwd)
        uv, _ = self.project((self.C + 1e6 * fwd)[None, :])
        return float(uv[0, 1])

    def project_box(self, corners: np.ndarray) -> tuple[float, float, float, float] | None:
        """Image bbox (x1, y1, x2, y2) of 3-D corners, clipped to the image; None if not visible."""
        uv, depth = self.project(corners)
        if np.any(depth <= NEAR_M):
            return None
        x1, y1 = uv.min(axis=0)
        x2, y2 = uv.max(axis=0)
        x1, x2 = max(0.0, x1), min(float(self.width_px), x2)
        y1, y2 = max(0.0, y1), min(float(self.height_px), y2)
        if x2 <= x1 or y2 <= y1:
            return None
        return float(x1), float(y1), float(x2), float(y2)
