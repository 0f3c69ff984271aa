"""The corridor's pinhole camera (``protocol.corridor.CameraConfig``) in OpenCV's terms, for commissioning
(:mod:`rsu.calibration.solve`) and its check image (:mod:`rsu.calibration.overlay`): angles from a rotation, the camera from
OpenCV's rvec/tvec and back, projection of world points and back-projection of pixels to a height plane, with
OpenCV's radial distortion when given."""

from __future__ import annotations

import math
from dataclasses import replace

import cv2
import numpy as np

from protocol.corridor import CameraConfig


def yaw_pitch_roll(rotation_world_to_camera: np.ndarray) -> tuple[float, float, float]:
    """Angles of ``CameraConfig`` (yaw from +x counter-clockwise, pitch down, roll about the optical axis)."""
    r = np.asarray(rotation_world_to_camera, dtype=float)
    fwd = r[2]
    pitch = math.asin(float(np.clip(-fwd[2], -1.0, 1.0)))
    yaw = math.atan2(float(fwd[1]), float(fwd[0]))
    r0 = replace(_UNIT_CAMERA, yaw_rad=yaw, pitch_rad=pitch).rotation_world_to_camera
    rr = r @ r0.T
    return yaw, pitch, math.atan2(float(rr[0, 1]), float(rr[0, 0]))


_UNIT_CAMERA = CameraConfig(0.0, 0.0, 10.0, 0.0, 0.0, 0.0, 640, 480, 500.0, 500.0, 320.0, 240.0)


def camera_from_rvec_tvec(rvec: np.ndarray, tvec: np.ndarray, k: np.ndarray, width_px: int, height_px: int,
                          fps: float = 15.0) -> CameraConfig:
    r, _ = cv2.Rodrigues(np.asarray(rvec, dtype=float).reshape(3, 1))
    c = -r.T @ np.asarray(tvec, dtype=float).reshape(3)
    yaw, pitch, roll = yaw_pitch_roll(r)
    return CameraConfig(x_m=float(c[0]), y_m=float(c[1]), height_m=float(c[2]), yaw_rad=yaw, pitch_rad=pitch,
                        roll_rad=roll, width_px=int(width_px), height_px=int(height_px), fx_px=float(k[0, 0]),
                        fy_px=float(k[1, 1]), cx_px=float(k[0, 2]), cy_px=float(k[1, 2]), fps=fps)


def rvec_tvec(camera: CameraConfig) -> tuple[np.ndarray, np.ndarray]:
    r = camera.rotation_world_to_camera
    rvec, _ = cv2.Rodrigues(r)
    return rvec.reshape(3), -r @ camera.centre_world


def project(camera: CameraConfig, xyz: np.ndarray, dist: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Pixels (N, 2) and depths along the optical axis (N,) of world points (N, 3); depth <= 0: behind."""
    xyz = np.asarray(xyz, dtype=float).reshape(-1, 3)
    rvec, tvec = rvec_tvec(camera)
    depth = (xyz - camera.centre_world) @ camera.rotation_world_to_camera[2]
    if len(xyz) == 0:
        return np.zeros((0, 2)), depth
    uv, _ = cv2.projectPoints(xyz, rvec, tvec, camera.intrinsic_matrix, dist5(dist))
    return uv.reshape(-1, 2), depth


def ground_points(camera: CameraConfig, uv: np.ndarray, dist: np.ndarray | None = None,
                  z_m: float | np.ndarray = 0.0) -> np.ndarray:
    """(N, 2) world x, y where the rays through pixels (N, 2) meet the plane z = z_m; NaN where they miss it."""
    uv = np.asarray(uv, dtype=float).reshape(-1, 2)
    k = camera.intrinsic_matrix
    norm = cv2.undistortPoints(uv.reshape(-1, 1, 2), k, dist5(dist)).reshape(-1, 2) if len(uv) else uv
    d = np.column_stack([norm, np.ones(len(norm))]) @ camera.rotation_world_to_camera  # R' [xn, yn, 1]
    c = camera.centre_world
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (np.asarray(z_m, dtype=float) - c[2]) / d[:, 2]
    xy = c[:2] + t[:, None] * d[:, :2]
    xy[~(np.isfinite(t) & (t > 0))] = np.nan
    return xy


def dist5(dist: np.ndarray | None) -> np.ndarray:
    """OpenCV's five distortion coefficients (k1, k2, p1, p2, k3) from the first ones given; zeros: none."""
    out = np.zeros(5)
    if dist is not None:
        d = np.asarray(dist, dtype=float).ravel()[:5]
        out[:len(d)] = d
    return out
