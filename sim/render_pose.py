"""Pure per-frame geometry of the renderer (``sim.render``): every actor in view posed and projected, its headlight
pool, cast-shadow outline and motion-blur vector, each for all actors in one batched product (issue 19: a Python
loop per actor cost more than the drawing). Camera matrices in, pixel arrays out; nothing here draws."""

from __future__ import annotations

import math

import cv2
import numpy as np

from protocol.messages import Actor
from sim.bodies import BodyModel
from sim.camera import NEAR_M, PinholeCamera

POOL_LOCAL_M = np.array([[0.5, -0.8], [0.5, 0.8], [18.0, 3.2], [18.0, -3.2]])  # headlight pool, ahead of the bumper


def pool_quads(actors: list[Actor], cam: PinholeCamera) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Headlight pools of ``actors``: pixel quads (N, 4, 2), the same x 16 rounded (int32, the fixed point the
    drawing takes) and whether each is in front of the camera (N,). The pool: a trapezoid on the road from 0.5 to
    18 m ahead of the front bumper."""
    cs = np.array([(math.cos(a.heading_rad), math.sin(a.heading_rad), a.pos_x_m, a.pos_y_m, a.length_m)
                   for a in actors]).reshape(-1, 5)
    c, s_, px, py, length = (cs[:, i:i + 1] for i in range(5))
    fx, fy = px + c * length / 2, py + s_ * length / 2
    lx, ly = POOL_LOCAL_M[:, 0], POOL_LOCAL_M[:, 1]
    pts = np.stack([fx + lx * c - ly * s_, fy + lx * s_ + ly * c, np.zeros_like(fx + lx)], axis=-1)
    uv, depth = cam.project(pts.reshape(-1, 3))
    uv = uv.reshape(-1, 4, 2)
    return uv, np.round(uv * 16).astype(np.int32), (depth.reshape(-1, 4) > NEAR_M).all(axis=1)


def pose_actors(actors: list[Actor], models: list[BodyModel], cam: PinholeCamera) -> list[tuple]:
    """Per actor (model, (m, tvec), rot, uv (N, 2), uv x 16 rounded (N, 2) int32, nearest part-corner depth,
    part corners' (x, y) pixel minimum and maximum, all its points' pixel box [x1, y1, x2, y2]): its body model
    posed and projected, every actor's points in one product (m = K R rot, tvec = K R (position - C))."""
    if not actors:
        return []
    rots = np.array([[[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]] for c, s in
                     ((math.cos(a.heading_rad), math.sin(a.heading_rad)) for a in actors)])
    m = cam.KR @ rots  # (A, 3, 3)
    tvec = (np.array([(a.pos_x_m, a.pos_y_m, 0.0) for a in actors]) - cam.C) @ cam.KR.T  # (A, 3)
    counts = [len(md.points) for md in models]
    idx = np.repeat(np.arange(len(actors)), counts)
    h = np.einsum("nij,nj->ni", m[idx], np.concatenate([md.points for md in models])) + tvec[idx]
    depth = h[:, 2]
    uv = h[:, :2] / np.where(depth > NEAR_M, depth, 1.0)[:, None]
    uv16 = np.round(uv * 16).astype(np.int32)
    ends = np.cumsum(counts).tolist()
    # per actor, over its part corners (the first 8 P points of its block): nearest depth, pixel bounds
    cuts = [i for n, e, md in zip(counts, ends, models, strict=True) for i in (e - n, e - n + 8 * len(md.parts))]
    near = np.minimum.reduceat(depth, cuts)[::2].tolist()
    lo, hi = np.minimum.reduceat(uv, cuts), np.maximum.reduceat(uv, cuts)
    # the whole block's (the decals' and contact shadow's points too): what its drawing may reach
    lo_all, hi_all = np.minimum(lo[::2], lo[1::2]).tolist(), np.maximum(hi[::2], hi[1::2]).tolist()
    lo, hi = lo[::2].tolist(), hi[::2].tolist()
    return [(md, (m[k], tvec[k]), rots[k], uv[e - n:e], uv16[e - n:e], near[k], lo[k], hi[k], lo_all[k] + hi_all[k])
            for k, (md, n, e) in enumerate(zip(models, counts, ends, strict=True))]


