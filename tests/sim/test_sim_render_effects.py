"""The renderer's effect numbers computed with array operations (issue 19) equal issue 17's per-tap and per-lamp
loops (``sim.render_reference``'s arithmetic, restated here)."""

import cv2
import numpy as np
import pytest

from sim.render_effects import halo_numbers, line_kernel


def _grid_kernel(vec):
    n = int(min(25, np.ceil(float(np.hypot(*vec)))))
    k = np.zeros((2 * n + 1, 2 * n + 1), np.float32)
    direction = vec / max(1e-6, float(np.hypot(*vec)))
    for i in range(n + 1):
        x, y = np.round(n + direction * (i - n / 2)).astype(int)
        k[np.clip(y, 0, 2 * n), np.clip(x, 0, 2 * n)] += 1.0
    return k / k.sum()


@pytest.mark.parametrize("vec", [(1.6, 0.0), (-7.3, 2.2), (0.4, -12.9), (40.0, 31.0), (3.0, 3.0), (-2.5, -0.5)])
def test_line_kernel_filters_like_the_full_grid(vec):
    vec = np.array(vec)
    k, anchor = line_kernel(vec)
    grid = _grid_kernel(vec)
    assert k.sum() == pytest.approx(1.0) and k.size <= grid.size
    img = np.random.default_rng(0).integers(0, 256, (60, 80, 3), dtype=np.uint8)
    a = cv2.filter2D(img, -1, k, anchor=anchor, borderType=cv2.BORDER_REPLICATE)
    b = cv2.filter2D(img, -1, grid, borderType=cv2.BORDER_REPLICATE)
    assert np.abs(a.astype(int) - b.astype(int)).max() <= 1


def test_halo_numbers_match_the_per_lamp_loop():
    rng = np.random.default_rng(1)
    glows = [(rng.uniform(0, 900, (4, 2)) * rng.uniform(0.001, 0.05), (50, 50, 200), 0.3),
             (rng.uniform(0, 40, (4, 2)) + 600, (0, 0, 255), 1.0),
             (rng.uniform(0, 30, (12, 2)) + 300, (255, 80, 0), 1.0),  # a light bar over three faces
             (np.full((4, 2), 5.0), (0, 160, 255), 0.8)]
    scale = 1.6
    expected = set()
    for puv, colour, strength in glows:  # issue 17's loop
        cx, cy = puv.mean(axis=0)
        size = max(2.0, float(np.ptp(puv[:, 0])), float(np.ptp(puv[:, 1])))
        r = int(min(60, max(3, size * 0.55 * scale)))
        col = tuple(int(c * min(1.0, strength * (0.6 + 0.25 * scale))) for c in colour)
        expected.add((int(round(cx)), int(round(cy)), r, col, strength >= 1.0, max(1, int(size / 12))))
    assert set(halo_numbers(glows, scale)) == expected
    assert halo_numbers([], scale) == []
