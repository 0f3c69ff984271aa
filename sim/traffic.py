"""Traffic: car-following (IDM), lane keeping, MOBIL-style lane changes, EV behaviour and driver
reactions to an EV with its lights on, behind the ``TrafficModel`` interface (a SUMO-backed model,
which has emergency vehicles built in, can implement the same three methods later).

IDM (Treiber, Hennecke, Helbing 2000): a = a_max [1 - (v/v0)^4 - (s*/s)^2],
s* = s0 + v T + v dv / (2 sqrt(a_max b)). Lane change (Kesting, Treiber, Helbing 2007, MOBIL):
change when a_new - a_old + p (gains of the followers) > threshold and the new follower's braking
stays above -b_safe. Drivers that yield to an EV (a seeded fraction, ``yield_fraction``) slow down,
move to the rightmost lane and hug its right edge while an EV with lights on is close behind; the
others keep driving (as on a real road).
"""

from __future__ import annotations

import math
from typing import Protocol

import numpy as np

from protocol.road import Road
from sim.lamps import assign_roof_lamps, assign_signal_lamps, with_roof_lamps, with_signal_lamps
from sim.scenario import DEBRIS_KINDS, Scenario
from sim.vehicles import (
    BLUE_BGR,
    LIVERY_AMBULANCE,
    LIVERY_PLAIN,
    LIVERY_POLICE,
    LIVERY_TWO_TONE,
    LIVERY_WORKS,
    RED_BGR,
    WORKS_BGR,
    SimVehicle,
    make_style,
    random_colour,
    random_size,
)

IDM_MIN_GAP_M = 2.0
IDM_COMFORT_DECEL_MPS2 = 2.0
IDM_DELTA = 4.0
MAX_DECEL_MPS2 = 8.0
MOBIL_SAFE_DECEL_MPS2 = 3.0
MOBIL_THRESHOLD_MPS2 = 0.2
LANE_CHECK_PERIOD_S = 1.0
LATERAL_GAIN_PER_S = 0.9
LATERAL_SPEED_MAX_MPS = 1.1
BRAKE_LIGHT_DECEL_MPS2 = 0.6
EXTERNAL_CUT_IN_HEADWAY_S = 2.0
"""Drivers change in front of the externally driven AV only with this much time headway (plus what the
speed difference eats in 3 s): the vehicle process follows its commanded path and has no car-following."""
EV_REACT_BEHIND_M = 90.0
EV_PASSED_AHEAD_M = 15.0
YIELD_SPEED_FACTOR = 0.35
YIELD_EDGE_SHIFT_M = 0.7
STOP_GO_WAVE_MPS = 5.0
"""Stop-and-go waves run upstream at about 18 km/h (Treiber and Kesting, Traffic Flow Dynamics, 2013)."""
STOP_GO_SLOW_FACTOR = 0.15
"""A driver in a wave's slow half wants this share of its speed (it brakes, brake lights on, then crawls)."""
HAZARD_RUN_UP_M = 40.0
"""No background vehicle starts this close behind debris that lies in its lane at t = 0."""
DEBRIS_COLOURS = {"box": (60, 75, 95), "rock": (105, 110, 112), "barrel": (30, 90, 200), "pallet": (120, 165, 195),
                  "pipe": (150, 150, 145), "tyre": (28, 28, 30)}
"""BGR body colour of each debris kind (wooden box, grey rock, orange oil barrel, pale pallet wood, steel
pipe, black tyre)."""


class TrafficModel(Protocol):
    """What the world needs from a traffic model."""

    def step(self, dt_s: float, t_s: float) -> None:
        """Advance every non-static, non-external vehicle by dt_s (t_s: sim time at the start)."""

    def vehicles(self) -> list[SimVehicle]:
        """All vehicles and static objects, with x_m, y_m, heading_rad up to date."""

    def set_external_pose(self, vehicle_id: str, x_m: float, y_m: float, heading_rad: float,
                          speed_mps: float) -> None:
        """Pose of a vehicle driven from outside (the AV's vehicle process)."""

    def release_external(self, vehicle_id: str) -> None:
        """The outside driver went quiet: the model drives the vehicle again from where it is."""

    def add(self, v: SimVehicle) -> None:
        """Put a vehicle or static object on the road (a scenario's debris with ``appear_s``)."""

    def remove(self, vehicle_id: str) -> None:
        """Take a vehicle or static object off the road (``remove_s``)."""


