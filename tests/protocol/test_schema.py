"""The published schemas (protocol/schema/*.json) describe the wire: kind, v, records as positional arrays,
every range pydantic enforces; `iea schema --check` names a stale file."""

from __future__ import annotations

import dataclasses

import pytest

from deploy.cli import main as iea
from protocol import codec
from protocol.messages import MESSAGE_TYPES, SCHEMA_VERSION, DetectedObject
from protocol.schema_export import (
    SCHEMA_DIR,
    field_title,
    field_unit,
    key_expressions,
    message_schemas,
    render,
    stale_schemas,
    write_schemas,
)

jsonschema = pytest.importorskip("jsonschema", reason="jsonschema is in the dev extra: pip install -e '.[dev]'")

BOUND_KEYS = ("minimum", "maximum", "exclusiveMinimum", "exclusiveMaximum", "minLength", "maxLength",
              "minItems", "maxItems", "maxProperties", "pattern", "enum", "const", "type")


def test_committed_schema_matches_the_code():
    stale = stale_schemas()
    assert not stale, f"protocol/schema is out of date: {stale}: run `iea schema` and commit the files"
    assert sorted(p.stem for p in SCHEMA_DIR.glob("*.json")) == sorted(m.KIND for m in MESSAGE_TYPES)


def test_check_names_the_stale_missing_and_foreign_files(tmp_path, capsys):
    write_schemas(tmp_path)
    assert stale_schemas(tmp_path) == []
    (tmp_path / "Health.json").write_text("{}\n")
    (tmp_path / "EvAlert.json").unlink()
    (tmp_path / "Old.json").write_text("{}\n")
    stale = stale_schemas(tmp_path)
    assert stale == ["EvAlert.json (missing)", "Health.json (differs from the message models)",
                     "Old.json (no such message kind)"]
    assert iea(["schema", "--check"]) == 0  # the committed folder is current
    assert "match the message models" in capsys.readouterr().out


def test_check_exits_non_zero_naming_the_file(monkeypatch, capsys):
    import protocol.schema_export as se

    real = se.stale_schemas
    monkeypatch.setattr(se, "stale_schemas", lambda: real(SCHEMA_DIR) + ["Health.json (differs from the message models)"])
    assert iea(["schema", "--check"]) == 1
    assert "Health.json" in capsys.readouterr().err


@pytest.mark.parametrize("kind", [m.KIND for m in MESSAGE_TYPES])
def test_each_schema_is_draft_2020_12_with_kind_and_version(kind):
    schema = message_schemas()[kind]
    jsonschema.Draft202012Validator.check_schema(schema)
    assert schema["$schema"] == "https://json-schema.org/draft/2020-12/schema"
    assert schema["properties"]["kind"]["const"] == kind
    assert schema["properties"]["v"]["const"] == SCHEMA_VERSION
    assert schema["required"][:2] == ["kind", "v"]
    assert schema["additionalProperties"] is False
    assert schema["x-key-expressions"] and all(k.startswith("iea/*/") for k in schema["x-key-expressions"])
    assert render(schema) == (SCHEMA_DIR / f"{kind}.json").read_text(encoding="utf-8")


def test_records_are_positional_arrays_in_the_codecs_field_order():
    for model in MESSAGE_TYPES:
        for name, sub in message_schemas()[model.KIND].get("$defs", {}).items():
            if sub.get("type") != "array":
                continue
            cls = next(c for c in codec._RECORD_PLANS if c.__name__ == name)
            names = [f.name for f in dataclasses.fields(cls)]
            assert names == list(codec._RECORD_PLANS[cls].names)
            assert sub["x-fields"] == names
            assert [i["title"] for i in sub["prefixItems"]] == [field_title(n) for n in names]
            assert sub["minItems"] == sub["maxItems"] == len(names) and sub["items"] is False
    record = message_schemas()["ObjectList"]["$defs"]["DetectedObject"]
    assert record["prefixItems"][1]["title"] == "pos_x_m [m]"
    assert record["prefixItems"][3] | {"title": None} == {"type": "number", "minimum": -90.0, "maximum": 90.0,
                                                          "title": None}
    assert message_schemas()["ObjectList"]["properties"]["objects"]["maxItems"] == 256


def _all_field_schemas():
    """(where, pydantic's own schema of the field, the wire schema of the field) for every field."""
    for model in MESSAGE_TYPES:
        base = model.model_json_schema(mode="validation")
        wire = message_schemas()[model.KIND]
        for name, sub in base["properties"].items():
            if name != "v":
                yield f"{model.KIND}.{name}", sub, wire["properties"][name]
        for rec, sub in base.get("$defs", {}).items():
            if sub.get("type") == "object":
                for i, (name, f) in enumerate(sub["properties"].items()):
                    yield f"{rec}.{name}", f, wire["$defs"][rec]["prefixItems"][i]


def test_every_bound_pydantic_enforces_is_in_the_wire_schema():
    """Ranges (e.g. protocol/ranges.py's physical bounds) carry over: each constraint keyword of pydantic's schema of a
    field is in the wire schema of the field, with the same value (bytes and dict keys aside, rewritten)."""
    checked = 0

    def same(where, a, b):
        nonlocal checked
        if a.get("format") == "binary":
            assert b["x-msgpack"] == "bin" and b["contentEncoding"] == "base64", where
            return
        for key in BOUND_KEYS:
            if key in a:
                assert b.get(key) == a[key], f"{where}: {key} {a[key]!r} -> {b.get(key)!r}"
                checked += 1
        if "patternProperties" in a:
            ((pattern, value),) = a["patternProperties"].items()
            assert b["propertyNames"]["pattern"] == pattern, where
            same(where + "{}", value, b["additionalProperties"])
        for key in ("anyOf", "prefixItems"):
            for x, y in zip(a.get(key, []), b.get(key, []), strict=True):
                same(where, x, y)
        if isinstance(a.get("items"), dict):
            same(where + "[]", a["items"], b["items"])
        if "$ref" in a:
            assert b["$ref"] == a["$ref"], where

    for where, a, b in _all_field_schemas():
        same(where, a, b)
    assert checked > 150


def test_units_come_from_the_field_names():
    assert field_unit("pos_x_m") == "m" and field_unit("speed_mps") == "m/s" and field_unit("accel_mps2") == "m/s^2"
    assert field_unit("pos_cov_m2") == "m^2" and field_unit("yaw_rate_rps") == "rad/s"
    assert field_unit("latency_ms") == "ms" and field_unit("flash_hz") == "Hz" and field_unit("bbox_px") == "px"
    assert field_unit("stamp") == "s" and field_unit("waypoints") == "m"
    assert field_unit("object_id") is None and field_title("lane") == "lane"
    assert field_title("heading_rad") == "heading_rad [rad]"


def test_key_expressions_of_each_kind():
    assert key_expressions("ObjectList") == ["iea/*/rsu/*/objects"]
    assert key_expressions("Health") == ["iea/*/rsu/*/health", "iea/*/vehicle/*/health", "iea/*/ddm/health",
                                         "iea/*/sim/health"]


def test_schema_accepts_the_codec_output_and_rejects_a_record_sent_as_a_map():
    import msgpack

    from protocol.examples import object_list

    validator = jsonschema.Draft202012Validator(message_schemas()["ObjectList"])
    body = msgpack.unpackb(codec.encode(object_list(3)), raw=False)
    assert not list(validator.iter_errors(body))
    body["objects"][0] = dict(zip(DetectedObject.__pydantic_fields__, body["objects"][0], strict=True))
    assert list(validator.iter_errors(body))
