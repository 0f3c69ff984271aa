"""The one yield judge (scenario/outcome.py): pass only out of the EV's lane before the EV is within
its following distance; stopped in the lane, blocked, never reached and collisions fail."""

from __future__ import annotations

import math

import pytest

from scenario.outcome import Body, YieldParams, YieldTrace, judge_run, judge_yield

AV = (5.0, 2.0)  # length, width
EV = (6.5, 2.4)
LANE1 = 5.55  # lane 1 centre (3.7 m lanes)


def _run(av_path, ev_speed=18.0, dt=0.1, steps=80, ev_s0=0.0, ev_d=lambda t, s: LANE1, lights_at=1.0,
         collision=False):
    """av_path(t) -> (s, d, speed); the EV starts at ev_s0 in lane 1; lights on at ``lights_at``."""
    tr = YieldTrace()
    for i in range(steps):
        t = i * dt
        s, d, v = av_path(t)
        es = ev_s0 + ev_speed * t
        tr.add(t, Body(s, d, *AV, v), Body(es, ev_d(t, es), *EV, ev_speed), t >= lights_at)
    return tr.verdict(collision=collision)


def cruise(d_of_t):
    return lambda t: (40.0 + 13.0 * t, d_of_t(t), 13.0)


def test_out_of_the_lane_in_time_passes_with_margin_and_ev_delay():
    v = _run(cruise(lambda t: LANE1 if t < 1.0 else max(1.0, LANE1 - 2.0 * (t - 1.0))))
    assert v.passed and v.status == "yielded" and v.margin_s > 0
    # the body (2 m wide) is out of lane 1 ([3.7, 7.4]) once d <= 2.7: at t = 1 + 2.85 / 2 = 2.43 s
    assert v.lane_clear_s == pytest.approx(2.5, abs=0.11)
    assert v.ev_lane_d_m == (3.7, 7.4) and v.ev_delay_s == pytest.approx(0.0)


def test_staying_in_lane_blocks_the_ev_and_says_how_late():
    v = _run(cruise(lambda t: LANE1 if t < 9.0 else 1.0), steps=120)
    assert not v.passed and v.status == "blocked" and v.margin_s is not None and v.margin_s < 0


def test_stopped_in_the_evs_lane_fails():
    def braking(t):  # 6.5 m/s^2 from 13 m/s: stopped at t = 2 s at s = 53 m
        tb = min(t, 2.0)
        return 40.0 + 13.0 * tb - 3.25 * tb * tb, LANE1, max(0.0, 13.0 - 6.5 * t)

    v = _run(braking, ev_s0=-40.0)
    assert not v.passed and v.status == "stopped_in_ev_lane"


def test_never_reached_is_not_a_pass():
    v = _run(cruise(lambda t: LANE1), ev_speed=13.0, ev_s0=-40.0)  # same speed: it never closes in
    assert not v.passed and v.status == "not_reached" and "re-time" in v.reason


def test_an_ev_that_goes_round_the_av_does_not_move_its_lane():
    """The EV swerves to lane 0 to get past an AV that never moved: the AV blocked it (a judge that
    recomputed the EV's lane per snapshot would call the AV 'out of the EV's lane')."""
    def ev_d(t, s):
        return LANE1 if t < 3.0 else 1.85  # lane 0 from 3 s, after it had reached the AV

    v = _run(cruise(lambda t: LANE1), ev_d=ev_d, steps=120)
    assert not v.passed and v.status == "blocked" and v.ev_lane_d_m == (3.7, 7.4)


def test_moving_back_before_the_ev_passed_fails():
    v = _run(cruise(lambda t: LANE1 if t < 1.0 else (1.0 if t < 3.5 else LANE1)), steps=120)
    assert not v.passed and v.status == "blocked" and "moved back" in v.reason


def test_collision_fails_and_ev_delay_counts_the_time_the_ev_lost():
    assert _run(cruise(lambda t: 1.0), collision=True).status == "collision"
    tr = YieldTrace()
    for i in range(100):  # the EV at 18 m/s, then 9 m/s for 2 s: 1 s lost
        t = i * 0.1
        v_ev = 9.0 if 2.0 <= t < 4.0 else 18.0
        tr.add(t, Body(1000.0, LANE1, *AV, 13.0), Body(0.0, LANE1, *EV, v_ev), True)
    assert tr.verdict().ev_delay_s == pytest.approx(1.0, abs=0.01)


def test_heading_turns_the_body_across_the_lane():
    straight = Body(0.0, 2.6, *AV, 10.0)
    turned = Body(0.0, 2.6, *AV, 10.0, heading_error_rad=math.radians(10))
    v1 = judge_yield([], YieldParams())
    assert v1.status == "no_lights"
    from scenario.outcome import out_of_strip

    assert out_of_strip(straight, (3.7, 7.4)) and not out_of_strip(turned, (3.7, 7.4))


def test_scenario_verdict_takes_the_yield_verdict():
    m = {"collision": False, "commands": [{"manoeuvre": "pull_over"}], "yield": {"passed": False,
         "status": "stopped_in_ev_lane", "reason": "stopped in the EV's lane"}, "stop_position_m": (1, 5), "stop_lane": 1}
    ok, why = judge_run(m, ev_lights_on=True)
    assert not ok and why.startswith("stopped_in_ev_lane")
    assert judge_run({**m, "yield": {"passed": True, "status": "yielded", "reason": "x"}}, ev_lights_on=True)[0]
    assert not judge_run({k: v for k, v in m.items() if k != "yield"}, ev_lights_on=True)[0]


def test_a_lane_the_ev_was_leaving_at_lights_on_is_not_its_lane():
    """Seed 3 of the corridor: the EV finishes its move into lane 1 as its lights go on (its body still over
    the line into lane 0); the AV that moved to lane 0 well before the EV reached it yielded."""
    def ev_d(t, s):
        return 4.2 + min(t, 1.0) * 1.35  # from d 4.2 (body over the line) to the lane-1 centre 5.55 by t = 1 s

    v = _run(cruise(lambda t: LANE1 if t < 0.5 else max(1.25, LANE1 - 3.0 * (t - 0.5))), ev_d=ev_d, lights_at=0.0)
    assert v.passed and v.status == "yielded" and v.ev_lane_d_m == (3.7, 7.4)
