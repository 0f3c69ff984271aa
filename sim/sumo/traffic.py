"""``SumoTraffic``: Eclipse SUMO drives the corridor's traffic through libsumo (the imperative shell).

One clock: the world's step is SUMO's step (``--step-length`` = the world's dt, checked every step). Each
step the shell (1) switches the EV's bluelight device as the scenario says (its reaction distance: 0 off,
``REACTION_DIST_M`` on, and its speed factor: the limit when off, the scenario's speed when on), (2) writes
the externally driven AV into SUMO (``vehicle.moveToXY`` with ``keepRoute=2``, its speed with
``vehicle.setSpeed``) so that SUMO's drivers react to it, (3) steps SUMO, (4) reads every vehicle's
position, angle, speed and signals (one subscription per vehicle) and turns them into the project's
``SimVehicle`` (``sim.sumo.convert``), which the world turns into the ``WorldSnapshot`` the cameras render.

The scenario's yielding drivers (``[traffic] yield_fraction``, the same drivers as on the project's traffic; a
seeded draw for those SUMO's flows bring) do what they do there: while an EV with its lights on is close behind
(``sim.traffic.EV_REACT_BEHIND_M``) they move to lane 0 and slow down (``vehicle.changeLane``, ``vehicle.setSpeed``);
SUMO drives them there. Its bluelight device alone only stops drivers changing lanes near the EV.

libsumo runs one simulation per process: a new ``SumoTraffic`` closes the one before it (which then refuses
to step); ``close()`` ends it.
"""

from __future__ import annotations

import logging
import shutil
import tempfile
from pathlib import Path

import numpy as np

from sim.lamps import with_signal_lamps
from sim.scenario import Scenario
from sim.sumo import convert, demand, require_sumo
from sim.sumo.corridor import SumoSection, sumo_section
from sim.sumo.network import CORRIDOR_EDGE, corridor_net
from sim.traffic import EV_PASSED_AHEAD_M, EV_REACT_BEHIND_M, YIELD_SPEED_FACTOR, build_population
from sim.vehicles import LIVERY_PLAIN, LIVERY_TWO_TONE, SimVehicle, make_style, random_colour

log = logging.getLogger("iea.sim.sumo")
STEP_S = 0.05
REACTION_DIST_M = 150.0
"""How far ahead of the EV drivers hear the siren and form the rescue lane once its lights are on (SUMO's
default is 25 m; the project's own drivers react from 90 m)."""
LATERAL_RESOLUTION_M = 0.8
"""SUMO's sublane model (``[traffic] sumo_sublane``): drivers that hear the siren move to the edge of their lane,
opening a rescue lane between lanes; without it SUMO changes lanes whole (LC2013, cheaper), and they only stop
changing lanes."""
_ACTIVE: SumoTraffic | None = None


def sumo_options(net: Path, routes: Path, seed: int, step_s: float, log_file: Path, sublane: bool = False) -> list[str]:
    return ["sumo", "--net-file", str(net), "--route-files", str(routes), "--step-length", f"{step_s}",
            "--seed", str(int(seed) % (2 ** 31)),
            *(["--lateral-resolution", f"{LATERAL_RESOLUTION_M}"] if sublane else []),
            "--collision.action", "warn", "--collision.check-junctions", "false", "--time-to-teleport", "-1",
            "--no-step-log", "true", "--no-warnings", "true", "--log", str(log_file),
            "--default.action-step-length", f"{step_s}", "--ignore-route-errors", "true"]


