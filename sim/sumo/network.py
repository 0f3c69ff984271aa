"""Road networks: a corridor's road as a SUMO network, and the road of a SUMO network.

``plain_xml`` (pure) writes SUMO's plain node and edge files of a ``protocol.road.Road``: one edge from
``start`` to ``end`` whose shape is the middle of the carriageway (``spreadType="center"``), sampled every
``SHAPE_STEP_M`` on arcs, with the road's lanes, lane width and speed limit; ``build_net`` runs SUMO's
``netconvert`` on them. ``road_of_polyline`` (pure) turns a curb line (the right edge of lane 0 along a
route of a network) into straight pieces joined by arcs tangent to both (a fillet at each vertex), which
``road_of_net`` reads with sumolib: the road the DDM plans on is the network's, whichever tool made it.
"""

from __future__ import annotations

import math
import os
import subprocess
import tempfile
from collections.abc import Sequence
from pathlib import Path
from xml.sax.saxutils import quoteattr

import numpy as np

from protocol.road import Road, Segment

CORRIDOR_EDGE = "corridor"
SHAPE_STEP_M = 2.0
MIN_PIECE_M = 0.2
"""Polyline points closer than this to the previous one are dropped."""
STRAIGHT_TOL_RAD = 1e-4
"""A vertex that turns less than this is no vertex."""
FILLET_SHARE = 0.5
"""An arc takes at most this share of each straight piece beside its vertex (so neighbouring arcs never overlap)."""


class NetworkError(ValueError):
    """A network that cannot be used as a corridor's road; the message says what and how to fix it."""


# ----------------------------------------------------------------------------- road -> network (pure)
def plain_xml(road: Road, edge_id: str = CORRIDOR_EDGE) -> tuple[str, str]:
    """(nodes XML, edges XML) of ``road`` as one SUMO edge: its lanes in the direction of travel."""
    n = max(2, int(math.ceil(road.length_m / SHAPE_STEP_M)) + 1)
    s = np.linspace(0.0, road.length_m, n)
    if all(seg.kind == "straight" for seg in road.segments) and len(road.segments) == 1:
        s = np.array([0.0, road.length_m])
    x, y, _ = road.pose_at(s, np.full_like(s, road.width_m / 2.0))
    shape = " ".join(f"{a:.3f},{b:.3f}" for a, b in zip(np.atleast_1d(x), np.atleast_1d(y), strict=True))
    nodes = ('<nodes>\n'
             f'  <node id="start" x="{float(np.atleast_1d(x)[0]):.3f}" y="{float(np.atleast_1d(y)[0]):.3f}"/>\n'
             f'  <node id="end" x="{float(np.atleast_1d(x)[-1]):.3f}" y="{float(np.atleast_1d(y)[-1]):.3f}"/>\n'
             '</nodes>\n')
    edges = ('<edges>\n'
             f'  <edge id={quoteattr(edge_id)} from="start" to="end" numLanes="{road.lanes}" '
             f'speed="{road.speed_limit_mps:.3f}" width="{road.lane_width_m:.3f}" spreadType="center" '
             f'shape="{shape}"/>\n'
             '</edges>\n')
    return nodes, edges


def tool(name: str) -> str:
    """Path of a SUMO binary (netconvert, netgenerate, sumo) of the installed eclipse-sumo package."""
    from sim.sumo import require_sumo

    require_sumo()
    import sumo

    path = Path(sumo.SUMO_HOME) / "bin" / name
    if not path.exists():
        raise FileNotFoundError(f"{path}: SUMO's {name} is missing from the eclipse-sumo package; reinstall it")
    return str(path)


NETCONVERT_OPTIONS = ("--offset.disable-normalization", "true", "--no-turnarounds", "true", "--no-warnings", "true")


