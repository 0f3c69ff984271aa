"""The corridor frame on the WGS84 ellipsoid, through PROJ (pyproj).

The corridor frame (x east, y north, metres, origin at the corridor's ``origin_lat_deg`` / ``origin_lon_deg``) is
a transverse Mercator projection of the WGS84 ellipsoid centred on the origin (``+proj=tmerc +lat_0 +lon_0 +k_0=1
+ellps=WGS84``; PROJ's implementation is Poder / Engsager's, exact to a few nanometres within 3,900 km of the
central meridian). It is conformal: a heading measured in the frame is a heading on the ground, turned by the
meridian convergence (about dlon * sin(lat): 0.0005 deg at 1 km east of the origin at 30 deg). Its scale is 1 on
the central meridian and 1 + x^2 / (2 R^2) off it (1.2e-8 at 1 km), so distances in the frame agree with
geodesic distances to well under a millimetre per kilometre over a corridor.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
from pyproj import CRS, Geod, Transformer

WGS84_GEOD = Geod(ellps="WGS84")
"""PROJ's geodesic on the WGS84 ellipsoid (Karney's algorithm): the reference for distances and azimuths."""


@dataclass(frozen=True, eq=False)
class CorridorFrame:
    """Corridor frame <-> WGS84 latitude / longitude for one origin (see the module docstring)."""

    origin_lat_deg: float
    origin_lon_deg: float
    _forward: Transformer
    _inverse: Transformer

    def to_latlon(self, x_m: float, y_m: float) -> tuple[float, float]:
        """(latitude, longitude) in degrees of the frame point (x east, y north) in metres."""
        lon, lat = self._inverse.transform(x_m, y_m)
        return float(lat), float(lon)

    def from_latlon(self, lat_deg: float, lon_deg: float) -> tuple[float, float]:
        """(x, y) in metres of a WGS84 position."""
        x, y = self._forward.transform(lon_deg, lat_deg)
        return float(x), float(y)

    def to_latlon_many(self, x_m: np.ndarray, y_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        lon, lat = self._inverse.transform(np.asarray(x_m, float), np.asarray(y_m, float))
        return np.asarray(lat), np.asarray(lon)

    def from_latlon_many(self, lat_deg: np.ndarray, lon_deg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        x, y = self._forward.transform(np.asarray(lon_deg, float), np.asarray(lat_deg, float))
        return np.asarray(x), np.asarray(y)

    def convergence_rad(self, x_m: float, y_m: float) -> float:
        """Grid north minus true north at a frame point (rad, counter-clockwise positive): add it to a frame
        heading measured from grid north to get one from true north."""
        lat, lon = self.to_latlon(x_m, y_m)
        x2, y2 = self.from_latlon(lat + 1e-5, lon)  # a step due north, seen in the frame
        return math.atan2(-(x2 - x_m), y2 - y_m)


@functools.lru_cache(maxsize=64)
def corridor_frame(origin_lat_deg: float, origin_lon_deg: float) -> CorridorFrame:
    """The frame of a corridor origin (cached: building the PROJ pipeline costs about a millisecond)."""
    if not (-90.0 < origin_lat_deg < 90.0 and -180.0 <= origin_lon_deg <= 180.0):
        raise ValueError(f"origin ({origin_lat_deg}, {origin_lon_deg}) deg is not a position on the ellipsoid "
                         "(latitude strictly inside -90..90, longitude -180..180)")
    tmerc = CRS.from_proj4(f"+proj=tmerc +lat_0={origin_lat_deg!r} +lon_0={origin_lon_deg!r} +k_0=1 +x_0=0 +y_0=0 "
                           "+ellps=WGS84 +units=m +no_defs")
    wgs84 = CRS.from_epsg(4326)
    return CorridorFrame(origin_lat_deg, origin_lon_deg,
                         Transformer.from_crs(wgs84, tmerc, always_xy=True),
                         Transformer.from_crs(tmerc, wgs84, always_xy=True))


def geodesic_distance_m(lat1_deg: float, lon1_deg: float, lat2_deg: float, lon2_deg: float) -> float:
    """Length of the WGS84 geodesic between two positions (PROJ / Karney)."""
    _az12, _az21, dist = WGS84_GEOD.inv(lon1_deg, lat1_deg, lon2_deg, lat2_deg)
    return float(dist)
