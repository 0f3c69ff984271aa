"""The network lab's fault rows and their judging (pure: no root, no processes)."""

from __future__ import annotations

import pytest

from deploy.netlab.schedule import (
    NET_FAULTS,
    NetFault,
    RowSeen,
    command_delay_s,
    fault_by_name,
    judge_row,
    message_figures,
    summary,
    unanswered_commands,
)
from scenario.fault_judges import FaultOutcome

YIELDED = {"status": "yielded", "passed": True, "reason": "out of the EV's lane", "margin_s": 0.5}
BLOCKED = {"status": "blocked", "passed": False, "reason": "stopped in the EV's lane", "margin_s": -1.0}


def _seen(**kw) -> RowSeen:
    base = dict(fault_at_s=100.0, restored_at_s=None, end_s=130.0,
                commands={"c1": (101.0, "pull_over"), "c2": (105.0, "resume")},
                acks=((101.2, "c1", "accepted"), (105.3, "c2", "accepted")))
    base.update(kw)
    return RowSeen(**base)


def test_the_table_has_every_row_the_lab_runs():
    names = [f.name for f in NET_FAULTS]
    assert len(names) == len(set(names)) == 13
    assert {f.action for f in NET_FAULTS} == {"loss", "cut", "cap", "hub_cut", "hub_lost"}
    assert [f.value for f in NET_FAULTS if f.action == "loss"] == [0.1, 0.3, 0.5]
    assert [f.length_s for f in NET_FAULTS if f.action == "cut" and f.target == "vehicle"] == [1.0, 3.0, 10.0]
    assert fault_by_name("segment router lost (mesh)").segments == 2
    with pytest.raises(KeyError, match="no fault row"):
        fault_by_name("nope")


def test_command_delay_counts_from_the_alert():
    cut3 = fault_by_name("vehicle link cut 3 s")  # from lights-on: the command waits what is left at the alert
    assert command_delay_s(cut3, 0.6) == pytest.approx(2.4) and command_delay_s(cut3, 4.0) == 0.0
    assert command_delay_s(NetFault("x", "dropout", "cut", "vehicle", "first_alert", length_s=2.0,
                                    fault_delay_s=2.0), 0.6) == 2.0
    assert command_delay_s(fault_by_name("DDM host cut 2 s"), 0.6) is None


def test_rows_refuse_nonsense():
    with pytest.raises(ValueError, match="fraction"):
        NetFault("x", "dropout", "loss", "vehicle", "start", value=1.5)
    with pytest.raises(ValueError, match="trigger"):
        NetFault("x", "dropout", "cut", "vehicle", "whenever")
    with pytest.raises(ValueError, match="action"):
        NetFault("x", "dropout", "melt", "vehicle", "start")


def test_message_figures_count_lost_expired_and_in_flight_commands():
    seen = _seen(commands={"c1": (101.0, "pull_over"), "c2": (110.0, "pull_over"), "c3": (129.5, "resume")},
                 acks=((101.4, "c1", "accepted"),), cmd_expired=1)
    f = message_figures(seen)
    # c2 never acked but the DDM expired one command: not lost; c3 is in flight at the end: not counted
    assert f["commands_issued"] == 2 and f["commands_unacked"] == 1 and f["commands_lost"] == 0
    assert f["ack_latency_p50_s"] == pytest.approx(0.4)
    assert message_figures(_seen(commands={"c1": (101.0, "pull_over"), "c2": (110.0, "pull_over")},
                                 acks=((101.4, "c1", "accepted"),)))["commands_lost"] == 1


def test_a_row_waits_for_commands_without_an_answer():
    issued = {"c3": 3.0, "c1": 1.0, "c2": 2.0}
    assert unanswered_commands(issued, set(), 0) == 3
    assert unanswered_commands(issued, {"c2"}, 0) == 1  # c1 answered by the later c2's ack, c3 still waits
    assert unanswered_commands(issued, {"c2"}, 1) == 0  # ... or it was expired at the DDM
    assert unanswered_commands(issued, {"c3"}, 0) == 0 and unanswered_commands({}, set(), 0) == 0


