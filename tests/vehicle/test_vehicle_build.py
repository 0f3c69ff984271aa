"""vehicle/build.py: the one place a vehicle process is assembled, used by ``iea-vehicle run``."""

from __future__ import annotations

import pytest

from protocol.clock import SimClock
from protocol.local_bus import LocalBus
from vehicle import cli
from vehicle.build import VehicleOptions, build_vehicle


def test_options_reach_the_service():
    svc = build_vehicle(VehicleOptions(corridor_id="c9", start_s_m=123.0, start_lane=1, cruise_speed_mps=9.0,
                                       link_timeout_s=2.0, localisation="both"), LocalBus(), SimClock())
    try:
        vc = svc.corridor.vehicle("av1")
        assert (svc.corridor.corridor_id, vc.start_s_m, vc.start_lane, vc.cruise_speed_mps) == ("c9", 123.0, 1, 9.0)
        assert svc.state_key == "iea/c9/vehicle/av1/state"
        assert svc.sim.core.config.failsafe.link_timeout_s == 2.0
        assert not svc.gate.active  # the default corridor trusts no DDM key
    finally:
        svc.close()


def test_bad_options_raise_before_anything_is_subscribed():
    bus = LocalBus()
    with pytest.raises(KeyError, match="no vehicle .nobody."):
        build_vehicle(VehicleOptions(vehicle_id="nobody"), bus, SimClock())
    with pytest.raises(ValueError, match="require-signed"):
        build_vehicle(VehicleOptions(require_signed=True), bus, SimClock())
    assert not bus._subs


@pytest.mark.parametrize("argv, message", [
    (["run", "--vehicle", "nobody"], "has no vehicle 'nobody'"),
    (["run", "--require-signed"], "require-signed"),
    (["run", "--corridor", "/nonexistent.toml"], "corridor file not found"),
])
def test_cli_refuses_bad_options_with_exit_2(argv, message, capsys):
    assert cli.main(argv) == 2
    assert message in capsys.readouterr().err


def test_an_attached_component_sees_the_service_and_a_failing_one_closes_it():
    bus = LocalBus()
    seen = []
    service = build_vehicle(VehicleOptions(), bus, SimClock(), attach=lambda s, t: seen.append((s, t)))
    assert seen == [(service, bus)]
    service.close()

    def broken(_service, _transport):
        raise FileNotFoundError("model missing")

    with pytest.raises(FileNotFoundError):
        build_vehicle(VehicleOptions(), bus, SimClock(), attach=broken)
    assert not bus._subs
