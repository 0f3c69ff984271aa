"""Signed V2X envelopes: an EV's CAM signed by the EV, passed on to the DDM by an RSU's radio signed by the RSU.

Real stations wrap a CAM in an IEEE 1609.2 / TS 103 097 ``SignedData`` with ECDSA P-256 and a certificate chain.
The corridor has its own PKI already (``protocol/security.py``: Ed25519 keys in the corridor file's ``[[trust]]``
list, each with a role and a scope), so the same keys, trust list and checks are used here: one trust list for
every signer, deterministic signatures, and 64-byte signatures that verify in about 50 us. The envelope keeps the
UPER bytes untouched, so a 1609.2 envelope can replace it without touching the CAM.

Envelope (msgpack map): ``payload`` (bytes: a UPER CAM, or for a relay the EV's envelope as received),
``key_id``, ``not_before`` / ``not_after`` (s), ``sig`` (64 bytes) and, for a relay, ``rsu_id``, ``heard_on`` (the
key the EV's envelope arrived on) and ``rx_time_s``. The signature covers

    b"iea-v2x-sig-v1\\0" + key + b"\\0" + msgpack([payload, rsu_id, heard_on, rx_time_s]) + not_before + not_after

so it is bound to the key it is published on and to its validity window (1 s for a CAM sent at 10 Hz, with
0.2 s of clock skew: a CAM recorded off the air and played back 1.2 s later is ``expired``).
``verify_relayed_cam`` refuses, each with ``AuthError``'s reason: an unsigned envelope, an unknown key, a bad
signature (a forged or altered CAM), an expired one, a signer out of scope (an RSU key speaking for another
RSU, an EV key for another station id), and, through :class:`CamReplayGuard`, a CAM older than the newest one
accepted from that station (``replayed``).
"""

from __future__ import annotations

import struct
from collections import OrderedDict
from dataclasses import dataclass
from typing import Any

import msgpack
from cryptography.exceptions import InvalidSignature

from protocol.security import AuthError, Signer, TrustedKey, TrustList
from protocol.v2x.build import CamInfo, cam_info
from protocol.v2x.codec import MAX_V2X_BYTES, V2xError, decode

DOMAIN = b"iea-v2x-sig-v1\x00"
CAM_VALID_FOR_S = 1.0
"""A CAM's signature is valid for this long after its generation (CAMs come at 1-10 Hz)."""
MAX_ENVELOPE_BYTES = MAX_V2X_BYTES * 2 + 512


@dataclass(frozen=True)
class SignedV2x:
    payload: bytes
    key_id: str
    not_before: float
    not_after: float
    sig: bytes
    rsu_id: str | None = None
    heard_on: str | None = None
    rx_time_s: float | None = None


def _signed_bytes(key: str, payload: bytes, rsu_id: str | None, heard_on: str | None, rx_time_s: float | None,
                  not_before: float, not_after: float) -> bytes:
    body = msgpack.packb([payload, rsu_id, heard_on, rx_time_s], use_bin_type=True)
    return DOMAIN + key.encode() + b"\x00" + body + struct.pack(">dd", not_before, not_after)


def seal(signer: Signer, key: str, payload: bytes, now_s: float, valid_for_s: float = CAM_VALID_FOR_S, *,
         rsu_id: str | None = None, heard_on: str | None = None, rx_time_s: float | None = None,
         skew_s: float = 0.5) -> bytes:
    """The envelope bytes of ``payload`` signed by ``signer`` for ``key``, valid from ``now_s - skew_s``."""
    nb, na = max(0.0, now_s - skew_s), now_s + valid_for_s
    sig = signer.private_key.sign(_signed_bytes(key, payload, rsu_id, heard_on, rx_time_s, nb, na))
    out: dict[str, Any] = {"payload": payload, "key_id": signer.key_id, "not_before": nb, "not_after": na, "sig": sig}
    if rsu_id is not None:
        out.update(rsu_id=rsu_id, heard_on=heard_on, rx_time_s=rx_time_s)
    return msgpack.packb(out, use_bin_type=True)


def _field(m: dict[str, Any], name: str, kind: type | tuple[type, ...], optional: bool = False) -> Any:
    v = m.get(name)
    if v is None and optional:
        return None
    if not isinstance(v, kind) or isinstance(v, bool):
        raise V2xError(f"V2X envelope: {name!r} must be {kind}, got {type(v).__name__}")
    return v


