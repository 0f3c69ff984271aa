"""bench/e2e_bench.py splits lights on -> manoeuvre at the DDM's first response, read from its log."""

from __future__ import annotations

import logging
from datetime import datetime

from bench.e2e_bench import DecisionRecorder, add_hops, logged_decisions

KEEP = ("av1: none (unsafe gap in lane 0: follower track 2 4.5 m < 14.5 m needed; keep speed past the slower "
        "vehicle, then pull over: EV track 10 49 m behind)")
NOT_YET = "av1: none (EV track 10 behind but not imminent (time to pass 40.0 s, 90 m))"
PULL = "av1: pull_over (pull over to lane 0 (gaps in lane 0 ok): EV track 10 39 m behind)"


def test_logged_decisions_reads_stamps_and_skips_other_lines(tmp_path):
    log = tmp_path / "ddm.log"
    log.write_text("2026-11-25 03:30:09,100 ddm INFO DDM ddm1 on corridor c: 4 RSUs\n"
                   f"2026-11-25 03:30:10,250 ddm INFO {KEEP}\n"
                   "2026-11-25 03:30:12,000 ddm INFO command ddm-av1-1 to av1 issued: pull over\n"
                   f"2026-11-25 03:30:14,500 ddm INFO {PULL}\n")
    got = logged_decisions(log)
    assert [d for _, d in got] == [KEEP, PULL]
    t0 = datetime(2026, 11, 25, 3, 30, 10, 250000).timestamp()
    assert abs(got[0][0] - t0) < 1e-6 and abs(got[1][0] - (t0 + 4.25)) < 1e-6
    assert logged_decisions(tmp_path / "absent.log") == []


def test_add_hops_splits_at_the_first_response_not_at_a_not_yet_decision():
    m = {"latency_s": {}}
    ev = {"lights_on": 100.0, "first_ev_alert": 100.4, "command_acked": 107.62, "manoeuvre_start": 107.65}
    add_hops(m, ev, [(99.0, PULL), (100.3, NOT_YET), (100.5, KEEP), (107.6, PULL)])
    lat = m["latency_s"]
    assert lat["lights_on_to_response_s"] == 0.5  # the keep-speed decision, not the earlier ones
    assert lat["response_to_manoeuvre_s"] == 7.15
    assert lat["alert_to_command_at_vehicle_s"] == 7.22
    m2 = {"latency_s": {}}
    add_hops(m2, {"lights_on": 1.0}, [(1.5, NOT_YET)])
    assert m2["latency_s"]["lights_on_to_response_s"] is None and m2["latency_s"]["response_to_manoeuvre_s"] is None


def test_decision_recorder_stamps_with_the_given_clock():
    clock = [3.25]
    rec = DecisionRecorder(lambda: clock[0])
    log = logging.getLogger("ddm.test_recorder")
    log.addHandler(rec)
    log.propagate = False
    log.setLevel(logging.INFO)
    try:
        log.info("%s: %s (%s)", "av1", "pull_over", "pull over to lane 0")
        log.info("command ddm-av1-1 to av1 issued")
    finally:
        log.removeHandler(rec)
    assert rec.records == [(3.25, "av1: pull_over (pull over to lane 0)")]