def placements(scenario: Scenario, population: list[SimVehicle], section: SumoSection) -> list[tuple[SimVehicle, dict]]:
    """Where each vehicle of the population enters SUMO (the corridor's route, its lane and s; the EV from
    its own route when the scenario gives one). Pure."""
    road = scenario.corridor.road
    edge_of_s = section.edge_at_s
    out = []
    ev = scenario.ev
    for v in population:
        s_front = min(v.s_m + v.length_m / 2.0, road.length_m - 0.1)
        s_front = max(s_front, v.length_m + 0.1)
        edge, pos = edge_of_s(s_front)
        route = f"r_from_{edge}"
        place = {"route": route, "edge": edge, "lane": v.lane, "depart_pos_m": pos}
        if v.kind == "ev":
            place["vtype"] = demand.ev_vtype(0.0 if ev is None or ev.lights_on_at_s is None or ev.lights_on_at_s > 0
                                             else REACTION_DIST_M)
            if ev is not None and ev.sumo_route:
                place.update(route="r_ev", edge=ev.sumo_route[0], lane=0, depart_pos_m=ev.sumo_depart_pos_m,
                             depart_s=ev.depart_s)
        elif v.kind == "debris":
            place["depart_s"] = float(v.extra.get("appear_s", 0.0))
            place["stop_pos_m"] = pos
            place["vtype"] = {"min_gap_m": 0.0, "sigma": 0.0}
        elif v.kind == "av":
            place["vtype"] = {"tau_s": v.idm_time_gap_s, "sigma": 0.0}
        out.append((v, place))
    return out


def flows_of(scenario: Scenario, section: SumoSection) -> list[demand.FlowSpec]:
    """The flows that keep traffic coming: onto the corridor at its start (the scenario's ``flow_veh_per_h``,
    else density x speed per lane) and on the side route if the scenario has one. Pure."""
    tr = scenario.traffic
    road = scenario.corridor.road
    end = scenario.duration_s + 60.0
    mix = (max(0.0, 1.0 - tr.van_fraction - tr.truck_fraction - tr.bus_fraction), tr.van_fraction,
           tr.truck_fraction, tr.bus_fraction)
    dev = tr.speed_spread_mps / tr.speed_mps if tr.speed_mps > 0 else 0.0
    out = []
    per_h = tr.flow_veh_per_h or tr.density_veh_per_km_lane * tr.speed_mps * 3.6 * road.lanes
    if per_h > 0:
        out.append(demand.FlowSpec("main", tuple(section.route), per_h, 0.0, end, speed_mps=tr.speed_mps,
                                   speed_dev=dev, mix=mix))
    if tr.side_flow_route and tr.side_flow_veh_per_h > 0:
        out.append(demand.FlowSpec("side", tr.side_flow_route, tr.side_flow_veh_per_h, 0.0, end,
                                   speed_mps=tr.speed_mps, speed_dev=dev, mix=mix))
    return out


