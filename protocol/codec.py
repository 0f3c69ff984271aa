"""msgpack encoding of the message models with strict validation on decode.

Wire format: one msgpack map ``{"kind": <model name>, **fields}``; nested value records
(``DetectedObject``, ``Actor``, ``EvEvidence``, ``LightBar``) travel as arrays of their fields in
declaration order, which keeps a 30-object ObjectList round trip under 100 us (bench/protocol_bench.py). ``decode`` accepts nothing but a
well-formed message of the expected kind: truncated or trailing bytes, a payload over the size cap,
a non-map, an unknown kind, the wrong kind for the key, an unknown schema version, a missing or
extra field, a wrong type, NaN/inf or an out-of-range value all raise ``ProtocolError`` whose text
names the field and the problem. Nothing else escapes ``decode``.

Bounded work: what one payload can make ``decode`` build is capped before validation, by
the largest valid message rather than by the payload size alone: the payload size, every array's and
map's length, every string's and binary's size, and (for payloads over ``HOOK_FROM_BYTES``) the number
of arrays and maps in the whole payload. A list field longer than its model allows is refused before
its records are built. A hostile payload therefore costs about as much as the largest valid message
(a ~190 kB WorldSnapshot of 1,024 actors decodes in a few ms), not megabytes of nested tuples.
"""

from __future__ import annotations

import dataclasses
import operator
import types
import typing
from dataclasses import dataclass
from typing import Any, TypeVar

import msgpack
from pydantic import ValidationError
from pydantic_core import ArgsKwargs

from protocol.messages import (
    MAX_ACTORS,
    MAX_HEALTH_ENTRIES,
    MAX_TEXT,
    MESSAGE_BY_KIND,
    MESSAGE_TYPES,
    SCHEMA_VERSION,
    Envelope,
)

MAX_PAYLOAD_BYTES = 256 * 1024
"""Largest payload a decoder accepts: the largest valid message, a WorldSnapshot of 1,024 actors with
64-character ids, is about 188 kB."""
MAX_CONTAINER_ITEMS = max(MAX_ACTORS, max(len(m.model_fields) + 1 for m in MESSAGE_TYPES), MAX_HEALTH_ENTRIES)
"""Longest array or map in any valid message (the actors of a WorldSnapshot)."""
MAX_STR_BYTES = 4 * MAX_TEXT
"""Longest string (a ``Text`` of 256 characters, 4 UTF-8 bytes each)."""
MAX_BIN_BYTES = 64
"""Longest binary (an Ed25519 signature)."""
MAX_CONTAINERS = 3 * MAX_ACTORS + 64
"""Most arrays and maps in one valid message: a WorldSnapshot holds 3 per actor (row, colour, light bar)."""
HOOK_FROM_BYTES = 16 * 1024
"""Payloads up to this size hold at most ~8,000 containers (cheap): only larger ones are counted."""
_UNPACK_LIMITS = dict(raw=False, use_list=False, strict_map_key=True, max_str_len=MAX_STR_BYTES,
                      max_bin_len=MAX_BIN_BYTES, max_array_len=MAX_CONTAINER_ITEMS,
                      max_map_len=MAX_CONTAINER_ITEMS, max_ext_len=0)

M = TypeVar("M", bound=Envelope)


class ProtocolError(ValueError):
    """Input that is not a valid message. ``reason`` is a short machine-friendly category."""

    def __init__(self, message: str, reason: str = "invalid") -> None:
        super().__init__(message)
        self.reason = reason


# ------------------------------------------------------------------ wire plans
@dataclass(frozen=True)
class _Nested:
    """A field holding a record (``many``: a list of them, at most ``max_items``)."""

    name: str
    index: int
    plan: _RecordPlan
    many: bool
    max_items: int | None = None


