"""Lateral controller (eqs. 4.13-4.15), its stability margin, the plant and the longitudinal controller."""

import math

import numpy as np
import pytest

from vehicle.lateral import LateralController, LateralGains, closed_loop_eigenvalues, stability_margin
from vehicle.longitudinal import LongitudinalController
from vehicle.plant import BicyclePlant, VehicleParams, VehicleStateVec
from vehicle.reference import ReferencePath


def test_gain_schedule_is_stable_with_margin_from_5_to_30_mps():
    params, gains = VehicleParams(), LateralGains()
    for v in np.arange(5.0, 30.01, 0.5):
        ev = closed_loop_eigenvalues(params, gains, float(v))
        assert np.all(ev.real < -0.5), (v, ev)  # every mode decays faster than e^{-0.5 t}
        assert np.all(-ev.real / np.abs(ev) > 0.5), (v, ev)  # and is well damped
    worst_re, worst_zeta = stability_margin(params, gains)
    assert worst_re < -0.5 and worst_zeta > 0.5


def test_unstable_gains_are_detected():
    # the check is not vacuous: a negative heading gain must show an unstable eigenvalue
    assert np.max(closed_loop_eigenvalues(VehicleParams(), LateralGains(zeta=-0.5), 13.4).real) > 0


def test_feedforward_is_eq_4_13():
    p = VehicleParams(cg_to_front_m=1.2, cg_to_rear_m=1.6, cornering_front_npr=120_000.0)
    lat = LateralController(p, sideslip_compensation=False, preview_s=0.0)
    r = 100.0
    a = np.linspace(-math.pi / 2 - 0.2, -math.pi / 2 + 0.4, 200)
    path = ReferencePath(np.column_stack([r * np.cos(a), r + r * np.sin(a)]))
    out = lat.step(path, 0.0, 0.0, 0.0, 15.0, 15.0 / r, 0.01)
    L = p.wheelbase_m
    expected = L / r + p.mass_kg / L * (p.cg_to_rear_m / p.cornering_front_npr
                                        - p.cg_to_front_m / p.cornering_rear_npr) * 15.0 ** 2 / r
    assert out.steer_ff_rad == pytest.approx(expected, rel=1e-3)
    assert abs(out.lateral_error_m) < 1e-3 and abs(out.steer_fb_rad) < 1e-3


def test_feedback_sign_and_limits():
    path = ReferencePath(np.array([[0.0, 0.0], [200.0, 0.0]]))
    lat = LateralController(preview_s=0.0)
    out = lat.step(path, 50.0, 0.5, 0.0, 13.4, 0.0, 0.01)  # 0.5 m left of an eastbound path
    assert out.lateral_error_m == pytest.approx(0.5) and out.steer_fb_rad < 0  # steer right
    assert abs(out.steer_cmd_rad) <= 0.53 * 0.01 + 1e-12  # rate limited from zero
    for _ in range(500):
        out = lat.step(path, 50.0, 30.0, 0.0, 5.0, 0.0, 0.01)  # absurd error: angle limit holds
    assert out.steer_cmd_rad == pytest.approx(-VehicleParams().max_steer_rad)


def test_plant_steady_cornering_matches_bicycle_theory():
    p = VehicleParams(cg_to_front_m=1.2, cg_to_rear_m=1.6)  # understeering car
    plant = BicyclePlant(p, VehicleStateVec(vx_mps=20.0))
    delta = 0.02
    for _ in range(1000):
        plant.step(0.01, delta, 0.0)
    k_us = p.understeer_gradient
    assert plant.state.yaw_rate_rps == pytest.approx(20.0 * delta / (p.wheelbase_m + k_us * 400.0), rel=1e-3)
    assert plant.state.steer_rad == pytest.approx(delta)