def build_net(nodes_xml: str, edges_xml: str, out: Path, connections_xml: str | None = None) -> Path:
    """Run netconvert on plain node/edge (and connection) XML; the network keeps the corridor's coordinates."""
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="iea-net-") as tmp:
        nod, edg = Path(tmp) / "n.nod.xml", Path(tmp) / "e.edg.xml"
        nod.write_text(nodes_xml)
        edg.write_text(edges_xml)
        extra = []
        if connections_xml is not None:
            con = Path(tmp) / "c.con.xml"
            con.write_text(connections_xml)
            extra = ["--connection-files", str(con)]
        res = subprocess.run([tool("netconvert"), "--node-files", str(nod), "--edge-files", str(edg), *extra,
                              "--output-file", str(out), *NETCONVERT_OPTIONS],
                             capture_output=True, text=True, timeout=120, env={**os.environ})
    if res.returncode != 0 or not out.exists():
        raise NetworkError(f"netconvert failed ({res.returncode}): {res.stderr.strip()[-800:]}")
    return out


def corridor_net(road: Road, out: Path) -> Path:
    """The corridor's road as a SUMO network file at ``out`` (one edge, ``CORRIDOR_EDGE``)."""
    return build_net(*plain_xml(road), out)


# ----------------------------------------------------------------------------- network -> road (pure)
def _clean(points: Sequence[tuple[float, float]]) -> np.ndarray:
    pts = [tuple(map(float, points[0][:2]))]
    for p in points[1:]:
        if math.hypot(p[0] - pts[-1][0], p[1] - pts[-1][1]) >= MIN_PIECE_M:
            pts.append((float(p[0]), float(p[1])))
    if len(pts) < 2:
        raise NetworkError("a road needs a polyline of at least two distinct points")
    return np.asarray(pts)


def road_of_polyline(points: Sequence[tuple[float, float]], *, lanes: int, lane_width_m: float,
                     speed_limit_mps: float, shoulder_width_m: float = 2.5) -> Road:
    """A ``Road`` whose reference line follows the polyline ``points`` (its curb line): straight pieces
    joined at each vertex by an arc tangent to both (radius R = t / tan(|theta| / 2) for tangent length t,
    at most ``FILLET_SHARE`` of each neighbouring piece); it leaves the polyline by R (1 / cos(theta / 2) - 1)
    at the vertex, millimetres on the dense shapes of a network's curves."""
    p = _clean(points)
    d = np.diff(p, axis=0)
    length = np.hypot(d[:, 0], d[:, 1])
    heading = np.arctan2(d[:, 1], d[:, 0])
    turn = [math.remainder(float(heading[i + 1] - heading[i]), 2 * math.pi) for i in range(len(heading) - 1)]
    tangent = [0.0] * (len(length) + 1)  # tangent length of the arc at vertex i (1..n-1)
    for i, th in enumerate(turn, start=1):
        if abs(th) > STRAIGHT_TOL_RAD:
            tangent[i] = FILLET_SHARE * min(length[i - 1], length[i])
    segs: list[Segment] = []

    def straight(lm: float) -> None:
        if lm <= 1e-6:
            return
        if segs and segs[-1].kind == "straight":
            segs[-1] = Segment("straight", segs[-1].length_m + lm)
        else:
            segs.append(Segment("straight", lm))

    for i in range(len(length)):
        straight(float(length[i] - tangent[i] - tangent[i + 1]))
        if i < len(turn) and tangent[i + 1] > 0:
            th = turn[i]
            radius = tangent[i + 1] / math.tan(abs(th) / 2.0)
            segs.append(Segment("arc", radius * abs(th), math.copysign(radius, th)))
    return Road(start_x_m=float(p[0, 0]), start_y_m=float(p[0, 1]), start_heading_rad=float(heading[0]),
                segments=tuple(segs), lanes=lanes, lane_width_m=lane_width_m, shoulder_width_m=shoulder_width_m,
                speed_limit_mps=speed_limit_mps)


def offset_polyline(points: np.ndarray, offset_m: float) -> np.ndarray:
    """The polyline moved ``offset_m`` to its right (negative: left), each vertex along its mitred normal."""
    p = np.asarray(points, dtype=float)
    d = np.diff(p, axis=0)
    n = np.column_stack([d[:, 1], -d[:, 0]]) / np.hypot(d[:, 0], d[:, 1])[:, None]  # right normals per piece
    vn = np.vstack([n[:1], n[:-1] + n[1:], n[-1:]])
    vn /= np.hypot(vn[:, 0], vn[:, 1])[:, None]
    cos_half = np.concatenate([[1.0], np.einsum("ij,ij->i", n[:-1], vn[1:-1]), [1.0]])
    return p + vn * (offset_m / np.maximum(cos_half, 0.3))[:, None]


