"""Latency and drop-out on the vehicle's radio link (docs/faults.md), in lockstep.

The real DdmService and VehicleService on one SimClock; every message to and from the vehicle passes a
DsrcLink with the channel under test; scripted RSUs report the EV approach (scenario/faults.py) with the
first EvAlert at the measured p99 alert delay. Each row passes only on its own criterion AND the one
yield judge (scenario/outcome.py); a row that cannot pass physically is listed beyond its computed bound.
"""

from __future__ import annotations

import dataclasses

import pytest

from protocol.radio import ChannelModel
from scenario.faults import (
    LATENCIES_S,
    LOSSES,
    MEASURED_ALERT_DELAY_S,
    OUTAGES_S,
    YieldScenario,
    dropout_faults,
    latency_channel,
    latency_faults,
    rig_bound,
    run_command_link,
)

P99 = MEASURED_ALERT_DELAY_S["p99"]


def _consistent(f):
    """PASS needs the yield; BEYOND needs the fault's earliest alert past the computed bound."""
    if f.passed:
        assert f.details["yield"]["passed"] and f.details["yield"]["status"] == "yielded", f.outcome
        assert not f.beyond_bound
    if f.beyond_bound:
        assert not f.passed
        assert f.details["earliest_alert_with_fault_s"] > f.details["bound_latest_alert_s"]
    assert f.passed or f.beyond_bound or f.verdict == "FAIL"


def test_the_rig_runs_at_the_measured_p99_alert_delay():
    assert YieldScenario().alert_delay_s == P99
    r = run_command_link(latency_channel(0.0), seed=1)
    assert r.events["first_alert"] - r.events["lights_on"] == pytest.approx(P99, abs=0.02)


@pytest.mark.parametrize("latency_s", LATENCIES_S)
def test_latency_command_arrives_as_late_as_the_radio_makes_it(latency_s):
    r = run_command_link(latency_channel(latency_s), name=f"latency {latency_s}", seed=1)
    ev = r.events
    start_delay = ev["manoeuvre"] - ev["command_sent"]
    assert latency_s - 0.011 <= start_delay <= latency_s + 0.2 + 4 * latency_s / 4, start_delay
    assert r.counts["lost_commands"] == [] and r.counts["duplicate_activations"] == {}
    assert "pull_over" in r.counts["manoeuvres"][0]
    if latency_s >= 0.1:  # an ack round trip beyond the first retransmission: retransmitted, answered idempotently
        assert r.counts["transmissions"] > r.counts["commands_issued"]


def test_every_rig_row_passes_only_with_the_yield_or_is_beyond_its_bound():
    rows = latency_faults(alert_delay_s=P99) + dropout_faults(alert_delay_s=P99)
    assert len(rows) == len(LATENCIES_S) + len(LOSSES) + 2 * len(OUTAGES_S)  # command-link and radio outages
    for f in rows:
        _consistent(f)
        assert f.verdict != "FAIL", f.row()  # at p99 every row passes or is physically impossible


def test_a_row_that_delivers_every_command_but_blocks_the_ev_does_not_pass():
    """An outage row that delivers every command does not pass on delivery alone when the AV blocks the EV."""
    r = run_command_link(ChannelModel(latency_s=0.003), kind="dropout", seed=3, outage_after_alert=(0.0, 2.0))
    f = r.outcome
    assert r.counts["lost_commands"] == [] and r.counts["duplicate_activations"] == {}  # delivery fine ...
    assert f.details["yield"]["status"] == "blocked" and not f.passed  # ... but the EV was blocked


def test_the_bound_is_where_the_yield_stops_passing():
    easy = YieldScenario(ev_gap_m=80.0, alert_delay_s=0.0)  # lights on with the EV far behind: time to spare
    latest, start = rig_bound(easy)
    assert 0.0 < latest < easy.duration_s
    ok = run_command_link(ChannelModel(), scenario=dataclasses.replace(easy, alert_delay_s=max(0.0, latest - 0.1)))
    late = run_command_link(ChannelModel(), scenario=dataclasses.replace(easy, alert_delay_s=latest + 0.1))
    assert ok.outcome.details["yield"]["passed"] and not late.outcome.details["yield"]["passed"]