def frenet(road, x_m: np.ndarray, y_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(s, d) of world points on ``road``: closed form on a road of one straight segment (every straight
    corridor), else ``Road.to_frenet``."""
    if len(road.segments) == 1 and road.segments[0].kind == "straight":
        c, sn = np.cos(road.start_heading_rad), np.sin(road.start_heading_rad)
        dx, dy = x_m - road.start_x_m, y_m - road.start_y_m
        return np.clip(dx * c + dy * sn, 0.0, road.length_m), -dx * sn + dy * c
    return road.to_frenet(x_m, y_m)


class SumoTraffic:
    """``sim.traffic.TrafficModel`` backed by SUMO (module docstring)."""

    def __init__(self, scenario: Scenario, seed: int, *, step_s: float = STEP_S,
                 population: list[SimVehicle] | None = None, flows: bool = True) -> None:
        require_sumo()
        import libsumo

        global _ACTIVE
        if _ACTIVE is not None and not _ACTIVE.closed:
            log.info("libsumo runs one simulation per process: closing the previous one")
            _ACTIVE.close()
        self._ls = libsumo
        self.scenario = scenario
        self.road = scenario.corridor.road
        self.step_s = float(step_s)
        self.t_s = 0.0
        self.closed = False
        self._dir = Path(tempfile.mkdtemp(prefix="iea-sumo-"))
        section = sumo_section(scenario.corridor)
        if section is None:
            net = corridor_net(self.road, self._dir / "corridor.net.xml")
            section = SumoSection(net=net, route=(CORRIDOR_EDGE,), edge_lengths_m=(self.road.length_m,))
        self.section = section
        rng = np.random.default_rng(seed)
        self._colour_rng = np.random.default_rng(seed + 7)
        if population is None:
            population = build_population(scenario, rng)
        self._static = {v.vehicle_id: v for v in population if v.is_static}
        self._known: dict[str, SimVehicle] = {v.vehicle_id: v for v in population}
        routes = {f"r_from_{e}": section.route[k:] for k, e in enumerate(section.route)}
        if scenario.ev is not None and scenario.ev.sumo_route:
            routes["r_ev"] = scenario.ev.sumo_route
        placed = placements(scenario, population, section)
        (self._dir / "demand.rou.xml").write_text(demand.routes_xml(
            placed, routes, flows_of(scenario, section) if flows else ()))
        libsumo.start(sumo_options(section.net, self._dir / "demand.rou.xml", seed, self.step_s,
                                   self._dir / "sumo.log", scenario.traffic.sumo_sublane))
        _ACTIVE = self
        self._live: dict[str, SimVehicle] = {}
        self._in_sumo: set[str] = set()
        for v, place in placed:  # on the road from t = 0 (SUMO inserts them in its first step): the world sees
            if place.get("depart_s", 0.0) == 0.0 and place["route"] != "r_ev":  # them, its AV among them, now
                v.x_m, v.y_m, v.heading_rad = self.road.pose_at(v.s_m, v.d_m)
                self._live[v.vehicle_id] = v
        self._removed: set[str] = set()
        self._external: dict[str, tuple[float, float, float, float]] = {}
        self._externally_driven: set[str] = set()
        ev = scenario.ev
        self._ev_on_at = None if ev is None else ev.lights_on_at_s
        self._ev_lit = False
        self._remove_at = sorted((v.extra["remove_s"], v.vehicle_id) for v in population
                                 if v.is_static and v.extra.get("remove_s") is not None)
        self._brakers = [v for v in population if v.brake_period_s > 0]
        self._yield_rng = np.random.default_rng(seed + 11)
        self._yielding: set[str] = set()
        self._vars = (libsumo.constants.VAR_POSITION, libsumo.constants.VAR_ANGLE, libsumo.constants.VAR_SPEED,
                      libsumo.constants.VAR_SIGNALS, libsumo.constants.VAR_ACCELERATION)
        self._admit(libsumo.vehicle.getIDList())

    # ---------------------------------------------------------------- interface
    def vehicles(self) -> list[SimVehicle]:
        return list(self._live.values())

    def set_external_pose(self, vehicle_id: str, x_m: float, y_m: float, heading_rad: float,
                          speed_mps: float) -> None:
        if vehicle_id not in self._live and vehicle_id not in self._known:
            raise KeyError(f"no vehicle {vehicle_id!r} in the world")
        self._external[vehicle_id] = (x_m, y_m, heading_rad, speed_mps)
        v = self._live.get(vehicle_id)
        if v is not None:
            v.external = True
            v.x_m, v.y_m, v.heading_rad, v.speed_mps = x_m, y_m, heading_rad, speed_mps
            v.s_m, v.d_m = self.road.to_frenet(x_m, y_m)

    def release_external(self, vehicle_id: str) -> None:
        self._external.pop(vehicle_id, None)
        if vehicle_id in self._externally_driven and vehicle_id in self._in_sumo:
            self._ls.vehicle.setSpeedMode(vehicle_id, 31)
            self._ls.vehicle.setSpeed(vehicle_id, -1)
            self._live[vehicle_id].external = False
        self._externally_driven.discard(vehicle_id)

    def add(self, v: SimVehicle) -> None:
        raise NotImplementedError("SUMO traffic takes its vehicles from the route file (debris: appear_s)")

    def remove(self, vehicle_id: str) -> None:
        if vehicle_id in self._in_sumo:
            self._ls.vehicle.remove(vehicle_id)
            self._in_sumo.discard(vehicle_id)
        self._live.pop(vehicle_id, None)
        self._removed.add(vehicle_id)

    # ---------------------------------------------------------------- step
    def step(self, dt_s: float, t_s: float) -> None:
        if self.closed:
            raise RuntimeError("this SUMO simulation was closed (libsumo runs one simulation per process)")
        if abs(dt_s - self.step_s) > 1e-9:
            raise ValueError(f"SUMO steps {self.step_s} s; the world asked for {dt_s} s (one clock: use the same)")
        ls = self._ls
        self._switch_ev(t_s)
        while self._remove_at and self._remove_at[0][0] <= t_s + 1e-9:
            self.remove(self._remove_at.pop(0)[1])
        for v in self._brakers:
            if v.vehicle_id in self._in_sumo:
                braking = (t_s % v.brake_period_s) >= v.brake_period_s / 2
                ls.vehicle.setSpeed(v.vehicle_id, 0.4 * v.desired_speed_mps if braking else -1)
        for vid, (x, y, h, spd) in self._external.items():
            if vid not in self._in_sumo:  # SUMO inserts it in this step; it is moved from the next one
                continue
            if vid not in self._externally_driven:
                ls.vehicle.setSpeedMode(vid, 0)
                ls.vehicle.setLaneChangeMode(vid, 0)
                self._externally_driven.add(vid)
            fx, fy = convert.front_of_centre(x, y, h, self._live[vid].length_m)
            ls.vehicle.moveToXY(vid, "", -1, fx, fy, convert.angle_deg_of_heading(h), 2, 100.0)
            ls.vehicle.setSpeed(vid, max(0.0, spd))
        self._yield_to_ev()
        ls.simulationStep()
        self.t_s = round(t_s + dt_s, 9)
        now = ls.simulation.getTime()
        if abs(now - self.t_s) > 1e-6:
            raise RuntimeError(f"SUMO's clock ({now} s) left the world's ({self.t_s} s)")
        for vid in ls.simulation.getArrivedIDList():  # gone first: an EV that left the road is read no more
            self._live.pop(vid, None)
            self._in_sumo.discard(vid)
        self._admit(ls.simulation.getDepartedIDList())
        self._read()

    def _yield_to_ev(self) -> None:
        """The scenario's yielding drivers with an EV with lights on close behind: to lane 0, slower there."""
        ev = self._live.get(demand.EV_ID)
        lit = ev is not None and self._ev_lit
        ls = self._ls
        for vid, v in self._live.items():
            if not v.yields_to_ev or v.external or v.is_static or v.kind in ("ev", "av") or vid not in self._in_sumo:
                continue
            threat = lit and v.s_m - EV_REACT_BEHIND_M < ev.s_m < v.s_m + EV_PASSED_AHEAD_M
            if threat:
                ls.vehicle.changeLane(vid, 0, 1.0)
                factor = YIELD_SPEED_FACTOR if v.lane == 0 else 0.8
                ls.vehicle.setSpeed(vid, factor * v.desired_speed_mps)
                self._yielding.add(vid)
            elif vid in self._yielding:
                ls.vehicle.setSpeed(vid, -1)
                self._yielding.discard(vid)

    def _switch_ev(self, t_s: float) -> None:
        ev = self.scenario.ev
        vid = demand.EV_ID
        if ev is None or vid not in self._in_sumo:
            return
        on = self._ev_on_at is not None and t_s >= self._ev_on_at - 1e-9
        if on != self._ev_lit:
            ls = self._ls
            ls.vehicle.setParameter(vid, "device.bluelight.reactiondist", f"{REACTION_DIST_M if on else 0.0}")
            limit = ls.lane.getMaxSpeed(ls.vehicle.getLaneID(vid)) or self.road.speed_limit_mps
            ls.vehicle.setSpeedFactor(vid, max(1.0, ev.speed_mps / limit) if on else 1.0)
            self._ev_lit = on

    def _admit(self, ids) -> None:
        ls = self._ls
        for vid in ids:
            if vid in self._removed:
                continue
            ls.vehicle.subscribe(vid, self._vars)
            self._in_sumo.add(vid)
            v = self._known.get(vid)
            if v is None:
                v = self._new_vehicle(vid)
            self._live[vid] = v

    def _new_vehicle(self, vid: str) -> SimVehicle:
        """A vehicle of a flow: its size and kind from SUMO, a seeded colour and style of the project's."""
        ls = self._ls
        kind = convert.kind_of(ls.vehicle.getVehicleClass(vid), ls.vehicle.getTypeID(vid).rsplit("_", 1)[-1])
        rng = self._colour_rng
        livery = LIVERY_TWO_TONE if kind in ("van", "truck") and rng.random() < 0.3 else LIVERY_PLAIN
        return SimVehicle(vid, kind, 0.0, 0.0, 0.0, 0, ls.vehicle.getLength(vid), ls.vehicle.getWidth(vid),
                          ls.vehicle.getHeight(vid), random_colour(rng), make_style(livery, int(rng.integers(256))),
                          desired_speed_mps=ls.vehicle.getMaxSpeed(vid),
                          yields_to_ev=bool(self._yield_rng.random() < self.scenario.traffic.yield_fraction))

    def _read(self) -> None:
        ls = self._ls
        res = ls.vehicle.getAllSubscriptionResults()
        k_pos, k_ang, k_spd, k_sig, k_acc = self._vars
        moved = []
        for vid, v in self._live.items():
            r = res.get(vid)
            if r is None or v.external:
                continue
            if v.is_static:  # debris keeps the scenario's pose (its offset in the lane)
                x, y, h = self.road.pose_at(v.s_m, v.d_m)
                v.x_m, v.y_m, v.heading_rad = x, y, h
                continue
            x, y = r[k_pos]
            p = convert.pose_of(convert.SumoState(x, y, r[k_ang], r[k_spd], int(r[k_sig]), r[k_acc]), v.length_m)
            v.x_m, v.y_m, v.heading_rad, v.speed_mps, v.brake_on = p.x_m, p.y_m, p.heading_rad, p.speed_mps, p.brake_on
            v.accel_mps2 = float(r[k_acc])
            if v.kind not in ("ev", "av"):
                mode = p.lamp_mode
                if mode or (v.style >> 12):
                    v.style = with_signal_lamps(v.style, mode, convert.BLINKER_FREQUENCY_HZ,
                                                convert.lamp_phase_frac(vid)) if mode else with_signal_lamps(v.style, "", 0.0, 0.0)
            moved.append(v)
        ev = self._live.get(demand.EV_ID)
        if ev is not None and ev.light_bar is not None and ev.vehicle_id in self._in_sumo:
            lit = float(ls.vehicle.getParameter(ev.vehicle_id, "device.bluelight.reactiondist") or 0.0) > 0.0
            if lit and ev.light_bar.get("on_at_s") is None:
                ev.light_bar["on_at_s"] = self.t_s
            elif not lit:
                ev.light_bar["on_at_s"] = None
        if moved:
            s, d = frenet(self.road, np.array([v.x_m for v in moved]), np.array([v.y_m for v in moved]))
            for v, si, di in zip(moved, np.atleast_1d(s).tolist(), np.atleast_1d(d).tolist(), strict=True):
                v.s_m, v.d_m = si, di
                lane = self.road.lane_of_offset(di)
                if lane is not None:
                    v.lane = lane

    def close(self) -> None:
        global _ACTIVE
        if not self.closed:
            self.closed = True
            try:
                self._ls.close()
            finally:
                if _ACTIVE is self:
                    _ACTIVE = None
                shutil.rmtree(self._dir, ignore_errors=True)
