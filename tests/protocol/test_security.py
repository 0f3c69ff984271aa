"""Signatures: valid ones pass; unsigned, forged, expired, out-of-scope and replayed ones are refused."""

from __future__ import annotations

import pytest

from protocol import keys
from protocol.codec import decode, encode
from protocol.examples import example_messages
from protocol.messages import EvAlert, PathSwitchCommand
from protocol.security import (
    AuthError,
    ReplayGuard,
    Signer,
    TrustList,
    Verifier,
    load_private_key,
    new_key_pair,
)

pytestmark = pytest.mark.serial  # processes, Zenoh or its own timing: make test runs it alone



@pytest.fixture(scope="module")
def pki(tmp_path_factory):
    d = tmp_path_factory.mktemp("keys")
    out = {}
    entries = []
    for kid, role, extra in [("ddm-1", "ddm", {"vehicles": ["av1"]}), ("rsu1-key", "rsu", {"rsu_id": "rsu1"})]:
        pem, pub = new_key_pair()
        (d / f"{kid}.pem").write_bytes(pem)
        out[kid] = Signer(kid, load_private_key(d / f"{kid}.pem"))
        entries.append({"key_id": kid, "role": role, "public_key": pub, **extra})
    rogue_pem, _ = new_key_pair()
    (d / "rogue.pem").write_bytes(rogue_pem)
    out["rogue"] = Signer("ddm-1", load_private_key(d / "rogue.pem"))  # claims the DDM's key id
    out["verifier"] = Verifier(TrustList.from_entries(entries))
    return out


def _command(**update) -> tuple[str, PathSwitchCommand]:
    key, cmd = example_messages("c", stamp=100.0)[3]
    return key, cmd.model_copy(update=update)


def test_valid_signature_passes_and_survives_the_wire(pki):
    key, cmd = _command()
    signed = pki["ddm-1"].sign(key, cmd, now=100.0)
    back = decode(encode(signed), PathSwitchCommand)
    pki["verifier"].check(key, back, now=101.0)
    assert back.auth.key_id == "ddm-1" and len(back.auth.sig) == 64


@pytest.mark.parametrize("case,reason", [
    ("unsigned", "unsigned"),
    ("forged", "bad_signature"),
    ("tampered", "bad_signature"),
    ("unknown", "unknown_key"),
    ("expired", "expired"),
    ("future", "not_yet_valid"),
    ("other_vehicle_key", "bad_signature"),
    ("out_of_scope", "out_of_scope"),
])
def test_bad_commands_are_refused_with_their_reason(pki, case, reason):
    key, cmd = _command()
    v, now = pki["verifier"], 101.0
    if case == "unsigned":
        msg = cmd
    elif case == "forged":
        msg = pki["rogue"].sign(key, cmd, now=100.0)
    elif case == "tampered":
        msg = pki["ddm-1"].sign(key, cmd, now=100.0).model_copy(update={"target_lane": 1})
    elif case == "unknown":
        msg = Signer("nobody", pki["ddm-1"].private_key).sign(key, cmd, now=100.0)
    elif case == "expired":
        msg, now = pki["ddm-1"].sign(key, cmd, now=100.0, valid_for_s=5.0), 110.0
    elif case == "future":
        msg, now = pki["ddm-1"].sign(key, cmd, now=100.0), 90.0
    elif case == "other_vehicle_key":  # a command signed for av1 replayed onto av2's key
        msg = pki["ddm-1"].sign(key, cmd, now=100.0)
        key = keys.vehicle_key("c", "av2", "cmd")
    elif case == "out_of_scope":  # an RSU key cannot command a vehicle
        msg = pki["rsu1-key"].sign(key, cmd, now=100.0)
    with pytest.raises(AuthError) as info:
        v.check(key, msg, now)
    assert info.value.reason == reason


def test_rsu_alerts_are_scoped_to_their_rsu(pki):
    key, alert = example_messages("c", stamp=100.0)[1]
    assert isinstance(alert, EvAlert)
    pki["verifier"].check(key, pki["rsu1-key"].sign(key, alert, now=100.0), now=100.5)
    other = keys.rsu_key("c", "rsu2", "ev")
    with pytest.raises(AuthError) as info:
        pki["verifier"].check(other, pki["rsu1-key"].sign(other, alert, now=100.0), now=100.5)
    assert info.value.reason == "out_of_scope"


def test_replay_guard(pki):
    key, cmd = _command(command_seq=5, command_id="c5")
    guard = ReplayGuard(capacity=8)
    signed = pki["ddm-1"].sign(key, cmd, now=100.0)
    assert guard.classify(signed) == "new"
    guard.remember(signed)
    assert guard.classify(signed) == "duplicate"  # a retransmission: ack again, act once
    older = pki["ddm-1"].sign(key, cmd.model_copy(update={"command_seq": 4, "command_id": "c4"}), now=100.0)
    with pytest.raises(AuthError, match="older"):
        guard.classify(older)
    reused = pki["ddm-1"].sign(key, cmd.model_copy(update={"target_lane": 1}), now=100.0)
    with pytest.raises(AuthError, match="reused"):
        guard.classify(reused)
    for i in range(6, 40):
        guard.remember(pki["ddm-1"].sign(key, cmd.model_copy(update={"command_seq": i, "command_id": f"c{i}"}),
                                         now=100.0))
    assert len(guard._seen) <= 8  # bounded


def test_trust_list_validation():
    with pytest.raises(ValueError, match="role"):
        TrustList.from_entries([{"key_id": "k", "role": "king", "public_key": "AAAA"}])
    with pytest.raises(ValueError, match="public_key"):
        TrustList.from_entries([{"key_id": "k", "role": "ddm", "public_key": "not base64!"}])
    with pytest.raises(ValueError, match="rsu_id"):
        _, pub = new_key_pair()
        TrustList.from_entries([{"key_id": "k", "role": "rsu", "public_key": pub}])


def test_keys_new_and_trust_from_corridor_file(spawn, tmp_path):
    import tomllib

    from protocol.corridor import parse_corridor

    p = spawn("-m", "deploy", "keys", "new", "ddm-1", "--role", "ddm", "--vehicles", "av1", "--out", str(tmp_path))
    out, err = p.communicate(timeout=30)
    assert p.returncode == 0, err
    assert (tmp_path / "ddm-1.pem").stat().st_mode & 0o777 == 0o600
    entry = tomllib.loads(out.split("\n", 1)[1])["trust"][0]
    base = tomllib.loads((__import__("protocol.corridor", fromlist=["x"]).DEFAULT_CORRIDOR).read_text())
    base["trust"] = [entry]
    corridor = parse_corridor(base, "with-trust.toml")
    verifier = Verifier(TrustList.from_entries(list(corridor.trust)))
    key, cmd = _command()
    signer = Signer("ddm-1", load_private_key(tmp_path / "ddm-1.pem"))
    verifier.check(key, signer.sign(key, cmd, now=100.0), now=100.0)
    again = spawn("-m", "deploy", "keys", "new", "ddm-1", "--role", "ddm", "--out", str(tmp_path))
    again.communicate(timeout=30)
    assert again.returncode == 1  # never overwrites a private key