@dataclass(frozen=True)
class _RecordPlan:
    cls: type
    names: tuple[str, ...]
    nested: tuple[_Nested, ...]

    def to_row(self, obj: Any) -> Any:
        row = self.getter(obj)
        if len(self.names) == 1:
            row = (row,)
        if not self.nested:
            return row
        row = list(row)
        for n in self.nested:
            v = row[n.index]
            if v is not None:
                row[n.index] = [n.plan.to_row(x) for x in v] if n.many else n.plan.to_row(v)
        return row

    @property
    def getter(self) -> operator.attrgetter:  # cached below in __post_init__
        return self._getter  # type: ignore[attr-defined]

    def __post_init__(self) -> None:
        object.__setattr__(self, "_getter", operator.attrgetter(*self.names))

    def from_row(self, row: Any, where: str) -> ArgsKwargs:
        if not isinstance(row, list | tuple) or len(row) != len(self.names):
            got = f"{len(row)} values" if isinstance(row, list | tuple) else type(row).__name__
            raise ProtocolError(
                f"{where}: a {self.cls.__name__} must be an array of {len(self.names)} fields "
                f"({', '.join(self.names[:3])}, ...), got {got}",
                "invalid",
            )
        if self.nested:
            row = list(row)
            for n in self.nested:
                row[n.index] = _from_wire(n, row[n.index], f"{where}.{n.name}")
        return ArgsKwargs(row if type(row) is tuple else tuple(row))


def _record_type(annotation: Any) -> tuple[type | None, bool]:
    """(record class, many) when ``annotation`` is a record, a list of records or Optional[record]."""
    origin = typing.get_origin(annotation)
    args = typing.get_args(annotation)
    if origin is list and args and dataclasses.is_dataclass(args[0]):
        return args[0], True
    if origin in (typing.Union, types.UnionType):
        recs = [a for a in args if dataclasses.is_dataclass(a)]
        if len(recs) == 1:
            return recs[0], False
    if dataclasses.is_dataclass(annotation):
        return annotation, False
    return None, False


def _plan_fields(fields: dict[str, Any]) -> tuple[tuple[str, ...], tuple[_Nested, ...]]:
    names = tuple(fields)
    nested = []
    for i, (name, info) in enumerate(fields.items()):
        cls, many = _record_type(info.annotation)
        if cls is not None:
            caps = [m.max_length for m in getattr(info, "metadata", ()) if hasattr(m, "max_length")]
            nested.append(_Nested(name, i, _record_plan(cls), many, min(caps) if caps else None))
    return names, tuple(nested)


_RECORD_PLANS: dict[type, _RecordPlan] = {}


def _record_plan(cls: type) -> _RecordPlan:
    if cls not in _RECORD_PLANS:
        names, nested = _plan_fields(cls.__pydantic_fields__)  # type: ignore[attr-defined]
        _RECORD_PLANS[cls] = _RecordPlan(cls, names, nested)
    return _RECORD_PLANS[cls]


_MESSAGE_PLANS: dict[type, tuple[tuple[str, ...], tuple[_Nested, ...]]] = {
    m: _plan_fields(m.model_fields) for m in MESSAGE_TYPES
}


def _from_wire(n: _Nested, value: Any, where: str) -> Any:
    if value is None:
        return None
    if n.many:
        if not isinstance(value, tuple | list):
            return value  # pydantic reports the wrong type with the field's name
        if n.max_items is not None and len(value) > n.max_items:
            raise ProtocolError(f"{where}: at most {n.max_items} items, got {len(value)}", "invalid")
        return [n.plan.from_row(r, f"{where}.{i}") for i, r in enumerate(value)]
    return n.plan.from_row(value, where)


def encode(message: Envelope) -> bytes:
    """Serialise a validated message to msgpack bytes."""
    plan = _MESSAGE_PLANS.get(type(message))
    if plan is None:
        raise ProtocolError(f"cannot encode {type(message).__name__}: not a protocol message", "type")
    names, nested = plan
    values = message.__dict__
    body = {"kind": message.KIND}
    for name in names:
        body[name] = values[name]
    for n in nested:
        v = body[n.name]
        if v is not None:
            body[n.name] = [n.plan.to_row(x) for x in v] if n.many else n.plan.to_row(v)
    return msgpack.packb(body, use_bin_type=True)


def _reject_ext(code: int, data: bytes) -> None:
    raise ProtocolError(f"msgpack extension type {code} is not allowed", "format")


class _ContainerBudget:
    """``list_hook`` / ``object_hook`` that refuses a payload once it built ``MAX_CONTAINERS`` arrays and maps."""

    __slots__ = ("left",)

    def __init__(self) -> None:
        self.left = MAX_CONTAINERS

    def __call__(self, container: Any) -> Any:
        self.left -= 1
        if self.left < 0:
            raise ProtocolError(f"more than {MAX_CONTAINERS} arrays and maps: larger than any message", "format")
        return container


