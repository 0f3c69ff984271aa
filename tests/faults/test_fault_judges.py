"""One judge per fault kind (scenario/fault_judges.py): each kind's own criterion AND the yield verdict, on
records of what a run saw; the rig, the lockstep corridor and the process runners all call these."""

from __future__ import annotations

import pytest

from scenario.fault_judges import (
    JUDGES,
    DdmRestartSeen,
    DeliverySeen,
    Judgement,
    RouterRestartSeen,
    RsuKillSeen,
    judge_ddm_restart,
    judge_dropout,
    judge_latency,
    judge_router_restart,
    judge_rsu_kill,
    lost_commands,
)

YIELDED = {"passed": True, "status": "yielded", "reason": "out of the lane 1.2 s early", "margin_s": 1.2}
BLOCKED = {"passed": False, "status": "blocked", "reason": "in the lane when reached", "margin_s": -0.4}


def test_every_kind_has_its_own_judge():
    assert set(JUDGES) == {"latency", "dropout", "rsu_kill", "ddm_restart", "router_restart"}
    assert len(set(JUDGES.values())) == len(JUDGES)


def test_latency_is_the_yield_verdict_alone_with_its_margin():
    ok = judge_latency(YIELDED)
    assert ok.passed and ok.margin_s == 1.2 and ok.outcome(", starts +1.00 s").endswith("early, starts +1.00 s")
    late = judge_latency(BLOCKED)
    assert not late.passed and late.margin_s == -0.4
    assert not judge_latency(None).passed and "no verdict" in judge_latency(None).outcome()


def test_a_command_superseded_by_a_later_acked_one_is_not_lost():
    assert lost_commands(["a", "b", "c"], {"b"}) == ["c"]
    assert lost_commands(["a", "b"], {"b"}) == []


def test_dropout_needs_every_command_delivered_once_and_none_expired():
    good = judge_dropout(DeliverySeen(("c1", "c2"), frozenset({"c2"}), {"c1": 1, "c2": 1}), YIELDED)
    assert good.passed and good.own == "every command acked, none executed twice" and good.margin_s == 1.2
    lost = judge_dropout(DeliverySeen(("c1", "c2"), frozenset({"c1"})), YIELDED)
    assert not lost.passed and lost.details["lost_commands"] == ["c2"] and "1 command(s) lost" in lost.outcome()
    twice = judge_dropout(DeliverySeen(("c1",), frozenset({"c1"}), {"c1": 2}), YIELDED)
    assert not twice.passed and "duplicate" in twice.own
    expired = judge_dropout(DeliverySeen(("c1",), frozenset({"c1"}), expired_at_ddm=1), YIELDED)
    assert not expired.passed and "expired" in expired.own
    # delivery fine, but the EV was blocked: the row fails on the yield verdict
    assert not judge_dropout(DeliverySeen(("c1",), frozenset({"c1"})), BLOCKED).passed


def _rsu_kill(**kw) -> RsuKillSeen:
    base = dict(victim="rsu2", killed_at_s=10.0,
                ddm_health=((9.5, "ok", ()), (10.8, "degraded", ("rsu2",))), resumes_s=(20.0,), ev_passed_at_s=15.0,
                neighbours_reporting=("rsu3",), reports_from_killed=0)
    return RsuKillSeen(**{**base, **kw})


def test_rsu_kill_passes_when_named_stale_in_time_and_the_ev_kept_by_a_neighbour():
    j = judge_rsu_kill(_rsu_kill(), YIELDED, stale_limit_s=2.0)
    assert j.passed and j.details["stale_after_s"] == pytest.approx(0.8) and j.margin_s == pytest.approx(1.2)
    assert "EV kept by rsu3" in j.own


