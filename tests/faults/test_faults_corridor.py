"""The worst link of the latency fault on the whole corridor in lockstep (scenario/lockstep.py): the simulator,
4 RSUs processing rendered pixels, the DDM and the vehicle behind a DsrcLink with 300 ms (+ jitter) each
way. One run (~15 s of scenario, 30-60 s of CPU on 2 loaded cores); the other cases run in the bench
(`python bench/e2e_bench.py --corridor-faults`) and, fast, on the DDM + vehicle rig (test_faults_command_link).
"""

from __future__ import annotations

import pytest

from scenario.corridor_faults import run_corridor_fault
from scenario.faults import latency_channel

pytestmark = [pytest.mark.slow, pytest.mark.timeout(240)]


def test_corridor_300ms_link_av_still_clears_the_ev_lane_in_time():
    f, m = run_corridor_fault("latency 300 ms", "latency", channel=latency_channel(0.3), duration_s=13.0)
    assert f.passed, f"{f.outcome}: {f.details}"
    assert f.margin_s is not None and f.margin_s > 0
    assert f.details["lost_commands"] == []
    assert not m["collision"]
    # the radio's latency is really in the loop: the vehicle acknowledges >= 300 ms after the DDM sent it
    assert m["latency_s"]["command_to_ack_s"] >= 0.3
    assert m["vehicle_link"]["rx"]["delivered"] > 0 and m["vehicle_link"]["tx"]["delivered"] > 0
