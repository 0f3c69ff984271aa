"""The simulated corridor world: a scenario's road, traffic, EV, hazards and AV over time.

``World.step(dt)`` is pure and deterministic for a given scenario and seed (no clocks, no I/O);
``snapshot()`` gives the protocol ``WorldSnapshot`` (ground truth for the simulated cameras and for
evaluation only). The AV pose comes from the vehicle process through ``set_av_pose`` when one runs;
otherwise the AV is scripted (lane keeping at its cruise speed with IDM).
"""

from __future__ import annotations

import math

import numpy as np

from protocol.enums import ActorKind, Lighting
from protocol.messages import Actor, LightBar, VehicleState, WorldSnapshot
from protocol.ranges import MAX_POSITION_M
from sim.scenario import Scenario
from sim.traffic import IdmTraffic, TrafficModel, build_population
from sim.vehicles import SimVehicle


def _wrap(a: float) -> float:
    return (a + math.pi) % (2 * math.pi) - math.pi


class World:
    def __init__(self, scenario: Scenario, seed: int | None = None, traffic: TrafficModel | None = None) -> None:
        self.scenario = scenario
        self.seed = scenario.seed if seed is None else int(seed)
        self.rng = np.random.default_rng(self.seed)
        self.road = scenario.corridor.road
        self._appear: list[SimVehicle] = []  # static objects that land on the road later, by time
        self._remove: list[tuple[float, str]] = []
        if traffic is None and scenario.traffic_model == "sumo":  # SUMO places, drives and clears everything
            from sim.sumo.traffic import SumoTraffic

            traffic = SumoTraffic(scenario, self.seed)
        if traffic is None:
            population = build_population(scenario, self.rng)
            self._appear = sorted((v for v in population if v.extra.get("appear_s", 0.0) > 0.0),
                                  key=lambda v: v.extra["appear_s"])
            later = {v.vehicle_id for v in self._appear}
            population = [v for v in population if v.vehicle_id not in later]
            self._remove = sorted((v.extra["remove_s"], v.vehicle_id) for v in population + self._appear
                                  if v.extra.get("remove_s") is not None)
            traffic = IdmTraffic(self.road, population, np.random.default_rng(self.seed + 1))
        self.traffic: TrafficModel = traffic
        self.t_s = 0.0
        self.steps = 0
        self.av_id = scenario.av.vehicle_id if scenario.av else None

    def step(self, dt_s: float) -> float:
        """Advance the world by dt_s; returns the new sim time (rounded to 1 ns so that fixed steps
        give exact times, e.g. 200 steps of 0.05 s end at 10.0 s)."""
        self._scheduled(self.t_s)
        self.traffic.step(dt_s, self.t_s)
        self.steps += 1
        self.t_s = round(self.t_s + dt_s, 9)
        return self.t_s

    def _scheduled(self, t_s: float) -> None:
        """Debris that lands on or is cleared from the road by time t_s (scenario ``appear_s``/``remove_s``)."""
        while self._appear and self._appear[0].extra["appear_s"] <= t_s + 1e-9:
            self.traffic.add(self._appear.pop(0))
        while self._remove and self._remove[0][0] <= t_s + 1e-9:
            _, vid = self._remove.pop(0)
            if any(p.vehicle_id == vid for p in self._appear):
                self._appear = [p for p in self._appear if p.vehicle_id != vid]
            else:
                self.traffic.remove(vid)

    def run_until(self, t_s: float, dt_s: float = 0.05) -> None:
        while self.t_s < t_s - 1e-9:
            self.step(dt_s)

    def close(self) -> None:
        """End the traffic model's outside resources (a SUMO simulation); the world steps no more."""
        close = getattr(self.traffic, "close", None)
        if close is not None:
            close()

    def set_av_pose(self, state: VehicleState, age_s: float = 0.0) -> None:
        """Take the AV's pose from the vehicle process (``iea/{c}/vehicle/{veh}/state``), carried forward
        ``age_s`` at its speed along its heading (dead reckoning: the car moves on between the states it sends)."""
        lim = MAX_POSITION_M  # a state at the edge of the corridor frame stays in it
        x, y = (min(max(c, -lim), lim) for c in state.position_after(age_s))
        self.traffic.set_external_pose(state.vehicle_id, x, y, state.heading_rad, state.speed_mps)

    def release_av(self, vehicle_id: str) -> None:
        """No vehicle state for a while: the AV is scripted again (lane keeping) from its last pose."""
        self.traffic.release_external(vehicle_id)

    def vehicles(self) -> list[SimVehicle]:
        return self.traffic.vehicles()

    def actor(self, v: SimVehicle) -> Actor:
        lb = None
        if v.light_bar is not None:
            lb = LightBar(on=v.light_bar_on(self.t_s), pattern=v.light_bar["pattern"],
                          frequency_hz=float(v.light_bar["frequency_hz"]), phase_s=float(v.light_bar["phase_s"]))
        lane = self.road.lane_of_offset(v.d_m)
        return Actor(actor_id=v.vehicle_id, kind=ActorKind(v.kind), pos_x_m=float(v.x_m), pos_y_m=float(v.y_m),
                     heading_rad=_wrap(float(v.heading_rad)), length_m=float(v.length_m), width_m=float(v.width_m),
                     height_m=float(v.height_m), speed_mps=float(max(0.0, v.speed_mps)), lane=lane,
                     colour_bgr=tuple(int(c) for c in v.colour_bgr), brake_on=bool(v.brake_on), light_bar=lb,
                     style=int(v.style))

    def snapshot(self, stamp: float | None = None, src: str = "sim", seq: int = 0) -> WorldSnapshot:
        return WorldSnapshot(src=src, seq=seq, stamp=float(self.t_s if stamp is None else stamp),
                             scenario=self.scenario.name, sim_time_s=float(self.t_s),
                             lighting=Lighting(self.scenario.lighting), seed=self.seed,
                             actors=[self.actor(v) for v in self.vehicles()])