def idm_accel(v: np.ndarray, v0: np.ndarray, gap: np.ndarray, dv: np.ndarray, t_gap: np.ndarray,
              a_max: np.ndarray) -> np.ndarray:
    """IDM acceleration; gap = bumper-to-bumper distance to the leader (inf: free road)."""
    v0 = np.maximum(v0, 0.1)
    s_star = IDM_MIN_GAP_M + np.maximum(0.0, v * t_gap + v * dv / (2.0 * np.sqrt(a_max * IDM_COMFORT_DECEL_MPS2)))
    interaction = np.where(np.isfinite(gap), (s_star / np.maximum(gap, 0.1)) ** 2, 0.0)
    return a_max * (1.0 - (v / v0) ** IDM_DELTA - interaction)


class IdmTraffic:
    """Built-in traffic model on one road (all lanes in the direction of travel)."""

    def __init__(self, road: Road, vehicles: list[SimVehicle], rng: np.random.Generator) -> None:
        self.road = road
        self._vehicles = vehicles
        self.rng = rng
        self.t_s = 0.0
        for v in self._vehicles:
            self._update_pose(v)

    # ---------------------------------------------------------------- interface
    def vehicles(self) -> list[SimVehicle]:
        return self._vehicles

    def set_external_pose(self, vehicle_id: str, x_m: float, y_m: float, heading_rad: float,
                          speed_mps: float) -> None:
        for v in self._vehicles:
            if v.vehicle_id == vehicle_id:
                v.external = True
                v.x_m, v.y_m, v.heading_rad, v.speed_mps = x_m, y_m, heading_rad, speed_mps
                v.s_m, v.d_m = self.road.to_frenet(x_m, y_m)
                lane = self.road.lane_of_offset(v.d_m)
                if lane is not None:
                    v.lane = lane
                return
        raise KeyError(f"no vehicle {vehicle_id!r} in the world")

    def release_external(self, vehicle_id: str) -> None:
        for v in self._vehicles:
            if v.vehicle_id == vehicle_id and v.external:
                v.external = False
                lane = self.road.lane_of_offset(v.d_m)
                v.lane = lane if lane is not None else 0
                v.target_lane = None
                return

    def add(self, v: SimVehicle) -> None:
        """Put a vehicle or object on the road now (debris falling off a truck)."""
        if any(o.vehicle_id == v.vehicle_id for o in self._vehicles):
            raise KeyError(f"vehicle {v.vehicle_id!r} is already in the world")
        self._vehicles.append(v)
        self._update_pose(v)

    def remove(self, vehicle_id: str) -> None:
        """Take a vehicle or object off the road (debris cleared)."""
        self._vehicles = [v for v in self._vehicles if v.vehicle_id != vehicle_id]

    # ---------------------------------------------------------------- model
    def _ev_threat(self, t_s: float) -> list[SimVehicle]:
        return [v for v in self._vehicles if v.kind == "ev" and v.light_bar_on(t_s)]

    def _leaders(self, s: np.ndarray, d: np.ndarray, length: np.ndarray, width: np.ndarray,
                 idx_query: np.ndarray, d_query: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """For query vehicles at lateral offsets d_query: gap to and index of the nearest overlapping
        vehicle ahead (gap inf / index -1 when the road is free)."""
        sq = s[idx_query][:, None]
        ahead = s[None, :] - sq
        lateral = np.abs(d[None, :] - d_query[:, None]) < (width[None, :] + width[idx_query][:, None]) / 2 + 0.3
        gap = ahead - (length[None, :] + length[idx_query][:, None]) / 2
        valid = lateral & (ahead > 0) & (np.arange(len(s))[None, :] != idx_query[:, None])
        gap = np.where(valid, gap, np.inf)
        j = np.argmin(gap, axis=1)
        g = gap[np.arange(len(idx_query)), j]
        return g, np.where(np.isfinite(g), j, -1)

    def step(self, dt_s: float, t_s: float) -> None:
        if not dt_s > 0:
            raise ValueError(f"dt_s must be > 0, got {dt_s}")
        vs = self._vehicles
        n = len(vs)
        if n == 0:
            return
        road = self.road
        s = np.array([v.s_m for v in vs])
        d = np.array([v.d_m for v in vs])
        spd = np.array([v.speed_mps for v in vs])
        length = np.array([v.length_m for v in vs])
        width = np.array([v.width_m for v in vs])
        evs = self._ev_threat(t_s)

        # driver reactions to an EV with lights on (only drivers that yield)
        for v in vs:
            if v.is_static or v.external or v.kind == "ev":
                continue
            threat = any(v.s_m - EV_REACT_BEHIND_M < e.s_m < v.s_m + EV_PASSED_AHEAD_M for e in evs)
            if v.yields_to_ev and threat and not v.yielding:
                v.yielding = True
                v.target_lane = 0
            elif v.yielding and not threat:
                v.yielding = False
                v.target_d_m = None

        # desired speeds (brake_car distractors alternate; yielding drivers slow)
        v0 = np.empty(n)
        for i, v in enumerate(vs):
            des = v.desired_speed_mps
            if v.brake_period_s > 0 and (t_s % v.brake_period_s) >= v.brake_period_s / 2:
                des *= 0.4
            if v.wave_period_s > 0 and ((t_s + v.s_m / STOP_GO_WAVE_MPS) % v.wave_period_s) >= v.wave_period_s / 2:
                des *= STOP_GO_SLOW_FACTOR
            if v.yielding:  # move right first, then slow down at the right edge
                des *= YIELD_SPEED_FACTOR if road.lane_of_offset(v.d_m) == 0 else 0.8
            if v.kind == "ev":
                if v.light_bar_on(t_s):
                    v.idm_time_gap_s = 0.7  # on duty: exempt from the limit, follows closely
                else:
                    des = min(des, road.speed_limit_mps)  # lights off: an EV is ordinary traffic
            v0[i] = des
        t_gap = np.array([v.idm_time_gap_s for v in vs])
        a_max = np.array([v.idm_max_accel_mps2 for v in vs])

        idx = np.arange(n)
        gap, lead = self._leaders(s, d, length, width, idx, d)
        dv = np.where(lead >= 0, spd - spd[np.maximum(lead, 0)], 0.0)
        acc = idm_accel(spd, v0, gap, dv, t_gap, a_max)

        # lane changes (MOBIL-like), checked once per LANE_CHECK_PERIOD_S per vehicle
        for i, v in enumerate(vs):
            if v.is_static or v.external or v.kind == "av" or t_s < v.next_lane_check_s:
                continue
            period = LANE_CHECK_PERIOD_S * (0.3 if v.kind == "ev" and v.light_bar_on(t_s) else 1.0)
            v.next_lane_check_s = t_s + period * (0.8 + 0.4 * self.rng.random())
            lane_now = road.lane_of_offset(v.d_m)
            if lane_now is None or (v.target_lane is not None and v.target_lane != lane_now and not v.yielding):
                continue
            options = [ln for ln in (lane_now - 1, lane_now + 1) if 0 <= ln < road.lanes]
            if v.yielding:  # only to the right, and never into the lane an EV is coming up in
                options = [ln for ln in options if ln < lane_now and not any(
                    e.s_m < v.s_m and v.s_m - e.s_m < 40.0 and road.lane_of_offset(e.d_m) == ln for e in evs)]
            best, best_gain = None, MOBIL_THRESHOLD_MPS2 if v.kind != "ev" else 0.05
            for ln in options:
                dn = road.lane_centre_offset_m(ln)
                g_new, l_new = self._leaders(s, d, length, width, np.array([i]), np.array([dn]))
                dv_new = spd[i] - spd[l_new[0]] if l_new[0] >= 0 else 0.0
                a_new = idm_accel(spd[i:i + 1], v0[i:i + 1], g_new, np.array([dv_new]), t_gap[i:i + 1], a_max[i:i + 1])[0]
                # safety: the follower in the new lane must not brake harder than MOBIL_SAFE_DECEL_MPS2
                behind = (np.abs(d - dn) < (width + width[i]) / 2 + 0.3) & (s < s[i]) & (idx != i)
                if np.any(behind):
                    f = int(np.argmax(np.where(behind, s, -np.inf)))
                    fgap = s[i] - s[f] - (length[i] + length[f]) / 2
                    if fgap < 1.0:
                        continue
                    if vs[f].external and fgap < EXTERNAL_CUT_IN_HEADWAY_S * spd[f] + max(0.0, spd[f] - spd[i]) * 3.0 + 5.0:
                        continue  # the AV drives its commanded path and does not brake for a cut-in
                    a_f = idm_accel(spd[f:f + 1], v0[f:f + 1], np.array([fgap]), np.array([spd[f] - spd[i]]),
                                    t_gap[f:f + 1], a_max[f:f + 1])[0]
                    if a_f < -MOBIL_SAFE_DECEL_MPS2:
                        continue
                g_here = gap[i] if np.isfinite(gap[i]) else 1e3
                if g_new[0] < 2.0 or g_new[0] < min(g_here, 8.0):
                    continue
                gain = a_new - acc[i]
                if v.yielding:
                    gain += 1.0  # moving right for the EV is the goal itself
                elif v.kind == "ev":  # EVs keep left (drivers yield to the right) and pass on the right reluctantly
                    gain += (0.8 if v.light_bar_on(t_s) else 0.2) if ln > lane_now else -0.6
                elif ln > lane_now:
                    gain -= 0.2  # keep-right bias
                if gain > best_gain:
                    best, best_gain = ln, gain
            if best is not None:
                v.target_lane = best
            elif v.yielding and lane_now == 0:
                v.target_lane = 0

        # integrate
        for i, v in enumerate(vs):
            if v.is_static or v.external:
                continue
            a = float(np.clip(acc[i], -MAX_DECEL_MPS2, v.idm_max_accel_mps2))
            new_speed = max(0.0, v.speed_mps + a * dt_s)
            v.s_m += (v.speed_mps + new_speed) / 2 * dt_s
            v.accel_mps2 = (new_speed - v.speed_mps) / dt_s
            v.speed_mps = new_speed
            v.brake_on = v.accel_mps2 < -BRAKE_LIGHT_DECEL_MPS2 or (v.speed_mps < 0.3 and v.desired_speed_mps > 0)
            if v.target_lane is not None:
                v.lane = v.target_lane
            target_d = road.lane_centre_offset_m(v.lane)
            if v.yielding and v.lane == 0:
                target_d -= YIELD_EDGE_SHIFT_M
            lat_max = LATERAL_SPEED_MAX_MPS * (1.4 if v.kind == "ev" else 1.0)
            v.lateral_speed_mps = float(np.clip(LATERAL_GAIN_PER_S * (target_d - v.d_m), -lat_max, lat_max))
            if v.speed_mps < 0.5:
                v.lateral_speed_mps *= v.speed_mps / 0.5
            v.d_m += v.lateral_speed_mps * dt_s
            if abs(target_d - v.d_m) < 0.05 and not v.yielding:
                v.target_lane = None
            # respawn background traffic that leaves the road (keeps the density)
            if v.s_m > road.length_m - 3.0 and v.kind not in ("ev", "av"):
                v.s_m -= road.length_m - 6.0
            self._update_pose(v)
        self.t_s = t_s + dt_s

    def _update_pose(self, v: SimVehicle) -> None:
        if v.external:
            return
        x, y, h = self.road.pose_at(min(v.s_m, self.road.length_m), v.d_m)
        slip = math.atan2(v.lateral_speed_mps, max(v.speed_mps, 1.0)) if not v.is_static else 0.0
        v.x_m, v.y_m, v.heading_rad = x, y, h + slip


# -------------------------------------------------------------------- population
def _kind_for(rng: np.random.Generator, spec) -> str:
    r = rng.random()
    if r < spec.bus_fraction:
        return "bus"
    if r < spec.bus_fraction + spec.truck_fraction:
        return "truck"
    if r < spec.bus_fraction + spec.truck_fraction + spec.van_fraction:
        return "van"
    return "car"


def build_population(scenario: Scenario, rng: np.random.Generator) -> list[SimVehicle]:
    """The initial vehicles of a scenario: AV, EV, distractors, hazards, works vehicles, then seeded background
    traffic placed where it does not overlap them, a seeded fraction of it with hazard flashers or a turn signal
    blinking, of its buses with an LED strip (``sim.lamps``), all of it in stop-and-go waves when the scenario
    asks."""
    road = scenario.corridor.road
    out: list[SimVehicle] = []

    def centre(lane: int) -> float:
        return road.lane_centre_offset_m(lane)

    av = scenario.av
    if av is not None:
        out.append(SimVehicle(av.vehicle_id, "av", av.start_s_m, centre(av.lane), av.speed_mps, av.lane, 4.9, 1.9, 1.5,
                              (245, 245, 245), make_style(LIVERY_PLAIN, 7), desired_speed_mps=av.speed_mps,
                              idm_time_gap_s=1.2))
    ev = scenario.ev
    if ev is not None:
        base = av.start_s_m if av is not None else 0.0
        s_ev = float(np.clip(base + ev.start_offset_m, 0.0, road.length_m))
        if ev.body == "ambulance":
            size, colour, livery = (6.2, 2.1, 2.6), (240, 240, 240), LIVERY_AMBULANCE
        else:
            size, colour, livery = (5.0, 1.95, 1.5), (245, 245, 245), LIVERY_POLICE
        out.append(SimVehicle("ev1", "ev", s_ev, centre(ev.lane), ev.speed_mps * 0.9, ev.lane, *size, colour,
                              make_style(livery, int(rng.integers(256))), desired_speed_mps=ev.speed_mps,
                              idm_time_gap_s=0.9, idm_max_accel_mps2=2.5, politeness=0.0,
                              light_bar={"pattern": ev.pattern, "frequency_hz": ev.frequency_hz,
                                         "phase_s": float(rng.uniform(0, 1.0 / ev.frequency_hz)),
                                         "on_at_s": ev.lights_on_at_s}))
    for k, dsp in enumerate(scenario.distractors):
        detail = int(rng.integers(256))
        if dsp.kind in ("red_car", "brake_car", "blue_car"):
            kind, size = "car", random_size("car", rng)
            colour = BLUE_BGR if dsp.kind == "blue_car" else RED_BGR
            livery = LIVERY_PLAIN
        elif dsp.kind == "red_truck":
            kind, size, colour, livery = "truck", random_size("truck", rng), RED_BGR, LIVERY_PLAIN
        elif dsp.kind in ("led_bus", "chasing_led_bus"):
            kind, size, colour, livery = "bus", random_size("bus", rng), (230, 230, 230), LIVERY_PLAIN
        else:
            kind, size = "van", random_size("van", rng)
            colour, livery = (238, 238, 238), LIVERY_AMBULANCE if dsp.kind == "red_white_van" else LIVERY_PLAIN
        style = make_style(livery, detail)
        if kind == "bus":  # a blue strip; rate and phase from the detail draw
            style = with_roof_lamps(style, "led" if dsp.kind == "led_bus" else "led_chase", 1.5 + detail / 102,
                                    detail / 256)
        out.append(SimVehicle(f"d{k}", kind, dsp.s_m, centre(dsp.lane), dsp.speed_mps, dsp.lane, *size, colour,
                              style, desired_speed_mps=dsp.speed_mps,
                              brake_period_s=dsp.brake_period_s, yields_to_ev=False))
    for k, hz in enumerate(scenario.hazards):
        kind_index = DEBRIS_KINDS.index(hz.kind)
        out.append(SimVehicle(f"hz{k}", "debris", hz.s_m, centre(hz.lane) + hz.offset_m, 0.0, hz.lane, hz.length_m,
                              hz.width_m, hz.height_m, DEBRIS_COLOURS[hz.kind], make_style(kind_index, k),
                              desired_speed_mps=0.0, is_static=True,
                              extra={"appear_s": hz.appear_s, "remove_s": hz.remove_s}))
    for k, wk in enumerate(scenario.works):
        size = random_size(wk.body, rng)
        detail = int(rng.integers(256))
        style = with_roof_lamps(make_style(LIVERY_WORKS, detail), "beacon", wk.beacon_hz, detail / 256)
        if wk.hazard_flashers:
            style = with_signal_lamps(style, "hazard", 1.5, detail / 256)
        out.append(SimVehicle(f"w{k}", wk.body, wk.s_m, centre(wk.lane) + wk.offset_m, wk.speed_mps, wk.lane, *size,
                              WORKS_BGR, style, desired_speed_mps=wk.speed_mps, is_static=wk.speed_mps == 0.0,
                              idm_time_gap_s=2.0))

    ev_gap = None
    if av is not None and ev is not None and ev.lane == av.lane and ev.start_offset_m < 0:
        ev_gap = (ev.lane, av.start_s_m + ev.start_offset_m, av.start_s_m)
    tr = scenario.traffic
    n_fixed = len(out)  # AV, EV, distractors, debris; background traffic follows
    span = tr.spawn_s_max_m - tr.spawn_s_min_m
    n_per_lane = int(round(tr.density_veh_per_km_lane * span / 1000.0))
    k = 0
    for lane in range(road.lanes):
        for _ in range(n_per_lane):
            kind = _kind_for(rng, tr)
            size = random_size(kind, rng)
            speed = float(max(2.0, rng.normal(tr.speed_mps, tr.speed_spread_mps)))
            if kind in ("truck", "bus"):
                speed *= 0.9
            for _attempt in range(20):
                s0 = float(rng.uniform(tr.spawn_s_min_m, tr.spawn_s_max_m))
                clear = all(abs(o.s_m - s0) > (o.length_m + size[0]) / 2 + 6.0 or abs(o.d_m - centre(lane)) > 2.0
                            for o in out)
                if ev_gap is not None and lane == ev_gap[0] and ev_gap[1] - 10.0 < s0 < ev_gap[2] + 10.0:
                    clear = False  # the EV's lane is free up to the AV (thesis test set-up)
                if av is not None and lane == av.lane and s0 > av.start_s_m - 10.0:
                    # the AV follows commanded paths only (no onboard car-following): nothing slower ahead
                    # of it in its lane that it would catch up with during the scenario
                    catch_up_m = max(0.0, av.speed_mps - speed) * scenario.duration_s + 30.0
                    if s0 - av.start_s_m < catch_up_m:
                        clear = False
                if any(h.appear_s <= 0.0 and road.lane_of_offset(centre(h.lane) + h.offset_m) == lane
                       and h.s_m - HAZARD_RUN_UP_M < s0 < h.s_m for h in scenario.hazards):
                    clear = False  # debris already on the road: traffic arrives from upstream, not parked behind it
                if clear:
                    break
            else:
                continue
            r = rng.random()
            if r < tr.red_fraction:
                colour = RED_BGR
            elif r < tr.red_fraction + tr.blue_fraction:
                colour = BLUE_BGR
            else:
                colour = random_colour(rng)
            if kind == "bus":
                colour = tuple(int(c) for c in rng.choice([(40, 160, 230), (230, 230, 230), (60, 60, 180)]))
            livery = LIVERY_TWO_TONE if kind in ("van", "truck") and rng.random() < 0.3 else LIVERY_PLAIN
            out.append(SimVehicle(f"v{k}", kind, s0, centre(lane), speed, lane, *size, colour,
                                  make_style(livery, int(rng.integers(256))), desired_speed_mps=speed,
                                  yields_to_ev=bool(rng.random() < tr.yield_fraction),
                                  next_lane_check_s=float(rng.uniform(0, LANE_CHECK_PERIOD_S))))
            k += 1
    # decoy lamps last, so that the draws above (and the traffic they place) are those of older versions
    assign_signal_lamps(out[n_fixed:], tr.hazard_flasher_fraction, tr.turn_signal_fraction, rng)
    assign_roof_lamps(out[n_fixed:], tr.bus_led_fraction, tr.bus_led_chase_fraction, rng)
    if tr.stop_and_go_period_s > 0:
        for v in out[n_fixed:]:
            v.wave_period_s = tr.stop_and_go_period_s
    return out
