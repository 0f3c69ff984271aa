"""A scenario's traffic as a SUMO route file. Pure (strings in, strings out).

Every vehicle of the scenario's initial population (``sim.traffic.build_population``: the AV, the EV,
distractors, debris and the seeded background traffic) becomes a SUMO vehicle of its own type (its size,
its desired speed as ``maxSpeed``) departing at t = 0 where the population puts it (SUMO's ``departPos`` is
the front bumper); a flow per lane at the corridor's start keeps the road's density (``density x speed``)
or the scenario's ``flow_veh_per_h``. The EV is SUMO's emergency vehicle (``vClass="emergency"``) with the
bluelight device, which the shell switches on and off (its reaction distance) as the scenario says.
Debris is a vehicle of class ``custom1`` stopped on its lane, so that SUMO's drivers go round it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from xml.sax.saxutils import quoteattr

from sim.vehicles import SimVehicle

EV_ID = "ev1"
EV_TAU_S = 0.7
"""An EV on duty follows closely (the project's own traffic: 0.7 s with its lights on)."""
EV_MIN_GAP_M = 2.0
EV_CAR_FOLLOWING = {"carFollowModel": "IDM", "decel": "2.0", "delta": "4"}
"""The EV drives SUMO's IDM (Treiber et al. 2000) with the project's EV parameters (a_max 2.5, b 2.0 m/s^2,
T 0.7 s, s0 2 m): it closes on what is ahead at speed and brakes late, as an EV on a call does; SUMO's
default (Krauss) slows down 40 m behind a slower vehicle."""
VCLASS_OF_KIND = {"car": "passenger", "van": "delivery", "truck": "truck", "bus": "bus", "ev": "emergency",
                  "av": "passenger", "debris": "custom1"}
FLOW_TYPES = (("car", "passenger", 4.5, 1.8, 1.5), ("van", "delivery", 5.4, 2.0, 2.3),
              ("truck", "truck", 8.5, 2.5, 3.3), ("bus", "bus", 12.0, 2.55, 3.1))
"""(kind, vClass, length, width, height) of the flows' vehicle types."""
STOP_S = 1e6


@dataclass(frozen=True)
class FlowSpec:
    flow_id: str
    route: tuple[str, ...]
    veh_per_h: float
    begin_s: float
    end_s: float
    depart_lane: str = "best"
    depart_speed: str = "max"
    speed_mps: float = 12.0
    """Desired speed of the flow's drivers (their ``maxSpeed``; ``speedDev`` spreads it)."""
    speed_dev: float = 0.1
    mix: tuple[float, float, float, float] = (0.73, 0.15, 0.08, 0.04)
    """Shares of car, van, truck, bus."""


def _attr(**kw) -> str:
    return " ".join(f"{k}={quoteattr(str(v))}" for k, v in kw.items())


def vtype_xml(type_id: str, kind: str, length_m: float, width_m: float, height_m: float, max_speed_mps: float,
              *, tau_s: float = 1.2, min_gap_m: float = 2.0, accel_mps2: float = 1.4, params: dict | None = None,
              speed_dev: float = 0.0, sigma: float = 0.3, attrs: dict | None = None) -> str:
    vclass = VCLASS_OF_KIND[kind]
    body = "".join(f'    <param {_attr(key=k, value=v)}/>\n' for k, v in (params or {}).items())
    head = (f'  <vType {_attr(id=type_id, vClass=vclass, length=f"{length_m:.3f}", width=f"{width_m:.3f}", height=f"{height_m:.3f}", maxSpeed=f"{max(max_speed_mps, 0.1):.3f}", speedFactor="1", speedDev=f"{speed_dev:.3f}", tau=f"{tau_s:.2f}", minGap=f"{min_gap_m:.2f}", accel=f"{accel_mps2:.2f}", sigma=f"{sigma:.2f}", **(attrs or {}))}')
    return head + (">\n" + body + "  </vType>\n" if body else "/>\n")


def vehicle_xml(v: SimVehicle, route_id: str, lane: int, edge: str, depart_pos_m: float, *,
                type_id: str, depart_s: float = 0.0, stop_pos_m: float | None = None) -> str:
    a = _attr(id=v.vehicle_id, type=type_id, route=route_id, depart=f"{depart_s:.2f}", departLane=str(lane),
              departPos=f"{depart_pos_m:.3f}", departSpeed=f"{max(0.0, v.speed_mps):.3f}", insertionChecks="none")
    if stop_pos_m is None:
        return f"  <vehicle {a}/>\n"
    stop = _attr(lane=f"{edge}_{lane}", endPos=f"{stop_pos_m:.3f}", duration=f"{STOP_S:.0f}")
    return f"  <vehicle {a}>\n    <stop {stop}/>\n  </vehicle>\n"


def flow_xml(f: FlowSpec, route_id: str) -> str:
    dist = f"dist_{f.flow_id}"
    types = "".join(vtype_xml(f"{dist}_{k}", k, ln, w, h, f.speed_mps * (0.9 if k in ("truck", "bus") else 1.0),
                              speed_dev=f.speed_dev).replace("<vType ", f'<vType probability="{p:.4f}" ')
                    for (k, _vc, ln, w, h), p in zip(FLOW_TYPES, f.mix, strict=True) if p > 0)
    dist_xml = f'  <vTypeDistribution id="{dist}">\n{types}  </vTypeDistribution>\n'
    flow = _attr(id=f.flow_id, type=dist, route=route_id, begin=f"{f.begin_s:.2f}", end=f"{f.end_s:.2f}",
                 vehsPerHour=f"{f.veh_per_h:.1f}", departLane=f.depart_lane, departSpeed=f.depart_speed,
                 departPos="base")
    return dist_xml + f"  <flow {flow}/>\n"


def routes_xml(vehicles: Sequence[tuple[SimVehicle, dict]], routes: dict[str, Sequence[str]],
               flows: Sequence[FlowSpec] = ()) -> str:
    """The route file: ``routes`` (id -> edges), then each vehicle with its placement (``route``, ``edge``,
    ``lane``, ``depart_pos_m``, ``depart_s``, ``stop_pos_m``, ``vtype`` keyword arguments of ``vtype_xml``
    besides kind and size), sorted by departure as SUMO wants, then the flows."""
    out = ["<routes>\n"]
    for rid, edges in routes.items():
        out.append(f'  <route {_attr(id=rid, edges=" ".join(edges))}/>\n')
    for f in flows:
        out.append(f'  <route {_attr(id=f"r_{f.flow_id}", edges=" ".join(f.route))}/>\n')
        out.append(flow_xml(f, f"r_{f.flow_id}"))
    for v, place in sorted(vehicles, key=lambda vp: vp[1].get("depart_s", 0.0)):
        tid = f"t_{v.vehicle_id}"
        out.append(vtype_xml(tid, v.kind, v.length_m, v.width_m, v.height_m, v.desired_speed_mps,
                             **place.get("vtype", {})))
        out.append(vehicle_xml(v, place["route"], place["lane"], place["edge"], place["depart_pos_m"],
                               type_id=tid, depart_s=place.get("depart_s", 0.0), stop_pos_m=place.get("stop_pos_m")))
    out.append("</routes>\n")
    return "".join(out)


def ev_vtype(reaction_dist_m: float) -> dict:
    """``vtype_xml`` keywords of the EV: close following, the bluelight device with its reaction distance."""
    return {"tau_s": EV_TAU_S, "min_gap_m": EV_MIN_GAP_M, "accel_mps2": 2.5, "sigma": 0.0, "attrs": EV_CAR_FOLLOWING,
            "params": {"has.bluelight.device": "true", "device.bluelight.reactiondist": f"{reaction_dist_m:.1f}"}}
