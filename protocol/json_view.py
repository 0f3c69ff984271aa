"""The JSON view of a wire payload, and back: what ``protocol/schema/*.json`` validates (``JSON_VIEW``).

A payload (``protocol.codec``) is one msgpack map. Its JSON view (RFC 8259) keeps the map's keys in
order, arrays as arrays, numbers as numbers (a float keeps its fraction or exponent: ``1.0`` stays a
float), and writes msgpack bin (only ``Signature.sig``) as base64 text (RFC 4648 section 4), as
``protocol.schema_export`` states. ``to_wire`` goes back: the strings the kind's schema marks
``x-msgpack: bin`` become bin again, and msgpack packs the result as ``protocol.codec.encode`` does,
so for a payload this project encoded the view carries the very wire bytes (``view_roundtrips``:
signatures still verify after a JSON round trip).

Pure functions. Recordings and the Foxglove bridge write the named form of the same message
(``protocol.record_view``, built on this module's schemas), which Foxglove's JSON Schema reader reads.
"""

from __future__ import annotations

import base64
import json
from functools import cache
from typing import Any

import msgpack

from protocol.schema_export import SCHEMA_DIR

_UNPACK = dict(raw=False, use_list=True, strict_map_key=True, max_ext_len=0)


class JsonViewError(ValueError):
    """A payload with no JSON view (not a msgpack map, an extension type, NaN/inf, non-UTF-8 text)."""


def _b64(value: Any) -> str:
    """``json.dumps``'s ``default``: msgpack bin (bytes) as base64 text; anything else has no JSON form."""
    if isinstance(value, bytes):
        return base64.b64encode(value).decode("ascii")
    raise TypeError(f"{type(value).__name__} has no JSON form")


def to_view(payload: bytes) -> dict[str, Any]:
    """The JSON view of one payload as Python data; ``JsonViewError`` when it has none."""
    return json.loads(to_json(payload))


def to_json(payload: bytes) -> bytes:
    """The JSON view of one payload as UTF-8 JSON text (compact); ``JsonViewError`` when it has none."""
    try:
        body = msgpack.unpackb(payload, **_UNPACK)
    except Exception as exc:  # msgpack raises many kinds (ExtraData, FormatError, ValueError, ...)
        raise JsonViewError(f"not a msgpack payload: {exc.__class__.__name__}: {exc}") from None
    if not isinstance(body, dict):
        raise JsonViewError(f"a payload is a map, got {type(body).__name__}")
    try:
        return json.dumps(body, separators=(",", ":"), ensure_ascii=False, allow_nan=False, default=_b64).encode()
    except (ValueError, TypeError) as exc:  # NaN or infinity, or a type JSON cannot hold: no JSON form
        raise JsonViewError(f"no JSON form: {exc}") from None


@cache
def kind_schema(kind: str) -> dict[str, Any]:
    """The committed JSON Schema of a message kind (``protocol/schema/<kind>.json``)."""
    path = SCHEMA_DIR / f"{kind}.json"
    if not path.is_file():
        raise JsonViewError(f"no schema for message kind {kind!r} in {SCHEMA_DIR}")
    return json.loads(path.read_text())


def _resolve(node: Any, root: dict[str, Any]) -> Any:
    while isinstance(node, dict) and "$ref" in node:
        ref = node["$ref"]
        if not ref.startswith("#/$defs/"):
            raise JsonViewError(f"unsupported $ref {ref!r}")
        node = root["$defs"][ref.removeprefix("#/$defs/")]
    return node


Path = tuple[str | int | None, ...]
"""Where a value sits in a view: object keys, array indexes, ``None`` for every item of an array."""


def _bin_paths(node: Any, root: dict[str, Any], here: Path = ()) -> list[Path]:
    """Every place the schema marks ``x-msgpack: bin`` (walked once per kind)."""
    node = _resolve(node, root)
    if not isinstance(node, dict):
        return []
    if node.get("x-msgpack") == "bin":
        return [here]
    out: list[Path] = []
    for branch in node.get("anyOf", []):
        out += _bin_paths(branch, root, here)
    for name, sub in node.get("properties", {}).items():
        out += _bin_paths(sub, root, (*here, name))
    for i, sub in enumerate(node.get("prefixItems", [])):
        out += _bin_paths(sub, root, (*here, i))
    if isinstance(node.get("items"), dict):
        out += _bin_paths(node["items"], root, (*here, None))
    return out


@cache
def bin_paths(kind: str) -> tuple[Path, ...]:
    schema = kind_schema(kind)
    return tuple(dict.fromkeys(_bin_paths(schema, schema)))


def _unbase64(value: Any, path: Path) -> Any:
    """``value`` with the string at ``path`` (if there) decoded from base64."""
    if not path:
        if isinstance(value, str):
            try:
                return base64.b64decode(value, validate=True)
            except ValueError as exc:
                raise JsonViewError(f"bin field is not base64: {exc}") from None
        return value
    head, rest = path[0], path[1:]
    if head is None:
        if isinstance(value, list):
            for i, v in enumerate(value):
                value[i] = _unbase64(v, rest)
    elif isinstance(head, int):
        if isinstance(value, list) and head < len(value):
            value[head] = _unbase64(value[head], rest)
    elif isinstance(value, dict) and head in value:
        value[head] = _unbase64(value[head], rest)
    return value


def to_wire(view: dict[str, Any] | bytes | str) -> bytes:
    """The msgpack payload of a JSON view (data, or JSON text); its ``kind`` selects the schema that says
    which strings are bin. ``JsonViewError`` for a view of no known kind."""
    if isinstance(view, bytes | str):
        try:
            view = json.loads(view)
        except ValueError as exc:
            raise JsonViewError(f"not JSON: {exc}") from None
    if not isinstance(view, dict) or not isinstance(view.get("kind"), str):
        raise JsonViewError("a JSON view is an object with a 'kind'")
    for path in bin_paths(view["kind"]):
        view = _unbase64(view, path)
    return msgpack.packb(view, use_bin_type=True)


def view_roundtrips(payload: bytes, view_json: bytes) -> bool:
    """True when ``view_json`` gives back exactly ``payload`` (the view can stand for the wire bytes)."""
    try:
        return to_wire(view_json) == bytes(payload)
    except JsonViewError:
        return False