@pytest.mark.parametrize("loss", LOSSES)
def test_independent_loss_no_command_lost_no_duplicate_manoeuvre(loss):
    r = run_command_link(ChannelModel(latency_s=0.003, loss=loss), name=f"loss {loss}", kind="dropout", seed=2)
    link = r.counts["link"]
    assert link["tx"].get("dropped_loss", 0) + link["rx"].get("dropped_loss", 0) > 0, "no loss was injected"
    assert r.counts["lost_commands"] == [] and r.counts["ddm_expired"] == 0
    assert r.counts["duplicate_activations"] == {}
    assert r.outcome.passed == r.outcome.details["yield"]["passed"]


@pytest.mark.parametrize("outage_s", OUTAGES_S)
def test_burst_outage_at_the_alert_command_retransmitted_and_acked(outage_s):
    r = run_command_link(ChannelModel(latency_s=0.003), name=f"outage {outage_s}", kind="dropout", seed=3,
                         outage_after_alert=(0.0, outage_s))
    ev = r.events
    assert r.counts["link"]["rx"].get("dropped_outage", 0) > 0, "the first send should fall in the outage"
    assert r.counts["transmissions"] > r.counts["commands_issued"]  # retransmitted ...
    assert r.counts["lost_commands"] == [] and r.counts["duplicate_activations"] == {}  # ... acked, once
    # The car starts the manoeuvre right after the outage: the DDM hears the car again with its command
    # unacknowledged and plans it again from the car's fresh state.
    assert outage_s <= ev["manoeuvre"] - ev["command_sent"] <= outage_s + 0.3


@pytest.mark.parametrize("outage_s", OUTAGES_S)
def test_a_command_link_outage_passes_because_the_car_acts_on_the_signed_alert(outage_s):
    """With the command link cut from the first command (the RSUs still heard) the car pulls over on
    the signed EvAlert once its command is 0.3 s late, and clears the EV's lane in time; without that it blocks.
    Alert delay 0.50 s: the p99 the bench measures over Zenoh."""
    from vehicle.ev_direct import DirectAlertConfig

    sc = YieldScenario(alert_delay_s=0.5)
    on = run_command_link(ChannelModel(latency_s=0.003), kind="dropout", seed=3, scenario=sc,
                          command_outage_after_alert=(0.0, outage_s))
    off = run_command_link(ChannelModel(latency_s=0.003), kind="dropout", seed=3, scenario=sc,
                           command_outage_after_alert=(0.0, outage_s), direct_alerts=DirectAlertConfig(enabled=False))
    assert on.counts["direct_pull_overs"] == 1 and on.counts["link"]["rx"].get("dropped_outage", 0) > 0
    assert on.counts["rsu_link"]["rx"].get("dropped_outage", 0) == 0  # the RSUs' broadcasts got through
    assert on.events["direct_pull_over"] - on.events["first_alert"] == pytest.approx(0.3, abs=0.03)
    assert on.outcome.passed and on.outcome.details["yield"]["status"] == "yielded", on.outcome.row()
    assert on.counts["lost_commands"] == [] and on.counts["duplicate_activations"] == {}
    assert off.counts["direct_pull_overs"] == 0 and off.outcome.details["yield"]["status"] == "blocked"


def test_a_radio_outage_silences_the_alert_too_and_stays_beyond_the_bound():
    sc = YieldScenario(alert_delay_s=0.5)
    r = run_command_link(ChannelModel(latency_s=0.003), kind="dropout", seed=3, scenario=sc,
                         outage_after_alert=(0.0, 1.0))
    assert r.counts["rsu_link"]["rx"].get("dropped_outage", 0) > 0 and r.counts["direct_pull_overs"] == 0
    rows = {f.name: f for f in dropout_faults(alert_delay_s=0.5)}
    assert rows["1 s radio outage"].beyond_bound and rows["2 s radio outage"].beyond_bound
    assert rows["1 s command-link outage"].passed and rows["2 s command-link outage"].passed
