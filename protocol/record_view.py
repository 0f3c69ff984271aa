"""The record view of a wire payload: the message as JSON with every field named, and its JSON Schema in
the form Foxglove and Lichtblick read (their ``parseJsonSchema``), derived from ``protocol/schema``.

The wire (``protocol.codec``) sends records (``DetectedObject``, ``EvEvidence``, ``Signature``,
``Actor``, ``LightBar``) as positional arrays, which ``protocol/schema/<Kind>.json`` describes with
``prefixItems``, ``$ref``, ``anyOf`` and ``const``. Foxglove and Lichtblick build a channel's fields
from a JSON Schema only when every property has one plain ``type`` (boolean, string - base64 with
``contentEncoding`` -, number, integer, object with ``properties``, or an array of one of those), so
the recorded JSON names every field instead, by these rules applied to the committed schema:

- a record is an object of its fields (``x-fields``), in order;
- a field whose value is null is left out (the schema lists it as optional, with its non-null type);
- an enum is a string with its ``enum``, a constant (``kind``, ``v``) its type with its ``const``;
- a tuple of numbers (``bbox_px``, ``stop_point``) stays an array of numbers; a list of tuples
  (``waypoints``) is a list of objects ``{"x", "y"}``;
- a map (``rates_hz``) is an object of its entries (schema: ``properties: {}`` and
  ``additionalProperties``);
- bin (``Signature.sig``) is base64 text (RFC 4648 section 4) with ``contentEncoding: base64``.

Every range, length, pattern and unit title of the committed schema is kept. ``to_wire`` goes back
(missing fields are null again, in the codec's field order) and gives the very wire bytes of a payload
this project encoded (``view_roundtrips``), so signatures still verify. Pure functions.
"""

from __future__ import annotations

import base64
import copy
import json
from dataclasses import dataclass
from functools import cache
from typing import Any

import msgpack

from protocol.json_view import JsonViewError, kind_schema
from protocol.messages import MESSAGE_BY_KIND

TUPLE_KEYS = ("x", "y", "z", "w")
"""Names of a tuple's entries where a list holds tuples (a waypoint is ``{"x", "y"}``)."""
_SCALAR_KEYS = ("minimum", "maximum", "exclusiveMinimum", "exclusiveMaximum", "minLength", "maxLength",
                "pattern", "enum", "const", "contentEncoding", "x-msgpack")


@dataclass(frozen=True)
class _Plan:
    """How one value travels between the wire (msgpack data) and the record view."""

    kind: str  # scalar | bin | record | tuple | point | list | map
    names: tuple[str, ...] = ()
    parts: tuple[_Plan, ...] = ()


_SCALAR = _Plan("scalar")


def _resolve(node: Any, root: dict[str, Any]) -> Any:
    while isinstance(node, dict) and "$ref" in node:
        node = root["$defs"][node["$ref"].removeprefix("#/$defs/")]
    return node


def _non_null(node: dict[str, Any], root: dict[str, Any]) -> tuple[Any, bool]:
    """``(the non-null branch, nullable)`` of a node."""
    node = _resolve(node, root)
    if isinstance(node, dict) and "anyOf" in node:
        branches = [b for b in node["anyOf"] if _resolve(b, root).get("type") != "null"]
        if len(branches) != 1:
            raise JsonViewError(f"a union of {len(branches)} non-null types has no record view")
        merged = {k: v for k, v in node.items() if k not in ("anyOf", "default")}
        return {**_resolve(branches[0], root), **{k: v for k, v in merged.items() if k == "title"}}, True
    return node, False


def _scalar_schema(node: dict[str, Any]) -> dict[str, Any]:
    out = {k: node[k] for k in _SCALAR_KEYS if k in node}
    if "type" in node:
        out["type"] = node["type"]
    elif "const" in node:
        c = node["const"]
        out["type"] = "integer" if isinstance(c, int) and not isinstance(c, bool) else "string"
    elif "enum" in node:
        out["type"] = "string"
    for k in ("title", "description"):
        if k in node:
            out[k] = node[k]
    return out


