"""YieldJudge: the outcome of an EV approach from ground-truth poses (road frame s, d)."""

from __future__ import annotations

from deploy.faults import YieldJudge

AV = (5.0, 2.0)  # length, width
EV = (6.5, 2.4)


def _run(av_path, ev_speed=18.0, dt=0.1, steps=80, ev_s0=0.0):
    """av_path(t) -> (s, d, speed); the EV starts at ev_s0 in the AV's starting lane (d = 5.55)."""
    j = YieldJudge()
    for i in range(steps):
        t = i * dt
        s, d, v = av_path(t)
        j.update(t, (s, d, *AV, v), (ev_s0 + ev_speed * t, 5.55, *EV, ev_speed), manoeuvring=t >= 1.0)
    return j


def test_out_of_lane_in_time_has_positive_margin():
    j = _run(lambda t: (40.0 + 13.0 * t, 5.55 if t < 1.0 else max(1.0, 5.55 - 2.0 * (t - 1.0)), 13.0))
    ok, outcome, margin = j.outcome()
    assert ok and outcome.startswith("out of the EV's lane") and margin > 0
    # the lane is clear when the sides are 0.2 m apart: |d - 5.55| >= 2.2 + 0.2 -> d <= 3.15 at t = 2.2 s
    assert abs(j.events["lane_clear"] - 2.2) < 0.11


def test_staying_in_lane_blocks_the_ev_and_reports_how_late():
    j = _run(lambda t: (40.0 + 13.0 * t, 5.55 if t < 9.0 else 1.0, 13.0), steps=120)
    ok, outcome, margin = j.outcome()
    assert not ok and outcome == "blocked the EV"
    assert margin is not None and margin < 0  # it left the lane only after the EV had reached it


def test_stopped_in_lane_before_the_ev_arrives_is_safe():
    def braking(t):  # 6.5 m/s^2 from 13 m/s: stopped at t = 2 s at s = 53 m
        tb = min(t, 2.0)
        return 40.0 + 13.0 * tb - 3.25 * tb * tb, 5.55, max(0.0, 13.0 - 6.5 * t)

    j = _run(braking, ev_s0=-40.0)  # the EV (18 m/s) is within 2 m + 18 m of the AV's rear at ~3.2 s
    ok, outcome, margin = j.outcome()
    assert ok and outcome == "stopped safely in lane" and margin > 0
