"""Signed by default: `iea deploy keys` writes a key per signing service and the corridor
file trusting them; `iea up` signs with throwaway keys unless told `--unsigned`."""

from __future__ import annotations

import stat
import subprocess
import sys
from pathlib import Path

import pytest

from deploy.signing import load_key_bundle, write_key_bundle
from deploy.up import Up
from protocol.corridor import DEFAULT_CORRIDOR, load_corridor
from protocol.security import TrustList, load_private_key
from vehicle.commands import CommandGate

pytestmark = pytest.mark.serial  # processes, Zenoh or its own timing: make test runs it alone


ROOT = Path(__file__).resolve().parents[2]


def test_iea_deploy_keys_writes_a_signed_corridor(tmp_path):
    out = tmp_path / "keys"
    r = subprocess.run([sys.executable, "-m", "deploy", "deploy", "keys", "--out", str(out)], capture_output=True,
                       text=True, cwd=ROOT, timeout=60)
    assert r.returncode == 0, r.stderr
    corridor = load_corridor(out / "corridor.toml")
    trust = TrustList.from_corridor(corridor)
    roles = sorted((k.role, k.rsu_id or "") for k in trust.keys.values())
    assert roles == [("ddm", ""), *sorted(("rsu", rr.rsu_id) for rr in corridor.rsus)]
    for name in ["ddm", *(rr.rsu_id for rr in corridor.rsus)]:
        pem = out / f"{name}.pem"
        assert stat.S_IMODE(pem.stat().st_mode) == 0o600
        assert trust.key_id_of(load_private_key(pem)) is not None  # the corridor trusts exactly this key
    assert CommandGate.from_trust(trust).active  # a vehicle on it refuses unsigned commands
    again = subprocess.run([sys.executable, "-m", "deploy", "deploy", "keys", "--out", str(out)],
                           capture_output=True, text=True, cwd=ROOT, timeout=60)
    assert again.returncode == 1 and "--force" in again.stderr  # a deployed bundle is never replaced by accident


def test_bundle_checks(tmp_path):
    target, paths = write_key_bundle(DEFAULT_CORRIDOR, tmp_path / "b", key_id_suffix="t")
    with pytest.raises(ValueError, match="already has"):
        write_key_bundle(target, tmp_path / "c", key_id_suffix="t")
    paths["rsu2"].unlink()
    with pytest.raises(FileNotFoundError, match="rsu2.pem"):
        load_key_bundle(tmp_path / "b", load_corridor())


def test_up_is_signed_by_default(tmp_path):
    up = Up(port=0, run_dir=tmp_path / "run", duration_s=5.0)
    args = {s.name: s.args for s in up.specs}
    assert up.signed and TrustList.from_corridor(up.corridor).has_role("ddm")
    assert "--key" in args["ddm"] and all("--key" in args[r.rsu_id] for r in up.corridor.rsus)
    assert all(str(up.corridor_file) in a for a in args.values())  # every service on the trusting corridor
    plain = Up(port=0, run_dir=tmp_path / "run2", duration_s=5.0, signed=False)
    assert not any("--key" in s.args for s in plain.specs)
