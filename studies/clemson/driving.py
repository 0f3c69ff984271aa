"""Hazard-avoidance driving episodes of the Clemson comparison: roads with debris, the teacher,
the infrastructure-guided controller and a camera-steered car, all in lockstep on the same roads.

- ``make_scenario(seed)``: a seeded two-lane road (a straight lead-in, an arc of radius 250-600 m either way
  or a straight, a straight run-out), the AV at 10 m/s in a seeded lane, and (``with_debris``) one piece of
  debris of the report's kinds in its lane, 0-0.5 m off the lane centre, 100-150 m ahead.
- Every run is the thesis controller (``vehicle.simulated.SimulatedVehicle``: bicycle plant, GNSS + EKF, lateral
  and longitudinal controllers, fail-safe) stepped at 100 Hz with the DDM's heartbeat, so the speed profile
  is the same for every driver.
- ``teacher``: the DDM's hazard rule with perfect knowledge: once the debris blocks the AV's lane
  (``ddm.policy.hazard`` geometry) and its threat value (report eq. 2-3, ``ddm.threat``) exceeds the DDM's
  threshold, a LANE_CHANGE planned by ``ddm.paths.plan_lane_change`` to the other lane, at once.
- ``iea``: the same rule as the infrastructure runs it: the debris position the RSUs report (N(0, 0.3 m)
  each axis, ``RSU_POSITION_SIGMA_M``), the AV's position as the DDM knows it (its own EKF estimate,
  published in its state), the decision on the DDM's 10 Hz cycle and the command arriving
  ``COMMAND_LATENCY_S`` later.
- ``camera``: a steering function of the dashcam image (and the radar) drives while the core is in DRIVING;
  whatever the core does otherwise (a manoeuvre, a minimal-risk stop) it keeps in charge
  (``studies.clemson.learned_steering.LearnedVehicle``).

``simulated_radar`` is the car's distance sensor (report section 4.1: Delphi ESR mid-range mode: 90 deg
field of view, 60 m range): (lx, ly) of the nearest debris from the front bumper, with range noise
``RADAR_RANGE_SIGMA_M`` and bearing noise ``RADAR_BEARING_SIGMA_RAD``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from ddm.config import DdmConfig
from ddm.geometry import RoadFrame
from ddm.paths import plan_lane_change
from ddm.threat import LX_MAX_M, av_hazard_distances, threat_value
from protocol.enums import Manoeuvre
from protocol.messages import Actor, PathSwitchCommand
from protocol.road import Road, Segment
from sim.scenario import DEBRIS_KINDS
from studies.clemson.dashcam import debris_actor
from vehicle.plant import VehicleParams
from vehicle.simulated import SimulatedVehicle

DT_S = 0.01
CAMERA_PERIOD_S = 0.1
"""The dashcam and the learned steering run at 10 Hz."""
DDM_PERIOD_S = 0.1
COMMAND_LATENCY_S = 0.25
"""DDM decision to the car (DDM cycle jitter, transport, validation)."""
RSU_POSITION_SIGMA_M = 0.3
THREAT_THRESHOLD = 0.3
"""The DDM's (``ddm.config.HazardConfig.threat_threshold``)."""
CLEARANCE_M = 1.3
"""``ddm.config.HazardConfig``: min_clearance_m + position_margin_m: a hazard closer than this to the car's side blocks."""
RADAR_RANGE_M, RADAR_HALF_FOV_RAD = 60.0, math.radians(45.0)
RADAR_RANGE_SIGMA_M, RADAR_BEARING_SIGMA_RAD = 0.25, math.radians(0.5)
SPEED_MPS = 10.0
PASS_M = 25.0
"""An episode ends when the car's centre is this far past the debris."""
DEBRIS_SIZES = {"box": (1.2, 0.9, 0.45), "rock": (0.7, 0.6, 0.35), "barrel": (0.6, 0.6, 0.9),
                "pallet": (1.2, 1.0, 0.15), "pipe": (2.0, 0.3, 0.3), "tyre": (0.7, 0.7, 0.22)}