def test_plant_rate_limit_no_reverse_and_low_speed_fallback():
    p = VehicleParams()
    plant = BicyclePlant(p, VehicleStateVec(vx_mps=0.3))
    plant.step(0.1, 0.4, 0.0)
    assert plant.state.steer_rad == pytest.approx(0.053, abs=1e-6)  # 0.53 rad/s road wheel
    for _ in range(300):
        plant.step(0.01, 0.4, -5.0)
    assert plant.state.vx_mps == 0.0 and math.isfinite(plant.state.yaw_rate_rps)
    slow = BicyclePlant(p, VehicleStateVec(vx_mps=0.5, steer_rad=0.3))
    for _ in range(200):
        slow.step(0.01, 0.3, 0.0)
    # kinematic bicycle at walking pace: r = v tan(delta) / L, no blow-up from dividing by v_x
    assert slow.state.yaw_rate_rps == pytest.approx(0.5 * math.tan(0.3) / p.wheelbase_m, rel=1e-6)


def test_longitudinal_comfortable_stop_at_point():
    ctl, plant = LongitudinalController(), BicyclePlant(VehicleParams(), VehicleStateVec(vx_mps=13.4))
    stop_x = 80.0
    decels = []
    for _ in range(3000):
        st = plant.state
        out = ctl.step(st.vx_mps, 13.4, stop_x - st.x_m)
        plant.step(0.01, 0.0, out.accel_cmd_mps2)
        decels.append(-plant.state.accel_mps2)
        assert not out.emergency
    assert plant.state.vx_mps < 0.01
    assert abs(plant.state.x_m - stop_x) < 1.0
    assert max(decels) <= 3.0 + 1e-9


def test_longitudinal_emergency_when_comfort_is_not_enough():
    out = LongitudinalController().step(20.0, 20.0, 30.0)  # needs 6.7 m/s^2
    assert out.emergency and out.accel_cmd_mps2 < -3.0
    calm = LongitudinalController().step(13.4, 13.4, None)
    assert not calm.emergency and calm.accel_cmd_mps2 == pytest.approx(0.0)


def test_cornering_steer_is_eq_4_13_and_steady_sideslip_at_constant_speed():
    p = VehicleParams(cg_to_front_m=1.2, cg_to_rear_m=1.6, cornering_front_npr=120_000.0)
    for v in (5.0, 15.0, 25.0):
        delta, beta = p.cornering_steer(0.005, v)
        assert delta == pytest.approx(p.wheelbase_m * 0.005 + p.understeer_gradient * v * v * 0.005, rel=1e-9)
        assert beta == pytest.approx(p.steady_sideslip_rad(0.005, v), rel=1e-9)
    # walking pace: the kinematic bicycle of the plant
    assert p.cornering_steer(0.1, 1.0) == pytest.approx((math.atan(p.wheelbase_m * 0.1), p.cg_to_rear_m * 0.1))


@pytest.mark.parametrize("with_accel, max_dev_m", [(True, 0.03), (False, None)])
def test_braking_through_a_bend_needs_the_acceleration_term(with_accel, max_dev_m):
    """Open loop: steer by the feedforward alone while braking 25 -> 5 m/s at 2 m/s^2 on R = 200 m.

    With the acceleration term the car stays on the circle; eq. 4.13 (constant-speed) steers too much
    as the sideslip unwinds and ends up metres inside it."""
    p, kappa, v0 = VehicleParams(), 1.0 / 200.0, 25.0
    d0, b0 = p.cornering_steer(kappa, v0)
    plant = BicyclePlant(p, VehicleStateVec(x_m=0.0, y_m=-200.0, yaw_rad=-b0, vx_mps=v0, vy_mps=b0 * v0,
                                            yaw_rate_rps=v0 * kappa, steer_rad=d0, accel_mps2=-2.0))
    dev = []
    while plant.state.vx_mps > 5.0:
        st = plant.state
        delta, _ = p.cornering_steer(kappa, st.vx_mps, st.accel_mps2 if with_accel else 0.0)
        plant.step(0.01, delta, -2.0)
        dev.append(math.hypot(plant.state.x_m, plant.state.y_m) - 200.0)
    if max_dev_m is not None:
        assert max(abs(d) for d in dev) < max_dev_m
    else:
        assert dev[-1] < -1.0  # metres inside the bend
