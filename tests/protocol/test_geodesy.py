"""The corridor frame on the WGS84 ellipsoid: round trips and distances against PROJ's geodesic."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from protocol.corridor import load_corridor
from protocol.geodesy import corridor_frame, geodesic_distance_m

LATITUDES_DEG = (0.0, 30.0, 60.0)
POINTS_M = [(0.0, 0.0), (1000.0, 0.0), (0.0, 1000.0), (-700.0, 400.0), (1500.0, -1200.0), (3.7, 250.0)]


@pytest.mark.parametrize("lat0", LATITUDES_DEG)
def test_round_trip_is_under_a_millimetre(lat0):
    frame = corridor_frame(lat0, -96.47)
    for x, y in POINTS_M:
        x2, y2 = frame.from_latlon(*frame.to_latlon(x, y))
        assert math.hypot(x2 - x, y2 - y) < 1e-3
    lat, lon = frame.to_latlon(0.0, 0.0)
    assert (lat, lon) == pytest.approx((lat0, -96.47), abs=1e-12)


@pytest.mark.parametrize("lat0", LATITUDES_DEG)
def test_frame_distances_agree_with_the_geodesic_within_a_millimetre_per_kilometre(lat0):
    frame = corridor_frame(lat0, 10.0)
    for i, (x1, y1) in enumerate(POINTS_M):
        for x2, y2 in POINTS_M[i + 1:]:
            frame_m = math.hypot(x2 - x1, y2 - y1)
            geodesic_m = geodesic_distance_m(*frame.to_latlon(x1, y1), *frame.to_latlon(x2, y2))
            assert abs(frame_m - geodesic_m) <= 1e-3 * frame_m / 1000.0, (lat0, (x1, y1), (x2, y2))


def test_the_spherical_approximation_it_replaces_is_off_by_metres_per_kilometre_at_30_deg():
    """What the test above guards against: 6,378,137 m in every direction puts a point 1 km north about 4.6 m
    short of 1 km along the geodesic at 30 deg (the meridian radius there is 6,351 km)."""
    lat0 = 30.0
    spherical_lat = lat0 + math.degrees(1000.0 / 6_378_137.0)
    assert abs(geodesic_distance_m(lat0, 0.0, spherical_lat, 0.0) - 1000.0) > 4.0
    assert geodesic_distance_m(*corridor_frame(lat0, 0.0).to_latlon(0.0, 1000.0), lat0, 0.0) == pytest.approx(
        1000.0, abs=1e-3)


def test_the_corridor_keeps_its_functions_and_vectorised_forms_agree():
    corridor = load_corridor()
    lat, lon = corridor.to_latlon(123.4, -56.7)
    assert corridor.from_latlon(lat, lon) == pytest.approx((123.4, -56.7), abs=1e-6)
    moved = replace(corridor, origin_lat_deg=60.0)
    assert moved.to_latlon(0.0, 1000.0)[0] != pytest.approx(lat)
    frame = corridor_frame(corridor.origin_lat_deg, corridor.origin_lon_deg)
    xs, ys = np.array([0.0, 50.0, -80.0]), np.array([0.0, 3.7, 400.0])
    lats, lons = frame.to_latlon_many(xs, ys)
    assert np.allclose(np.column_stack(frame.from_latlon_many(lats, lons)), np.column_stack([xs, ys]), atol=1e-6)
    assert abs(frame.convergence_rad(1000.0, 0.0)) < math.radians(0.01)


def test_an_origin_off_the_ellipsoid_is_refused():
    with pytest.raises(ValueError, match="not a position on the ellipsoid"):
        corridor_frame(95.0, 0.0)