# ----------------------------------------------------------------------------- network files (sumolib)
def read_net(path: str | Path):
    """A sumolib network (shapes in the network's own x, y)."""
    from sim.sumo import require_sumo

    require_sumo()
    import sumolib

    p = Path(path)
    if not p.is_file():
        raise NetworkError(f"{p}: SUMO network not found")
    return sumolib.net.readNet(str(p), withInternal=True)


def route_curb_line(net, route: Sequence[str]) -> tuple[np.ndarray, int, float, float]:
    """(curb polyline, lanes, lane width, speed limit) of consecutive edges ``route``: the right edge of their
    lane 0, joined through the internal lanes of the junctions between them. The number of lanes is the least
    along the route (an added merge lane is not one of the corridor's lanes)."""
    if not route:
        raise NetworkError("a corridor route names at least one edge")
    pts: list[tuple[float, float]] = []
    lanes, widths, speeds = [], [], []
    for k, eid in enumerate(route):
        if not net.hasEdge(eid):
            raise NetworkError(f"edge {eid!r} is not in the network (its edges: {sorted(e.getID() for e in net.getEdges(withInternal=False))[:20]} ...)")
        e = net.getEdge(eid)
        lane0 = e.getLane(0)
        lanes.append(e.getLaneNumber())
        widths.append(lane0.getWidth())
        speeds.append(e.getSpeed())
        shape = lane0.getShape()
        if k > 0:
            prev = net.getEdge(route[k - 1])
            if e not in prev.getOutgoing():
                raise NetworkError(f"edge {eid!r} does not follow {route[k - 1]!r} in the network: the route must be "
                                   f"a path (outgoing of {route[k - 1]!r}: {[o.getID() for o in prev.getOutgoing()]})")
            via = [c.getViaLaneID() for c in prev.getConnections(e) if c.getViaLaneID()]
            if via and net.hasEdge(via[0].rsplit("_", 1)[0]):
                internal = net.getLane(via[0]).getShape()
                if internal and net.getLane(via[0]).getIndex() == 0:
                    pts.extend(map(tuple, internal))
        pts.extend((float(a), float(b)) for a, b in shape)
    width = float(min(widths))
    curb = offset_polyline(_clean(pts), width / 2.0)
    return curb, int(min(lanes)), width, float(min(speeds))


def road_of_net(path: str | Path, route: Sequence[str], shoulder_width_m: float = 2.5) -> Road:
    """The road along ``route`` of the network at ``path`` (lanes, width, curves, speed limit from the network)."""
    curb, lanes, width, speed = route_curb_line(read_net(path), route)
    return road_of_polyline(curb, lanes=lanes, lane_width_m=width, speed_limit_mps=speed,
                            shoulder_width_m=shoulder_width_m)


def edge_point(net, edge_id: str, pos_m: float) -> tuple[float, float]:
    """World (x, y) of the right edge of lane 0 of ``edge_id``, ``pos_m`` along it."""
    import sumolib

    if not net.hasEdge(edge_id):
        raise NetworkError(f"edge {edge_id!r} is not in the network")
    lane0 = net.getEdge(edge_id).getLane(0)
    if not 0.0 <= pos_m <= lane0.getLength():
        raise NetworkError(f"position {pos_m} m is off edge {edge_id!r} (0..{lane0.getLength():.1f} m)")
    shape = offset_polyline(_clean(lane0.getShape()), lane0.getWidth() / 2.0)
    x, y = sumolib.geomhelper.positionAtShapeOffset([tuple(p) for p in shape], pos_m)
    return float(x), float(y)


def road_deviation_m(road: Road, other: Road, step_m: float = 5.0) -> float:
    """Largest distance between the reference lines of two roads, sampled along ``road``."""
    s = np.arange(0.0, road.length_m + 1e-9, step_m)
    x, y, _ = road.pose_at(s, np.zeros_like(s))
    s2, d2 = other.to_frenet(np.atleast_1d(x), np.atleast_1d(y))
    return float(np.max(np.abs(d2))) if len(s) else 0.0