@pytest.mark.parametrize("change, words", [
    (dict(ddm_health=((10.8, "ok", ()),)), "never reported rsu2 stale"),
    (dict(ddm_health=((12.5, "degraded", ("rsu2",)),)), "stale after 2.50 s"),  # beyond the 2 s limit
    (dict(neighbours_reporting=()), "no neighbouring RSU"),
    (dict(resumes_s=(12.0,)), "resumed before the EV passed"),
    (dict(reports_from_killed=3), "still reported the EV 3 time(s)"),
])
def test_rsu_kill_fails_on_each_broken_criterion(change, words):
    j = judge_rsu_kill(_rsu_kill(**change), YIELDED, stale_limit_s=2.0)
    assert not j.passed and words in j.own


def test_rsu_kill_without_neighbour_reports_judges_what_the_runner_saw():
    j = judge_rsu_kill(_rsu_kill(neighbours_reporting=None, reports_from_killed=None), YIELDED)
    assert j.passed and "EV kept" not in j.own  # the lockstep runner does not watch the RSUs' reports


def _ddm_restart(**kw) -> DdmRestartSeen:
    base = dict(killed_at_s=10.0, active_at_kill="c1", new_commands=((12.0, "pull_over", "c9"), (18.0, "resume", "c10")),
                acks=((12.1, "c9", "accepted"),), modes=((10.5, "manoeuvre"), (11.5, "stopped"), (12.5, "manoeuvre")),
                ddm_back_at_s=11.2, ev_passed_at_s=16.0, end_s=25.0)
    return DdmRestartSeen(**{**base, **kw})


def test_ddm_restart_passes_when_the_av_keeps_its_command_and_the_ddm_comes_back():
    j = judge_ddm_restart(_ddm_restart(), YIELDED)
    assert j.passed and j.details["modes_on_its_own"] == ["manoeuvre", "stopped"]
    assert j.margin_s == pytest.approx(2.0)  # EV passed at 16, first RESUME of the restarted DDM at 18
    assert j.details["ddm_heard_again_after_s"] == pytest.approx(1.2)


def test_ddm_restart_fails_on_driving_on_alone_an_early_resume_or_no_ddm():
    alone = judge_ddm_restart(_ddm_restart(modes=((10.5, "driving"),)), YIELDED)
    assert not alone.passed and "driving" in alone.own
    early = judge_ddm_restart(_ddm_restart(new_commands=((14.0, "resume", "c9"),)), YIELDED)
    assert not early.passed and "resume before the EV passed" in early.own
    assert not judge_ddm_restart(_ddm_restart(ddm_back_at_s=None), YIELDED).passed


def test_ddm_restart_driving_on_is_fine_once_the_command_was_completed():
    done = _ddm_restart(modes=((10.5, "driving"),), acks=((10.4, "c1", "completed"),))
    assert judge_ddm_restart(done, YIELDED).passed


def test_router_restart_needs_every_service_back_in_time_and_a_command_accepted():
    ok = judge_router_restart(RouterRestartSeen({"ddm": 1.5, "rsu1": 3.0}, True), YIELDED, reconnect_limit_s=10.0)
    assert ok.passed and ok.margin_s == pytest.approx(7.0)
    assert "rsu1" in judge_router_restart(RouterRestartSeen({"ddm": 1.5, "rsu1": None}, True), YIELDED).own
    assert not judge_router_restart(RouterRestartSeen({"ddm": 11.0}, True), YIELDED, reconnect_limit_s=10.0).passed
    assert not judge_router_restart(RouterRestartSeen({"ddm": 1.0}, False), YIELDED).passed


def test_a_row_passes_only_on_its_own_criterion_and_the_yield_verdict():
    fine = Judgement(True, "fine", None, {}, YIELDED)
    assert fine.passed and fine.outcome() == "fine; yield yielded: out of the lane 1.2 s early"
    assert not Judgement(True, "fine", None, {}, BLOCKED).passed
    assert not Judgement(False, "broken", None, {}, YIELDED).passed
    row = judge_latency(YIELDED).row("latency 0 ms", "latency", "rig", {"seed": 3})
    assert row.passed and row.verdict == "PASS" and row.details == {"seed": 3} and row.margin_s == 1.2
