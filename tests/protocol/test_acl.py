"""A router with the corridor's ACL: only the DDM may publish a command; RSUs only under their own id."""

from __future__ import annotations

import socket
import time

import pytest

from protocol import keys
from protocol.corridor import load_corridor
from protocol.examples import example_messages
from protocol.zenoh_transport import ZenohSettings, ZenohTransport

pytestmark = pytest.mark.serial  # processes, Zenoh or its own timing: make test runs it alone



def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_only_the_ddm_can_publish_a_command(spawn, tmp_path, corridor_id):
    from protocol.corridor import DEFAULT_CORRIDOR

    corridor_file = tmp_path / "corridor.toml"  # the default corridor under this test's own id
    corridor_file.write_text(DEFAULT_CORRIDOR.read_text().replace('id = "rellis"', f'id = "{corridor_id}"', 1))
    assert load_corridor(corridor_file).corridor_id == corridor_id

    port = _free_port()
    ep = f"tcp/127.0.0.1:{port}"
    gen = spawn("-m", "deploy", "deploy", "acl", "--corridor", str(corridor_file), "--out", str(tmp_path / "acl"),
                "--listen", ep)
    out, err = gen.communicate(timeout=30)
    assert gen.returncode == 0, err
    router = spawn("-m", "deploy", "router", "--config", str(tmp_path / "acl" / "router-acl.json5"),
                   "--duration-s", "40")
    assert "router ready" in router.stdout.readline()

    def join(user: str | None) -> ZenohTransport:
        cfg = str(tmp_path / "acl" / f"{user}.json5") if user else None
        return ZenohTransport(ZenohSettings(mode="client", connect=[ep], config_file=cfg))

    watcher, ddm, rsu1, vehicle = join("rsu4"), join("ddm"), join("rsu1"), join("av1")
    try:
        got: list[tuple[str, str]] = []
        watcher.subscribe(keys.corridor_expr(corridor_id), lambda k, m: got.append((k, m.src)))
        time.sleep(0.5)
        msgs = {type(m).__name__: m for _, m in example_messages(corridor_id)}
        cmd_key = keys.vehicle_key(corridor_id, "av1", "cmd")
        for _ in range(3):
            ddm.publish(cmd_key, msgs["PathSwitchCommand"].model_copy(update={"src": "ddm"}))
            rsu1.publish(cmd_key, msgs["PathSwitchCommand"].model_copy(update={"src": "rsu1"}))
            vehicle.publish(cmd_key, msgs["PathSwitchCommand"].model_copy(update={"src": "av1"}))
            rsu1.publish(keys.rsu_key(corridor_id, "rsu1", "objects"), msgs["ObjectList"])
            rsu1.publish(keys.rsu_key(corridor_id, "rsu2", "objects"), msgs["ObjectList"])  # not its own id
            vehicle.publish(keys.vehicle_key(corridor_id, "av1", "state"), msgs["VehicleState"])
            time.sleep(0.2)
        time.sleep(0.5)
        senders_of_commands = {src for k, src in got if k == cmd_key}
        assert senders_of_commands == {"ddm"}
        assert (keys.rsu_key(corridor_id, "rsu1", "objects"), "rsu1") in got
        assert not any(k == keys.rsu_key(corridor_id, "rsu2", "objects") for k, _ in got)
        assert any(k == keys.vehicle_key(corridor_id, "av1", "state") for k, _ in got)
    finally:
        for t in (watcher, ddm, rsu1, vehicle):
            t.close()


def test_unknown_user_cannot_join(spawn, tmp_path):
    from deploy.acl import write_acl_bundle

    port = _free_port()
    ep = f"tcp/127.0.0.1:{port}"
    written = write_acl_bundle(load_corridor(), tmp_path, [ep])
    router = spawn("-m", "deploy", "router", "--config", str(written["router"]), "--duration-s", "20")
    assert "router ready" in router.stdout.readline()
    bad = tmp_path / "bad.json5"
    bad.write_text('{transport: {auth: {usrpwd: {user: "ddm", password: "guess"}}}}')
    try:
        ZenohTransport(ZenohSettings(mode="client", connect=[ep], config_file=str(bad)))
    except Exception as exc:  # zenoh refuses the session
        assert "connect" in str(exc).lower()
    else:
        raise AssertionError("a wrong password was accepted")


def test_mutual_tls_router_with_acl(spawn, tmp_path, corridor_id):
    from deploy.acl import write_mtls_bundle
    from protocol.corridor import DEFAULT_CORRIDOR

    corridor_file = tmp_path / "corridor.toml"
    corridor_file.write_text(DEFAULT_CORRIDOR.read_text().replace('id = "rellis"', f'id = "{corridor_id}"', 1))
    ep = f"tls/localhost:{_free_port()}"
    written = write_mtls_bundle(load_corridor(corridor_file), tmp_path / "pki", [ep])
    router = spawn("-m", "deploy", "router", "--config", str(written["router"]), "--duration-s", "30")
    assert "router ready" in router.stdout.readline()

    def join(user: str) -> ZenohTransport:
        return ZenohTransport(ZenohSettings(mode="client", connect=[ep], config_file=str(written[user])))

    watcher, ddm, rsu1 = join("rsu4"), join("ddm"), join("rsu1")
    try:
        got: list[str] = []
        cmd_key = keys.vehicle_key(corridor_id, "av1", "cmd")
        watcher.subscribe(keys.corridor_expr(corridor_id), lambda k, m: got.append(m.src) if k == cmd_key else None)
        time.sleep(0.5)
        cmd = example_messages(corridor_id)[3][1]
        for _ in range(3):
            ddm.publish(cmd_key, cmd.model_copy(update={"src": "ddm"}))
            rsu1.publish(cmd_key, cmd.model_copy(update={"src": "rsu1"}))
            time.sleep(0.2)
        time.sleep(0.5)
        assert set(got) == {"ddm"}
    finally:
        for t in (watcher, ddm, rsu1):
            t.close()
    # a client without a certificate from the corridor's CA is refused
    plain = tmp_path / "nocert.json5"
    plain.write_text('{transport: {link: {tls: {root_ca_certificate: "%s"}}}}' % (tmp_path / "pki" / "ca.pem"))
    try:
        ZenohTransport(ZenohSettings(mode="client", connect=[ep], config_file=str(plain)))
    except Exception as exc:
        assert "connect" in str(exc).lower()
    else:
        raise AssertionError("a client without a certificate joined an mTLS router")