def test_recovery_is_the_slowest_cut_off_host_heard_again():
    seen = _seen(restored_at_s=103.0, victims=("vehicle", "ddm"),
                 heard={"vehicle": (99.0, 103.4, 104.0), "ddm": (102.0, 103.9)})
    f = message_figures(seen)
    assert f["recovered_after_s"] == {"vehicle": 0.4, "ddm": 0.9} and f["recovery_s"] == pytest.approx(0.9)
    assert message_figures(_seen(restored_at_s=103.0, victims=("vehicle",), heard={}))["recovery_s"] is None


def test_dropout_row_passes_only_with_every_command_acked_and_the_yield():
    row = fault_by_name("vehicle link loss 30%")
    assert judge_row(row, _seen(), YIELDED).passed
    assert not judge_row(row, _seen(), BLOCKED).passed
    lost = judge_row(row, _seen(acks=((101.2, "c1", "accepted"),)), YIELDED)
    assert not lost.passed and "lost" in lost.own


def test_rsu_cut_row_needs_stale_detection_within_the_limit():
    row = fault_by_name("RSU host cut, EV in its view")
    ok = _seen(victims=("rsu2",), commands={"c1": (101.0, "pull_over"), "c2": (113.0, "resume")}, ddm_health=((100.5, "ok", ()), (101.2, "degraded", ("rsu2",))),
               ev_reports=((99.0, "rsu2", "alert"), (102.0, "rsu3", "object")), ev_passed_at_s=112.0)
    j = judge_row(row, ok, YIELDED)
    assert j.passed and j.details["stale_after_s"] == pytest.approx(1.2)
    late = _seen(victims=("rsu2",), ddm_health=((103.5, "degraded", ("rsu2",)),),
                 ev_reports=((102.0, "rsu3", "object"),), ev_passed_at_s=112.0)
    assert not judge_row(row, late, YIELDED).passed
    assert message_figures(ok)["stale_detected_after_s"] == pytest.approx(1.2)


def test_router_row_needs_every_service_back_and_a_command_accepted_after():
    row = fault_by_name("router host cut 2 s, restored")
    seen = _seen(restored_at_s=102.0, heard={"ddm": (103.0,), "vehicle": (102.5,)},
                 acks=((104.0, "c2", "accepted"),))
    assert judge_row(row, seen, YIELDED).passed
    gone = _seen(restored_at_s=102.0, heard={"ddm": (103.0,), "vehicle": (99.0,)}, acks=((104.0, "c2", "accepted"),))
    assert "not heard again: vehicle" in judge_row(row, gone, YIELDED).own


def test_summary_counts_verdicts_losses_and_recoveries():
    rows = [FaultOutcome("a", "dropout", True, "", 0.1, "lab", {"commands_lost": 0, "recovery_s": 0.4}),
            FaultOutcome("b", "dropout", False, "", -1.0, "lab", {"commands_lost": 1}, beyond_bound="too late"),
            FaultOutcome("c", "dropout", False, "", -1.0, "lab", {})]
    s = summary(rows)
    assert (s["rows_total"], s["rows_passed"], s["rows_beyond_bound"], s["rows_failed"]) == (3, 1, 1, 1)
    assert s["commands_lost"] == 1 and s["recovery_s"] == {"a": 0.4} and s["bounds"] == {"b": "too late"}


def test_every_kind_also_fails_on_a_lost_command():
    row = fault_by_name("router host cut 2 s, restored")
    seen = _seen(restored_at_s=102.0, heard={"ddm": (103.0,), "vehicle": (102.5,)},
                 commands={"c1": (101.0, "pull_over"), "c2": (110.0, "pull_over")}, acks=((101.2, "c1", "accepted"),))
    j = judge_row(row, seen, YIELDED)
    assert not j.passed and "1 command(s) lost" in j.own
    assert judge_row(row, _seen(restored_at_s=102.0, heard={"ddm": (103.0,)}, acks=((101.2, "c1", "accepted"),
                                                                                   (110.2, "c2", "accepted"))),
                     YIELDED).passed


def test_a_row_where_no_alert_got_through_has_no_bound():
    from deploy.netlab.rows import beyond_bound

    failed = FaultOutcome("RSU uplinks capped 16 kbit/s", "dropout", False, "collision", None, "lab", {})
    assert beyond_bound(failed, fault_by_name("RSU uplinks capped 16 kbit/s"), None).verdict == "FAIL"
    passed = FaultOutcome("x", "dropout", True, "", 1.0, "lab", {})
    assert beyond_bound(passed, fault_by_name("vehicle link cut 10 s"), 0.6) is passed