def _compile(node: Any, root: dict[str, Any], in_list: bool = False) -> tuple[_Plan, dict[str, Any]]:
    """The plan and the record-view schema of one (non-null) node of a committed schema."""
    node = _resolve(node, root)
    if node.get("x-msgpack") == "bin":
        return _Plan("bin"), _scalar_schema(node)
    if "x-fields" in node:  # a record: an object of its fields
        plans, props, required = [], {}, []
        for name, item in zip(node["x-fields"], node["prefixItems"], strict=True):
            inner, nullable = _non_null(item, root)
            plan, schema = _compile(inner, root)
            plans.append(plan)
            props[name] = {**schema, **({"title": item["title"]} if "title" in item else {})}
            if not nullable:
                required.append(name)
        schema = {"type": "object", "properties": props, "required": required, "additionalProperties": False}
        if "title" in node:
            schema["title"] = node["title"]
        if "description" in node:
            schema["description"] = node["description"]
        return _Plan("record", tuple(node["x-fields"]), tuple(plans)), schema
    if node.get("type") == "array" and "prefixItems" in node:  # a tuple
        items = [_resolve(i, root) for i in node["prefixItems"]]
        if in_list:
            names = TUPLE_KEYS[:len(items)]
            props = {n: _scalar_schema(i) for n, i in zip(names, items, strict=False)}
            return _Plan("point", names), {"type": "object", "properties": props, "required": list(names),
                                             "additionalProperties": False}
        types = {i.get("type") for i in items}
        item = {"type": types.pop() if len(types) == 1 else "number"}
        schema = {"type": "array", "items": item, "minItems": len(items), "maxItems": len(items)}
        if "title" in node:
            schema["title"] = node["title"]
        return _Plan("tuple"), schema
    if node.get("type") == "array":
        inner, _ = _non_null(node.get("items", {}), root)
        plan, item_schema = _compile(inner, root, in_list=True)
        schema = {"type": "array", "items": item_schema,
                  **{k: node[k] for k in ("minItems", "maxItems", "title") if k in node}}
        return _Plan("list", parts=(plan,)), schema
    if node.get("type") == "object" and "additionalProperties" in node and "properties" not in node:
        plan, value_schema = _compile(node["additionalProperties"], root)
        schema = {"type": "object", "properties": {}, "additionalProperties": value_schema,
                  **{k: node[k] for k in ("maxProperties", "propertyNames", "title") if k in node}}
        return _Plan("map", parts=(plan,)), schema
    return _SCALAR, _scalar_schema(node)


@cache
def _message(kind: str) -> tuple[tuple[str, ...], tuple[_Plan, ...], dict[str, Any]]:
    """``(field names in wire order, their plans, the record-view schema)`` of a message kind."""
    model = MESSAGE_BY_KIND.get(kind)
    if model is None:
        raise JsonViewError(f"unknown message kind {kind!r}")
    root = kind_schema(kind)
    names = ("kind", *model.model_fields)
    plans, props, required = [], {}, []
    for name in names:
        prop = root["properties"][name]
        inner, nullable = _non_null(prop, root)
        plan, schema = _compile(inner, root)
        if "title" in prop:
            schema["title"] = prop["title"]
        plans.append(plan)
        props[name] = schema
        if not nullable:
            required.append(name)
    schema = {
        "$schema": root["$schema"],
        "$id": root["$id"].replace(":v1:", ":v1:record-view:"),
        "$comment": (f"The record view of protocol/schema/{kind}.json (protocol.record_view): every record an "
                     "object of its named fields, a null field left out, bin as base64; the form Foxglove and "
                     "Lichtblick read. The wire is msgpack with records as positional arrays; the view gives "
                     "back its very bytes."),
        "title": kind, "description": root.get("description", ""), "type": "object",
        "properties": props, "required": required, "additionalProperties": False,
    }
    if "allOf" in root:
        schema["allOf"] = copy.deepcopy(root["allOf"])
    return names, tuple(plans), schema


def record_view_schema(kind: str) -> dict[str, Any]:
    """The record-view JSON Schema of a message kind (a copy)."""
    return copy.deepcopy(_message(kind)[2])


