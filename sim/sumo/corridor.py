"""Corridors on SUMO networks: a corridor file that names a ``.net.xml``, and the tool that writes one.

A corridor file may carry a ``[sumo]`` table::

    [sumo]
    net = "motorway_ramp.net.xml"      # beside the corridor file, or an absolute path
    route = ["main_a", "main_b"]       # the corridor: consecutive edges of the network

and each ``[[rsu]]`` may say where it stands along which edge (``edge``, ``pos_m``, ``side_m``: metres to
the right of the curb line). The corridor's road (``[road]``) is the network's along ``route``
(``sim.sumo.network.road_of_net``): the writer below puts it there, and ``sumo_section`` refuses a
corridor whose road has drifted from its network by more than ``MAX_DRIFT_M``.

    python -m sim.sumo.corridor NET.net.xml --route E1,E2 --rsu rsu1:E1:120 --rsu rsu2:E1:220 \
        --id mycorridor --out deploy/corridors/mycorridor.toml

writes a corridor file (road from the network, RSU masts at the given edge positions with the RELLIS camera,
calibration pairs from a simulated survey, ``sim.survey``) that every service of the project reads.
"""

from __future__ import annotations

import argparse
import bisect
import math
import tomllib
from dataclasses import dataclass, replace
from functools import lru_cache
from pathlib import Path

from protocol.corridor import CameraConfig, Corridor, RsuConfig, VehicleConfig
from protocol.road import Road
from sim.sumo.network import NetworkError, edge_point, read_net, road_deviation_m, road_of_net

MAX_DRIFT_M = 0.5
CAMERA_TEMPLATE = {"height_m": 10.7, "yaw_off_rad": 0.1802, "pitch_rad": 0.2298, "width_px": 1280, "height_px": 720,
                   "fx_px": 1100.0, "fps": 15.0}
"""The RELLIS RSU camera: 10.7 m up, looking 10.3 degrees left of the road's heading, 13.2 degrees down."""
DEFAULT_SIDE_M = 4.5
DEFAULT_RANGE_M = 85.0


@dataclass(frozen=True)
class SumoSection:
    """The corridor's place in a SUMO network: the network file, the route, and each route edge's start in s."""

    net: Path
    route: tuple[str, ...]
    edge_lengths_m: tuple[float, ...]
    edge_starts_m: tuple[float, ...] = ()

    def edge_at_s(self, s_m: float) -> tuple[str, float]:
        """(edge, position along it) of the corridor's s (clamped onto the route's edges)."""
        starts = self.edge_starts_m or tuple(sum(self.edge_lengths_m[:k]) for k in range(len(self.route)))
        k = max(0, bisect.bisect_right(starts, s_m) - 1)
        pos = min(max(s_m - starts[k], 0.0), self.edge_lengths_m[k] - 0.1)
        return self.route[k], pos


