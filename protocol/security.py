"""Signed messages (after IEEE 1609.2): only trusted keys may command a vehicle or raise an alert.

A signer attaches a ``Signature`` to a ``PathSwitchCommand``, ``EvAlert``, ``HazardAlert`` or its own
``Health`` (a heartbeat: a vehicle's link watchdog counts only a trusted DDM's): an
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
import logging
import struct
import threading
from collections import OrderedDict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from cryptography.exceptions import InvalidSignature
from cryptography.hazmat.primitives import serialization
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey, Ed25519PublicKey

from protocol.clock import Clock, WallClock
from protocol.codec import encode
from protocol.keys import parse_key
from protocol.messages import EvAlert, HazardAlert, Health, PathSwitchCommand, Signature
from protocol.transport import MessageCallback, RejectCallback, Subscription, Transport

log = logging.getLogger(__name__)

SIGNED_TYPES = (PathSwitchCommand, EvAlert, HazardAlert)
"""Kinds that must be signed in a signed corridor (unsigned ones are refused)."""
HEARTBEAT_TYPES = (Health,)
"""Kinds a signer signs and a verifier checks when they carry a signature; unsigned ones pass (vehicles
publish unsigned Health); the vehicle itself requires a signed DDM heartbeat (vehicle/service.py)."""
HEARTBEAT_VALID_FOR_S = 5.0
"""Validity of a heartbeat's signature after its stamp: beats come at 1 Hz."""
_DOMAIN = b"iea-sig-v1\x00"
ALERT_VALID_FOR_S = 5.0
"""Validity of an alert's signature after its stamp: alerts repeat at 2 Hz and the DDM forgets one
after 5 s (``DdmConfig.ev_alert_timeout_s``), so a captured alert cannot be replayed for longer."""


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
        return self._sign(key, message, max(0.0, now - skew_s), now + valid_for_s)

    def sign_message(self, key: str, message: Any, valid_for_s: float = ALERT_VALID_FOR_S,
                     skew_s: float = 1.0) -> Any:
        """Sign with a window taken from the message itself, so that signing is deterministic (Ed25519
        is) and a retransmission carries the very same signature (``ReplayGuard`` calls it a duplicate):
        a command from ``issued_at - skew_s`` to its ``valid_until``; an alert from ``stamp - skew_s``
        for ``valid_for_s``."""
        if isinstance(message, PathSwitchCommand):
            return self._sign(key, message, max(0.0, message.issued_at - skew_s), message.valid_until)
        if isinstance(message, EvAlert | HazardAlert):
            return self._sign(key, message, max(0.0, message.stamp - skew_s), message.stamp + valid_for_s)
        if isinstance(message, Health):
            return self._sign(key, message, max(0.0, message.stamp - skew_s), message.stamp + HEARTBEAT_VALID_FOR_S)
        raise TypeError(f"{type(message).__name__} is not a signed message kind")

    def _sign(self, key: str, message: Any, not_before: float, not_after: float) -> Any:
        if not isinstance(message, SIGNED_TYPES + HEARTBEAT_TYPES):
            raise TypeError(f"{type(message).__name__} is not a signed message kind")
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
    station_id: int | None = None
    """For an EV key (role ``ev``): the V2X StationId whose CAMs it signs (protocol/v2x/secure.py)."""

    def may_sign(self, key: str, message: Any) -> bool:
        parsed = parse_key(key)
        if isinstance(message, PathSwitchCommand):
            return (self.role == "ddm" and parsed.domain == "vehicle" and message.vehicle_id == parsed.node
                    and ("*" in self.vehicles or parsed.node in self.vehicles))
        if isinstance(message, EvAlert | HazardAlert):
            return (self.role == "rsu" and parsed.domain == "rsu" and parsed.node == self.rsu_id
                    and message.rsu_id == self.rsu_id)
        if isinstance(message, Health):  # a service's own heartbeat, on its own key
            return ((self.role == "ddm" and parsed.domain == "ddm" and parsed.topic == "health")
                    or (self.role == "rsu" and parsed.domain == "rsu" and parsed.node == self.rsu_id
                        and parsed.topic == "health"))
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
            if role not in ("ddm", "rsu", "ev"):
                raise ValueError(f"{where}.role: expected 'ddm', 'rsu' or 'ev', got {role!r}")
            vehicles = tuple(e.get("vehicles", ["*"]))
            rsu_id = e.get("rsu_id")
            if role == "rsu" and not isinstance(rsu_id, str):
                raise ValueError(f"{where}.rsu_id: an RSU key must name the RSU it speaks for")
            station = e.get("station_id")
            if role == "ev" and (not isinstance(station, int) or isinstance(station, bool)
                                 or not 0 <= station < 2**32):
                raise ValueError(f"{where}.station_id: an EV key must name the V2X station id (0..2^32-1) it signs for")
            out[kid] = TrustedKey(kid, parse_public_key(e.get("public_key", ""), f"{where}.public_key"), role,
                                  vehicles, rsu_id, station if role == "ev" else None)
        return cls(out)

    @classmethod
    def from_corridor(cls, corridor: Any) -> TrustList:
        """The corridor file's ``[[trust]]`` entries (empty when it has none)."""
        return cls.from_entries(list(getattr(corridor, "trust", ())), f"{getattr(corridor, 'source', '') or 'corridor'}: trust")

    def has_role(self, role: str) -> bool:
        return any(k.role == role for k in self.keys.values())

    def key_id_of(self, private_key: Ed25519PrivateKey) -> str | None:
        """The id under which this private key's public half is trusted (None: not in the list)."""
        mine = public_key_b64(private_key.public_key())
        for k in self.keys.values():
            if public_key_b64(k.public_key) == mine:
                return k.key_id
        return None


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
    a known command id with different content, or a copy of a command that a newer one from the same
    signer has replaced. An identical copy of the newest command (a retransmission) is a
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
        newest = self._newest_seq.get((signer, command.vehicle_id))
        if seen is not None:
            if seen != digest:
                raise AuthError("replayed", f"command id {command.command_id!r} reused with different content")
            if newest is not None and command.command_seq < newest:
                raise AuthError("replayed", f"command {command.command_id!r} (seq {command.command_seq}) was "
                                            f"already replaced by seq {newest}")
            return "duplicate"
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


