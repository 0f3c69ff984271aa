"""The field test in lockstep (report Figs. 12-16) and the fail-safe stop."""

import time
from dataclasses import replace

import numpy as np
import pytest

from protocol.enums import AckStatus, VehicleMode
from vehicle.failsafe import FailsafeConfig
from vehicle.lockstep import field_test_scenario, run_scenario


def check_field_test(m):
    assert m["completed"] and m["stopped"]
    assert m["max_lateral_error_m"] <= 0.25  # the field test had 0.55 m
    assert m["settled_lateral_error_m"] <= 0.05  # RMS after settling (field: ~0.10 m)
    assert m["max_yaw_error_rad"] <= 0.05
    assert m["stop_error_m"] <= 1.0
    assert m["max_decel_mps2"] <= 3.0


@pytest.mark.serial  # it times itself
def test_field_test_13_4_mps_reproduced():
    t0 = time.perf_counter()
    r = run_scenario(field_test_scenario(13.4, sigma_m=0.2, latency_s=0.1, rate_hz=10.0))
    elapsed = time.perf_counter() - t0
    m = r.metrics
    check_field_test(m)
    assert [a.status for a in r.acks] == [AckStatus.ACCEPTED, AckStatus.COMPLETED]
    # it really changed lane: ends in lane 0 (3.7 m right of where it started)
    c = r.record.columns()
    assert c["y_m"][0] == pytest.approx(5.55, abs=0.01) and abs(c["y_m"][-1] - 1.85) < 0.15
    assert elapsed < 5.0, f"a {m['duration_s']:.0f} s scenario took {elapsed:.1f} s"


@pytest.mark.parametrize("speed, radius", [(25.0, None), (13.4, 200.0), (25.0, 200.0)])
def test_field_test_at_speed_and_on_a_curve(speed, radius):
    m = run_scenario(field_test_scenario(speed, radius_m=radius)).metrics
    assert m["completed"] and m["stopped"]
    assert m["max_lateral_error_m"] <= 0.25
    assert m["max_yaw_error_rad"] <= 0.05
    assert m["stop_error_m"] <= 1.0
    assert m["settled_lateral_error_m"] <= 0.05  # RMS after settling, as in the reference case


@pytest.mark.parametrize("speed, radius", [(13.4, None), (25.0, None), (13.4, 200.0), (25.0, 200.0)])
def test_settled_error_max_without_gnss_noise(speed, radius):
    """The controller's own share of the settled error, read as a MAX over the window (sigma = 0,
    latency 100 ms): <= 0.05 m everywhere. With sigma 0.2 m the estimate itself wanders by ~0.04 m
    (1 sigma, the EKF's floor with this gyro and GNSS; see bench/control_bench.py), which no
    controller can see, so the max reading there is the estimator's, not the controller's."""
    m = run_scenario(field_test_scenario(speed, sigma_m=0.0, latency_s=0.1, radius_m=radius)).metrics
    assert m["completed"] and m["stopped"]
    assert m["settled_lateral_max_m"] <= 0.05
    assert m["settled_lateral_error_m"] <= 0.02
    assert m["max_lateral_error_m"] <= 0.25 and m["max_yaw_error_rad"] <= 0.05 and m["stop_error_m"] <= 1.0


def test_braking_in_the_bend_without_the_acceleration_feedforward_settles_off_the_path():
    # the check above is not vacuous: with eq. 4.13 at constant speed the car brakes through the
    # bend 3-7 cm off the path (noise-free)
    def constant_speed_feedforward(sim, now):
        sim.core.lateral.accel_feedforward = False

    m = run_scenario(field_test_scenario(25.0, sigma_m=0.0, latency_s=0.1, radius_m=200.0),
                     constant_speed_feedforward).metrics
    assert m["settled_lateral_max_m"] > 0.05 and m["settled_lateral_error_m"] > 0.025


def test_many_seeds_stay_stable():
    for seed in range(1, 4):
        m = run_scenario(field_test_scenario(13.4, seed=seed)).metrics
        assert m["max_lateral_error_m"] <= 0.25 and m["stop_error_m"] <= 1.0 and m["completed"]


def test_rsu_track_localisation_with_more_latency():
    m = run_scenario(field_test_scenario(13.4, sigma_m=0.3, latency_s=0.2, rate_hz=15.0, source="rsu",
                                         dropout_prob=0.05)).metrics
    assert m["completed"] and m["max_lateral_error_m"] <= 0.25 and m["stop_error_m"] <= 1.0


def test_failsafe_stop_when_the_ddm_goes_silent():
    sc = field_test_scenario(13.4)
    sc = replace(sc, ddm_silent_from_s=sc.command_at_s - 0.5)  # silent from just before the command
    r = run_scenario(sc)
    c = r.record.columns()
    core = r.sim.core
    assert core.mode == VehicleMode.MINIMAL_RISK and "link lost" in core.watchdog.reason
    assert core.watchdog.triggered_at_s == pytest.approx(sc.command_at_s + FailsafeConfig().link_timeout_s, abs=0.05)
    assert [a.status for a in r.acks] == [AckStatus.ACCEPTED, AckStatus.REJECTED]
    assert r.acks[1].reason.startswith("aborted: link lost")
    assert c["speed_mps"][-1] < 0.01  # stopped
    assert -c["accel_mps2"].min() <= 3.0  # controlled, not an emergency stop
    # stopped at the curb: on the shoulder (2.5 m wide: its middle, d = -1.25 m), out of every lane
    y_end = c["y_m"][-1]
    assert abs(y_end - core.curb_offset_m()) < 0.3 and core.curb_offset_m() == pytest.approx(-1.25)
    assert "at the curb" in core.detail


