"""Signed messages (after IEEE 1609.2): only trusted keys may command a vehicle or raise an alert.

A signer attaches a ``Signature`` to a ``PathSwitchCommand``, ``EvAlert`` or ``HazardAlert``: an
Ed25519 signature (RFC 8032, via the ``cryptography`` library) over

    b"iea-sig-v1\\0" + key + b"\\0" + canonical_encoding(message without its signature)
                                       + not_before + not_after (IEEE-754 doubles, big-endian)

so a signature is bound to the key expression it was published on (a command for av1 cannot be
replayed to av2) and to its validity window. ``Verifier.check`` refuses, each with its own reason:
``unsigned``, ``unknown_key``, ``bad_signature``, ``expired`` / ``not_yet_valid`` (outside the window,
with a clock-skew allowance), ``out_of_scope`` (the key may not sign this message for this key), and
``ReplayGuard`` refuses ``replayed`` commands (a command id already seen, or an older ``command_seq``
from the same signer).

Trust lists come from the corridor file (``[[trust]]`` tables): key id, base64 public key, role
(``ddm`` or ``rsu``), and scope (the vehicles a DDM key may command, the RSU id an RSU key speaks for).
"""

from __future__ import annotations

import base64
import struct
from collections import OrderedDict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from cryptography.exceptions import InvalidSignature
from cryptography.hazmat.primitives import serialization
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey, Ed25519PublicKey

from protocol.codec import encode
from protocol.keys import parse_key
from protocol.messages import EvAlert, HazardAlert, PathSwitchCommand, Signature

SIGNED_TYPES = (PathSwitchCommand, EvAlert, HazardAlert)
_DOMAIN = b"iea-sig-v1\x00"


class AuthError(ValueError):
    """A message that fails authentication; ``reason`` is one of the counted categories."""

    REASONS = ("unsigned", "unknown_key", "bad_signature", "expired", "not_yet_valid", "out_of_scope", "replayed")

    def __init__(self, reason: str, message: str) -> None:
        assert reason in self.REASONS
        super().__init__(f"{reason}: {message}")
        self.reason = reason


def signed_bytes(key: str, message: Any, not_before: float, not_after: float) -> bytes:
    """The exact bytes a signature covers (see the module docstring)."""
    unsigned = message.model_copy(update={"auth": None})
    return _DOMAIN + key.encode() + b"\x00" + encode(unsigned) + struct.pack(">dd", not_before, not_after)


# ----------------------------------------------------------------------------- keys
def new_key_pair() -> tuple[bytes, str]:
    """A fresh Ed25519 key: (private key PEM, public key base64)."""
    private = Ed25519PrivateKey.generate()
    pem = private.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                                serialization.NoEncryption())
    return pem, public_key_b64(private.public_key())


def public_key_b64(public: Ed25519PublicKey) -> str:
    raw = public.public_bytes(serialization.Encoding.Raw, serialization.PublicFormat.Raw)
    return base64.b64encode(raw).decode()


def load_private_key(path: str | Path) -> Ed25519PrivateKey:
    p = Path(path)
    try:
        key = serialization.load_pem_private_key(p.read_bytes(), password=None)
    except FileNotFoundError:
        raise ValueError(f"{p}: private key file not found (create one with `iea keys new`)") from None
    except (ValueError, TypeError) as exc:
        raise ValueError(f"{p}: not a PEM private key: {exc}") from None
    if not isinstance(key, Ed25519PrivateKey):
        raise ValueError(f"{p}: not an Ed25519 private key")
    return key


def parse_public_key(b64: str, where: str = "public_key") -> Ed25519PublicKey:
    try:
        raw = base64.b64decode(b64, validate=True)
        return Ed25519PublicKey.from_public_bytes(raw)
    except (ValueError, TypeError) as exc:
        raise ValueError(f"{where}: expected a base64 Ed25519 public key (32 bytes): {exc}") from None


# ----------------------------------------------------------------------------- signing
@dataclass
class Signer:
    key_id: str
    private_key: Ed25519PrivateKey

    @classmethod
    def from_file(cls, key_id: str, path: str | Path) -> Signer:
        return cls(key_id, load_private_key(path))

    def sign(self, key: str, message: Any, now: float, valid_for_s: float = 30.0, skew_s: float = 1.0) -> Any:
        """A copy of ``message`` carrying a signature valid from ``now - skew_s`` for ``valid_for_s``."""
        if not isinstance(message, SIGNED_TYPES):
            raise TypeError(f"{type(message).__name__} is not a signed message kind")
        not_before, not_after = max(0.0, now - skew_s), now + valid_for_s
        sig = self.private_key.sign(signed_bytes(key, message, not_before, not_after))
        return message.model_copy(update={"auth": Signature(self.key_id, not_before, not_after, sig)})