# ----------------------------------------------------------------------------- transport wrapper
class SecureTransport(Transport):
    """Any ``Transport`` with message signatures: ``publish`` signs every unsigned ``PathSwitchCommand``,
    ``EvAlert`` and ``HazardAlert`` with ``signer`` (``Signer.sign_message``: deterministic, so a
    retransmission is byte-identical); ``subscribe`` checks those kinds with ``verifier`` before the
    callback sees them. A refused message is counted in the shared ``stats.rejected`` as
    ``auth_<reason>`` and passed to ``on_reject``. ``require_signed=False`` lets unsigned messages
    through (signed ones are still checked). Other kinds pass untouched. Closing it closes ``inner``."""

    def __init__(self, inner: Transport, clock: Clock | None = None, *, signer: Signer | None = None,
                 verifier: Verifier | None = None, require_signed: bool = True,
                 alert_valid_for_s: float = ALERT_VALID_FOR_S) -> None:
        self.inner = inner
        self.stats = inner.stats  # one set of counters: the service's Health reads them
        self._stats_lock = getattr(inner, "_stats_lock", threading.Lock())
        self.clock = clock or WallClock()
        self.signer, self.verifier, self.require_signed = signer, verifier, require_signed
        self.alert_valid_for_s = alert_valid_for_s

    def publish_bytes(self, key: str, payload: bytes) -> None:
        self.inner.publish_bytes(key, payload)

    def subscribe_bytes(self, key_expr: str, callback: Any) -> Subscription:
        return self.inner.subscribe_bytes(key_expr, callback)

    def publish(self, key: str, message: Any) -> None:
        if self.signer is not None and isinstance(message, SIGNED_TYPES + HEARTBEAT_TYPES) and message.auth is None:
            message = self.signer.sign_message(key, message, self.alert_valid_for_s)
        self.inner.publish(key, message)

    def subscribe(self, key_expr: str, callback: MessageCallback,
                  on_reject: RejectCallback | None = None) -> Subscription:
        if self.verifier is None:
            return self.inner.subscribe(key_expr, callback, on_reject)
        verifier = self.verifier

        def checked(key: str, message: Any) -> None:
            if (isinstance(message, SIGNED_TYPES) and (message.auth is not None or self.require_signed)) \
                    or (isinstance(message, HEARTBEAT_TYPES) and message.auth is not None):
                try:
                    verifier.check(key, message, self.clock.now())
                except AuthError as exc:
                    with self._stats_lock:
                        self.stats.rejected[f"auth_{exc.reason}"] += 1
                    log.debug("refused %s on %s: %s", type(message).__name__, key, exc)
                    if on_reject is not None:
                        on_reject(key, exc)
                    return
            callback(key, message)

        return self.inner.subscribe(key_expr, checked, on_reject)

    def close(self) -> None:
        self.inner.close()


def load_signer(path: str | Path, key_id: str | None = None, trust: TrustList | None = None) -> Signer:
    """A signer from a PEM file; without ``key_id`` the id is the trust-list entry of its public key."""
    private = load_private_key(path)
    if key_id is None:
        key_id = trust.key_id_of(private) if trust is not None else None
        if key_id is None:
            raise ValueError(f"{path}: its public key is not in the corridor's trust list; give --key-id "
                             "or add the [[trust]] entry printed by `iea keys new`")
    return Signer(key_id, private)
