"""Corridor files (docs/architecture.md §Corridor file): load and validate a TOML file into typed objects.

A corridor has an origin (lat/lon of the local east/north frame), a road (reference line made of
straight and arc segments, lanes to its left, a shoulder to its right), RSUs with their cameras and
calibration pairs, the autonomous vehicles, and transport settings.

Road frame (``protocol.road``): the reference line is the right edge of lane 0 (the curb
line), in the direction of travel; ``s`` is the distance along it and ``d`` the signed offset, positive to the
left. Lane ``i`` spans ``d`` in [i*w, (i+1)*w] (lane 0 = rightmost); the shoulder is d in [-shoulder, 0].

Cameras: position (x, y, height) and orientation (yaw: viewing direction from +x, counter-clockwise;
pitch: downward tilt; roll about the optical axis), pinhole intrinsics. ``CameraConfig`` gives K, R
(world -> camera, OpenCV axes: x right, y down, z forward) and the centre C, so p_cam = R (p_world - C).

A bad file fails with ``CorridorError`` naming the file, the field and what was expected.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from protocol.geodesy import corridor_frame
from protocol.road import Road, Segment
from protocol.tomlfields import FieldReader

DEFAULT_CORRIDOR = Path(__file__).resolve().parent.parent / "deploy" / "corridors" / "rellis.toml"


class CorridorError(ValueError):
    """A corridor file that cannot be used; the message says where and why."""


# ----------------------------------------------------------------------------- cameras and RSUs
@dataclass(frozen=True)
class CameraConfig:
    x_m: float
    y_m: float
    height_m: float
    yaw_rad: float
    pitch_rad: float
    roll_rad: float
    width_px: int
    height_px: int
    fx_px: float
    fy_px: float
    cx_px: float
    cy_px: float
    fps: float = 15.0

    @property
    def intrinsic_matrix(self) -> np.ndarray:
        return np.array([[self.fx_px, 0.0, self.cx_px], [0.0, self.fy_px, self.cy_px], [0.0, 0.0, 1.0]])

    @property
    def centre_world(self) -> np.ndarray:
        return np.array([self.x_m, self.y_m, self.height_m])

    @property
    def rotation_world_to_camera(self) -> np.ndarray:
        cy, sy = math.cos(self.yaw_rad), math.sin(self.yaw_rad)
        cp, sp = math.cos(self.pitch_rad), math.sin(self.pitch_rad)
        forward = np.array([cp * cy, cp * sy, -sp])
        right = np.array([sy, -cy, 0.0])
        down = np.cross(forward, right)
        r = np.stack([right, down, forward])
        if self.roll_rad:
            c, s = math.cos(self.roll_rad), math.sin(self.roll_rad)
            r = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]]) @ r
        return r

    @property
    def projection_matrix(self) -> np.ndarray:
        """P = K [R | -R C] (3x4)."""
        r = self.rotation_world_to_camera
        return self.intrinsic_matrix @ np.hstack([r, (-r @ self.centre_world)[:, None]])


@dataclass(frozen=True)
class RsuConfig:
    rsu_id: str
    camera: CameraConfig
    calibration: tuple[tuple[float, float, float, float], ...] = ()
    """Surveyed pairs (u_px, v_px, x_m, y_m): pixel -> road-plane world position (thesis App. B)."""
    max_range_m: float | None = None
    """The RSU reports objects up to this ground distance from its mast (its zone of responsibility:
    farther away a pixel spans metres and vehicles merge in the image); None: whatever it sees."""

    @property
    def position(self) -> tuple[float, float]:
        return (self.camera.x_m, self.camera.y_m)


@dataclass(frozen=True)
class VehicleConfig:
    vehicle_id: str
    start_s_m: float = 0.0
    start_lane: int = 1
    cruise_speed_mps: float = 13.4
    length_m: float = 4.9
    width_m: float = 1.9


@dataclass(frozen=True)
class TransportConfig:
    connect: tuple[str, ...] = ()
    dsrc_latency_s: float = 0.003
    dsrc_jitter_s: float = 0.001
    dsrc_loss: float = 0.01
    dsrc_range_m: float = 300.0


@dataclass(frozen=True)
class Corridor:
    corridor_id: str
    name: str
    origin_lat_deg: float
    origin_lon_deg: float
    road: Road
    rsus: tuple[RsuConfig, ...]
    vehicles: tuple[VehicleConfig, ...] = ()
    transport: TransportConfig = field(default_factory=TransportConfig)
    trust: tuple[dict[str, Any], ...] = ()
    """``[[trust]]`` entries (key_id, role, public_key, vehicles / rsu_id / station_id): see protocol/security.py."""
    source: str = ""

    def rsu(self, rsu_id: str) -> RsuConfig:
        return self.rsus[self.rsu_index(rsu_id)]

    def rsu_index(self, rsu_id: str) -> int:
        """The RSU's place in the corridor's list (KeyError naming the corridor's RSUs when it has no such RSU)."""
        for k, r in enumerate(self.rsus):
            if r.rsu_id == rsu_id:
                return k
        raise KeyError(f"corridor {self.corridor_id!r} has no RSU {rsu_id!r}; it has {[r.rsu_id for r in self.rsus]}")

    def vehicle(self, vehicle_id: str) -> VehicleConfig:
        for v in self.vehicles:
            if v.vehicle_id == vehicle_id:
                return v
        raise KeyError(f"corridor {self.corridor_id!r} has no vehicle {vehicle_id!r}")

    def with_vehicle(self, vehicle_id: str, **changes: Any) -> Corridor:
        """A copy with one vehicle's start/speed changed (e.g. a scenario's AV start), validated as on load."""
        old = self.vehicle(vehicle_id)
        new = replace(old, **changes)
        if not (0.0 <= new.start_s_m <= self.road.length_m):
            raise CorridorError(f"vehicle {vehicle_id!r}: start_s_m {new.start_s_m} is off the road "
                                f"(0..{self.road.length_m:.1f} m)")
        if not (0 <= new.start_lane < self.road.lanes):
            raise CorridorError(f"vehicle {vehicle_id!r}: start_lane {new.start_lane} is not a lane (0..{self.road.lanes - 1})")
        if not (math.isfinite(new.cruise_speed_mps) and 0.0 < new.cruise_speed_mps <= 70.0):
            raise CorridorError(f"vehicle {vehicle_id!r}: cruise_speed_mps {new.cruise_speed_mps} must be in (0, 70]")
        return replace(self, vehicles=tuple(new if v is old else v for v in self.vehicles))

    def to_latlon(self, x_m: float, y_m: float) -> tuple[float, float]:
        """Corridor frame (east/north metres) -> WGS84 degrees, on the ellipsoid (``protocol.geodesy``)."""
        return corridor_frame(self.origin_lat_deg, self.origin_lon_deg).to_latlon(x_m, y_m)

    def from_latlon(self, lat_deg: float, lon_deg: float) -> tuple[float, float]:
        """WGS84 degrees -> corridor frame (east/north metres), on the ellipsoid (``protocol.geodesy``)."""
        return corridor_frame(self.origin_lat_deg, self.origin_lon_deg).from_latlon(lat_deg, lon_deg)


# ----------------------------------------------------------------------------- loading
def _load_road(r: FieldReader) -> Road:
    segs = []
    for sr in r.tables("segments"):
        kind = sr.text("kind", choices=("straight", "arc"))
        length = sr.num("length_m", positive=True)
        radius = None
        if kind == "arc":
            radius = sr.num("radius_m")
            if abs(radius) < 5.0:
                raise sr.fail("radius_m", "an arc radius with |R| >= 5 m (sign: + left, - right)", radius)
        segs.append(Segment(kind, length, radius))
    if not segs:
        raise r.fail("segments", "at least one segment")
    return Road(
        start_x_m=r.num("start_x_m", 0.0),
        start_y_m=r.num("start_y_m", 0.0),
        start_heading_rad=r.num("start_heading_rad", 0.0, lo=-math.pi, hi=math.pi),
        segments=tuple(segs),
        lanes=r.integer("lanes", 2, lo=1, hi=8),
        lane_width_m=r.num("lane_width_m", 3.7, lo=2.5, hi=5.0),
        shoulder_width_m=r.num("shoulder_width_m", 2.5, lo=0.0, hi=6.0),
        opposite_lanes=r.integer("opposite_lanes", 0, lo=0, hi=8),
        speed_limit_mps=r.num("speed_limit_mps", 13.4, lo=1.0, hi=45.0),
    )


def _load_camera(c: FieldReader, x: float, y: float) -> CameraConfig:
    width = c.integer("width_px", 1280, lo=64, hi=8192)
    height = c.integer("height_px", 720, lo=48, hi=8192)
    fx = c.num("fx_px", positive=True)
    return CameraConfig(
        x_m=x,
        y_m=y,
        height_m=c.num("height_m", 10.7, lo=1.0, hi=50.0),
        yaw_rad=c.num("yaw_rad", lo=-2 * math.pi, hi=2 * math.pi),
        pitch_rad=c.num("pitch_rad", lo=0.0, hi=math.pi / 2),
        roll_rad=c.num("roll_rad", 0.0, lo=-0.5, hi=0.5),
        width_px=width,
        height_px=height,
        fx_px=fx,
        fy_px=c.num("fy_px", fx, positive=True),
        cx_px=c.num("cx_px", width / 2.0, lo=0.0, hi=float(width)),
        cy_px=c.num("cy_px", height / 2.0, lo=0.0, hi=float(height)),
        fps=c.num("fps", 15.0, lo=1.0, hi=120.0),
    )


def _load_calibration(r: FieldReader) -> tuple[tuple[float, float, float, float], ...]:
    pts = r.data.get("calibration", [])
    if not isinstance(pts, list):
        raise r.fail("calibration", "a list of [u_px, v_px, x_m, y_m]", type(pts).__name__)
    out = []
    for i, p in enumerate(pts):
        if (not isinstance(p, list) or len(p) != 4
                or not all(isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v) for v in p)):
            raise r.fail(f"calibration[{i}]", "[u_px, v_px, x_m, y_m] of 4 finite numbers", p)
        out.append(tuple(float(v) for v in p))
    return tuple(out)  # type: ignore[return-value]


