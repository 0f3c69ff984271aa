"""Every number a message carries has a physical range; the decoder refuses what no sensor or
clock produces and names the field; the crash fuzzing found is refused at the boundary."""

from __future__ import annotations

import dataclasses
import math
import types
import typing

import msgpack
import pytest

from protocol import keys
from protocol.codec import ProtocolError, decode, encode
from protocol.examples import example_messages
from protocol.local_bus import LocalBus
from protocol.messages import MESSAGE_TYPES, WorldSnapshot
from protocol.ranges import MAX_COUNT, MAX_SIM_TIME_S

FUZZER_CRASH = bytes.fromhex(
    "8aa46b696e64ad576f726c64536e617073686f74a17601a3737263a373696da373657100a57374616d70cb3ff0000000000000a873"
    "63656e6172696faf72656c6c69735f65765f7969656c64aa73696d5f74696d655f73cb7fefffffffffffffa86c69676874696e67a3"
    "646179a47365656401a66163746f7273929ea3617631a26176cb4059000000000000cb4016333333333333cb0000000000000000cb40"
    "1399999999999acb3ffe666666666666cb3ff8000000000000cb402acccccccccccd0193cc80cc80cc80c2c0009ea3657631a26576cb"
    "4049000000000000cb4016333333333333cb0000000000000000cb4016000000000000cb4000000000000000cb400199999999999acb"
    "40330000000000000193ccffccffccffc294c3ab616c7465726e6174696e67cb4000000000000000cb000000000000000000")
"""``fuzz_bench.py`` seed 0, rsu_sim_camera input 88,393: a WorldSnapshot with
``sim_time_s`` = 1.7976931348623157e308 which, without range checks, decodes and then crashes
``SimCamera.frame_index`` with OverflowError (``int(sim_time_s * fps)``) at the next render."""


# ------------------------------------------------------------------ the crash, as a regression test
def test_the_fuzzer_crash_payload_is_refused_naming_the_field():
    assert msgpack.unpackb(FUZZER_CRASH)["sim_time_s"] == 1.7976931348623157e308
    with pytest.raises(ProtocolError) as info:
        decode(FUZZER_CRASH, WorldSnapshot)
    assert "WorldSnapshot.sim_time_s" in str(info.value) and "less than or equal to" in str(info.value)
    assert info.value.reason == "invalid"


def test_the_rsu_sim_camera_never_holds_the_crashing_snapshot():
    from protocol.corridor import load_corridor
    from sim.camera_source import SimCamera

    corridor = dataclasses.replace(load_corridor(), corridor_id="r24")
    bus = LocalBus()
    camera = SimCamera(corridor, "rsu1", transport=bus, seed=0)
    bus.publish_bytes(keys.sim_world_key("r24"), FUZZER_CRASH)
    assert camera.newest_held is None and bus.stats.rejected["invalid"] == 1 and bus.stats.handler_errors == 0
    # the latest sim time a message may carry still makes an integer frame counter and a frame
    body = msgpack.unpackb(FUZZER_CRASH)
    body["sim_time_s"] = MAX_SIM_TIME_S
    bus.publish_bytes(keys.sim_world_key("r24"), msgpack.packb(body))
    assert camera.newest_held is not None and camera.frames_held == 1
    frame = camera.render(camera.newest_held)
    assert frame.frame_number == camera.frame_index(MAX_SIM_TIME_S) == int(MAX_SIM_TIME_S * camera.fps)
    assert frame.image.shape[:2] == (camera.height_px, camera.width_px)


# ------------------------------------------------------------------ every number is bounded
def _leaves(annotation, metadata=(), where=""):
    """(path, base type, metadata) of every scalar inside an annotation (tuples, lists, dicts, records)."""
    origin, args = typing.get_origin(annotation), typing.get_args(annotation)
    if origin is typing.Annotated:
        meta = [m for extra in args[1:] for m in getattr(extra, "metadata", [extra])]
        yield from _leaves(args[0], (*metadata, *meta), where)
    elif origin in (typing.Union, types.UnionType):
        for a in args:
            if a is not type(None):
                yield from _leaves(a, metadata, where)
    elif origin in (tuple, list):
        for i, a in enumerate(args):
            if a is not Ellipsis:
                yield from _leaves(a, (), f"{where}[{i}]")
    elif origin is dict:
        yield from _leaves(args[1], (), f"{where}{{}}")
    elif dataclasses.is_dataclass(annotation):
        for name, info in annotation.__pydantic_fields__.items():
            yield from _leaves(info.annotation, tuple(info.metadata), f"{where}.{name}")
    else:
        yield where, annotation, metadata