def _read_toml(path: Path) -> dict:
    try:
        return tomllib.loads(path.read_text(encoding="utf-8"))
    except (OSError, tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise NetworkError(f"{path}: cannot read the corridor file: {exc}") from None


@lru_cache(maxsize=16)
def _section(source: str, road: Road) -> SumoSection | None:
    if not source or not Path(source).is_file():
        return None
    data = _read_toml(Path(source)).get("sumo")
    if data is None:
        return None
    if not isinstance(data, dict) or not isinstance(data.get("net"), str) or not isinstance(data.get("route"), list) \
            or not all(isinstance(e, str) for e in data["route"]) or not data["route"]:
        raise NetworkError(f"{source}: [sumo] wants net = \"FILE.net.xml\" and route = [\"EDGE\", ...]")
    net_path = Path(data["net"])
    if not net_path.is_absolute():
        net_path = Path(source).parent / net_path
    route = tuple(data["route"])
    net = read_net(net_path)
    built = road_of_net(net_path, route, road.shoulder_width_m)
    drift = road_deviation_m(road, built)
    if drift > MAX_DRIFT_M or built.lanes != road.lanes or abs(built.length_m - road.length_m) > 2.0:
        raise NetworkError(f"{source}: the [road] is not the road of {net_path} along {list(route)} (off by "
                           f"{drift:.2f} m, {road.lanes} vs {built.lanes} lanes, {road.length_m:.1f} vs "
                           f"{built.length_m:.1f} m): write the corridor again with python -m sim.sumo.corridor")
    starts, lengths = [], []
    for eid in route:
        x, y = edge_point(net, eid, 0.0)
        s, _ = road.to_frenet(x, y)
        starts.append(float(s))
        lengths.append(float(net.getEdge(eid).getLane(0).getLength()))
    return SumoSection(net_path, route, tuple(lengths), tuple(starts))


def sumo_section(corridor: Corridor) -> SumoSection | None:
    """The corridor's ``[sumo]`` table, checked against its road; None when it has none (SUMO then runs on the
    corridor's road generated as a network, ``sim.sumo.network.corridor_net``)."""
    return _section(corridor.source, corridor.road)


# ----------------------------------------------------------------------------- writing a corridor
def rsu_on_road(road: Road, rsu_id: str, x_m: float, y_m: float, side_m: float = DEFAULT_SIDE_M,
                max_range_m: float = DEFAULT_RANGE_M) -> RsuConfig:
    """An RSU with the RELLIS camera beside the road point nearest (x, y), ``side_m`` right of the curb line,
    looking along the road. Pure."""
    s, _ = road.to_frenet(x_m, y_m)
    cx, cy, h = road.pose_at(float(s), -side_m)
    t = CAMERA_TEMPLATE
    cam = CameraConfig(x_m=float(cx), y_m=float(cy), height_m=t["height_m"],
                       yaw_rad=math.remainder(h + t["yaw_off_rad"], 2 * math.pi), pitch_rad=t["pitch_rad"],
                       roll_rad=0.0, width_px=t["width_px"], height_px=t["height_px"], fx_px=t["fx_px"],
                       fy_px=t["fx_px"], cx_px=t["width_px"] / 2.0, cy_px=t["height_px"] / 2.0, fps=t["fps"])
    return RsuConfig(rsu_id, cam, (), max_range_m)


def _num(v: float) -> str:
    return repr(round(float(v), 6))


def corridor_toml(corridor: Corridor, net_ref: str, route: list[str], placed: list[tuple[str, str, float, float]],
                  vehicle: VehicleConfig | None = None) -> str:
    """The corridor file text (its road, RSUs with calibration pairs, ``[sumo]``); ``placed``: (rsu, edge,
    pos_m, side_m) per RSU. Pure."""
    r = corridor.road
    out = [f"# Written by python -m sim.sumo.corridor from {net_ref} along {route}: the [road] is the network's.\n\n",
           "[corridor]\n", f"id = \"{corridor.corridor_id}\"\n", f"name = \"{corridor.name}\"\n",
           f"origin_lat_deg = {_num(corridor.origin_lat_deg)}\n", f"origin_lon_deg = {_num(corridor.origin_lon_deg)}\n\n",
           "[road]\n", f"start_x_m = {_num(r.start_x_m)}\n", f"start_y_m = {_num(r.start_y_m)}\n",
           f"start_heading_rad = {_num(r.start_heading_rad)}\n", f"lanes = {r.lanes}\n",
           f"lane_width_m = {_num(r.lane_width_m)}\n", f"shoulder_width_m = {_num(r.shoulder_width_m)}\n",
           f"speed_limit_mps = {_num(r.speed_limit_mps)}\n\n"]
    for seg in r.segments:
        out.append(f"[[road.segments]]\nkind = \"{seg.kind}\"\nlength_m = {_num(seg.length_m)}\n")
        if seg.kind == "arc":
            out.append(f"radius_m = {_num(seg.radius_m)}\n")
        out.append("\n")
    out.append("[transport]\ndsrc_latency_s = 0.003\ndsrc_jitter_s = 0.001\ndsrc_loss = 0.01\ndsrc_range_m = 300.0\n\n")
    if vehicle is not None:
        out.append(f"[[vehicle]]\nid = \"{vehicle.vehicle_id}\"\nstart_s_m = {_num(vehicle.start_s_m)}\n"
                   f"start_lane = {vehicle.start_lane}\ncruise_speed_mps = {_num(vehicle.cruise_speed_mps)}\n\n")
    where = {p[0]: p for p in placed}
    for rsu in corridor.rsus:
        c = rsu.camera
        _, edge, pos, side = where[rsu.rsu_id]
        out.append(f"[[rsu]]\nid = \"{rsu.rsu_id}\"\nx_m = {_num(c.x_m)}\ny_m = {_num(c.y_m)}\n"
                   f"edge = \"{edge}\"\npos_m = {_num(pos)}\nside_m = {_num(side)}\n"
                   f"max_range_m = {_num(rsu.max_range_m or DEFAULT_RANGE_M)}\ncalibration = [\n")
        out.extend(f"  [{u}, {v}, {x}, {y}],\n" for u, v, x, y in rsu.calibration)
        out.append(f"]\n  [rsu.camera]\n  height_m = {_num(c.height_m)}\n  yaw_rad = {_num(c.yaw_rad)}\n"
                   f"  pitch_rad = {_num(c.pitch_rad)}\n  width_px = {c.width_px}\n  height_px = {c.height_px}\n"
                   f"  fx_px = {_num(c.fx_px)}\n  fps = {_num(c.fps)}\n\n")
    out.append(f"[sumo]\nnet = \"{net_ref}\"\nroute = [{', '.join(f'{e!r}'.replace(chr(39), chr(34)) for e in route)}]\n")
    return "".join(out)


def write_corridor(net_path: str | Path, route: list[str], rsus: list[tuple[str, str, float, float]], out: str | Path,
                   *, corridor_id: str, name: str = "", origin_lat_deg: float = 30.633, origin_lon_deg: float = -96.479,
                   av_start_s_m: float | None = None, av_lane: int | None = None, av_speed_mps: float = 13.4) -> Path:
    """Write a corridor file for the network at ``net_path`` (module docstring); returns its path."""
    from sim.survey import survey

    net_path, out = Path(net_path).resolve(), Path(out)
    road = road_of_net(net_path, route)
    net = read_net(net_path)
    configs = []
    for rid, edge, pos, side in rsus:
        x, y = edge_point(net, edge, pos)
        configs.append(rsu_on_road(road, rid, x, y, side))
    vehicle = VehicleConfig("av1", av_start_s_m if av_start_s_m is not None else min(100.0, road.length_m / 4),
                            road.lanes - 1 if av_lane is None else av_lane, av_speed_mps)
    corridor = Corridor(corridor_id, name or corridor_id, origin_lat_deg, origin_lon_deg, road, tuple(configs),
                        (vehicle,))
    surveyed = tuple(replace(r, calibration=tuple(survey(corridor, r, seed=k))) for k, r in enumerate(configs))
    corridor = replace(corridor, rsus=surveyed)
    for r in surveyed:
        if len(r.calibration) < 8:
            raise NetworkError(f"RSU {r.rsu_id!r}: its camera sees {len(r.calibration)} survey points of the road; "
                               "place it beside the corridor's route")
    try:
        ref = str(net_path.relative_to(out.resolve().parent))
    except ValueError:
        ref = str(net_path)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(corridor_toml(corridor, ref, list(route), list(rsus), vehicle), encoding="utf-8")
    return out


def parse_rsu(item: str) -> tuple[str, str, float, float]:
    """``ID:EDGE:POS_M[:SIDE_M]`` -> (id, edge, pos, side)."""
    parts = item.split(":")
    try:
        if len(parts) not in (3, 4):
            raise ValueError
        return parts[0], parts[1], float(parts[2]), float(parts[3]) if len(parts) == 4 else DEFAULT_SIDE_M
    except ValueError:
        raise ValueError(f"--rsu wants ID:EDGE:POS_M[:SIDE_M], got {item!r}") from None


def main(argv: list[str] | None = None) -> int:
    import sys

    ap = argparse.ArgumentParser(prog="python -m sim.sumo.corridor", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("net", help="SUMO network (.net.xml)")
    ap.add_argument("--route", required=True, help="the corridor's edges, comma-separated, in driving order")
    ap.add_argument("--rsu", action="append", default=[], required=True, metavar="ID:EDGE:POS_M[:SIDE_M]",
                    help="an RSU mast beside EDGE, POS_M along it, SIDE_M right of the curb line (default 4.5)")
    ap.add_argument("--id", required=True, help="corridor id")
    ap.add_argument("--name", default="")
    ap.add_argument("--out", required=True, help="corridor TOML file to write")
    ap.add_argument("--av-start-s", type=float, default=None, help="the AV's start along the corridor (m)")
    ap.add_argument("--av-lane", type=int, default=None)
    args = ap.parse_args(argv)
    try:
        out = write_corridor(args.net, [e for e in args.route.split(",") if e], [parse_rsu(r) for r in args.rsu],
                             args.out, corridor_id=args.id, name=args.name, av_start_s_m=args.av_start_s,
                             av_lane=args.av_lane)
    except (ValueError, KeyError) as exc:
        print(f"sim.sumo.corridor: error: {exc}", file=sys.stderr)
        return 2
    print(out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
