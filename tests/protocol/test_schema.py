from protocol.schema_export import SCHEMA_DIR, message_schemas, stale_schemas


def test_committed_schema_matches_the_code():
    stale = stale_schemas()
    assert not stale, f"protocol/schema is out of date for {stale}: run `iea schema` and commit the files"


def test_schema_documents_the_wire_layout_of_records():
    schema = message_schemas()["ObjectList"]
    record = schema["$defs"]["DetectedObject"]
    assert record["x-wire"] == "array"
    assert record["x-wire-fields"][:3] == ["object_id", "pos_x_m", "pos_y_m"]
    assert schema["properties"]["objects"]["maxItems"] == 256
    assert len(list(SCHEMA_DIR.glob("*.json"))) == 8
