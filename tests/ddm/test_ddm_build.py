"""ddm/build.py: the one place a DDM is assembled from its options, used by ``iea-ddm run``."""

from __future__ import annotations

import pytest

from ddm import cli
from ddm.build import DdmOptions, build_ddm
from ddm.config import DdmConfig
from protocol.clock import SimClock
from protocol.local_bus import LocalBus
from protocol.security import SecureTransport, new_key_pair


def _key_file(tmp_path) -> str:
    pem, _public = new_key_pair()
    path = tmp_path / "ddm.pem"
    path.write_bytes(pem)
    return str(path)


def test_options_reach_the_service():
    bus = LocalBus()
    svc = build_ddm(DdmOptions(corridor_id="c7", ddm_id="ddm-b", config=DdmConfig(rate_hz=5.0)), bus, SimClock())
    try:
        assert (svc.corridor_id, svc.ddm_id, svc.config.rate_hz) == ("c7", "ddm-b", 5.0)
        assert svc.transport is bus  # no key and no RSU keys trusted: commands leave unsigned
        assert bus._subs and all(expr.startswith("iea/c7/") for expr, _cb in bus._subs.values())
    finally:
        svc.close()


def test_a_key_signs_commands_under_its_id(tmp_path):
    svc = build_ddm(DdmOptions(key=_key_file(tmp_path), key_id="ddm-k"), LocalBus(), SimClock())
    try:
        assert isinstance(svc.transport, SecureTransport) and svc.transport.signer.key_id == "ddm-k"
    finally:
        svc.close()


def test_bad_options_raise_before_anything_is_subscribed(tmp_path):
    bus = LocalBus()
    with pytest.raises(ValueError, match="key chunk"):
        build_ddm(DdmOptions(corridor_id="a/b"), bus, SimClock())
    with pytest.raises(ValueError, match="trust list"):  # a key the corridor does not know, and no key id
        build_ddm(DdmOptions(key=_key_file(tmp_path)), bus, SimClock())
    assert not bus._subs


@pytest.mark.parametrize("argv, message", [
    (["run", "--corridor", "/nonexistent.toml"], "corridor file not found"),
    (["run", "--corridor-id", "a/b"], "not a valid key chunk"),
    (["run", "--key", "/nonexistent.pem"], "private key file not found"),
])
def test_cli_refuses_bad_options_with_exit_2(argv, message, capsys):
    assert cli.main(argv) == 2
    assert message in capsys.readouterr().err


def test_a_loaded_corridor_is_used_as_given():
    import dataclasses

    from protocol.corridor import load_corridor

    edited = dataclasses.replace(load_corridor(), corridor_id="edited")
    svc = build_ddm(DdmOptions(corridor_file="/nonexistent.toml", catch_up=False), LocalBus(), SimClock(), edited)
    try:  # the file is not read: the runner's or bench's corridor is the DDM's
        assert svc.corridor is edited and svc.corridor_id == "edited"
    finally:
        svc.close()
