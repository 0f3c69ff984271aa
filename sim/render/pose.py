"""Pure per-frame geometry of the renderer (``sim.render.renderer``): every actor of a snapshot posed and projected, its
painter's place, headlight pool, cast-shadow outline, motion-blur vector and visible faces and decals, each for all
actors in a few array operations (a Python loop per actor costs more than the drawing, and so does
concatenating the actors' body models every frame). ``ActorBatch`` holds the snapshot's body models concatenated
once (``Renderer`` keeps it while the snapshot's actors keep their looks); ``pose_frame`` poses them for one frame.
Camera matrices in, pixel arrays out; nothing here draws."""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from protocol.messages import Actor
from sim.bodies import BodyModel
from sim.camera import NEAR_M, PinholeCamera

POOL_LOCAL_M = np.array([[0.5, -0.8], [0.5, 0.8], [18.0, 3.2], [18.0, -3.2]])  # headlight pool, ahead of the bumper
FAR_M = 400.0
"""Actors whose centre is farther ahead of the camera than this are not drawn."""


@dataclass(frozen=True)
class ActorBatch:
    """The body models of a snapshot's actors (in its order), concatenated: per actor its block of ``points`` (part
    corners, decal quads, contact footprint: ``BodyModel.points``), per part (all actors' parts in order) its faces'
    shading arrays, per decal its quad and face, all indices global (into the concatenation)."""

    models: tuple[BodyModel, ...]
    points: np.ndarray  # (N, 3) every actor's points
    owner: np.ndarray  # (N,) actor of each point
    point_start: list[int]  # (A + 1) each actor's first point
    corner_cuts: list[int]  # per actor, its first point and the end of its part corners (np.*.reduceat)
    corner_idx: np.ndarray  # (Nc,) every part corner, actor by actor (shadows)
    corner_owner: np.ndarray  # (Nc,)
    corner_start: list[int]  # (A + 1) each actor's first part corner in corner_idx
    part_start: list[int]  # (A + 1) each actor's first part
    part_owner: np.ndarray  # (S,)
    normals: np.ndarray  # (S, 5, 3), as BodyModel
    centres: np.ndarray
    face_ok: np.ndarray
    glass: np.ndarray
    top: np.ndarray
    base_bgr: np.ndarray
    face_points: np.ndarray  # (S, 5, 4) global point indices of each face's corners
    decal_start: np.ndarray  # (A + 1,) each actor's first decal
    decal_points: np.ndarray  # (D, 4) global point indices of each decal's quad
    decal_part: np.ndarray  # (D,) global part index
    decal_face: np.ndarray  # (D,)
    silhouettes: list[np.ndarray]  # per actor, (P_sil, 8) global point indices of its silhouette parts' corners


def actor_batch(models: list[BodyModel]) -> ActorBatch:
    """The ``ActorBatch`` of these body models (one per actor, in the snapshot's order)."""
    n_points = [len(md.points) for md in models]
    n_parts = [len(md.parts) for md in models]
    n_decals = [len(md.decals) for md in models]
    point_start = np.concatenate([[0], np.cumsum(n_points)]).astype(int)
    part_start = np.concatenate([[0], np.cumsum(n_parts)]).astype(int)
    decal_start = np.concatenate([[0], np.cumsum(n_decals)]).astype(int)
    corner_idx = np.concatenate([s + np.arange(8 * p) for s, p in zip(point_start[:-1], n_parts, strict=True)])
    actors = np.arange(len(models))
    return ActorBatch(
        models=tuple(models),
        points=np.concatenate([md.points for md in models]),
        owner=np.repeat(actors, n_points),
        point_start=point_start.tolist(),
        corner_cuts=[i for s, p in zip(point_start[:-1].tolist(), n_parts, strict=True) for i in (s, s + 8 * p)],
        corner_idx=corner_idx,
        corner_owner=np.repeat(actors, [8 * p for p in n_parts]),
        corner_start=np.concatenate([[0], np.cumsum([8 * p for p in n_parts])]).astype(int).tolist(),
        part_start=part_start.tolist(),
        part_owner=np.repeat(actors, n_parts),
        normals=np.concatenate([md.normals for md in models]),
        centres=np.concatenate([md.centres for md in models]),
        face_ok=np.concatenate([md.face_ok for md in models]),
        glass=np.concatenate([md.glass for md in models]),
        top=np.concatenate([md.top for md in models]),
        base_bgr=np.concatenate([md.base_bgr for md in models]),
        face_points=np.concatenate([md.face_points + s for md, s in zip(models, point_start, strict=False)]),
        decal_start=decal_start,
        decal_points=np.concatenate([md.decal_points.reshape(-1, 4) + s
                                     for md, s in zip(models, point_start, strict=False)]).astype(int),
        decal_part=np.concatenate([md.decal_part.astype(int) + s for md, s in zip(models, part_start, strict=False)]),
        decal_face=np.concatenate([md.decal_face.astype(int) for md in models]),
        silhouettes=[s + 8 * np.flatnonzero([p.silhouette for p in md.parts])[:, None] + np.arange(8)
                     for md, s in zip(models, point_start.tolist(), strict=False)],
    )


