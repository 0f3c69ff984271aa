"""Two short rows of the network lab's fault table on this machine (needs CAP_NET_ADMIN, ``ip``, ``iptables``,
``tc``; skips naming them otherwise): 30 % random loss on the vehicle's link from the EV's lights-on, and the
vehicle's link cut for 1 s, each on the whole corridor. The full table runs in bench/netfault_bench.py."""

from __future__ import annotations

import pytest

from deploy.netlab.net import leftovers, unavailable_reason
from deploy.netlab.schedule import fault_by_name

REASON = unavailable_reason()
pytestmark = [pytest.mark.serial, pytest.mark.slow, pytest.mark.timeout(180),
              pytest.mark.skipif(REASON is not None, reason=REASON or "")]


@pytest.fixture(scope="module")
def loss_row(tmp_path_factory):
    from deploy.netlab.rows import run_row

    return run_row(fault_by_name("vehicle link loss 30%"), tmp_path_factory.mktemp("loss"))


@pytest.fixture(scope="module")
def cut_row(tmp_path_factory):
    from deploy.netlab.rows import run_row

    return run_row(fault_by_name("vehicle link cut 1 s"), tmp_path_factory.mktemp("cut"))


def test_loss_row_delivers_every_command_and_the_av_yields(loss_row):
    d = loss_row.details
    assert d["fault_after_lights_on_s"] is not None and 0.0 <= d["fault_after_lights_on_s"] < 0.5, d
    assert d["commands_issued"] >= 1 and d["commands_lost"] == 0, d
    assert d["ack_latency_p50_s"] is not None
    assert loss_row.verdict in ("PASS", "BEYOND"), loss_row.row()
    assert leftovers(d["prefix"]) == {"namespaces": [], "links": [], "processes": []}


def test_cut_row_recovers_after_the_link_returns(cut_row):
    d = cut_row.details
    assert d["victims"] == ["vehicle"] and d["length_s"] == 1.0
    # the vehicle is heard again soon after its link returns (its TCP session to the router survived the cut)
    assert d["recovery_s"] is not None and d["recovery_s"] < 3.0, d
    assert d["commands_lost"] == 0, d
    assert cut_row.verdict in ("PASS", "BEYOND"), cut_row.row()
    assert leftovers(d["prefix"]) == {"namespaces": [], "links": [], "processes": []}
