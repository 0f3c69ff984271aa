"""Localisation: position fixes with noise and latency, and a pose estimator that copes with both.

Sources (``FixSourceConfig``): the car's own low-grade GNSS (default: sigma 0.2 m, 10 Hz, 100 ms
latency) or the RSU's track of the car (``RSU_TRACK``: sigma 0.3 m, 15 Hz, 200 ms latency). A fix is
(measurement time, x, y) and arrives ``latency_s`` later.

``PoseEstimator`` is an extended Kalman filter on (x, y, yaw, gyro bias, wheel-speed scale) driven by the car's odometry (wheel
speed and yaw-rate gyro, dead reckoning at the control rate). A fix stamped in the past is applied
at its measurement time in a short history of states and the odometry since then is replayed, so
the estimate is the delayed fix propagated to now with the vehicle's own speed and yaw rate.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class FixSourceConfig:
    name: str = "gnss"
    sigma_m: float = 0.2
    rate_hz: float = 10.0
    latency_s: float = 0.1
    dropout_prob: float = 0.0

    def __post_init__(self) -> None:
        if self.sigma_m < 0 or not self.rate_hz > 0 or self.latency_s < 0 or not 0 <= self.dropout_prob < 1:
            raise ValueError(f"invalid fix source {self}")


GNSS = FixSourceConfig()
RSU_TRACK = FixSourceConfig(name="rsu", sigma_m=0.3, rate_hz=15.0, latency_s=0.2, dropout_prob=0.05)


@dataclass(frozen=True, slots=True)
class Fix:
    measured_at_s: float
    x_m: float
    y_m: float
    sigma_m: float


def lateral_error_floor_m(speed_mps: float, fix: FixSourceConfig = GNSS, gyro_sigma_rps: float = 0.002,
                          dt_s: float = 0.01) -> float:
    """Steady standard deviation of the lateral position of ANY estimate from these fixes and a gyro.

    Dead reckoning integrates the gyro's white noise (``gyro_sigma_rps`` per sample every ``dt_s``)
    into a heading random walk of density q_psi = gyro_sigma^2 dt, so across the path the position
    is a double integrator driven by white noise of density v^2 q_psi; the fixes measure it with
    density r = sigma^2 / rate. The Kalman steady state of that model is
    P_yy = sqrt(2) (v^2 q_psi)^(1/4) r^(3/4): 0.034 m at 13.4 m/s and 0.040 m at 25 m/s for the
    default GNSS (sigma 0.2 m, 10 Hz). No controller can hold the TRUE lateral error below this,
    because it only sees the estimate.
    """
    q = speed_mps ** 2 * gyro_sigma_rps ** 2 * dt_s
    r = fix.sigma_m ** 2 / fix.rate_hz
    return math.sqrt(math.sqrt(2.0) * q ** 0.25 * r ** 0.75)


class SimulatedFixSource:
    """Samples the true position at ``rate_hz``, adds Gaussian noise, delivers after ``latency_s``."""

    def __init__(self, config: FixSourceConfig = GNSS, seed: int = 0) -> None:
        self.config = config
        self._rng = np.random.default_rng(seed)
        self._next_sample_s: float | None = None
        self._in_flight: deque[tuple[float, Fix]] = deque()

    def step(self, now_s: float, true_x_m: float, true_y_m: float) -> list[Fix]:
        """Call once per control step with the truth; returns the fixes that arrive by ``now_s``."""
        c = self.config
        if self._next_sample_s is None:
            self._next_sample_s = now_s
        if now_s + 1e-9 >= self._next_sample_s:
            self._next_sample_s += 1.0 / c.rate_hz
            if c.dropout_prob == 0 or self._rng.random() >= c.dropout_prob:
                nx, ny = self._rng.normal(0.0, c.sigma_m, 2) if c.sigma_m > 0 else (0.0, 0.0)
                fix = Fix(now_s, true_x_m + float(nx), true_y_m + float(ny), max(c.sigma_m, 0.01))
                self._in_flight.append((now_s + c.latency_s, fix))
        out = []
        while self._in_flight and self._in_flight[0][0] <= now_s + 1e-9:
            out.append(self._in_flight.popleft()[1])
        return out


@dataclass(frozen=True)
class OdometryNoise:
    """Errors of the car's own sensors that the estimator dead-reckons with."""

    speed_sigma_mps: float = 0.02
    speed_scale_error: float = 0.003
    gyro_sigma_rps: float = 0.002
    gyro_bias_rps: float = 0.0005


