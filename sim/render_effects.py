"""Pure per-frame numbers of the renderer's effects (issue 19: computed with a few array operations instead of a
Python loop per lamp or kernel tap), kept apart from ``sim.render`` so they can be tested alone."""

from __future__ import annotations

import numpy as np


def line_kernel(vec: np.ndarray) -> tuple[np.ndarray, tuple[int, int]]:
    """Motion-blur kernel for an image motion ``vec`` (px) during the exposure: n + 1 = min(25, ceil(|vec|)) + 1
    samples along the line through the centre of a (2n + 1)^2 grid, normalised; returned as the line's bounding box
    with the anchor (x, y) of the grid's centre in it, the same correlation as the full grid (which OpenCV would
    apply by DFT: a 51 x 51 kernel cost 4 ms a frame at night)."""
    length = float(np.hypot(*vec))
    n = int(min(25, np.ceil(length)))
    direction = vec / max(1e-6, length)
    xy = np.clip(np.round(n + direction * (np.arange(n + 1) - n / 2)[:, None]).astype(int), 0, 2 * n)
    (c0, r0), (c1, r1) = xy.min(axis=0).tolist(), xy.max(axis=0).tolist()
    k = np.zeros((r1 - r0 + 1, c1 - c0 + 1), np.float32)
    np.add.at(k, (xy[:, 1] - r0, xy[:, 0] - c0), 1.0)
    k /= k.sum()
    return k, (n - c0, n - r0)


def halo_numbers(glows: list[tuple[np.ndarray, tuple, float]], scale: float) -> list[tuple]:
    """Per lamp that is on (its pixel points (N, 2), colour BGR, strength), its halo: (centre x, y in whole pixels,
    radius r = clip(0.55 size scale, 3, 60) with size = max(2, the points' extent), colour times
    min(1, strength (0.6 + 0.25 scale)) truncated, hot core when strength >= 1, core radius max(1, size / 12)).
    The four-point lamps are computed together; a light bar's halo spans its faces' points. Saturated adds commute,
    so the order of the halos returned is not the order given."""
    quads = [g for g in glows if len(g[0]) == 4]
    glows = quads + [g for g in glows if len(g[0]) != 4]
    centres, sizes = [], []
    if quads:
        pts = np.stack([g[0] for g in quads])  # (G, 4, 2)
        centres.append(pts.mean(axis=1))
        sizes.append(np.ptp(pts, axis=1).max(axis=1))
    for pts, _c, _s in glows[len(quads):]:
        centres.append(pts.mean(axis=0)[None])
        sizes.append(np.ptp(pts, axis=0).max(keepdims=True))
    if not glows:
        return []
    centres, sizes = np.concatenate(centres), np.maximum(2.0, np.concatenate(sizes))
    radii = np.clip(sizes * 0.55 * scale, 3, 60).astype(int).tolist()
    strengths = np.array([st for _p, _c, st in glows])
    cols = (np.array([c for _p, c, _s in glows], float)
            * np.minimum(1.0, strengths * (0.6 + 0.25 * scale))[:, None]).astype(int).tolist()
    cores = np.maximum(1, (sizes / 12).astype(int)).tolist()
    return [(cx, cy, r, tuple(col), hot, core) for (cx, cy), r, col, hot, core in
            zip(np.round(centres).astype(int).tolist(), radii, cols, (strengths >= 1.0).tolist(), cores, strict=True)]
