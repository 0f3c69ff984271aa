"""Lateral controller of thesis 4.2.2 (Liu, Rathinam, Darbha 2019): feedforward + feedback steering.

- Feedforward (eq. 4.13): delta_ff = L kappa + (m/L)(b/C_f - a/C_r) v_x^2 kappa, with the signed
  curvature kappa = 1/R of the arc fitted a short preview ahead (the actuator lags the command), plus
  the sideslip term -k_theta beta(kappa, v_x) so that the yaw-error feedback does not fight the
  heading a car must hold to corner on the path (zero on a straight road). When the car speeds up or
  brakes in a bend, (delta, beta) come from eqs. 4.11-4.12 with the longitudinal acceleration
  (``VehicleParams.cornering_steer``): braking from 25 m/s on R = 200 m the sideslip unwinds, so the
  heading turns slower than the path and the car needs ~5 % less steering than eq. 4.13; with the
  weak high-speed feedback (k_e ~ 1/v^2) that mismatch alone held the car 3-7 cm off the path.
- Feedback (eq. 4.14 in the report's form, docs/architecture.md §Vehicle controller): delta_fb = -k_e e_lat - k_theta yaw_err - k_omega yaw_rate_err.
- Steering (eq. 4.15): delta = delta_ff + delta_fb, clipped to the angle limit and rate limited.

Gains are scheduled with speed so that the lateral error behaves the same at every speed: for the
kinematic error model e'' ~ (v^2/L) delta this gives k_e = omega_n^2 L / v^2 and
k_theta = 2 zeta omega_n L / v. ``closed_loop_eigenvalues`` checks the schedule on the dynamic
error model (bicycle + feedback + steering lag), see tests/vehicle and bench/control_bench.py.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from vehicle.geometry import LINE_TOLERANCE_M
from vehicle.plant import VehicleParams
from vehicle.reference import FIT_POINTS, ReferencePath


@dataclass(frozen=True)
class LateralGains:
    """Speed-scheduled gains: omega_n (rad/s) and zeta of the lateral-error response, k_omega fixed."""

    omega_n_rps: float = 1.2
    zeta: float = 0.9
    k_omega: float = 0.02
    """Yaw-rate-error gain (rad per rad/s)."""
    min_speed_mps: float = 4.0
    """Below this the gains stay at their value for this speed (they would grow as 1/v^2)."""

    def at(self, speed_mps: float) -> tuple[float, float, float]:
        """(k_e rad/m, k_theta rad/rad, k_omega rad/(rad/s)) at this speed for wheelbase 2.8448 m."""
        return self.at_wheelbase(speed_mps, VehicleParams().wheelbase_m)

    def at_wheelbase(self, speed_mps: float, wheelbase_m: float) -> tuple[float, float, float]:
        v = max(self.min_speed_mps, speed_mps)
        k_e = self.omega_n_rps ** 2 * wheelbase_m / (v * v)
        k_theta = 2.0 * self.zeta * self.omega_n_rps * wheelbase_m / v
        return k_e, k_theta, self.k_omega


@dataclass(frozen=True, slots=True)
class LateralOutput:
    steer_cmd_rad: float
    steer_ff_rad: float
    steer_fb_rad: float
    lateral_error_m: float
    yaw_error_rad: float
    yaw_rate_error_rps: float
    curvature_1pm: float
    s_m: float
    """Distance along the reference of the vehicle's projection."""
    distance_to_path_m: float
    is_line: bool


