"""JSON Schemas (draft 2020-12) of the bytes on the wire, written to ``protocol/schema/`` by ``iea schema``.

A payload (protocol/codec.py) is one msgpack map ``{"kind": <name>, "v": 1, **fields}``; nested records
(``DetectedObject``, ``EvEvidence``, ``Signature``, ``Actor``, ``LightBar``) travel as arrays of their
fields in declaration order. Each schema describes exactly that: ``kind`` and ``v`` as constants, every
record as an array with ``prefixItems`` (each item titled "field [unit]") and the ranges pydantic
enforces (minimum/maximum, lengths, patterns), so a client with msgpack and a JSON Schema validator
alone can check every message.

The schemas are applied to the JSON view of the msgpack value (``JSON_VIEW``): maps with string keys
are objects, arrays are arrays, msgpack bin (only ``Signature.sig``) is a base64 string (RFC 4648 §4,
as RFC 8949 §6.1 maps CBOR byte strings to JSON), NaN and +-inf have no JSON form and are refused, and
extension types are refused. What the decoder checks beyond JSON Schema is listed in each schema's
``$comment``: the invariants between fields (e.g. a box's x2 >= x1), integer vs float (JSON has one
number type: a schema accepts 1.0 where the decoder wants 1), and bin vs str (both JSON strings).
"""

from __future__ import annotations

import copy
import dataclasses
import json
from pathlib import Path
from typing import Any

from protocol import keys
from protocol.messages import MESSAGE_TYPES, SCHEMA_VERSION, Envelope

SCHEMA_DIR = Path(__file__).resolve().parent / "schema"
DRAFT = "https://json-schema.org/draft/2020-12/schema"

JSON_VIEW = (
    "Validate the JSON view of the msgpack payload: a map with string keys is an object, an array an array, "
    "bin a base64 string (RFC 4648 section 4), a float that is NaN or infinite and any extension type are "
    "invalid (they have no JSON form). Records travel as positional arrays (prefixItems, in field order). "
    "Beyond JSON Schema the decoder also refuses a float with an integral value where an integer is due "
    "(integer vs float: JSON has one number type) and text where the schema says x-msgpack: bin, or bin "
    "where it does not (both are JSON strings)."
)

UNIT_BY_SUFFIX = (
    ("_mps2", "m/s^2"), ("_mps", "m/s"), ("_rps", "rad/s"), ("_m2", "m^2"), ("_ms", "ms"), ("_m", "m"),
    ("_s", "s"), ("_rad", "rad"), ("_deg", "deg"), ("_hz", "Hz"), ("_px", "px"),
)
"""Unit of a field from its name's suffix (house rule: SI units in names), longest suffix first."""

UNIT_BY_NAME = {
    "stamp": "s", "measurement_time": "s", "first_seen": "s", "issued_at": "s", "valid_until": "s",
    "not_before": "s", "not_after": "s", "waypoints": "m", "stop_point": "m",
}
"""Fields whose unit the name does not end in (times on the publisher's clock; corridor-frame points)."""

INVARIANTS = {
    "ObjectList": ["objects[].bbox_px: x2 >= x1 and y2 >= y1"],
    "PathSwitchCommand": ["valid_until > issued_at",
                          "speed_profile_mps is empty or has one entry per waypoint"],
}
"""Cross-field rules the decoder enforces that JSON Schema cannot state (listed in ``$comment``)."""

CONDITIONAL_RULES = {
    "PathSwitchCommand": [{
        "if": {"properties": {"manoeuvre": {"not": {"const": "resume"}}}},
        "then": {"properties": {"waypoints": {"minItems": 2}}},
    }],
}
"""Cross-field rules JSON Schema can state (``allOf`` of if/then)."""

_BYTES_BASE64 = "base64"


def field_unit(name: str) -> str | None:
    """Unit of a field: from ``UNIT_BY_NAME`` or the name's suffix; None for counts, ids and enums."""
    if name in UNIT_BY_NAME:
        return UNIT_BY_NAME[name]
    return next((unit for suffix, unit in UNIT_BY_SUFFIX if name.endswith(suffix)), None)


def field_title(name: str) -> str:
    """``pos_x_m [m]``: the field's wire name and its unit."""
    unit = field_unit(name)
    return f"{name} [{unit}]" if unit else name


def key_expressions(kind: str) -> list[str]:
    """Key expressions (``*``: any corridor, RSU or vehicle id) a message of ``kind`` is published on."""
    groups = [("iea/*/rsu/*/", keys.RSU_TOPICS), ("iea/*/vehicle/*/", keys.VEHICLE_TOPICS),
              ("iea/*/ddm/", keys.DDM_TOPICS), ("iea/*/sim/", keys.SIM_TOPICS)]
    return [prefix + topic for prefix, topics in groups for topic, model in topics.items() if model.KIND == kind]


def _records() -> dict[str, type]:
    from protocol import messages

    return {name: v for name, v in vars(messages).items() if isinstance(v, type) and dataclasses.is_dataclass(v)}


def _base64_pattern(n_bytes: int | None) -> str:
    """Padded base64 (RFC 4648 section 4) of any length, or of exactly ``n_bytes`` bytes."""
    if n_bytes is None:
        return "^(?:[A-Za-z0-9+/]{4})*(?:[A-Za-z0-9+/]{2}==|[A-Za-z0-9+/]{3}=)?$"
    tail = {0: "", 1: "[A-Za-z0-9+/]{2}==", 2: "[A-Za-z0-9+/]{3}="}[n_bytes % 3]
    return f"^[A-Za-z0-9+/]{{{4 * (n_bytes // 3)}}}{tail}$"


