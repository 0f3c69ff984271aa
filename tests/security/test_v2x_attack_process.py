"""Over Zenoh, as processes (``iea up --v2x`` and ``python -m scenario.v2x_attack``): forged lights-on CAMs for the
EV reach every RSU gateway through the radio model, are passed on to the DDM, and are refused there; no car moves."""

from __future__ import annotations

import pytest

from protocol.enums import Role
from protocol.v2x.keys import v2x_rsu_expr

pytestmark = [pytest.mark.serial, pytest.mark.slow, pytest.mark.timeout(150)]


def test_a_forged_cam_attack_moves_no_car(tmp_path, corridor_id):
    from deploy.up import Up

    up = Up(scenario="ev_lights_never_on", corridor_id=corridor_id, port=0, run_dir=tmp_path / "run",
            duration_s=8.0, seed=1, restart="no", v2x=True)
    up.add_service("attacker", ["-m", "scenario.v2x_attack", "--kind", "forged", "--ev-key", str(up.ev_key)])
    cameras = {r.rsu_id for r in up.corridor.rsus}
    for spec in up.specs:  # a camera's hazard (a stopped car taken for debris) is another way to move a car: off
        if spec.name in cameras:
            spec.args += ["--hazards", "none"]
    health = []
    relayed = []
    try:
        up.start(extra_subscribers=[lambda _k, m: health.append(m) if m.KIND == "Health" and m.role == Role.DDM
                                    else None])
        up.transport.subscribe_bytes(v2x_rsu_expr(up.corridor_id, "rx"), lambda k, _p: relayed.append(k))
        assert up.wait_for_scenario(60.0)
    finally:
        up.stop()
    m = up.metrics()
    log = up.group.log_path("attacker").read_text()
    assert "forged attack:" in log and "CAMs sent" in log, log[-2000:]
    assert len({k.split("/")[-2] for k in relayed}) >= 2, relayed[:5]  # several RSU radios heard it
    assert health and health[-1].rejected.get("v2x_bad_signature", 0) > 0, health[-1:] or "no DDM Health"
    assert m["commands"] == [], m["commands"]
