"""Two routers in a chain on loopback (``iea deploy mesh``): a segment router with the RSUs and the
vehicle, a core router with the DDM, the ACL enforced on both.

The scenario crosses both routers every way: the DDM (on the core) sees the RSUs' tokens (on the
segment), starts late and is EV-aware from their answers at once, commands the vehicle (on the segment)
through the chain, and learns that the RSUs are gone when their process is killed.
"""

from __future__ import annotations

import time

import pytest

from ddm.build import DdmOptions, build_ddm
from protocol import keys
from protocol.clock import WallClock
from protocol.zenoh_transport import ZenohSettings, ZenohTransport
from tests.protocol.test_presence_queries import ROOT, _acl_checks, _free_port, _wait, _wait_line

pytestmark = pytest.mark.serial  # processes, Zenoh or its own timing: make test runs it alone



@pytest.mark.timeout(150)
@pytest.mark.parametrize("auth", ["password", "mtls"])
def test_two_routers_in_a_chain_with_acl_on_both(spawn, tmp_path, corridor_id, auth):
    from protocol.corridor import DEFAULT_CORRIDOR

    corridor_file = tmp_path / "corridor.toml"
    corridor_file.write_text(DEFAULT_CORRIDOR.read_text().replace('id = "rellis"', f'id = "{corridor_id}"', 1))
    proto = "tls" if auth == "mtls" else "tcp"
    core_ep, seg_ep = f"{proto}/127.0.0.1:{_free_port()}", f"{proto}/127.0.0.1:{_free_port()}"
    out = tmp_path / "mesh"
    gen = spawn("-m", "deploy", "deploy", "mesh", "--corridor", str(corridor_file), "--out", str(out),
                "--core-listen", core_ep, "--segment-listen", seg_ep, *(["--mtls"] if auth == "mtls" else []))
    _, err = gen.communicate(timeout=30)
    assert gen.returncode == 0, err
    for name in ("core", "seg1"):
        p = spawn("-m", "deploy", "router", "--config", str(out / f"router-{name}.json5"), "--duration-s", "120")
        _wait_line(p, "router ready", 20.0)

    def join(ep: str, user: str) -> ZenohTransport:
        return ZenohTransport(ZenohSettings(mode="client", connect=[ep], config_file=str(out / f"{user}.json5")))

    # the ACL holds on both routers: an RSU declares only its own token and answers only on its own keys
    _acl_checks(lambda user: join(seg_ep, user), corridor_id)
    _acl_checks(lambda user: join(core_ep, user), corridor_id)

    stub = spawn(str(ROOT / "bench" / "zenoh_corridor_stub.py"), "--corridor", str(corridor_file), "--corridor-id",
                 corridor_id, "--connect", seg_ep, "--credentials-dir", str(out), "--duration-s", "60")
    _wait_line(stub, "ready", 30.0)
    time.sleep(0.5)
    watcher = join(seg_ep, "rsu4")
    commands: list = []
    watcher.subscribe(keys.vehicle_key(corridor_id, "av1", "cmd"), lambda _k, m: commands.append(m))
    t = join(core_ep, "ddm")
    ddm = build_ddm(DdmOptions(corridor_file=str(corridor_file), corridor_id=corridor_id), t, WallClock())
    try:
        assert ddm.catch_up_replies.get("ev") == 1 and ddm.ev_aware_s is not None  # through both routers
        assert ddm.presence.alive.get("rsu") == {"rsu1", "rsu2", "rsu3", "rsu4"}
        assert _wait(lambda: bool(commands), 10.0, step=ddm.step) is not None, "no command crossed the chain"
        assert commands[0].vehicle_id == "av1" and commands[0].src == "ddm"
        t_kill = time.perf_counter()
        stub.kill()
        assert _wait(lambda: len(ddm.presence.lost("rsu")) == 4, 5.0) is not None
        assert time.perf_counter() - t_kill < 0.5
    finally:
        ddm.close()
        t.close()
        watcher.close()
