"""The simulated car: linear dynamic bicycle (thesis eqs. 4.11-4.12) with world-frame kinematics.

States: x, y (CG, corridor frame, m), yaw (rad), v_x, v_y (body frame, m/s), yaw_rate (rad/s),
steer (road-wheel angle, rad) and accel (m/s^2, the longitudinal actuator's output).

- Lateral (eqs. 4.11-4.12, per-axle cornering stiffness C_f, C_r):
  m (v_y' + v_x r) = C_f delta - (C_f + C_r)/v_x v_y - (a C_f - b C_r)/v_x r
  I r'             = a C_f delta - (a C_f - b C_r)/v_x v_y - (a^2 C_f + b^2 C_r)/v_x r
- Below ``kinematic_below_mps`` the dynamic model (which divides by v_x) is replaced by the
  kinematic bicycle: r = v_x tan(delta)/L, v_y = b r (no tyre slip at walking pace).
- Actuators: steering is a first-order lag with a road-wheel rate limit and an angle limit; the
  longitudinal channel is a first-order lag on the commanded acceleration with limits; the car
  never rolls backwards.
Integration: explicit Euler on sub-steps of ``substep_s`` (2 ms, well inside the fastest tyre mode
at low speed), called at 100 Hz or finer.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace


@dataclass(frozen=True)
class VehicleParams:
    """A mid-size car (Apollo's Lincoln MKZ; docs/architecture.md §Vehicle controller)."""

    mass_kg: float = 2080.0
    yaw_inertia_kgm2: float = 4208.0
    cg_to_front_m: float = 1.4224
    """a"""
    cg_to_rear_m: float = 1.4224
    """b"""
    cornering_front_npr: float = 155_495.0
    """C_f, per axle (N/rad)"""
    cornering_rear_npr: float = 155_495.0
    """C_r, per axle (N/rad)"""
    steering_ratio: float = 16.0
    max_steer_rad: float = 0.5
    """Road-wheel angle limit (~470 deg at the steering wheel / 16)."""
    max_steer_rate_rps: float = 0.53
    steer_lag_s: float = 0.05
    accel_lag_s: float = 0.25
    max_accel_mps2: float = 3.0
    max_decel_mps2: float = 8.0
    length_m: float = 4.9
    width_m: float = 1.9
    kinematic_below_mps: float = 1.5

    @property
    def wheelbase_m(self) -> float:
        return self.cg_to_front_m + self.cg_to_rear_m

    @property
    def understeer_gradient(self) -> float:
        """(m/L)(b/C_f - a/C_r), the v_x^2/R coefficient of eq. 4.13 (rad s^2/m)."""
        p = self
        return p.mass_kg / p.wheelbase_m * (p.cg_to_rear_m / p.cornering_front_npr
                                            - p.cg_to_front_m / p.cornering_rear_npr)

    def steady_sideslip_rad(self, curvature_1pm: float, speed_mps: float) -> float:
        """CG sideslip beta = v_y/v_x when cornering steadily on a path of this curvature.

        beta = kappa (b - a m v_x^2 / (C_r L)); the yaw error of a car that tracks the path
        exactly is then -beta (heading = path heading - beta).
        """
        p = self
        return curvature_1pm * (p.cg_to_rear_m - p.cg_to_front_m * p.mass_kg * speed_mps ** 2
                                / (p.cornering_rear_npr * p.wheelbase_m))

    def cornering_steer(self, curvature_1pm: float, speed_mps: float,
                        accel_mps2: float = 0.0) -> tuple[float, float]:
        """(road-wheel angle, CG sideslip) that hold a path of this curvature at this speed and accel.

        Eqs. 4.11-4.12 solved for (delta, v_y) with the course turning at v_x kappa while the sideslip
        follows its steady value beta_ss(v_x) = kappa (b - a m v_x^2 / (C_r L)): r = v_x kappa - beta_ss',
        r' ~ a_x kappa, v_y' = d/dt(v_x beta_ss) = kappa a_x (b - 3 a m v_x^2 / (C_r L)). At a_x = 0 this is eq. 4.13,
        delta = L kappa + K_us v_x^2 kappa, and beta = beta_ss; braking through a bend needs the yaw
        moment I r' and the changing sideslip too. Below ``kinematic_below_mps``: the kinematic
        bicycle (delta = atan(L kappa), beta = b kappa).
        """
        p, v, k = self, speed_mps, curvature_1pm
        if v < p.kinematic_below_mps:
            return math.atan(p.wheelbase_m * k), p.cg_to_rear_m * k
        m, iz, a, b = p.mass_kg, p.yaw_inertia_kgm2, p.cg_to_front_m, p.cg_to_rear_m
        cf, cr, wb = p.cornering_front_npr, p.cornering_rear_npr, p.wheelbase_m
        # the course (not the heading) turns at v kappa: r = v kappa - beta'
        beta_dot = -2.0 * k * accel_mps2 * a * m * v / (cr * wb)
        r, r_dot = v * k - beta_dot, accel_mps2 * k
        vy_dot = k * accel_mps2 * (b - 3.0 * a * m * v * v / (cr * wb))
        # [cf, -(cf+cr)/v; a cf, -(a cf - b cr)/v] [delta; v_y] = rhs  (determinant cf cr L / v)
        rhs1 = m * (vy_dot + v * r) + (a * cf - b * cr) * r / v
        rhs2 = iz * r_dot + (a * a * cf + b * b * cr) * r / v
        det = cf * cr * wb / v
        delta = (-(a * cf - b * cr) / v * rhs1 + (cf + cr) / v * rhs2) / det
        vy = (cf * rhs2 - a * cf * rhs1) / det
        return delta, vy / v


@dataclass
class VehicleStateVec:
    x_m: float = 0.0
    y_m: float = 0.0
    yaw_rad: float = 0.0
    vx_mps: float = 0.0
    vy_mps: float = 0.0
    yaw_rate_rps: float = 0.0
    steer_rad: float = 0.0
    accel_mps2: float = 0.0

    def copy(self) -> VehicleStateVec:
        return replace(self)


@dataclass
class BicyclePlant:
    """Integrates the car forward under steering and acceleration commands."""

    params: VehicleParams = field(default_factory=VehicleParams)
    state: VehicleStateVec = field(default_factory=VehicleStateVec)
    substep_s: float = 0.002

    def step(self, dt_s: float, steer_cmd_rad: float, accel_cmd_mps2: float) -> VehicleStateVec:
        if not dt_s > 0:
            raise ValueError(f"dt_s must be > 0, got {dt_s}")
        n = max(1, int(math.ceil(dt_s / self.substep_s - 1e-9)))
        h = dt_s / n
        p, st = self.params, self.state
        steer_cmd = min(p.max_steer_rad, max(-p.max_steer_rad, steer_cmd_rad))
        accel_cmd = min(p.max_accel_mps2, max(-p.max_decel_mps2, accel_cmd_mps2))
        m, iz, a, b = p.mass_kg, p.yaw_inertia_kgm2, p.cg_to_front_m, p.cg_to_rear_m
        cf, cr, wb = p.cornering_front_npr, p.cornering_rear_npr, p.wheelbase_m
        for _ in range(n):
            # actuators
            rate = (steer_cmd - st.steer_rad) / p.steer_lag_s if p.steer_lag_s > 0 else (steer_cmd - st.steer_rad) / h
            rate = min(p.max_steer_rate_rps, max(-p.max_steer_rate_rps, rate))
            st.steer_rad += rate * h
            st.accel_mps2 += (accel_cmd - st.accel_mps2) * min(1.0, h / p.accel_lag_s)
            delta, vx = st.steer_rad, st.vx_mps
            # lateral / yaw
            if vx < p.kinematic_below_mps:
                r = vx * math.tan(delta) / wb
                st.yaw_rate_rps, st.vy_mps = r, b * r
            else:
                vy, r = st.vy_mps, st.yaw_rate_rps
                dvy = (cf * delta - (cf + cr) / vx * vy - (a * cf - b * cr) / vx * r) / m - vx * r
                dr = (a * cf * delta - (a * cf - b * cr) / vx * vy - (a * a * cf + b * b * cr) / vx * r) / iz
                st.vy_mps += dvy * h
                st.yaw_rate_rps += dr * h
            # world-frame kinematics
            c, s = math.cos(st.yaw_rad), math.sin(st.yaw_rad)
            st.x_m += (vx * c - st.vy_mps * s) * h
            st.y_m += (vx * s + st.vy_mps * c) * h
            st.yaw_rad += st.yaw_rate_rps * h
            st.vx_mps = max(0.0, vx + st.accel_mps2 * h)
            if st.vx_mps == 0.0 and st.accel_mps2 < 0.0:
                st.accel_mps2 = 0.0
        st.yaw_rad = math.remainder(st.yaw_rad, 2.0 * math.pi)
        return st
