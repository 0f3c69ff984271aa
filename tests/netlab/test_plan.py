"""The network lab's pure parts: names, the address plan, the mesh layout, the capability check (no root)."""

from __future__ import annotations

import ipaddress

import pytest

from deploy.netlab.net import has_net_admin
from deploy.netlab.plan import (
    HOST_NET,
    IFNAME_MAX,
    MONITOR,
    MONITOR_NET,
    corridor_hosts,
    lab_plan,
    make_prefix,
    mesh_hosts,
    owner_pid,
    pick_monitor_slot,
)

SERVICES = ["ddm", "rsu1", "rsu2", "rsu3", "rsu4", "vehicle", "sim"]


def test_prefix_names_its_process_and_runs_differ():
    a, b = make_prefix(4194303, 0), make_prefix(4194303, 1)
    assert a != b and owner_pid(a) == owner_pid(f"{b}-router") == owner_pid(f"{a}12h") == 4194303
    assert owner_pid("eth0") is None and owner_pid("nl") is None
    with pytest.raises(ValueError):
        make_prefix(0)


def test_corridor_plan_gives_each_host_its_own_link_and_addresses():
    plan = lab_plan(make_prefix(1234, 0), corridor_hosts(SERVICES), ["router"], monitor_slot=5)
    assert [link.host for link in plan.links] == [*SERVICES, MONITOR]
    ips = [ip for link in plan.links for ip in (link.host_ip, link.hub_ip)]
    assert len(set(ips)) == len(ips)
    for link in plan.links:
        net = ipaddress.ip_network(f"{link.hub_ip}/30", strict=False)
        assert ipaddress.ip_address(link.host_ip) in net  # both ends on one /30
        assert len(link.host_if) <= IFNAME_MAX and len(link.hub_if) <= IFNAME_MAX
        assert link.host_if.startswith(plan.prefix) and link.hub_ns == f"{plan.prefix}-router"
        assert (net.subnet_of(MONITOR_NET) if link.host == MONITOR else net.subnet_of(HOST_NET))
    assert plan.ns(MONITOR) is None and plan.link(MONITOR).host_ns is None
    assert plan.endpoint("rsu2") == f"tcp/{plan.link('rsu2').hub_ip}:7447"
    assert plan.namespaces() == [f"{plan.prefix}-{n}" for n in ["router", *SERVICES]]
    with pytest.raises(KeyError, match="no host or hub 'rsu9'"):
        plan.ns("rsu9")


def test_plan_refuses_what_cannot_be_laid_out():
    with pytest.raises(ValueError, match="not one of"):
        lab_plan("nl0000a0", {"ddm": "core"}, ["router"])
    with pytest.raises(ValueError, match="at least one hub"):
        lab_plan("nl0000a0", {}, [])
    with pytest.raises(ValueError, match="caller's own host"):
        lab_plan("nl0000a0", {MONITOR: "router"}, ["router"])
    with pytest.raises(ValueError, match="monitor_slot"):
        lab_plan("nl0000a0", {}, ["router"], monitor_slot=10**6)


def test_mesh_plan_hangs_segment_routers_off_the_core():
    layout = {"ddm": "core", "sim": "core", "av1": "core", "rsu1": "seg1", "rsu2": "seg1", "rsu3": "seg2",
              "rsu4": "seg2"}
    hosts, hubs = mesh_hosts(layout, SERVICES)
    assert hubs == ["core", "seg1", "seg2"]
    assert hosts["seg1"] == hosts["seg2"] == hosts["vehicle"] == hosts["ddm"] == "core"
    assert hosts["rsu1"] == "seg1" and hosts["rsu4"] == "seg2"
    plan = lab_plan("nl0000b0", hosts, hubs)
    assert plan.link("rsu3").hub_ns == plan.ns("seg2") == plan.link("seg2").host_ns  # one namespace: hub and host
    assert plan.namespaces().count(f"{plan.prefix}-seg1") == 1


def test_monitor_slot_avoids_routes_in_use():
    prefix = "nl0000c0"
    slot = pick_monitor_slot(prefix, [])
    taken = ipaddress.ip_network(f"{MONITOR_NET.network_address + 4 * slot}/30")
    other = pick_monitor_slot(prefix, [taken])
    assert other != slot
    assert pick_monitor_slot(prefix, [ipaddress.ip_network("192.168.0.0/16")]) == slot


def test_capability_check_reads_the_effective_set():
    assert has_net_admin("Name:\tx\nCapEff:\t000001ffffffffff\n")
    assert not has_net_admin("CapEff:\t0000000000000000\n")
    assert not has_net_admin("CapEff:\t0000000000000800\n")  # bit 11 only (CAP_NET_BROADCAST)
    assert has_net_admin("CapEff:\t0000000000001000\n")


def test_bench_refuses_a_setting_that_is_not_a_network_one(capsys):
    from bench.netfault_bench import main

    with pytest.raises(SystemExit) as exc:
        main(["--sysctl", "kernel.panic=1"])
    assert exc.value.code == 2 and "expected net.KEY=VALUE" in capsys.readouterr().err