def open_envelope(data: bytes) -> SignedV2x:
    """Parse an envelope strictly (bounded sizes, typed fields); ``V2xError`` for anything else."""
    if not isinstance(data, bytes | bytearray) or len(data) > MAX_ENVELOPE_BYTES:
        raise V2xError(f"V2X envelope: bytes of at most {MAX_ENVELOPE_BYTES} expected")
    try:
        m = msgpack.unpackb(bytes(data), raw=False, max_bin_len=MAX_ENVELOPE_BYTES, max_str_len=256,
                            max_array_len=16, max_map_len=16, strict_map_key=True)
    except Exception as e:  # noqa: BLE001 - msgpack raises several types on bad bytes
        raise V2xError(f"V2X envelope: not msgpack ({type(e).__name__})") from None
    if not isinstance(m, dict):
        raise V2xError("V2X envelope: a map expected")
    env = SignedV2x(_field(m, "payload", bytes), _field(m, "key_id", str), float(_field(m, "not_before", (int, float))),
                    float(_field(m, "not_after", (int, float))), _field(m, "sig", bytes),
                    _field(m, "rsu_id", str, True), _field(m, "heard_on", str, True),
                    _field(m, "rx_time_s", (int, float), True))
    if len(env.sig) != 64:
        raise V2xError("V2X envelope: an Ed25519 signature has 64 bytes")
    return env


def _check(env: SignedV2x, key: str, trust: TrustList, now_s: float, role: str, skew_s: float) -> TrustedKey:
    trusted = trust.keys.get(env.key_id)
    if trusted is None:
        raise AuthError("unknown_key", f"key id {env.key_id!r} is not in the trust list")
    if trusted.role != role:
        raise AuthError("out_of_scope", f"key {env.key_id!r} ({trusted.role}) may not sign a {role}'s V2X envelope")
    try:
        trusted.public_key.verify(env.sig, _signed_bytes(key, env.payload, env.rsu_id, env.heard_on, env.rx_time_s,
                                                         env.not_before, env.not_after))
    except InvalidSignature:
        raise AuthError("bad_signature", f"signature by {env.key_id!r} does not match the envelope on {key}") from None
    if now_s > env.not_after + skew_s:
        raise AuthError("expired", f"signature expired at {env.not_after:.3f} (now {now_s:.3f})")
    if now_s < env.not_before - skew_s:
        raise AuthError("not_yet_valid", f"signature valid from {env.not_before:.3f} (now {now_s:.3f})")
    return trusted


class CamReplayGuard:
    """The newest CAM generation window accepted per station: an older one is ``replayed``; the same one (the
    same CAM passed on by two RSUs) is a duplicate, returned as False. Bounded to ``capacity`` stations."""

    def __init__(self, capacity: int = 1024) -> None:
        self.capacity = capacity
        self._newest: OrderedDict[int, float] = OrderedDict()

    def admit(self, station_id: int, signed_from_s: float) -> bool:
        last = self._newest.get(station_id)
        if last is not None and signed_from_s < last:
            raise AuthError("replayed", f"station {station_id}: CAM signed from {signed_from_s:.3f} is older than "
                                        f"the newest accepted ({last:.3f})")
        if last is not None and signed_from_s == last:
            return False
        self._newest[station_id] = signed_from_s
        self._newest.move_to_end(station_id)
        while len(self._newest) > self.capacity:
            self._newest.popitem(last=False)
        return True


@dataclass(frozen=True)
class RelayedCam:
    info: CamInfo
    rsu_id: str
    rx_time_s: float
    signed_from_s: float
    """Start of the EV's signature window: its generation time less the signer's skew."""


V2X_SKEW_S = 0.2
"""Clock skew allowed on a V2X signature's window: ITS stations keep GNSS time (TS 102 894-2 TimestampIts)."""


def verify_relayed_cam(key: str, data: bytes, trust: TrustList, now_s: float, replay: CamReplayGuard | None = None,
                       skew_s: float = V2X_SKEW_S) -> RelayedCam | None:
    """The CAM an RSU passed on, checked end to end: the RSU's envelope (role ``rsu``, its own RSU), the EV's
    envelope inside it (role ``ev``, its own station id), the CAM itself. None for a duplicate. Raises
    ``AuthError`` (with its reason) or ``V2xError`` (bad bytes)."""
    outer = open_envelope(data)
    rsu = _check(outer, key, trust, now_s, "rsu", skew_s)
    if outer.rsu_id is None or outer.heard_on is None or outer.rx_time_s is None:
        raise V2xError("V2X relay: rsu_id, heard_on and rx_time_s are required")
    if rsu.rsu_id != outer.rsu_id or f"/v2x/rsu/{outer.rsu_id}/" not in key:
        raise AuthError("out_of_scope", f"RSU key {rsu.key_id!r} speaks for {rsu.rsu_id!r}, not for this relay")
    inner = open_envelope(outer.payload)
    ev = _check(inner, outer.heard_on, trust, now_s, "ev", skew_s)
    msg = decode(inner.payload, expected="CAM")
    if ev.station_id != msg.header.station_id:
        raise AuthError("out_of_scope", f"EV key {ev.key_id!r} signs for station {ev.station_id}, the CAM says "
                                        f"{msg.header.station_id}")
    if replay is not None and not replay.admit(msg.header.station_id, inner.not_before):
        return None
    return RelayedCam(cam_info(msg), outer.rsu_id, float(outer.rx_time_s), inner.not_before)