class Odometry:
    def __init__(self, noise: OdometryNoise = OdometryNoise(), seed: int = 0) -> None:
        self.noise = noise
        self._rng = np.random.default_rng(seed + 7919)

    def measure(self, speed_mps: float, yaw_rate_rps: float) -> tuple[float, float]:
        n = self.noise
        v = speed_mps * (1.0 + n.speed_scale_error) + (self._rng.normal(0.0, n.speed_sigma_mps) if speed_mps > 0 else 0.0)
        w = yaw_rate_rps + n.gyro_bias_rps + self._rng.normal(0.0, n.gyro_sigma_rps)
        return max(0.0, v), w


class PoseEstimator:
    """EKF on (x, y, yaw, gyro bias, speed scale): odometry prediction at the control rate, delayed position updates."""

    def __init__(self, history_s: float = 1.5, speed_sigma_mps: float = 0.05, gyro_sigma_rps: float = 0.002,
                 heading_walk_rps: float = 0.0, position_walk_mps: float = 0.01,
                 bias_walk_rps2: float = 2e-6, bias_sigma_rps: float = 0.002,
                 scale_sigma: float = 0.01, scale_walk: float = 1e-5) -> None:
        """Noise model: ``speed_sigma_mps`` / ``gyro_sigma_rps`` are per-step odometry noise, the walks are
        random-walk densities (per sqrt(s)) of position (slip, scale error), heading and gyro bias."""
        self.x = np.zeros(5)
        """x, y, yaw, gyro bias (rad/s, subtracted), wheel-speed scale error (v = v_odo (1 + k))."""
        self.P = np.diag([100.0, 100.0, 1.0, bias_sigma_rps ** 2, scale_sigma ** 2])
        self.initialised = False
        self.time_s = 0.0
        self.last_fix_s: float | None = None
        """Measurement time of the newest fix used."""
        self.history_s = history_s
        self._q_v, self._q_w = speed_sigma_mps ** 2, gyro_sigma_rps ** 2 + heading_walk_rps ** 2
        self._q_p, self._q_b = position_walk_mps ** 2, bias_walk_rps2 ** 2
        self._bias_sigma, self._scale_sigma, self._q_k = bias_sigma_rps, scale_sigma, scale_walk ** 2
        # (time after the step, dt, v, w, v_y, state after, P after)
        self._hist: deque[tuple[float, float, float, float, float, np.ndarray, np.ndarray]] = deque()
        self.rejected_fixes = 0
        self._consecutive_rejects = 0
        self._pending: list[Fix] = []

    def initialise(self, now_s: float, x_m: float, y_m: float, yaw_rad: float,
                   pos_sigma_m: float = 0.5, yaw_sigma_rad: float = 0.05) -> None:
        self.x = np.array([x_m, y_m, yaw_rad, 0.0, 0.0], dtype=float)
        self.P = np.diag([pos_sigma_m ** 2, pos_sigma_m ** 2, yaw_sigma_rad ** 2, self._bias_sigma ** 2,
                          self._scale_sigma ** 2])
        self.time_s = now_s
        self.initialised = True
        self._hist.clear()
        self._pending.clear()
        self._hist.append((now_s, 0.0, 0.0, 0.0, 0.0, self.x.copy(), self.P.copy()))

    def _predict(self, x: np.ndarray, P: np.ndarray, dt: float, v: float, w: float,
                 vy: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        rate = w - x[3]
        vm = v
        v = vm * (1.0 + x[4])
        yaw = x[2] + 0.5 * rate * dt  # midpoint heading
        c, s = math.cos(yaw), math.sin(yaw)
        dx, dy = (v * c - vy * s) * dt, (v * s + vy * c) * dt
        xn = np.array([x[0] + dx, x[1] + dy, x[2] + rate * dt, x[3], x[4]])
        F = np.array([[1.0, 0.0, -dy, 0.5 * dy * dt, vm * c * dt],
                      [0.0, 1.0, dx, -0.5 * dx * dt, vm * s * dt],
                      [0.0, 0.0, 1.0, -dt, 0.0],
                      [0.0, 0.0, 0.0, 1.0, 0.0],
                      [0.0, 0.0, 0.0, 0.0, 1.0]])
        G = np.array([[c * dt, 0.0], [s * dt, 0.0], [0.0, dt], [0.0, 0.0], [0.0, 0.0]])
        Q = G @ np.diag([self._q_v, self._q_w]) @ G.T \
            + np.diag([self._q_p, self._q_p, 0.0, self._q_b, self._q_k]) * dt
        return xn, F @ P @ F.T + Q

    def predict(self, now_s: float, speed_mps: float, yaw_rate_rps: float, lateral_speed_mps: float = 0.0) -> None:
        """Dead-reckon from the last call to ``now_s`` with the odometry.

        ``lateral_speed_mps``: the car's model of its body-frame v_y (sideslip when cornering), so
        that the estimated yaw stays the heading of the body and not the direction of travel.
        """
        if not self.initialised:
            self.time_s = now_s
            return
        dt = now_s - self.time_s
        if dt < 0:
            raise ValueError(f"time went backwards: {now_s} < {self.time_s}")
        if dt > 0:
            self.x, self.P = self._predict(self.x, self.P, dt, speed_mps, yaw_rate_rps, lateral_speed_mps)
        self.time_s = now_s
        self._hist.append((now_s, dt, speed_mps, yaw_rate_rps, lateral_speed_mps, self.x.copy(), self.P.copy()))
        while self._hist and self._hist[0][0] < now_s - self.history_s:
            self._hist.popleft()
        if self._pending:
            due = [f for f in self._pending if f.measured_at_s <= now_s + 1e-9]
            self._pending = [f for f in self._pending if f.measured_at_s > now_s + 1e-9]
            for f in due:
                self.update(f)

    def update(self, fix: Fix, gate_sigma: float = 5.0) -> bool:
        """Apply a (possibly delayed) fix; returns False when it is too old or fails the gate."""
        if not self.initialised:
            return False
        if fix.measured_at_s > self.time_s + 1e-9:
            # measured after the newest state (e.g. no latency, fix before this step's odometry):
            # applied by the predict() that reaches its time
            self._pending.append(fix)
            return True
        hist = self._hist
        k = None
        for i in range(len(hist) - 1, -1, -1):
            if hist[i][0] <= fix.measured_at_s + 1e-9:
                k = i
                break
        if k is None:
            self.rejected_fixes += 1
            return False
        xk, Pk = hist[k][5], hist[k][6]
        R = np.eye(2) * fix.sigma_m ** 2
        innov = np.array([fix.x_m - xk[0], fix.y_m - xk[1]])
        S = Pk[:2, :2] + R
        Sinv = np.linalg.inv(S)
        if float(innov @ Sinv @ innov) > gate_sigma ** 2 and self._consecutive_rejects < 5:
            # an outlier; but 5 in a row mean the estimate, not the fixes, is wrong: take them
            self.rejected_fixes += 1
            self._consecutive_rejects += 1
            return False
        if self._consecutive_rejects >= 5:
            Pk = Pk.copy()
            Pk[:2, :2] += np.eye(2) * float(innov @ innov)
            S = Pk[:2, :2] + R
            Sinv = np.linalg.inv(S)
        self._consecutive_rejects = 0
        K = Pk[:, :2] @ Sinv
        x = xk + K @ innov
        P = (np.eye(5) - K @ np.eye(2, 5)) @ Pk
        new_hist = list(hist)[: k]
        new_hist.append((*hist[k][:5], x.copy(), P.copy()))
        for j in range(k + 1, len(hist)):
            tj, dt, v, w, vy, _, _ = hist[j]
            x, P = self._predict(x, P, dt, v, w, vy)
            new_hist.append((tj, dt, v, w, vy, x.copy(), P.copy()))
        self._hist = deque(new_hist)
        self.x, self.P = x, P
        self.last_fix_s = fix.measured_at_s if self.last_fix_s is None else max(self.last_fix_s, fix.measured_at_s)
        return True

    @property
    def pose(self) -> tuple[float, float, float]:
        return float(self.x[0]), float(self.x[1]), math.remainder(float(self.x[2]), 2.0 * math.pi)

    def age_s(self, now_s: float) -> float:
        """Time since the newest fix was measured (inf before the first)."""
        return math.inf if self.last_fix_s is None else max(0.0, now_s - self.last_fix_s)
