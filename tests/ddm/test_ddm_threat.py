"""Threat formulas of the Clemson hazard report (eq. 1-4) against hand-computed values."""

import math

import numpy as np
import pytest

from ddm.threat import (
    av_hazard_distances,
    fuse_image,
    image_threat,
    nearest_to_bottom_centre,
    raw_threat,
    threat_value,
)


@pytest.mark.parametrize(("lx", "ly", "expected"), [
    (0.0, 0.0, 1.0),                                   # T = sqrt(1 + 1) = sqrt 2 -> 1
    (30.0, 1.85, 0.5),                                 # T = sqrt(0.25 + 0.25) = 0.70711 -> 0.5
    (15.0, 0.0, 1.25 / math.sqrt(2.0)),                # T = sqrt(0.75^2 + 1) = 1.25 -> 0.88388
    (45.0, 3.7, 0.25 / math.sqrt(2.0)),                # T = 0.25 -> 0.17678
    (60.0, 3.7, 0.0),                                  # the corner of the region
    (30.0, -1.85, 0.5),                                # lateral side does not matter
    (60.01, 0.0, 0.0),                                 # beyond lx_max
    (10.0, 3.71, 0.0),                                 # beyond ly_max (a lane width)
    (-0.5, 0.0, 0.0),                                  # behind the front bumper
])
def test_threat_value_eq2_eq3(lx, ly, expected):
    assert threat_value(lx, ly) == pytest.approx(expected, abs=1e-9)


def test_threat_value_raw_and_arrays():
    assert float(raw_threat(30.0, 1.85)) == pytest.approx(math.sqrt(0.5))
    out = threat_value(np.array([0.0, 30.0, 70.0]), np.array([0.0, 1.85, 0.0]))
    np.testing.assert_allclose(out, [1.0, 0.5, 0.0])
    # custom limits: lx_max 6000 cm, ly_max 370 cm as in the report's units give the same value
    assert threat_value(3000.0, 185.0, 6000.0, 370.0) == pytest.approx(0.5)
    # monotone: nearer is more threatening, both ways
    assert threat_value(10.0, 1.0) > threat_value(20.0, 1.0) > threat_value(20.0, 2.0)
    with pytest.raises(ValueError):
        threat_value(float("nan"), 0.0)


def test_av_hazard_distances():
    lx, ly = av_hazard_distances(100.0, 5.0, 4.9, 140.0, 5.55, 1.2)
    assert lx == pytest.approx(139.4 - 102.45)
    assert ly == pytest.approx(0.55)


def test_image_threat_eq4_hand_computed():
    h, w = 400, 600                       # the report's image size; denominator sqrt(400^2 + 300^2) = 500
    mask = np.zeros((h, w), bool)
    assert image_threat(mask) == 0.0      # no hazard pixel
    mask[0, 0] = True                     # the top-left corner: distance 500 -> 0
    assert image_threat(mask) == pytest.approx(0.0)
    mask[160, 480] = True                 # (160 - 400, 480 - 300) = (-240, 180): distance 300 -> 0.4
    assert nearest_to_bottom_centre(mask) == (160, 480)
    assert image_threat(mask) == pytest.approx(0.4)
    mask[399, 300] = True                 # the bottom-centre pixel's neighbour: distance 1 -> 0.998
    assert image_threat(mask) == pytest.approx(0.998)


def test_image_threat_on_label_image():
    labels = np.zeros((400, 600), np.uint8)
    labels[160:200, 480:500] = 3          # hazard class 3; the nearest pixel is (199, 480)
    labels[390:, :] = 1                   # road class 1 at the bottom: not a hazard
    expected = 1.0 - math.hypot(199 - 400, 480 - 300) / 500.0
    assert image_threat(labels, labels=3) == pytest.approx(expected)
    assert image_threat(labels, labels=(2, 3)) == pytest.approx(expected)
    with pytest.raises(ValueError):
        image_threat(np.zeros((4, 4, 3), bool))


def test_fuse_image_eq1():
    a = np.full((2, 2, 3), 100, np.uint8)
    b = np.full((2, 2, 3), 200, np.uint8)
    assert fuse_image(a, b, 0.0).tolist() == a.tolist()
    assert int(fuse_image(a, b, 0.25)[0, 0, 0]) == 125
    with pytest.raises(ValueError):
        fuse_image(a, b, 1.5)