"""Length, width, height (m) of each debris kind (as in the hazard scenarios)."""


@dataclass(frozen=True)
class Debris:
    s_m: float
    d_m: float
    kind: str
    length_m: float
    width_m: float
    height_m: float


@dataclass(frozen=True)
class DrivingScenario:
    seed: int
    road: Road
    start_lane: int
    debris: tuple[Debris, ...]
    start_s_m: float = 10.0
    speed_mps: float = SPEED_MPS
    end_s_m: float = 0.0

    def actors(self) -> list[Actor]:
        return [debris_actor(self.road, f"hz{k}", d.s_m, d.d_m, d.kind, d.length_m, d.width_m, d.height_m, k)
                for k, d in enumerate(self.debris)]


def make_scenario(seed: int, with_debris: bool = True) -> DrivingScenario:
    """The seeded road, start lane and debris of episode ``seed`` (see the module doc)."""
    rng = np.random.default_rng([23, int(seed)])
    shape = rng.uniform()
    radius = float(rng.uniform(250.0, 600.0)) * (1 if rng.uniform() < 0.5 else -1)
    mid = Segment("straight", 200.0) if shape < 0.3 else Segment("arc", 200.0, radius)
    road = Road(0.0, 0.0, 0.0, (Segment("straight", 40.0), mid, Segment("straight", 150.0)), lanes=2)
    lane = int(rng.integers(0, 2))
    debris: tuple[Debris, ...] = ()
    s_hz = float(rng.uniform(110.0, 160.0))
    if with_debris:
        kind = DEBRIS_KINDS[int(rng.integers(0, len(DEBRIS_KINDS)))]
        L, W, H = DEBRIS_SIZES[kind]
        debris = (Debris(s_hz, road.lane_centre_offset_m(lane) + float(rng.uniform(-0.5, 0.5)), kind, L, W, H),)
    return DrivingScenario(seed, road, lane, debris, end_s_m=s_hz + PASS_M)


def simulated_radar(x_m: float, y_m: float, yaw_rad: float, debris: list[Actor], rng: np.random.Generator,
                    car_length_m: float = VehicleParams().length_m) -> tuple[float, float] | None:
    """(lx, ly) in m of the nearest debris in the radar's field: lx from the front bumper to the debris'
    near edge along the car's axis, ly its lateral offset from the car's centre line (noisy); None if none."""
    best = None
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    bumper = car_length_m / 2.0
    for a in debris:
        dx, dy = a.pos_x_m - (x_m + c * bumper), a.pos_y_m - (y_m + s * bumper)
        rng_m = math.hypot(dx, dy)
        bearing = math.atan2(-s * dx + c * dy, c * dx + s * dy)
        if rng_m > RADAR_RANGE_M or abs(bearing) > RADAR_HALF_FOV_RAD:
            continue
        r = rng_m + rng.normal(0.0, RADAR_RANGE_SIGMA_M)
        b = bearing + rng.normal(0.0, RADAR_BEARING_SIGMA_RAD)
        lx, ly = r * math.cos(b) - a.length_m / 2.0, abs(r * math.sin(b))
        if best is None or lx < best[0]:
            best = (max(0.0, lx), ly)
    return best


@dataclass
class Trace:
    """One run, sampled every CAMERA_PERIOD_S: true pose, road frame, the steering command, the threat used."""

    rows: list[tuple] = field(default_factory=list)
    command_t_s: float | None = None
    FIELDS = ("t_s", "x_m", "y_m", "yaw_rad", "s_m", "d_m", "steer_cmd_rad", "threat", "mode")

    def arrays(self) -> dict[str, np.ndarray]:
        a = np.asarray(self.rows, dtype=float).reshape(-1, len(self.FIELDS))
        return {k: a[:, i] for i, k in enumerate(self.FIELDS)}