@dataclass(frozen=True)
class FramePose:
    """One frame's pose of an ``ActorBatch``: per actor its state (A, 7: cos and sin of its heading, x, y (m),
    length, height (m), speed (m/s)), position (A, 3: x, y, 0), rotation (A, 3, 3), m = K R rot (A, 3, 3) and
    tvec = K R (position - C) (A, 3); per point its pixel (N, 2) and the same x 16 rounded (int32, the drawing's fixed
    point); per actor (lists) its part corners' nearest depth and pixel minimum and maximum (x, y), and
    all its points' pixel box [x1, y1, x2, y2] (what its drawing may reach)."""

    state: np.ndarray
    positions: np.ndarray
    rots: np.ndarray
    m: np.ndarray
    tvec: np.ndarray
    uv: np.ndarray
    uv16: np.ndarray
    near: list[float]
    lo: list[list[float]]
    hi: list[list[float]]
    box: list[list[float]]


def pose_frame(batch: ActorBatch, actors: list[Actor], cam: PinholeCamera) -> FramePose:
    """Every actor's body model posed and projected (``FramePose``), every point in one product."""
    state = np.array([(math.cos(a.heading_rad), math.sin(a.heading_rad), a.pos_x_m, a.pos_y_m, a.length_m,
                       a.height_m, a.speed_mps) for a in actors])
    c, s = state[:, 0], state[:, 1]
    rots = np.zeros((len(actors), 3, 3))
    rots[:, 0, 0], rots[:, 0, 1], rots[:, 1, 0], rots[:, 1, 1], rots[:, 2, 2] = c, -s, s, c, 1.0
    m = cam.KR @ rots  # (A, 3, 3)
    positions = np.zeros((len(actors), 3))
    positions[:, :2] = state[:, 2:4]
    tvec = (positions - cam.C) @ cam.KR.T  # (A, 3)
    h = np.einsum("nij,nj->ni", m[batch.owner], batch.points) + tvec[batch.owner]
    depth = h[:, 2]
    uv = h[:, :2] / np.where(depth > NEAR_M, depth, 1.0)[:, None]
    cuts = batch.corner_cuts
    near = np.minimum.reduceat(depth, cuts)[::2].tolist()
    lo, hi = np.minimum.reduceat(uv, cuts), np.maximum.reduceat(uv, cuts)
    # the whole block's (the decals' and contact shadow's points too): what its drawing may reach
    box = np.hstack([np.minimum(lo[::2], lo[1::2]), np.maximum(hi[::2], hi[1::2])]).tolist()
    return FramePose(state, positions, rots, m, tvec, uv, np.round(uv * 16).astype(np.int32), near,
                     lo[::2].tolist(), hi[::2].tolist(), box)


