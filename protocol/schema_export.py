"""JSON Schema of every message model, written to ``protocol/schema/`` by ``iea schema``.

The schema describes each message's fields, types and ranges. On the wire (protocol/codec.py) a
message is a msgpack map of these fields plus ``kind``; nested records marked ``x-wire: array``
travel as arrays of their fields in the order listed in ``x-wire-fields``.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

from protocol.messages import MESSAGE_TYPES, SCHEMA_VERSION

SCHEMA_DIR = Path(__file__).resolve().parent / "schema"


def message_schemas() -> dict[str, dict[str, Any]]:
    out = {}
    for model in MESSAGE_TYPES:
        schema = model.model_json_schema(mode="validation")
        schema["x-kind"] = model.KIND
        schema["x-schema-version"] = SCHEMA_VERSION
        for name, sub in schema.get("$defs", {}).items():
            cls = next((c for c in _records() if c.__name__ == name), None)
            if cls is not None:
                sub["x-wire"] = "array"
                sub["x-wire-fields"] = [f.name for f in dataclasses.fields(cls)]
        out[model.KIND] = schema
    return out


def _records() -> list[type]:
    from protocol import messages

    return [v for v in vars(messages).values() if isinstance(v, type) and dataclasses.is_dataclass(v)]


def render(schema: dict[str, Any]) -> str:
    return json.dumps(schema, indent=2, sort_keys=True) + "\n"


def write_schemas(directory: Path = SCHEMA_DIR) -> list[Path]:
    directory.mkdir(parents=True, exist_ok=True)
    written = []
    for kind, schema in message_schemas().items():
        path = directory / f"{kind}.json"
        path.write_text(render(schema), encoding="utf-8")
        written.append(path)
    return written


def stale_schemas(directory: Path = SCHEMA_DIR) -> list[str]:
    """Kinds whose committed schema differs from the code (empty when all match)."""
    stale = []
    for kind, schema in message_schemas().items():
        path = directory / f"{kind}.json"
        if not path.is_file() or path.read_text(encoding="utf-8") != render(schema):
            stale.append(kind)
    return stale