CameraSteering = Callable[[SimulatedVehicle, float], tuple[float | None, float]]
"""(sim, now) -> (steering angle in rad or None to leave the thesis controller's, threat value used)."""


def _lane_change(sc: DrivingScenario, frame: RoadFrame, cfg: DdmConfig, s0: float, d0: float, now: float,
                 vehicle_id: str) -> PathSwitchCommand:
    target = 1 - sc.start_lane
    plan = plan_lane_change(frame, s0, d0, 0.0, sc.speed_mps, sc.road.lane_centre_offset_m(target),
                            sc.speed_mps, cfg)
    return PathSwitchCommand(src="ddm", stamp=now, command_id="hz-1", command_seq=1, vehicle_id=vehicle_id,
                             manoeuvre=Manoeuvre.LANE_CHANGE, reason="debris ahead", target_lane=target,
                             waypoints=plan.waypoints, speed_profile_mps=plan.speeds_mps,
                             target_speed_mps=plan.target_speed_mps, stop_point=None, issued_at=now,
                             valid_until=now + 5.0)


def blocking_threat(sc: DrivingScenario, s_car: float, d_car: float, hazards: list[tuple[float, float, Debris]],
                    params: VehicleParams) -> float:
    """Largest threat value (eq. 2-3) of the hazards (s, d, debris) that block the car's lane, else 0."""
    lane_d = sc.road.lane_centre_offset_m(sc.start_lane)
    best = 0.0
    for s_hz, d_hz, hz in hazards:
        gap = abs(d_hz - lane_d) - (params.width_m + hz.width_m) / 2.0
        if gap >= CLEARANCE_M:
            continue
        lx, ly = av_hazard_distances(s_car, d_car, params.length_m, s_hz, d_hz, hz.length_m)
        best = max(best, threat_value(lx, ly, LX_MAX_M, sc.road.lane_width_m))
    return best