def _to_view(value: Any, plan: _Plan) -> Any:
    k = plan.kind
    if value is None or k == "scalar" or k == "tuple":
        return list(value) if isinstance(value, tuple) else value
    if k == "bin":
        if not isinstance(value, bytes):
            raise JsonViewError("text where the schema says bin")
        return base64.b64encode(value).decode("ascii")
    if k == "record":
        if not isinstance(value, list | tuple) or len(value) != len(plan.names):
            raise JsonViewError(f"a record of {len(plan.names)} fields expected")
        return {n: _to_view(v, p) for n, v, p in zip(plan.names, value, plan.parts, strict=True) if v is not None}
    if k == "point":
        if not isinstance(value, list | tuple) or len(value) != len(plan.names):
            raise JsonViewError(f"a tuple of {len(plan.names)} expected")
        return dict(zip(plan.names, value, strict=True))
    if k == "list":
        if not isinstance(value, list | tuple):
            raise JsonViewError("a list expected")
        return [_to_view(v, plan.parts[0]) for v in value]
    if k == "map":
        if not isinstance(value, dict):
            raise JsonViewError("a map expected")
        return {key: _to_view(v, plan.parts[0]) for key, v in value.items()}
    raise JsonViewError(f"unknown plan {k}")


def _to_wire(value: Any, plan: _Plan) -> Any:
    k = plan.kind
    if value is None or k == "scalar" or k == "tuple":
        return value
    if k == "bin":
        try:
            return base64.b64decode(value, validate=True)
        except (ValueError, TypeError) as exc:
            raise JsonViewError(f"bin field is not base64: {exc}") from None
    if k == "record":
        if not isinstance(value, dict):
            raise JsonViewError("a record is an object")
        return [_to_wire(value.get(n), p) for n, p in zip(plan.names, plan.parts, strict=True)]
    if k == "point":
        return [value.get(n) for n in plan.names] if isinstance(value, dict) else value
    if k == "list":
        return [_to_wire(v, plan.parts[0]) for v in value] if isinstance(value, list) else value
    if k == "map":
        return {key: _to_wire(v, plan.parts[0]) for key, v in value.items()} if isinstance(value, dict) else value
    raise JsonViewError(f"unknown plan {k}")


def to_view(payload: bytes) -> dict[str, Any]:
    """The record view of one payload as Python data; ``JsonViewError`` when it has none."""
    try:
        body = msgpack.unpackb(payload, raw=False, use_list=True, strict_map_key=True, max_ext_len=0)
    except Exception as exc:  # msgpack raises many kinds
        raise JsonViewError(f"not a msgpack payload: {exc.__class__.__name__}: {exc}") from None
    if not isinstance(body, dict) or not isinstance(body.get("kind"), str):
        raise JsonViewError("a payload is a map with a 'kind'")
    names, plans, _ = _message(body["kind"])
    if list(body) != list(names[:len(body)]) or len(body) != len(names):
        raise JsonViewError(f"the fields of a {body['kind']} are not those of this build, in its order")
    return {n: _to_view(body[n], p) for n, p in zip(names, plans, strict=True) if body[n] is not None}


def to_json(payload: bytes) -> bytes:
    """The record view of one payload as compact UTF-8 JSON; ``JsonViewError`` when it has none."""
    try:
        return json.dumps(to_view(payload), separators=(",", ":"), ensure_ascii=False, allow_nan=False).encode()
    except ValueError as exc:  # NaN or infinity
        raise JsonViewError(f"no JSON form: {exc}") from None


def to_wire(view: dict[str, Any] | bytes | str) -> bytes:
    """The msgpack payload of a record view (data, or JSON text)."""
    if isinstance(view, bytes | str):
        try:
            view = json.loads(view)
        except ValueError as exc:
            raise JsonViewError(f"not JSON: {exc}") from None
    if not isinstance(view, dict) or not isinstance(view.get("kind"), str):
        raise JsonViewError("a record view is an object with a 'kind'")
    names, plans, _ = _message(view["kind"])
    body = {n: _to_wire(view.get(n), p) for n, p in zip(names, plans, strict=True)}
    return msgpack.packb(body, use_bin_type=True)


def view_roundtrips(payload: bytes, view_json: bytes) -> bool:
    """True when ``view_json`` gives back exactly ``payload``."""
    try:
        return to_wire(view_json) == bytes(payload)
    except JsonViewError:
        return False
