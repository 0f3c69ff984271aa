"""The whole corridor in lockstep (scenario/lockstep.py): simulator -> 4 RSUs on rendered pixels -> DDM ->
vehicle, on a simulated clock. Perception sees pixels only; scoring reads the simulator's ground truth."""

from __future__ import annotations

import pytest

from protocol.enums import ClearReason
from scenario.lockstep import CorridorLockstep, LockstepConfig, ev_lights_on
from scenario.outcome import judge_run


@pytest.fixture(scope="module")
def rellis_run():
    """rellis_ev_yield, seed 1, 16 s of scenario time (~30-40 s of CPU)."""
    runner = CorridorLockstep(LockstepConfig(seed=1, duration_s=16.0))
    clear_reasons = []
    runner.bus.subscribe(f"iea/{runner.corridor_id}/rsu/*/ev",
                         lambda _k, m: clear_reasons.append(m.clear_reason) if m.state.value == "cleared" else None)
    metrics = runner.run()
    return runner, metrics, clear_reasons


def test_ev_yield_end_to_end_in_lockstep(rellis_run):
    runner, m, _ = rellis_run
    lat = m["latency_s"]
    # the RSUs raised an EvAlert from pixels and the DDM commanded a pull-over the vehicle accepted
    assert m["alerts"] > 0 and lat["lights_on_to_alert_s"] < 2.0
    assert m["commands"][0]["manoeuvre"] == "pull_over"
    assert {"id": m["commands"][0]["id"], "status": "accepted"} in m["acks"]
    # it moved out of the EV's lane before the EV passed and stopped at the curb side of lane 0
    assert m["moved_over_before_ev_passed"] and m["stop_lane"] == 0
    assert 0.5 < m["stop_position_m"][1] < 2.5
    assert not m["collision"] and m["min_gap_to_any_vehicle_m"] > 0.5
    ok, why = judge_run(m, ev_lights_on=ev_lights_on(runner.scenario, 16.0))
    assert ok, why
    # lockstep: every camera frame of the 16 s was processed (4 RSUs x 15 fps)
    assert m["frames"] == pytest.approx(4 * 15 * 16, abs=8)


def test_lockstep_is_deterministic_and_alerts_carry_a_clear_reason(rellis_run):
    _, m, reasons = rellis_run
    again = CorridorLockstep(LockstepConfig(seed=1, duration_s=7.0)).run()
    assert again["latency_s"]["lights_on_to_alert_s"] == m["latency_s"]["lights_on_to_alert_s"]
    assert again["first_alert_rsu"] == m["first_alert_rsu"]
    assert all(r in (ClearReason.LIGHTS_OFF, ClearReason.OUT_OF_VIEW) for r in reasons)


def test_lockstep_vehicle_link_through_a_lossy_radio():
    """The DsrcLink option: 100 ms latency and 20 % loss on the vehicle's link; commands still arrive
    (retransmitted until acked) and the link counts what it dropped."""
    from protocol.radio import ChannelModel

    runner = CorridorLockstep(LockstepConfig(seed=1, duration_s=9.0, channel_seed=3,
                                             vehicle_channel=ChannelModel(latency_s=0.1, jitter_s=0.02, loss=0.2)))
    m = runner.run()
    link = m["vehicle_link"]
    assert link["rx"]["offered"] > 0 and link["tx"]["offered"] > 100
    assert sum(v for k, v in link["tx"].items() if k.startswith("dropped")) > 0
    assert m["commands"] and any(a["status"] == "accepted" for a in m["acks"])
    assert m["latency_s"]["command_to_ack_s"] >= 0.08  # the command crossed the radio (100 ms +- 20 ms)