def _numeric_fields():
    for model in MESSAGE_TYPES:
        for name, info in model.model_fields.items():
            for where, base, meta in _leaves(info.annotation, tuple(info.metadata), f"{model.KIND}.{name}"):
                if base in (int, float) and not where.endswith(".v"):
                    yield where, base, meta


def _bounds(meta):
    lo = [getattr(m, a) for m in meta for a in ("ge", "gt") if getattr(m, a, None) is not None]
    hi = [getattr(m, a) for m in meta for a in ("le", "lt") if getattr(m, a, None) is not None]
    return (max(lo) if lo else None), (min(hi) if hi else None)


NUMERIC = sorted(_numeric_fields())


def test_the_walk_sees_the_numbers_of_every_record():
    names = {w for w, _, _ in NUMERIC}
    assert len(NUMERIC) > 100
    assert {"WorldSnapshot.sim_time_s", "WorldSnapshot.actors[0].light_bar.frequency_hz",
            "ObjectList.objects[0].bbox_px[3]", "Health.rates_hz{}", "EvAlert.auth.not_after",
            "PathSwitchCommand.waypoints[0][1]", "WorldSnapshot.actors[0].colour_bgr[2]"} <= names


@pytest.mark.parametrize("where,base,meta", NUMERIC, ids=[w for w, _, _ in NUMERIC])
def test_every_number_has_a_finite_physical_range(where, base, meta):
    lo, hi = _bounds(meta)
    assert lo is not None and hi is not None, f"{where} has no range: give it a type from protocol/ranges.py"
    assert math.isfinite(lo) and math.isfinite(hi) and lo < hi
    assert abs(lo) <= MAX_COUNT and abs(hi) <= MAX_COUNT  # nothing near the float maximum: products stay finite
    if base is float:
        assert any(getattr(m, "allow_inf_nan", None) is False for m in meta), f"{where} may be NaN/inf"
    assert any(getattr(m, "strict", None) for m in meta), f"{where} is not strict"


# ------------------------------------------------------------------ each refusal names the field
def _strip(ann):
    """The type under Annotated / Optional."""
    while True:
        origin = typing.get_origin(ann)
        if origin is typing.Annotated:
            ann = typing.get_args(ann)[0]
        elif origin in (typing.Union, types.UnionType):
            ann = next(a for a in typing.get_args(ann) if a is not type(None))
        else:
            return ann


def _wire_path(model, where: str) -> tuple:
    """The msgpack path of a field path like ``objects[0].bbox_px[3]`` (records travel as arrays)."""
    tokens = where.replace("[", ".[").split(".")
    path: list = [tokens[0]]
    ann = model.model_fields[tokens[0]].annotation
    for tok in tokens[1:]:
        ann = _strip(ann)
        if tok.startswith("["):
            i = int(tok[1:-1])
            path.append(i)
            args = typing.get_args(ann)
            ann = args[0] if typing.get_origin(ann) is list else args[i]
        else:
            names = list(ann.__pydantic_fields__)
            path.append(names.index(tok))
            ann = ann.__pydantic_fields__[tok].annotation
    return tuple(path)


def _get(tree, path):
    for p in path:
        if isinstance(tree, dict):
            tree = tree.get(p)
        elif isinstance(tree, list) and isinstance(p, int) and p < len(tree):
            tree = tree[p]
        else:
            return None
    return tree


@pytest.mark.parametrize("kind", [m.KIND for m in MESSAGE_TYPES])
def test_a_number_beyond_its_range_is_refused_and_the_refusal_names_the_field(kind):
    model = next(m for m in MESSAGE_TYPES if m.KIND == kind)
    msg = next(m for _, m in example_messages("r24", stamp=100.0) if type(m) is model)
    checked = 0
    for where, _base, meta in NUMERIC:
        if not where.startswith(f"{kind}.") or "{}" in where:
            continue
        field_path = where[len(kind) + 1:]
        path = _wire_path(model, field_path)
        if _get(msgpack.unpackb(encode(msg), raw=False), path) is None:
            continue  # an optional part the example leaves out
        lo, hi = _bounds(meta)
        name = field_path.split(".")[-1].split("[")[0]
        for bad in (hi * 2 + 1, lo * 2 - 1 if lo < 0 else -1):
            body = msgpack.unpackb(encode(msg), raw=False)
            parent = _get(body, path[:-1])
            parent[path[-1]] = bad
            with pytest.raises(ProtocolError) as info:
                decode(msgpack.packb(body), model)
            assert f".{name}" in str(info.value) and "than" in str(info.value), (where, bad, str(info.value))
            checked += 1
    assert checked >= 4


def test_the_examples_and_a_wall_clock_stamp_decode():
    import time

    for stamp in (0.0, 1.0, time.time()):
        for _, msg in example_messages("r24", stamp=stamp):
            assert decode(encode(msg), type(msg)) == msg