def run(sc: DrivingScenario, driver: str, camera_steering: CameraSteering | None = None, seed: int = 0,
        sim: SimulatedVehicle | None = None, max_duration_s: float = 40.0, late_trigger_m: float | None = None) -> Trace:
    """Drive ``sc`` with ``driver`` in {"teacher", "iea", "camera"}; for "camera", ``sim`` is the car to drive
    (a ``LearnedVehicle``) and ``camera_steering`` is called every CAMERA_PERIOD_S. ``late_trigger_m``: the
    teacher waits until the debris is this close (centre to centre along the road) before it steers away
    (training data only: demonstrations of a late avoidance, the states a learned car that saw the debris late
    is in)."""
    if driver not in ("teacher", "iea", "camera"):
        raise ValueError(f"driver must be teacher, iea or camera, got {driver!r}")
    if driver == "camera" and (camera_steering is None or sim is None):
        raise ValueError("the camera driver needs camera_steering and its vehicle (sim)")
    if sim is None:
        sim = SimulatedVehicle(sc.road, "av1", sc.start_s_m, sc.start_lane, sc.speed_mps, seed=seed)
    params = sim.core.config.params
    frame, cfg = RoadFrame(sc.road), DdmConfig()
    rng = np.random.default_rng([23, sc.seed, seed, 1])
    seen = [(d.s_m, d.d_m, d) for d in sc.debris]
    if driver == "iea":  # the RSUs' report of the debris: one fused position, off by their localisation error
        seen = []
        for d in sc.debris:
            x, y, _ = sc.road.pose_at(d.s_m, d.d_m)
            s_d = frame.to_frenet(x + rng.normal(0, RSU_POSITION_SIGMA_M), y + rng.normal(0, RSU_POSITION_SIGMA_M))
            seen.append((float(s_d[0][0]), float(s_d[1][0]), d))
    trace = Trace()
    pending: tuple[float, PathSwitchCommand] | None = None
    commanded = False
    steer_hold, threat_used = None, 0.0
    n = int(round(max_duration_s / DT_S))
    every_cam = int(round(CAMERA_PERIOD_S / DT_S))
    every_ddm = int(round(DDM_PERIOD_S / DT_S))
    for k in range(n):
        now = k * DT_S
        if k % 100 == 0:
            sim.core.on_link(now)
        st = sim.truth
        if driver in ("teacher", "iea") and not commanded and k % every_ddm == 0:
            if driver == "teacher":
                s_car, d_car = (float(v[0]) for v in frame.to_frenet(st.x_m, st.y_m))
            else:
                ex, ey, _ = sim.core.estimator.pose
                s_car, d_car = (float(v[0]) for v in frame.to_frenet(ex, ey))
            threat_used = blocking_threat(sc, s_car, d_car, seen, params)
            late = late_trigger_m is not None and all(h[0] - s_car > late_trigger_m for h in seen)
            if threat_used > THREAT_THRESHOLD and not late:
                cmd = _lane_change(sc, frame, cfg, s_car, d_car, now, sim.core.vehicle_id)
                pending = (now + (COMMAND_LATENCY_S if driver == "iea" else 0.0), cmd)
                commanded = True
        if pending is not None and now + 1e-9 >= pending[0]:
            sim.core.on_command(pending[1], now)
            trace.command_t_s = now
            pending = None
        if driver == "camera" and k % every_cam == 0:
            assert camera_steering is not None
            steer_hold, threat_used = camera_steering(sim, now)
            sim.learned_steer_rad = steer_hold  # type: ignore[attr-defined]
        out = sim.step(now, DT_S)
        if k % every_cam == 0:
            s_now, d_now = sc.road.to_frenet(st.x_m, st.y_m)
            steer = out.steer_cmd_rad if driver != "camera" else getattr(sim, "applied_steer_rad", out.steer_cmd_rad)
            trace.rows.append((now, st.x_m, st.y_m, st.yaw_rad, float(np.atleast_1d(s_now)[0]),
                               float(np.atleast_1d(d_now)[0]), steer, threat_used, float(list(type(out.mode)).index(out.mode))))
            if float(np.atleast_1d(s_now)[0]) >= sc.end_s_m:
                break
    return trace


def clearance_m(sc: DrivingScenario, trace: Trace, params: VehicleParams = VehicleParams()) -> float:
    """Smallest gap between the car's box and any debris box along the run, in the road frame (m);
    negative: the boxes overlapped (a collision), by that much."""
    a = trace.arrays()
    best = math.inf
    for d in sc.debris:
        dx = np.abs(a["s_m"] - d.s_m) - (params.length_m + d.length_m) / 2.0
        dy = np.abs(a["d_m"] - d.d_m) - (params.width_m + d.width_m) / 2.0
        gap = np.where((dx < 0) & (dy < 0), np.maximum(dx, dy), np.hypot(np.maximum(dx, 0), np.maximum(dy, 0)))
        best = min(best, float(gap.min()))
    return best


def camera_driver(sc: DrivingScenario, steering: Callable[[np.ndarray, tuple[float, float] | None],
                                                          tuple[float, float]],
                  seed: int = 0, noise: bool = True) -> CameraSteering:
    """The ``camera`` driver's loop: render the dashcam at the car's true pose, measure the radar, call
    ``steering(image, radar)`` -> (angle rad, T_f)."""
    from studies.clemson.dashcam import DashCamera

    cam = DashCamera(sc.road, seed=sc.seed, noise=noise)
    actors = sc.actors()
    rng = np.random.default_rng([23, sc.seed, seed, 2])

    def step(sim: SimulatedVehicle, now: float) -> tuple[float | None, float]:
        st = sim.truth
        img = cam.render(st.x_m, st.y_m, st.yaw_rad, actors, now, frame_index=int(round(now * 10)))
        radar = simulated_radar(st.x_m, st.y_m, st.yaw_rad, actors, rng, sim.core.config.params.length_m)
        return steering(img, radar)

    return step
