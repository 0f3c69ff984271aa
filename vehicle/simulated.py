"""``SimulatedVehicle`` closes the loop for the simulator, tests and the service: the bicycle plant
(``vehicle/plant.py``), a simulated fix source and odometry feed a :class:`~vehicle.core.VehicleCore`, stepped at
the control rate."""

from __future__ import annotations

from vehicle.core import ControlOutput, CoreConfig, VehicleCore
from vehicle.localisation import GNSS, FixSourceConfig, Odometry, OdometryNoise, SimulatedFixSource
from vehicle.plant import BicyclePlant, VehicleStateVec


class SimulatedVehicle:
    """Plant + sensors + core, stepped at the control rate (the car of the simulator and the service)."""

    def __init__(self, road, vehicle_id: str, start_s_m: float, start_lane: int, cruise_speed_mps: float,
                 config: CoreConfig = CoreConfig(), fix_source: FixSourceConfig | None = GNSS,
                 odometry: OdometryNoise = OdometryNoise(), seed: int = 0, start_time_s: float = 0.0,
                 start_speed_mps: float | None = None) -> None:
        self.road = road
        x, y, h = road.pose_at(start_s_m, road.lane_centre_offset_m(start_lane))
        v0 = cruise_speed_mps if start_speed_mps is None else start_speed_mps
        self.plant = BicyclePlant(config.params, VehicleStateVec(x_m=x, y_m=y, yaw_rad=h, vx_mps=v0))
        self.fixes = SimulatedFixSource(fix_source, seed) if fix_source is not None else None
        self.odometry = Odometry(odometry, seed)
        self.core = VehicleCore(road, vehicle_id, cruise_speed_mps, config)
        self.core.initialise(start_time_s, x, y, h, v0)
        self.fix_source_enabled = True

    @property
    def truth(self) -> VehicleStateVec:
        return self.plant.state

    def step(self, now_s: float, dt_s: float) -> ControlOutput:
        """Sense (fixes, odometry), control (the core), then move the plant by ``plant_steer_rad``."""
        st = self.plant.state
        if self.fixes is not None:
            for fix in self.fixes.step(now_s, st.x_m, st.y_m):
                if self.fix_source_enabled:
                    self.core.on_fix(fix)
        v, w = self.odometry.measure(st.vx_mps, st.yaw_rate_rps)
        out = self.core.control(now_s, v, w, dt_s, st.steer_rad)
        self.plant.step(dt_s, self.plant_steer_rad(out), out.accel_cmd_mps2)
        return out

    def plant_steer_rad(self, out: ControlOutput) -> float:
        return out.steer_cmd_rad  # the thesis controller's (a learned driver overrides this)

    def true_errors(self) -> tuple[float, float, float, float]:
        """(e_lat, yaw err, yaw-rate err, s) of the TRUE pose against the active path."""
        core, st = self.core, self.plant.state
        path = core.path
        assert path is not None
        proj = path.project(st.x_m, st.y_m, getattr(self, "_hint", None))
        self._hint = proj.index
        fit = path.fit_at(proj.s_m, core.lateral.fit_points, core.lateral.line_tolerance_m)
        e, ye, yre = fit.errors(st.x_m, st.y_m, st.yaw_rad, st.yaw_rate_rps, st.vx_mps)
        return e, ye, yre, proj.s_m

    def stop_error_m(self) -> float | None:
        """Signed distance along the path from the stop point to the car (+ past it)."""
        core = self.core
        if core.stop_s_m is None or core.path is None:
            return None
        st = self.plant.state
        return core.path.project(st.x_m, st.y_m).s_m - core.stop_s_m

