"""Reference paths (resampling, projection, speeds, stop point) and the pure watchdog."""

import math

import numpy as np
import pytest

from vehicle.failsafe import FailsafeConfig, Watchdog
from vehicle.reference import ReferencePath, lane_change_waypoints


def test_resampling_projection_speed_and_stop():
    wp = np.array([[0.0, 0.0], [10.0, 0.0], [20.0, 0.0], [30.0, 0.0]])
    path = ReferencePath(wp, speeds_mps=[10.0, 10.0, 5.0, 0.0], stop_point=(25.0, 0.4))
    assert path.length_m == pytest.approx(30.0)
    assert np.allclose(np.diff(path.s), 0.5)
    proj = path.project(12.3, 1.0)
    assert proj.s_m == pytest.approx(12.3) and proj.distance_m == pytest.approx(1.0)
    assert path.project(12.3, 1.0, hint=proj.index).s_m == pytest.approx(12.3)
    assert path.project(28.0, -0.5, hint=0).s_m == pytest.approx(28.0)  # hint far off: global search
    assert path.speed_at(15.0, 99.0) == pytest.approx(7.5)
    assert path.stop_s_m == pytest.approx(25.0) and path.stop_offset_m == pytest.approx(0.4)
    assert ReferencePath(wp).speed_at(3.0, 13.4) == 13.4


def test_lane_change_path_shape(road):
    wp = lane_change_waypoints(road, 100.0, 1, 0, 40.0, 100.0, lead_m=10.0)
    assert wp[0] == pytest.approx([90.0, 5.55]) and wp[-1] == pytest.approx([200.0, 1.85])
    path = ReferencePath(wp)
    # quintic: peak curvature 5.77 * 3.7 / 40^2 = 0.0133 1/m, zero at both ends
    assert path.max_curvature_1pm() == pytest.approx(5.7735 * 3.7 / 1600.0, rel=0.05)
    assert abs(path.fit_at(5.0).curvature_1pm) < 1e-4 and abs(path.fit_at(100.0).curvature_1pm) < 1e-4


def test_reference_refuses_bad_waypoints():
    with pytest.raises(ValueError):
        ReferencePath([[0.0, 0.0]])
    with pytest.raises(ValueError):
        ReferencePath([[0.0, 0.0], [0.0, 0.0]])
    with pytest.raises(ValueError):
        ReferencePath([[0.0, 0.0], [1.0, math.inf]])
    with pytest.raises(ValueError):
        ReferencePath([[0.0, 0.0], [5.0, 0.0]], speeds_mps=[1.0])


def test_watchdog_triggers_latches_and_clears():
    wd = Watchdog(FailsafeConfig(link_timeout_s=2.0, link_lost_s=5.0, localisation_stale_s=1.0))
    assert wd.check(0.0, in_manoeuvre=False, localisation_age_s=0.1) is None  # silence counts from here
    assert wd.check(2.1, in_manoeuvre=False, localisation_age_s=0.1) is None and wd.degraded  # cruising: degraded
    assert "while cruising" in wd.check(5.1, in_manoeuvre=False, localisation_age_s=0.1)  # never heard the DDM
    wd.clear()
    wd.link_seen(10.0)
    assert wd.check(11.9, True, 0.1) is None
    reason = wd.check(12.1, True, 0.1)
    assert reason.startswith("link lost") and wd.triggered_at_s == 12.1
    wd.link_seen(12.2)
    assert wd.check(12.3, True, 0.1) == reason  # latched until cleared
    wd.clear()
    assert "localisation stale" in wd.check(13.0, False, 1.5)
    assert wd.healthy(13.0, 1.5) is not None and wd.healthy(13.0, 0.2) is None
    with pytest.raises(ValueError):
        FailsafeConfig(link_timeout_s=0.0)
    with pytest.raises(ValueError):
        FailsafeConfig(link_timeout_s=4.0, link_lost_s=3.0)


def test_project_ignores_a_hint_from_a_longer_path():
    """The core keeps its last projection index across a path switch: a hint past the end of the new
    (shorter) path must fall back to the global search, not crash (seen in the demo on a pull-over)."""
    short = ReferencePath([(0.0, 0.0), (10.0, 0.0)], step_m=0.5)
    proj = short.project(4.0, 0.3, hint=10_000)
    assert proj.s_m == pytest.approx(4.0, abs=1e-6)
    assert proj.distance_m == pytest.approx(0.3, abs=1e-6)


def test_fit_at_reuses_a_window_fitted_before_and_gives_the_fit_of_its_window():
    """The cached fit is the fit of the window around s, for every s along an arc-then-line path."""
    from vehicle.geometry import fit_path

    t = np.linspace(0, np.pi / 2, 40)
    arc = np.c_[50 * np.sin(t), 50 - 50 * np.cos(t)]
    line = np.c_[np.full(30, 50.0), 50 + np.arange(1, 31) * 2.0]
    path = ReferencePath(np.vstack([arc, line]))
    for s in np.linspace(0, path.length_m, 500):
        assert path.fit_at(float(s)) == fit_path(path.window(float(s)))
    assert 0 < len(path._fits) <= 64  # windows, not calls