def _wire_value(schema: dict[str, Any]) -> dict[str, Any]:
    """Rewrite what the JSON view changes: bytes -> base64 string, dict key patterns -> propertyNames."""
    out = dict(schema)
    if out.get("format") == "binary" and out.get("type") == "string":
        del out["format"]
        n_min, n_max = out.pop("minLength", None), out.pop("maxLength", None)
        out["contentEncoding"] = _BYTES_BASE64
        out["x-msgpack"] = "bin"
        out["pattern"] = _base64_pattern(n_min if n_min == n_max else None)
        if n_min is not None:
            out["minLength"] = 4 * ((n_min + 2) // 3)
        if n_max is not None:
            out["maxLength"] = 4 * ((n_max + 2) // 3)
    if "patternProperties" in out:  # pydantic: key pattern here, value unconstrained for other keys
        (pattern, value), = out.pop("patternProperties").items()
        out["propertyNames"] = {**out.get("propertyNames", {}), "pattern": pattern}
        out["additionalProperties"] = value
    for key in ("anyOf", "prefixItems"):
        if key in out:
            out[key] = [_wire_value(s) for s in out[key]]
    for key in ("items", "additionalProperties"):
        if isinstance(out.get(key), dict):
            out[key] = _wire_value(out[key])
    return out


def _titled(name: str, schema: dict[str, Any]) -> dict[str, Any]:
    return {**_wire_value(schema), "title": field_title(name)}


def _record_as_array(name: str, obj: dict[str, Any]) -> dict[str, Any]:
    """A record's object schema -> the positional array it is on the wire (every item present)."""
    fields = list(_records()[name].__pydantic_fields__)  # type: ignore[attr-defined]
    props = obj["properties"]
    assert list(props) == fields, f"{name}: schema fields {list(props)} differ from the record {fields}"
    items = []
    for field in fields:
        item = _titled(field, props[field])
        item.pop("default", None)  # positional: every item is on the wire
        items.append(item)
    out = {"title": name, "type": "array", "prefixItems": items, "items": False,
           "minItems": len(items), "maxItems": len(items), "x-fields": fields}
    if "description" in obj:
        out["description"] = obj["description"]
    return out


def wire_schema(model: type[Envelope]) -> dict[str, Any]:
    """The draft 2020-12 schema of the wire payload of one message kind."""
    base = copy.deepcopy(model.model_json_schema(mode="validation"))
    records = _records()
    defs = {}
    for name, sub in base.get("$defs", {}).items():
        defs[name] = _record_as_array(name, sub) if name in records else sub
    props: dict[str, Any] = {
        "kind": {"const": model.KIND, "title": "kind", "description": "message kind: selects this schema"},
        "v": {"const": SCHEMA_VERSION, "title": "v",
              "description": "schema version: the layout of this file; a decoder refuses any other"},
    }
    for name, sub in base["properties"].items():
        if name != "v":
            props[name] = _titled(name, sub)
    comment = [JSON_VIEW]
    if INVARIANTS.get(model.KIND):
        comment.append("Also enforced by the decoder, beyond this schema: " + "; ".join(INVARIANTS[model.KIND]) + ".")
    out: dict[str, Any] = {
        "$schema": DRAFT,
        "$id": f"urn:iea:protocol:v{SCHEMA_VERSION}:{model.KIND}",
        "$comment": " ".join(comment),
        "title": model.KIND,
        "description": base.get("description", ""),
        "type": "object",
        "properties": props,
        "required": ["kind", "v", *[r for r in base.get("required", []) if r != "v"]],
        "additionalProperties": False,
        "x-key-expressions": key_expressions(model.KIND),
    }
    if CONDITIONAL_RULES.get(model.KIND):
        out["allOf"] = copy.deepcopy(CONDITIONAL_RULES[model.KIND])
    if defs:
        out["$defs"] = defs
    return out


def message_schemas() -> dict[str, dict[str, Any]]:
    return {model.KIND: wire_schema(model) for model in MESSAGE_TYPES}


def render(schema: dict[str, Any]) -> str:
    return json.dumps(schema, indent=2, sort_keys=True, ensure_ascii=False) + "\n"


def write_schemas(directory: Path = SCHEMA_DIR) -> list[Path]:
    directory.mkdir(parents=True, exist_ok=True)
    written = []
    for kind, schema in message_schemas().items():
        path = directory / f"{kind}.json"
        path.write_text(render(schema), encoding="utf-8")
        written.append(path)
    return written


def stale_schemas(directory: Path = SCHEMA_DIR) -> list[str]:
    """Files in ``directory`` that differ from the code, are missing or belong to no message kind."""
    schemas = message_schemas()
    stale = []
    for kind, schema in schemas.items():
        path = directory / f"{kind}.json"
        if not path.is_file():
            stale.append(f"{path.name} (missing)")
        elif path.read_text(encoding="utf-8") != render(schema):
            stale.append(f"{path.name} (differs from the message models)")
    for path in sorted(directory.glob("*.json")):
        if path.stem not in schemas:
            stale.append(f"{path.name} (no such message kind)")
    return stale