def painter_order(actors: list[Actor], cam: PinholeCamera) -> list[int]:
    """Indices of the actors in view depth (their centre from NEAR_M + their length to ``FAR_M`` ahead of the
    camera), far to near by ground distance from the camera (painter's order; ties keep the snapshot's order)."""
    cx, cy, cz = cam.C.tolist()
    fx, fy, fz = cam.R[2].tolist()
    out = []
    for k, a in enumerate(actors):
        rx, ry = a.pos_x_m - cx, a.pos_y_m - cy
        depth = rx * fx + ry * fy + (a.height_m / 2 - cz) * fz
        if NEAR_M + a.length_m <= depth <= FAR_M:
            out.append((-math.hypot(rx, ry), k))
    out.sort(key=lambda t: t[0])
    return [k for _d, k in out]


def pool_quads(pose: FramePose, cam: PinholeCamera) -> tuple[np.ndarray, list[tuple[int, int, int, int] | None]]:
    """Headlight pools of the posed actors: pixel quads x 16 rounded (N, 4, 2 int32, the fixed point the drawing
    takes) on each pool's canvas (from its box's top-left corner), and per pool the box its blurred light may reach
    (x1, y1, x2, y2: the quad's whole-pixel box, 1 px of anti-aliasing and the 7 x 7 blur's 3 px beyond it, cut to
    the image and 3 px beyond it: what the blur reads), None when the pool is behind the camera or its box in the
    image is under 2 px either way. The pool: a trapezoid on the road from 0.5 to 18 m ahead of the front bumper."""
    c, s_, px, py, length = (pose.state[:, i:i + 1] for i in range(5))
    fx, fy = px + c * length / 2, py + s_ * length / 2
    lx, ly = POOL_LOCAL_M[:, 0], POOL_LOCAL_M[:, 1]
    pts = np.stack([fx + lx * c - ly * s_, fy + lx * s_ + ly * c, np.zeros_like(fx + lx)], axis=-1)
    uv, depth = cam.project(pts.reshape(-1, 3))
    uv = uv.reshape(-1, 4, 2)
    w, h = cam.width_px, cam.height_px
    lo, hi = np.floor(uv.min(axis=1)).astype(int) - 4, np.ceil(uv.max(axis=1)).astype(int) + 5
    o_lo, o_hi = np.maximum(lo, 0), np.minimum(hi, (w, h))  # in the image
    ok = (depth.reshape(-1, 4) > NEAR_M).all(axis=1) & (o_hi - o_lo >= 2).all(axis=1)
    boxes = np.hstack([np.maximum(lo, o_lo - 3), np.minimum(hi, o_hi + 3)])
    quads16 = np.round(uv * 16).astype(np.int32) - 16 * boxes[:, None, :2].astype(np.int32)  # on each canvas
    return quads16, [tuple(b) if k else None for b, k in zip(boxes.tolist(), ok.tolist(), strict=True)]


