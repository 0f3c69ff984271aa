"""Feature extractors on synthetic crops of known content (thesis 2.4.1)."""

from __future__ import annotations

import numpy as np
import pytest

from rsu.classify import features as F


def solid(bgr, h=60, w=90):
    img = np.zeros((h, w, 3), np.uint8)
    img[:] = bgr
    return img


def test_pixel_array_is_128x128x3_scaled():
    v = F.pixel_array(solid((0, 0, 255)))
    assert v.shape == (128 * 128 * 3,) and v.dtype == np.float32
    assert np.allclose(v.reshape(128, 128, 3)[..., 2], 1.0) and np.allclose(v.reshape(128, 128, 3)[..., :2], 0.0)


def test_hog_finds_the_edge_orientation():
    img = np.zeros((128, 128, 3), np.uint8)
    img[:, 64:] = 255  # a vertical edge: horizontal gradient, orientation bin 0
    h = F.hog(img).reshape(12 * 12, 8)
    assert h.shape == (144, 8)
    edge_cells = h[h.sum(axis=1) > 0]
    assert len(edge_cells) > 0 and np.all(np.argmax(edge_cells, axis=1) == 0)
    assert np.allclose(edge_cells.sum(axis=1), 1.0, atol=1e-3)  # L1 normalised
    img2 = np.ascontiguousarray(np.transpose(img, (1, 0, 2)))  # horizontal edge: vertical gradient, bin 4 (90 deg)
    cells2 = F.hog(img2).reshape(144, 8)
    assert np.all(np.argmax(cells2[cells2.sum(axis=1) > 0], axis=1) == 4)
    assert np.allclose(F.hog(solid((80, 80, 80))), 0.0)


def test_colour_histogram_puts_a_solid_colour_in_one_bin():
    hist = F.colour_histogram(solid((0, 0, 255)))  # BGR pure red -> RGB (255, 0, 0)
    assert hist.shape == (32**3,)
    assert hist[31 * 32 * 32] == pytest.approx(1.0) and hist.sum() == pytest.approx(1.0)


def test_hsv_custom_measures_red_and_blue_blobs():
    img = solid((40, 40, 40), h=100, w=200)
    img[10:30, 20:60] = (0, 0, 255)  # red 40x20 = 800 px, centre (40, 20)
    img[50:90, 120:180] = (255, 0, 0)  # blue 60x40 = 2400 px, centre (150, 70)
    img[80:84, 10:14] = (0, 0, 255)  # a small second red blob
    blue_area, red_area, b_area, r_area, b_cx, b_cy, r_cx, r_cy = F.hsv_custom(img)
    assert blue_area == pytest.approx(2400 / 20000) and red_area == pytest.approx(816 / 20000)
    assert b_area == pytest.approx(59 * 39 / 20000, rel=0.05) and r_area == pytest.approx(39 * 19 / 20000, rel=0.06)
    assert (b_cx, b_cy) == pytest.approx((149.5 / 200, 69.5 / 100), abs=0.01)
    assert (r_cx, r_cy) == pytest.approx((39.5 / 200, 19.5 / 100), abs=0.01)
    assert np.all(F.hsv_custom(solid((0, 200, 0))) == 0)  # green: neither


def test_top_variant_sees_only_the_top_fifth():
    img = solid((40, 40, 40), h=100, w=100)
    img[2:15, 30:70] = (255, 0, 0)  # blue light bar in the top 20%
    img[60:80, 10:30] = (0, 0, 255)  # red tail light lower down
    top = F.hsv_custom_top(img)
    assert top[0] > 0.2 and top[1] == 0.0
    assert F.hsv_custom(img)[1] > 0


def test_batch_and_validation():
    crops = [solid((0, 0, 255)), solid((255, 0, 0), h=30, w=30)]
    assert F.extract_batch("hsv8", crops).shape == (2, 8)
    with pytest.raises(ValueError, match="unknown feature"):
        F.extract_batch("sift", crops)
    with pytest.raises(ValueError, match="BGR uint8"):
        F.hog(np.zeros((10, 10), np.uint8))
    with pytest.raises(ValueError, match="too small"):
        F.hsv_custom(np.zeros((1, 5, 3), np.uint8))