# ----------------------------------------------------------------------------- trust
@dataclass(frozen=True)
class TrustedKey:
    key_id: str
    public_key: Ed25519PublicKey
    role: str  # "ddm" | "rsu"
    vehicles: tuple[str, ...] = ("*",)
    """For a DDM key: the vehicles it may command ("*": all)."""
    rsu_id: str | None = None
    """For an RSU key: the RSU it speaks for."""

    def may_sign(self, key: str, message: Any) -> bool:
        parsed = parse_key(key)
        if isinstance(message, PathSwitchCommand):
            return (self.role == "ddm" and parsed.domain == "vehicle" and message.vehicle_id == parsed.node
                    and ("*" in self.vehicles or parsed.node in self.vehicles))
        if isinstance(message, EvAlert | HazardAlert):
            return (self.role == "rsu" and parsed.domain == "rsu" and parsed.node == self.rsu_id
                    and message.rsu_id == self.rsu_id)
        return False


@dataclass
class TrustList:
    keys: dict[str, TrustedKey] = field(default_factory=dict)

    @classmethod
    def from_entries(cls, entries: list[dict[str, Any]], source: str = "trust") -> TrustList:
        out: dict[str, TrustedKey] = {}
        for i, e in enumerate(entries):
            where = f"{source}[{i}]"
            kid = e.get("key_id")
            if not isinstance(kid, str) or not kid:
                raise ValueError(f"{where}.key_id: expected a non-empty string")
            role = e.get("role")
            if role not in ("ddm", "rsu"):
                raise ValueError(f"{where}.role: expected 'ddm' or 'rsu', got {role!r}")
            vehicles = tuple(e.get("vehicles", ["*"]))
            rsu_id = e.get("rsu_id")
            if role == "rsu" and not isinstance(rsu_id, str):
                raise ValueError(f"{where}.rsu_id: an RSU key must name the RSU it speaks for")
            out[kid] = TrustedKey(kid, parse_public_key(e.get("public_key", ""), f"{where}.public_key"), role,
                                  vehicles, rsu_id)
        return cls(out)


@dataclass
class Verifier:
    trust: TrustList
    skew_s: float = 1.0

    def check(self, key: str, message: Any, now: float) -> None:
        """Raise ``AuthError`` unless ``message`` is validly signed, in time and in scope for ``key``."""
        auth = getattr(message, "auth", None)
        if auth is None:
            raise AuthError("unsigned", f"{type(message).__name__} on {key} carries no signature")
        trusted = self.trust.keys.get(auth.key_id)
        if trusted is None:
            raise AuthError("unknown_key", f"key id {auth.key_id!r} is not in the trust list")
        try:
            trusted.public_key.verify(auth.sig, signed_bytes(key, message, auth.not_before, auth.not_after))
        except InvalidSignature:
            raise AuthError("bad_signature", f"signature by {auth.key_id!r} does not match the message") from None
        if now > auth.not_after + self.skew_s:
            raise AuthError("expired", f"signature expired at {auth.not_after:.3f} (now {now:.3f})")
        if now < auth.not_before - self.skew_s:
            raise AuthError("not_yet_valid", f"signature valid from {auth.not_before:.3f} (now {now:.3f})")
        if not trusted.may_sign(key, message):
            raise AuthError("out_of_scope", f"key {auth.key_id!r} ({trusted.role}) may not sign this for {key}")


class ReplayGuard:
    """Refuses replays: an older ``command_seq`` than the newest seen from that signer for that vehicle,
    or a known command id with different content. An identical copy (a retransmission) is a
    ``"duplicate"``, to be acknowledged again without acting twice. Bounded to ``capacity`` ids."""

    def __init__(self, capacity: int = 4096) -> None:
        self.capacity = capacity
        self._seen: OrderedDict[tuple[str, str], bytes] = OrderedDict()
        self._newest_seq: OrderedDict[tuple[str, str], int] = OrderedDict()

    @staticmethod
    def _signer(command: PathSwitchCommand) -> str:
        return command.auth.key_id if command.auth is not None else "-"

    def classify(self, command: PathSwitchCommand) -> str:
        """``"new"`` or ``"duplicate"``; raises ``AuthError("replayed")`` for a replay."""
        signer = self._signer(command)
        digest = command.auth.sig if command.auth is not None else encode(command)
        seen = self._seen.get((signer, command.command_id))
        if seen is not None:
            if seen == digest:
                return "duplicate"
            raise AuthError("replayed", f"command id {command.command_id!r} reused with different content")
        newest = self._newest_seq.get((signer, command.vehicle_id))
        if newest is not None and command.command_seq < newest:
            raise AuthError("replayed", f"command_seq {command.command_seq} is older than {newest}")
        return "new"

    def remember(self, command: PathSwitchCommand) -> None:
        signer = self._signer(command)
        self._seen[(signer, command.command_id)] = command.auth.sig if command.auth is not None else encode(command)
        while len(self._seen) > self.capacity:
            self._seen.popitem(last=False)
        k = (signer, command.vehicle_id)
        self._newest_seq[k] = max(command.command_seq, self._newest_seq.get(k, -1))
        while len(self._newest_seq) > self.capacity:
            self._newest_seq.popitem(last=False)
