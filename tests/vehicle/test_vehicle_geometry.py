"""Curve fit and tracking errors (thesis 4.2.1, eqs. 4.1-4.7) against analytic cases."""

import math

import numpy as np
import pytest

from vehicle.geometry import chord_deviation_m, fit_circle, fit_path, wrap_angle


def arc_points(xc, yc, r, a0, a1, n=13):
    a = np.linspace(a0, a1, n)
    return np.column_stack([xc + r * np.cos(a), yc + r * np.sin(a)])


@pytest.mark.parametrize("xc, yc, r", [(0.0, 0.0, 50.0), (1234.5, -987.25, 200.0), (-3e4, 2e4, 35.0)])
def test_points_on_a_circle_recover_centre_and_radius(xc, yc, r):
    pts = arc_points(xc, yc, r, 0.3, 0.3 + 6.0 / r)  # a 6 m arc, as in the controller's window
    fx, fy, fr = fit_circle(pts)
    assert abs(fx - xc) < 1e-9 * max(1.0, abs(xc)) * 10 and abs(fy - yc) < 1e-9 * max(1.0, abs(yc)) * 10
    assert abs(fr - r) < 1e-9 * r * 10
    fit = fit_path(pts)
    assert not fit.is_line and fit.turn == 1 and abs(fit.radius_m - r) < 1e-6


def test_exact_circle_to_1e9():
    pts = arc_points(10.0, -20.0, 80.0, -0.5, 1.5, 25)
    fx, fy, fr = fit_circle(pts)
    assert max(abs(fx - 10.0), abs(fy + 20.0), abs(fr - 80.0)) < 1e-9


def test_noisy_points_within_tolerance():
    rng = np.random.default_rng(3)
    pts = arc_points(5.0, 7.0, 60.0, 0.0, 1.2, 60) + rng.normal(0, 0.01, (60, 2))
    fx, fy, fr = fit_circle(pts)
    assert math.hypot(fx - 5.0, fy - 7.0) < 0.5 and abs(fr - 60.0) < 0.5


def test_straight_line_detected_and_lateral_error_matches_eq_4_4():
    m, c = 0.3, 2.0
    x = np.linspace(0, 6, 13)
    pts = np.column_stack([x, m * x + c])
    fit = fit_path(pts)
    assert fit.is_line and fit.curvature_1pm == 0.0
    xv, yv = 3.0, 5.0
    assert fit.lateral_error_m(xv, yv) == pytest.approx((yv - m * xv - c) / math.sqrt(1 + m * m), abs=1e-12)
    assert fit.heading_at(xv, yv) == pytest.approx(math.atan(m))
    # a barely bent set is a line within the threshold, an arc outside it
    assert chord_deviation_m(arc_points(0, 0, 1e5, 0, 6e-5)) < 1e-3
    assert fit_path(arc_points(0, 0, 1e5, 0, 6e-5)).is_line
    assert not fit_path(arc_points(0, 0, 200.0, 0, 0.03)).is_line


def test_sign_convention_left_is_positive_on_lines_and_both_arc_directions():
    line = fit_path(np.array([[0.0, 0.0], [5.0, 0.0], [10.0, 0.0]]))
    assert line.lateral_error_m(5.0, 1.0) == pytest.approx(1.0)  # left of an eastbound line
    back = fit_path(np.array([[10.0, 0.0], [5.0, 0.0], [0.0, 0.0]]))
    assert back.lateral_error_m(5.0, 1.0) == pytest.approx(-1.0)  # right of a westbound line
    # left (CCW) turn around (0, 100), car at the bottom heading east
    ccw = fit_path(arc_points(0.0, 100.0, 100.0, -math.pi / 2 - 0.03, -math.pi / 2 + 0.03))
    assert ccw.turn == 1 and ccw.curvature_1pm == pytest.approx(0.01)
    assert ccw.lateral_error_m(0.0, 0.5) == pytest.approx(0.5)  # inside the left turn = left
    assert ccw.heading_at(0.0, 0.0) == pytest.approx(0.0, abs=1e-9)
    # right (CW) turn around (0, -100), car at the top heading east
    cw = fit_path(arc_points(0.0, -100.0, 100.0, math.pi / 2 + 0.03, math.pi / 2 - 0.03))
    assert cw.turn == -1 and cw.curvature_1pm == pytest.approx(-0.01)
    assert cw.lateral_error_m(0.0, 0.5) == pytest.approx(0.5)  # outside the right turn = left
    assert cw.heading_at(0.0, 0.0) == pytest.approx(0.0, abs=1e-9)


def test_yaw_and_yaw_rate_errors():
    ccw = fit_path(arc_points(0.0, 100.0, 100.0, -math.pi / 2 - 0.03, -math.pi / 2 + 0.03))
    e, yaw_err, rate_err = ccw.errors(0.0, 0.0, 0.05, 0.2, 10.0)
    assert e == pytest.approx(0.0, abs=1e-9)
    assert yaw_err == pytest.approx(0.05)  # eq. 4.6
    assert rate_err == pytest.approx(0.2 - 10.0 / 100.0)  # eq. 4.7
    assert wrap_angle(math.pi + 0.1) == pytest.approx(-math.pi + 0.1)
    assert wrap_angle(-math.pi) == pytest.approx(math.pi)


def test_bad_input_is_refused():
    with pytest.raises(ValueError):
        fit_path(np.array([[0.0, 0.0]]))
    with pytest.raises(ValueError):
        fit_path(np.array([[0.0, 0.0], [np.nan, 1.0], [2.0, 2.0]]))
    with pytest.raises(ValueError):
        fit_circle(np.array([[0.0, 0.0], [1.0, 1.0]]))
