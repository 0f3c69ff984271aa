"""UPER codec of the ETSI ITS Release 2 CAM (TS 103 900), DENM (TS 103 831) and CPM (TS 103 324).

- Dispatch: the ItsPduHeader (TS 102 894-2 A.114) opens every message, byte-aligned: ``protocolVersion`` (one
  octet), ``messageId`` (one octet), ``stationId`` (four). The pair (protocolVersion, messageId) picks the schema
  before anything else is decoded: a version-1 CAM or DENM (EN 302 637-2 / -3 v1.x) does not decode under the
  Release 2 modules, and a short version-2 CAM can "decode" under a version-1 schema into nonsense. Unknown pairs
  are refused with the reason. Another family (a user's SAE J2735 codec) plugs in with :func:`register`.
- Open types (CAM ``extensionContainers``, CPM ``cpmContainers``): asn1tools hands them over as bytes; they are
  decoded in a second step against the container's own type (``containerData`` becomes the decoded value;
  an unknown container id keeps its bytes) and encoded in a first step on the way out.
- Strictness (as the msgpack codec, ``protocol/codec.py``): at most ``MAX_V2X_BYTES``; constraints checked both
  ways; bytes after the encoding other than zero padding refused; any failure is one :class:`V2xError` saying
  what was wrong, never another exception.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import Any

from asn1tools.codecs import uper as _uper

from protocol.v2x.schema import specification

MAX_V2X_BYTES = 8192
"""Largest message accepted (a CPM of 255 objects is about 6 kB; an ITS-G5 frame carries at most 1,500 bytes)."""

MESSAGE_ID = {"DENM": 1, "CAM": 2, "CPM": 14}
"""``MessageId`` values (TS 102 894-2 A.48)."""
RELEASE2_VERSION = 2

CAM_EXTENSION_CONTAINERS = {
    1: "TwoWheelerContainer", 2: "EHorizonLocationSharingContainer", 3: "VeryLowFrequencyContainer",
    4: "PathPredictionContainer", 5: "GeneralizedLanePositionsContainer", 6: "VehicleMovementControlContainer"}
"""TS 103 900 ``ExtensionContainers`` (id -> type)."""
CPM_CONTAINERS = {
    1: "OriginatingVehicleContainer", 2: "OriginatingRsuContainer", 3: "SensorInformationContainer",
    4: "PerceptionRegionContainer", 5: "PerceivedObjectContainer"}
"""TS 103 324 ``CpmContainers`` (id -> type)."""


class V2xError(ValueError):
    """Bytes that are not a message this codec accepts, or a value it cannot encode; the message says why."""


@dataclass(frozen=True)
class Header:
    protocol_version: int
    message_id: int
    station_id: int


@dataclass(frozen=True)
class V2xMessage:
    """A decoded message: its kind (``CAM``, ``DENM``, ``CPM``), header and asn1tools value (open types decoded)."""

    kind: str
    header: Header
    value: dict[str, Any]


def read_header(data: bytes) -> Header:
    """The ItsPduHeader of ``data`` (6 octets, byte-aligned in UPER: two 8-bit and one 32-bit constrained integer)."""
    if not isinstance(data, bytes | bytearray | memoryview):
        raise V2xError(f"a V2X message is bytes, not {type(data).__name__}")
    if len(data) < 6:
        raise V2xError(f"{len(data)} bytes: too short for an ITS PDU header (6 bytes: protocolVersion, messageId, "
                       "stationId)")
    version, msg_id, station = struct.unpack_from(">BBI", data)
    return Header(version, msg_id, station)


# ----------------------------------------------------------------------------- open types
def _wrap_open(containers: list[dict[str, Any]], types: dict[int, str], encode: bool) -> list[dict[str, Any]]:
    spec = specification()
    out = []
    for c in containers:
        cid, data = c["containerId"], c["containerData"]
        name = types.get(cid)
        if name is not None:
            if encode:
                data = spec.encode(name, data, check_constraints=True) or b"\x00"  # X.691 11.2: never empty
            else:
                data = spec.decode(name, data, check_constraints=True)
        out.append({"containerId": cid, "containerData": data})
    return out


def _open_types(kind: str, value: dict[str, Any], encode: bool) -> dict[str, Any]:
    if kind == "CAM":
        params = value["cam"]["camParameters"]
        if "extensionContainers" in params:
            params = {**params, "extensionContainers": _wrap_open(params["extensionContainers"],
                                                                  CAM_EXTENSION_CONTAINERS, encode)}
            return {**value, "cam": {**value["cam"], "camParameters": params}}
    elif kind == "CPM":
        payload = value["payload"]
        payload = {**payload, "cpmContainers": _wrap_open(payload["cpmContainers"], CPM_CONTAINERS, encode)}
        return {**value, "payload": payload}
    return value


# ----------------------------------------------------------------------------- codecs and dispatch
def _decode_with_length(type_name: str, data: bytes) -> tuple[Any, int | None]:
    """(value, octets used) of a UPER decode with constraints checked. asn1tools' public API gives no length
    for UPER, so its decoder is driven directly; the octet count is None where its internals differ."""
    compiled = specification().types[type_name]
    inner = getattr(compiled, "_type", None)
    if inner is None or not hasattr(inner, "decode"):
        value = specification().decode(type_name, data, check_constraints=True)
        return value, None
    decoder = _uper.Decoder(bytearray(data))
    value = inner.decode(decoder)
    compiled.check_constraints(value)
    return value, (decoder.number_of_read_bits() + 7) // 8


@dataclass(frozen=True)
class _Asn1Codec:
    kind: str
    type_name: str

    def decode(self, data: bytes) -> dict[str, Any]:
        value, length = _decode_with_length(self.type_name, data)
        if length is not None and any(data[length:]):
            raise V2xError(f"{len(data) - length} bytes after the {self.kind} that are not zero padding")
        return _open_types(self.kind, value, encode=False)

    def encode(self, value: dict[str, Any]) -> bytes:
        return specification().encode(self.type_name, _open_types(self.kind, value, encode=True),
                                       check_constraints=True)


_CODECS: dict[tuple[int, int], _Asn1Codec] = {
    (RELEASE2_VERSION, MESSAGE_ID["CAM"]): _Asn1Codec("CAM", "CAM"),
    (RELEASE2_VERSION, MESSAGE_ID["DENM"]): _Asn1Codec("DENM", "DENM"),
    (RELEASE2_VERSION, MESSAGE_ID["CPM"]): _Asn1Codec("CPM", "CollectivePerceptionMessage"),
}
_REFUSED_VERSIONS = {
    1: "protocolVersion 1 (EN 302 637-2 v1.x CAM / EN 302 637-3 v1.x DENM) is the first-generation schema; "
       "this station speaks Release 2 (protocolVersion 2) only",
}


def register(protocol_version: int, message_id: int, kind: str, codec: Any) -> None:
    """Add a codec for another (protocolVersion, messageId): an object with ``decode(bytes) -> dict`` and
    ``encode(dict) -> bytes`` (e.g. a user's SAE J2735 codec behind its own header family)."""
    _CODECS[(protocol_version, message_id)] = codec
    MESSAGE_ID.setdefault(kind, message_id)


def _codec_for(header: Header) -> Any:
    codec = _CODECS.get((header.protocol_version, header.message_id))
    if codec is not None:
        return codec
    if header.protocol_version in _REFUSED_VERSIONS:
        raise V2xError(f"messageId {header.message_id}: {_REFUSED_VERSIONS[header.protocol_version]}")
    known = ", ".join(f"{c.kind} v{v}" for (v, _m), c in sorted(_CODECS.items()))
    raise V2xError(f"no codec for protocolVersion {header.protocol_version}, messageId {header.message_id} "
                   f"(this station decodes {known})")


def decode(data: bytes, expected: str | None = None) -> V2xMessage:
    """Decode one UPER message, dispatched on its header; ``expected`` (``CAM``, ``DENM``, ``CPM``) refuses others.

    Raises :class:`V2xError` for anything it does not accept, with the reason."""
    if isinstance(data, bytearray | memoryview):
        data = bytes(data)
    header = read_header(data)
    if len(data) > MAX_V2X_BYTES:
        raise V2xError(f"{len(data)} bytes: larger than the {MAX_V2X_BYTES} a V2X message may have")
    codec = _codec_for(header)
    if expected is not None and codec.kind != expected:
        raise V2xError(f"expected a {expected}, got a {codec.kind} (messageId {header.message_id})")
    try:
        value = codec.decode(data)
    except V2xError:
        raise
    except Exception as e:  # asn1tools raises DecodeError, but also IndexError/ValueError/... on bad bytes
        raise V2xError(f"not a valid {codec.kind} (protocolVersion {header.protocol_version}): "
                       f"{type(e).__name__}: {e}") from None
    return V2xMessage(codec.kind, header, value)


def encode(kind: str, value: dict[str, Any]) -> bytes:
    """UPER bytes of a CAM / DENM / CPM value (asn1tools form; open-type containers given as values)."""
    try:
        header = value["header"]
        codec = _codec_for(Header(header["protocolVersion"], header["messageId"], header["stationId"]))
    except (KeyError, TypeError) as e:
        raise V2xError(f"a {kind} value needs its header (protocolVersion, messageId, stationId): missing {e}") from None
    if codec.kind != kind:
        raise V2xError(f"the header says {codec.kind} (messageId {header['messageId']}), the caller {kind}")
    try:
        data = codec.encode(value)
    except Exception as e:
        raise V2xError(f"cannot encode this {kind}: {type(e).__name__}: {e}") from None
    if len(data) > MAX_V2X_BYTES:
        raise V2xError(f"the {kind} encodes to {len(data)} bytes, more than {MAX_V2X_BYTES}")
    return data


def to_plain(value: Any) -> Any:
    """A decoded value as JSON-able data: bytes -> hex, a BIT STRING (bytes, bits) -> its bits as '0'/'1', a CHOICE
    (name, value) -> {name: value}."""
    if isinstance(value, dict):
        return {k: to_plain(v) for k, v in value.items()}
    if isinstance(value, list):
        return [to_plain(v) for v in value]
    if isinstance(value, tuple):
        if len(value) == 2 and isinstance(value[0], bytes) and isinstance(value[1], int):
            bits = "".join(f"{b:08b}" for b in value[0])
            return bits[: value[1]]
        if len(value) == 2 and isinstance(value[0], str):
            return {value[0]: to_plain(value[1])}
        return [to_plain(v) for v in value]
    if isinstance(value, bytes | bytearray):
        return bytes(value).hex()
    return value