def _unpack(payload: bytes | bytearray | memoryview) -> Any:
    """msgpack -> Python with the limits above (module docstring)."""
    if len(payload) <= HOOK_FROM_BYTES:
        return msgpack.unpackb(payload, ext_hook=_reject_ext, **_UNPACK_LIMITS)
    budget = _ContainerBudget()
    return msgpack.unpackb(payload, ext_hook=_reject_ext, list_hook=budget, object_hook=budget, **_UNPACK_LIMITS)


def _name_loc(loc: tuple[Any, ...], nested: tuple[_Nested, ...]) -> list[str]:
    """Replace positional indexes inside records by field names (records travel as arrays)."""
    out: list[str] = []
    i = 0
    by_name = {n.name: n for n in nested}
    while i < len(loc):
        item = loc[i]
        out.append(str(item))
        n = by_name.get(item) if isinstance(item, str) else None
        i += 1
        if n is None:
            continue
        if n.many and i < len(loc) and isinstance(loc[i], int):
            out.append(str(loc[i]))
            i += 1
        if i < len(loc) and isinstance(loc[i], int) and loc[i] < len(n.plan.names):
            field_name = n.plan.names[loc[i]]
            out.append(field_name)
            by_name = {m.name: m for m in n.plan.nested}
            sub = by_name.get(field_name)
            i += 1
            if sub is not None:
                # continue resolving inside the nested record
                rest = _name_loc((field_name, *loc[i:]), (sub,))
                return out[:-1] + rest
    return out


def _describe(err: ValidationError, kind: str, nested: tuple[_Nested, ...] = ()) -> str:
    parts = []
    for item in err.errors(include_url=False)[:5]:
        loc = ".".join(_name_loc(tuple(item["loc"]), nested)) or "<message>"
        parts.append(f"{kind}.{loc}: {item['msg']}")
    more = err.error_count() - len(parts)
    return "; ".join(parts) + (f" (and {more} more)" if more > 0 else "")


def decode(
    payload: bytes | bytearray | memoryview,
    expected: type[M] | None = None,
    *,
    max_bytes: int = MAX_PAYLOAD_BYTES,
) -> M:
    """Decode and validate one message; ``expected`` is the kind the key carries (None: any kind)."""
    if not isinstance(payload, bytes | bytearray | memoryview):
        raise ProtocolError(f"payload must be bytes, got {type(payload).__name__}", "type")
    size = len(payload)
    if size > max_bytes:
        raise ProtocolError(f"payload of {size} bytes exceeds the {max_bytes}-byte cap", "oversize")
    if size == 0:
        raise ProtocolError("empty payload", "format")
    try:
        body = _unpack(payload)
    except ProtocolError:
        raise
    except msgpack.ExtraData:
        raise ProtocolError("trailing bytes after the message", "format") from None
    except (ValueError, TypeError, msgpack.UnpackException, RecursionError) as exc:
        raise ProtocolError(f"not a msgpack message: {exc.__class__.__name__}: {exc}", "format") from None
    if not isinstance(body, dict):
        raise ProtocolError(f"message must be a map, got {type(body).__name__}", "format")
    kind = body.pop("kind", None)
    if not isinstance(kind, str):
        raise ProtocolError("field 'kind' is missing or not a string", "format")
    model = MESSAGE_BY_KIND.get(kind)
    if model is None:
        raise ProtocolError(f"unknown message kind {kind!r}", "kind")
    if expected is not None and model is not expected:
        raise ProtocolError(f"got a {kind} where a {expected.KIND} was expected for this key", "kind")
    version = body.get("v")
    if version != SCHEMA_VERSION:
        raise ProtocolError(
            f"{kind}.v: unknown schema version {version!r}; this build speaks v{SCHEMA_VERSION}", "version"
        )
    nested = _MESSAGE_PLANS[model][1]
    for n in nested:
        if n.name in body:
            body[n.name] = _from_wire(n, body[n.name], f"{kind}.{n.name}")
    try:
        return model.model_validate(body)  # type: ignore[return-value]
    except ValidationError as err:
        raise ProtocolError(_describe(err, kind, nested), "invalid") from None
    except (ValueError, TypeError, RecursionError) as exc:  # defensive: validators must not leak
        raise ProtocolError(f"{kind}: {exc}", "invalid") from None