def shadow_outlines(batch: ActorBatch, pose: FramePose, which: list[int], sun: np.ndarray,
                    cam: PinholeCamera, ground_m: np.ndarray, ground_t: np.ndarray
                    ) -> dict[int, tuple[tuple[int, int, int, int], np.ndarray]]:
    """Per actor in ``which``, its cast shadow's box in the image (x1, y1, x2, y2: floor to ceil + 1 of its pixels,
    cut to the image) and outline in pixels x 16 rounded (K, 2 int32, the drawing's fixed point) from the box's
    top-left corner, left out when any of it is behind the camera or its box is under 2 px either way: the part
    corners projected along the unit vector ``sun`` onto z = 0 (``sim.render.effects.shadow_hull``'s projection, in
    float32 as ``cv2.convexHull`` takes them), every actor's in one product, and into the image (a road point
    (x, y) -> homogeneous pixel (x, y) @ ground_m - ground_t); the outline is its ground hull's points, the box every
    corner's (the same: the image of a hull is the hull of the image, in front of the camera)."""
    local = batch.points[batch.corner_idx]  # (Nc, 3)
    owner = batch.corner_owner
    ground = (np.einsum("nij,nj->ni", pose.rots[:, :2, :2][owner], local[:, :2]) + pose.state[owner, 2:4]
              - local[:, 2:3] * (sun[:2] / max(sun[2], 0.25))).astype(np.float32)
    h = ground.astype(float) @ ground_m - ground_t
    starts = batch.corner_start
    near = np.minimum.reduceat(h[:, 2], starts[:-1]).tolist()
    uv = h[:, :2] / np.where(h[:, 2:] > NEAR_M, h[:, 2:], 1.0)
    lo = np.maximum(np.floor(np.minimum.reduceat(uv, starts[:-1])), 0).astype(int)
    hi = np.minimum(np.ceil(np.maximum.reduceat(uv, starts[:-1])) + 1, (cam.width_px, cam.height_px)).astype(int)
    uv16 = np.round(uv * 16).astype(np.int32) - 16 * lo[owner].astype(np.int32)  # on each shadow's mask
    boxes = np.hstack([lo, hi]).tolist()
    out = {}
    for k in which:
        x1, y1, x2, y2 = boxes[k]
        if near[k] > NEAR_M and x2 - x1 >= 2 and y2 - y1 >= 2:
            s = starts[k]
            hull = cv2.convexHull(ground[s:starts[k + 1]], returnPoints=False).ravel() + s
            out[k] = ((x1, y1, x2, y2), uv16[hull])
    return out


def blur_vectors(pose: FramePose, exposure_s: float) -> list[np.ndarray | None]:
    """Per actor, the image motion (px) of its centre during the exposure, from its pose (m, tvec), all in one
    product; None below 0.5 m/s, below 1.5 px, or behind the camera."""
    m, tvec = pose.m, pose.tvec
    hz, speed = pose.state[:, 5] / 2, pose.state[:, 6]
    run = speed * exposure_s
    h0 = m[:, :, 2] * hz[:, None] + tvec  # the centre (0, 0, h/2), and (run, 0, h/2)
    h1 = h0 + m[:, :, 0] * run[:, None]
    ok = (h0[:, 2] > NEAR_M) & (h1[:, 2] > NEAR_M)
    vec = (h1[:, :2] / np.where(ok, h1[:, 2], 1.0)[:, None] - h0[:, :2] / np.where(ok, h0[:, 2], 1.0)[:, None])
    ok &= (speed >= 0.5) & (np.hypot(vec[:, 0], vec[:, 1]) >= 1.5)
    return [v if k else None for v, k in zip(vec, ok.tolist(), strict=True)]


@dataclass(frozen=True)
class VisiblePolygons:
    """What every actor draws: its visible part faces' quads ((4, 2) int32 each, in drawing order, all actors') with
    their shaded colours, actor k's being ``faces[face_start[k]:face_start[k + 1]]``; its decals that lie on
    visible faces (global decal indices ``decals``, their quads ``decal_quads``; actor k's from
    ``decal_seen_start[k]``)."""

    faces: list[np.ndarray]
    colours: list[tuple[float, float, float]]
    face_start: list[int]
    decals: list[int]
    decal_quads: list[np.ndarray]
    decal_seen_start: list[int]


def visible_polygons(batch: ActorBatch, pose: FramePose, vis: np.ndarray, colours: np.ndarray) -> VisiblePolygons:
    """The ``VisiblePolygons`` of every actor from its faces' visibility and shaded colours (``vis``, ``colours``:
    ``sim.render.effects.shade_faces``), in a few array operations."""
    all16 = pose.uv16
    faces = list(all16[batch.face_points[vis]])
    face_start = [0, *np.cumsum(np.add.reduceat(vis.sum(axis=1), batch.part_start[:-1])).tolist()]
    seen = np.flatnonzero(vis[batch.decal_part, batch.decal_face])
    # (colours as tuples: OpenCV reads a tuple as a colour ~0.7 us faster than a list)
    return VisiblePolygons(faces, list(map(tuple, colours[vis].tolist())), face_start, seen.tolist(),
                           list(all16[batch.decal_points[seen]]),
                           [0, *np.searchsorted(seen, batch.decal_start[1:]).tolist()])