@dataclass
class LateralController:
    params: VehicleParams = field(default_factory=VehicleParams)
    gains: LateralGains = field(default_factory=LateralGains)
    fit_points: int = FIT_POINTS
    line_tolerance_m: float = LINE_TOLERANCE_M
    preview_s: float | None = None
    """Feedforward curvature is taken this far ahead (x speed). None: the steering lag plus the yaw
    time constant of the bicycle, I v / (a^2 C_f + b^2 C_r), which is how late the yaw rate follows
    a steering change."""
    sideslip_compensation: bool = True
    accel_feedforward: bool = True
    """Include the longitudinal acceleration in the feedforward (off: eq. 4.13 at constant speed)."""
    _hint: int | None = None
    _last_cmd: float = 0.0

    def preview_time_s(self, speed_mps: float) -> float:
        p = self.params
        tau_yaw = p.yaw_inertia_kgm2 * speed_mps / (p.cg_to_front_m ** 2 * p.cornering_front_npr
                                                    + p.cg_to_rear_m ** 2 * p.cornering_rear_npr)
        return p.steer_lag_s + tau_yaw

    def reset(self) -> None:
        self._hint = None

    def step(self, path: ReferencePath, x_m: float, y_m: float, yaw_rad: float, speed_mps: float,
             yaw_rate_rps: float, dt_s: float, accel_mps2: float = 0.0) -> LateralOutput:
        p = self.params
        proj = path.project(x_m, y_m, self._hint)
        self._hint = proj.index
        fit = path.fit_at(proj.s_m, self.fit_points, self.line_tolerance_m)
        e_lat, yaw_err, yaw_rate_err = fit.errors(x_m, y_m, yaw_rad, yaw_rate_rps, speed_mps)
        preview_s = self.preview_time_s(speed_mps) if self.preview_s is None else self.preview_s
        ahead = path.fit_at(proj.s_m + speed_mps * preview_s, self.fit_points, self.line_tolerance_m) \
            if preview_s > 0 and speed_mps > 0 else fit
        kappa = ahead.curvature_1pm
        k_e, k_theta, k_omega = self.gains.at_wheelbase(speed_mps, p.wheelbase_m)
        # eq. 4.13 with signed curvature
        ff, beta = p.cornering_steer(kappa, speed_mps, accel_mps2 if self.accel_feedforward else 0.0)
        if self.sideslip_compensation:
            ff -= k_theta * beta
        # eq. 4.14 (the report's form) and 4.15
        fb = -k_e * e_lat - k_theta * yaw_err - k_omega * yaw_rate_err
        cmd = min(p.max_steer_rad, max(-p.max_steer_rad, ff + fb))
        max_step = p.max_steer_rate_rps * dt_s
        cmd = min(self._last_cmd + max_step, max(self._last_cmd - max_step, cmd))
        self._last_cmd = cmd
        return LateralOutput(cmd, ff, fb, e_lat, yaw_err, yaw_rate_err, kappa, proj.s_m, proj.distance_m,
                             fit.is_line)


# ---------------------------------------------------------------------- stability analysis
def error_dynamics(params: VehicleParams, speed_mps: float) -> tuple[np.ndarray, np.ndarray]:
    """Linear lateral-error model (path-frame bicycle, eqs. 4.11-4.12 rewritten in errors).

    State [e_lat, e_lat', yaw_err, yaw_err'] on a straight path (curvature enters as a disturbance
    that the feedforward cancels); input delta. Returns (A, B).
    """
    p, v = params, speed_mps
    m, iz, a, b = p.mass_kg, p.yaw_inertia_kgm2, p.cg_to_front_m, p.cg_to_rear_m
    cf, cr = p.cornering_front_npr, p.cornering_rear_npr
    A = np.array([
        [0.0, 1.0, 0.0, 0.0],
        [0.0, -(cf + cr) / (m * v), (cf + cr) / m, -(a * cf - b * cr) / (m * v)],
        [0.0, 0.0, 0.0, 1.0],
        [0.0, -(a * cf - b * cr) / (iz * v), (a * cf - b * cr) / iz, -(a * a * cf + b * b * cr) / (iz * v)],
    ])
    B = np.array([0.0, cf / m, 0.0, a * cf / iz])
    return A, B


def closed_loop_eigenvalues(params: VehicleParams, gains: LateralGains, speed_mps: float) -> np.ndarray:
    """Eigenvalues of error dynamics + feedback (eq. 4.14) + first-order steering lag.

    Augmented state [e, e', yaw_err, yaw_err', delta]; delta' = (delta_cmd - delta)/tau.
    """
    A4, B4 = error_dynamics(params, speed_mps)
    k_e, k_th, k_w = gains.at_wheelbase(speed_mps, params.wheelbase_m)
    tau = max(params.steer_lag_s, 1e-3)
    A = np.zeros((5, 5))
    A[:4, :4] = A4
    A[:4, 4] = B4
    A[4, :4] = np.array([-k_e, 0.0, -k_th, -k_w]) / tau
    A[4, 4] = -1.0 / tau
    return np.linalg.eigvals(A)


def stability_margin(params: VehicleParams, gains: LateralGains,
                     speeds_mps: np.ndarray | list | None = None) -> tuple[float, float]:
    """(worst max real part over the speeds (negative = stable), smallest damping ratio)."""
    speeds = np.arange(5.0, 30.01, 0.5) if speeds_mps is None else np.asarray(speeds_mps, dtype=float)
    worst_re, worst_zeta = -math.inf, math.inf
    for v in speeds:
        ev = closed_loop_eigenvalues(params, gains, float(v))
        worst_re = max(worst_re, float(np.max(ev.real)))
        zeta = -ev.real / np.maximum(np.abs(ev), 1e-12)
        worst_zeta = min(worst_zeta, float(np.min(zeta)))
    return worst_re, worst_zeta