def test_failsafe_stop_when_localisation_goes_stale():
    sc = replace(field_test_scenario(13.4), make_command=None, duration_s=18.0, fix_outage=(4.0, 99.0))
    r = run_scenario(sc)
    core = r.sim.core
    assert core.mode == VehicleMode.MINIMAL_RISK and "localisation stale" in core.watchdog.reason
    assert 4.75 <= core.watchdog.triggered_at_s <= 5.05  # newest fix measured at ~3.8 s, stale after 1 s
    c = r.record.columns()
    assert c["speed_mps"][-1] < 0.01 and -c["accel_mps2"].min() <= 3.0
    # dead reckoning steers it to the curb (2 lanes and a half to the right) within 0.5 m of the path
    assert np.abs(c["lateral_error_m"]).max() < 0.5
    assert abs(c["y_m"][-1] - core.curb_offset_m()) < 0.5


def test_no_failsafe_in_normal_driving():
    sc = replace(field_test_scenario(13.4), make_command=None, duration_s=12.0)  # the DDM's heartbeat at 1 Hz
    r = run_scenario(sc)
    assert r.sim.core.mode == VehicleMode.DRIVING and r.sim.core.watchdog.reason is None
    assert abs(r.record.columns()["speed_mps"][-1] - 13.4) < 0.2


def test_cruising_without_a_ddm_heartbeat_degrades_then_stops_at_the_curb():
    """The link watchdog runs while cruising too. 3.5 s without a DDM heartbeat: degraded (speed
    capped at 8 m/s, said in the VehicleState detail); 10 s: minimal-risk stop at the curb."""
    fs = FailsafeConfig()
    sc = replace(field_test_scenario(13.4), make_command=None, duration_s=25.0, ddm_silent_from_s=2.0)
    seen: dict[str, float] = {}

    def watch(sim, now):
        core = sim.core
        if core.detail.startswith("degraded:"):
            seen.setdefault("degraded", now)
        if core.mode == VehicleMode.MINIMAL_RISK:
            seen.setdefault("mrm", now)
            seen.setdefault("speed_at_mrm", sim.truth.vx_mps)

    r = run_scenario(replace(sc, stop_when_done=False), on_step=watch)
    core = r.sim.core
    # the last beat was at t = 2 s (beats at 0, 1, 2 s; silent from 2 s, so the 2 s beat is not heard: 1 s)
    assert seen["degraded"] == pytest.approx(1.0 + fs.link_timeout_s, abs=0.05)
    assert seen["mrm"] == pytest.approx(1.0 + fs.link_lost_s, abs=0.05)
    assert seen["speed_at_mrm"] <= fs.degraded_speed_mps + 0.3  # capped while degraded
    assert core.mode == VehicleMode.MINIMAL_RISK and "while cruising" in core.watchdog.reason
    c = r.record.columns()
    assert c["speed_mps"][-1] < 0.01 and abs(c["y_m"][-1] - core.curb_offset_m()) < 0.3


def test_degraded_ends_when_the_ddm_is_heard_again():
    sc = replace(field_test_scenario(13.4), make_command=None, duration_s=8.0, ddm_silent_from_s=0.5)
    r = run_scenario(sc, on_step=lambda sim, now: sim.core.on_link(now) if abs(now - 6.0) < 1e-6 else None)
    core = r.sim.core
    assert core.mode == VehicleMode.DRIVING and core.watchdog.degraded is None
    assert not core.detail.startswith("degraded")


def test_minimal_risk_stop_stays_in_lane_when_the_picture_shows_the_curb_side_occupied():
    """A car keeps pace in lane 0 beside the AV (lane 1): the fail-safe stop must not steer into it."""
    sc = replace(field_test_scenario(13.4), make_command=None, duration_s=25.0, ddm_silent_from_s=2.0,
                 stop_when_done=False)

    def beside(sim, now):
        st = sim.truth
        sim.core.on_picture(now, [(st.x_m, st.y_m, 4.9, 1.9), (st.x_m + 2.0, 1.85, 4.5, 1.8)])

    r = run_scenario(sc, on_step=beside)
    core = r.sim.core
    assert core.mode == VehicleMode.MINIMAL_RISK and "curb side is occupied" in core.detail
    assert abs(r.record.columns()["y_m"][-1] - 5.55) < 0.3  # stopped in its own lane
    # with the same car well ahead (beyond the stop point) the curb is free
    r = run_scenario(sc, on_step=lambda sim, now: sim.core.on_picture(now, [(sim.truth.x_m + 200.0, 1.85, 4.5, 1.8)]))
    assert "at the curb" in r.sim.core.detail and abs(r.record.columns()["y_m"][-1] - r.sim.core.curb_offset_m()) < 0.3