def parse_corridor(data: dict[str, Any], source: str = "<corridor>") -> Corridor:
    top = FieldReader(source, data, error=CorridorError)
    c = top.table("corridor")
    corridor_id = c.text("id", ident=True)
    road = _load_road(top.table("road"))
    rsus = []
    for rr in top.tables("rsu"):
        rid = rr.text("id", ident=True)
        x, y = rr.num("x_m"), rr.num("y_m")
        max_range = rr.num("max_range_m", positive=True) if "max_range_m" in rr.data else None
        rsus.append(RsuConfig(rid, _load_camera(rr.table("camera"), x, y), _load_calibration(rr), max_range))
    ids = [r.rsu_id for r in rsus]
    if len(set(ids)) != len(ids):
        raise top.fail("rsu", "unique RSU ids", ids)
    vehicles = []
    for vr in top.tables("vehicle", required=False):
        v = VehicleConfig(
            vehicle_id=vr.text("id", ident=True),
            start_s_m=vr.num("start_s_m", 0.0, lo=0.0, hi=road.length_m),
            start_lane=vr.integer("start_lane", road.lanes - 1, lo=0, hi=road.lanes - 1),
            cruise_speed_mps=vr.num("cruise_speed_mps", 13.4, lo=0.0, hi=45.0),
            length_m=vr.num("length_m", 4.9, lo=1.0, hi=20.0),
            width_m=vr.num("width_m", 1.9, lo=0.5, hi=3.0),
        )
        vehicles.append(v)
    t = top.table("transport", required=False)
    transport = TransportConfig(
        connect=tuple(t.str_list("connect")),
        dsrc_latency_s=t.num("dsrc_latency_s", 0.003, lo=0.0, hi=5.0),
        dsrc_jitter_s=t.num("dsrc_jitter_s", 0.001, lo=0.0, hi=5.0),
        dsrc_loss=t.num("dsrc_loss", 0.01, lo=0.0, hi=1.0),
        dsrc_range_m=t.num("dsrc_range_m", 300.0, positive=True),
    )
    trust = []
    for tr in top.tables("trust", required=False):
        entry = {"key_id": tr.text("key_id", ident=True), "role": tr.text("role", choices=("ddm", "rsu", "ev")),
                 "public_key": tr.text("public_key")}
        if tr.has("vehicles"):
            entry["vehicles"] = tr.str_list("vehicles")
        if tr.has("rsu_id"):
            entry["rsu_id"] = tr.text("rsu_id", ident=True)
        elif entry["role"] == "rsu":
            raise tr.fail("rsu_id", "the RSU id this key speaks for (role = 'rsu')")
        if entry["role"] == "ev":  # an EV's V2X key signs the CAMs of one StationId (protocol/v2x/secure.py)
            entry["station_id"] = tr.integer("station_id", lo=0, hi=2**32 - 1)
        trust.append(entry)
    return Corridor(
        corridor_id=corridor_id,
        name=c.text("name", corridor_id),
        origin_lat_deg=c.num("origin_lat_deg", lo=-90.0, hi=90.0),
        origin_lon_deg=c.num("origin_lon_deg", lo=-180.0, hi=180.0),
        road=road,
        rsus=tuple(rsus),
        vehicles=tuple(vehicles),
        transport=transport,
        trust=tuple(trust),
        source=source,
    )


def load_corridor(path: str | Path | None = None) -> Corridor:
    """Load a corridor TOML file (default: ``deploy/corridors/rellis.toml``)."""
    p = Path(path) if path is not None else DEFAULT_CORRIDOR
    if not p.is_file():
        raise CorridorError(f"{p}: corridor file not found (give a path to a .toml file, e.g. {DEFAULT_CORRIDOR})")
    try:
        data = tomllib.loads(p.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise CorridorError(f"{p}: not valid TOML: {exc}") from None
    return parse_corridor(data, str(p))