def shadow_outlines(posed: list[tuple], sun: np.ndarray, ground_m: np.ndarray, ground_t: np.ndarray
                    ) -> list[tuple[np.ndarray, np.ndarray] | None]:
    """Per actor (body model, rotation 3x3, x m, y m), its cast shadow's outline in pixels (K, 2) and the same x 16
    rounded (int32, the drawing's fixed point), None when any
    of it is behind the camera: the part corners projected along the unit vector ``sun`` onto z = 0
    (``sim.render_effects.shadow_hull``'s projection, in float32 as ``cv2.convexHull`` takes them), every actor's in
    one product, and into the image (a road point (x, y) -> homogeneous pixel (x, y) @ ground_m - ground_t); each
    outline is its ground hull's points."""
    if not posed:
        return []
    counts = [8 * len(p[0].parts) for p in posed]
    local = np.concatenate([p[0].points[:n] for p, n in zip(posed, counts, strict=True)])  # (N, 3)
    idx = np.repeat(np.arange(len(posed)), counts)
    rot2 = np.stack([p[1][:2, :2] for p in posed])[idx]  # (N, 2, 2)
    ground = (np.einsum("nij,nj->ni", rot2, local[:, :2]) + np.array([(p[2], p[3]) for p in posed])[idx]
              - local[:, 2:3] * (sun[:2] / max(sun[2], 0.25))).astype(np.float32)
    h = ground.astype(float) @ ground_m - ground_t
    near = np.minimum.reduceat(h[:, 2], np.cumsum([0, *counts[:-1]])).tolist()
    uv = h[:, :2] / np.where(h[:, 2:] > NEAR_M, h[:, 2:], 1.0)
    uv16 = np.round(uv * 16).astype(np.int32)
    out: list[tuple[np.ndarray, np.ndarray] | None] = []
    start = 0
    for n, z in zip(counts, near, strict=True):
        hull = cv2.convexHull(ground[start:start + n], returnPoints=False).ravel() + start
        out.append(None if z <= NEAR_M else (uv[hull], uv16[hull]))
        start += n
    return out


def blur_vectors(actors: list[Actor], poses: list[tuple[np.ndarray, np.ndarray]], exposure_s: float
                 ) -> list[np.ndarray | None]:
    """Per actor, the image motion (px) of its centre during the exposure, from its pose (m, tvec), all in one
    product; None below 0.5 m/s, below 1.5 px, or behind the camera."""
    if not actors:
        return []
    m = np.stack([p[0] for p in poses])  # (A, 3, 3)
    tvec = np.stack([p[1] for p in poses])
    hz = np.array([a.height_m / 2 for a in actors])
    run = np.array([a.speed_mps * exposure_s for a in actors])
    h0 = m[:, :, 2] * hz[:, None] + tvec  # the centre (0, 0, h/2), and (run, 0, h/2)
    h1 = h0 + m[:, :, 0] * run[:, None]
    ok = (h0[:, 2] > NEAR_M) & (h1[:, 2] > NEAR_M)
    vec = (h1[:, :2] / np.where(ok, h1[:, 2], 1.0)[:, None] - h0[:, :2] / np.where(ok, h0[:, 2], 1.0)[:, None])
    ok &= (np.array([a.speed_mps for a in actors]) >= 0.5) & (np.hypot(vec[:, 0], vec[:, 1]) >= 1.5)
    return [v if k else None for v, k in zip(vec, ok.tolist(), strict=True)]


def visible_polygons(models: list[BodyModel], uv16_blocks: list[np.ndarray], vis: np.ndarray, colours: np.ndarray,
                     first_part: list[int]) -> list[tuple[list, list, list[int], list]]:
    """Per actor (its body model and its points' pixels x 16, int32, from ``pose_actors``), what it draws: its
    visible part faces' quads ((4, 2) int32 each, in drawing order) with their shaded colours (``vis``, ``colours``
    and ``first_part`` from ``sim.render_effects.shade_faces``), the indices of its decals that lie on visible faces,
    and every decal's quad; all actors' in a few array operations (issue 19: a handful of numpy calls per actor
    cost more than drawing its faces)."""
    if not models:
        return []
    starts = np.cumsum([0, *[len(b) for b in uv16_blocks[:-1]]])
    all16 = np.concatenate(uv16_blocks)
    n_parts = np.diff(first_part)
    n_decals = [len(md.decals) for md in models]
    face_idx = np.concatenate([md.face_points for md in models]) + np.repeat(starts, n_parts)[:, None, None]
    quads = list(all16[face_idx[vis]])
    cols = colours[vis].tolist()
    face_ends = np.cumsum(np.add.reduceat(vis.sum(axis=1), first_part[:-1])).tolist()
    decal_ends = np.cumsum(n_decals).tolist()
    decal_quads = list(all16[np.concatenate([md.decal_points for md in models]).reshape(-1, 4)
                             + np.repeat(starts, n_decals)[:, None]])
    decal_vis = vis[np.concatenate([md.decal_part for md in models]).astype(int) + np.repeat(first_part[:-1], n_decals),
                    np.concatenate([md.decal_face for md in models]).astype(int)]
    out = []
    f0 = d0 = 0
    for f1, d1 in zip(face_ends, decal_ends, strict=True):
        out.append((quads[f0:f1], cols[f0:f1], np.flatnonzero(decal_vis[d0:d1]).tolist(), decal_quads[d0:d1]))
        f0, d0 = f1, d1
    return out
