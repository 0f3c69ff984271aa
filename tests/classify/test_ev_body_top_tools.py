"""The CPU fine-tune of the EV-body student's top: near-duplicate checks that keep the photo test set out of its
training, the validation split of the police photos, and the shipped model's sure operating point reaching the
per-track fusion."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from models.ev_body_top import difference_hash, near_duplicates
from models.train_lamp_state import is_validation_photo
from rsu.classify.body import DEFAULT_BODY_MODEL, EvBodyClassifier
from rsu.classify.ev import TrackEvClassifier


def _photo(seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    img = cv2.resize(rng.integers(0, 256, (12, 16, 3), dtype=np.uint8), (320, 240), interpolation=cv2.INTER_CUBIC)
    return img


def test_a_recompressed_rescaled_copy_is_a_near_duplicate_and_another_photo_is_not():
    a, b = _photo(1), _photo(2)
    ok, buf = cv2.imencode(".jpg", cv2.resize(a, (200, 150)), [cv2.IMWRITE_JPEG_QUALITY, 40])
    copy = cv2.imdecode(buf, cv2.IMREAD_COLOR)
    ha, hb, hc = difference_hash(a), difference_hash(b), difference_hash(copy)
    assert ha.shape == (64,) and ha.dtype == bool
    assert (ha != hc).sum() <= 10 < (ha != hb).sum()
    mask = near_duplicates(np.array([hc, hb]), np.array([ha]))
    assert mask.tolist() == [True, False]
    assert near_duplicates(np.zeros((0, 64), bool), np.array([ha])).tolist() == []


def test_police_validation_photos_are_every_fifth_number():
    assert is_validation_photo("police_scenes/on/on-055.jpg")
    assert is_validation_photo("off-100.png")
    assert not is_validation_photo("police_crops/off/off-056.jpg")
    assert not is_validation_photo("no_number.jpg")


def test_the_shipped_models_sure_threshold_reaches_the_fusion():
    if not DEFAULT_BODY_MODEL.is_file():
        pytest.skip(f"{DEFAULT_BODY_MODEL} absent")
    body = EvBodyClassifier(DEFAULT_BODY_MODEL)
    assert body.sure_threshold is not None and body.confident_threshold <= body.sure_threshold <= 1.0
    fusion = TrackEvClassifier(body=body)
    assert fusion.config.body_sure_threshold == body.sure_threshold
    assert fusion.config.body_threshold == body.confident_threshold


def test_the_top_of_an_int8_student_is_required(tmp_path):
    pytest.importorskip("torch")
    from models.ev_body_top import make_top

    bad = tmp_path / "m.onnx"
    import onnx
    from onnx import helper

    g = helper.make_graph([helper.make_node("Identity", ["x"], ["y"])], "g",
                          [helper.make_tensor_value_info("x", onnx.TensorProto.FLOAT, [1])],
                          [helper.make_tensor_value_info("y", onnx.TensorProto.FLOAT, [1])])
    onnx.save(helper.make_model(g), bad)
    with pytest.raises(SystemExit, match="not an int8 EV-body student"):
        make_top(bad)


def test_a_body_model_with_a_bad_sure_threshold_is_refused(tmp_path):
    if not DEFAULT_BODY_MODEL.is_file():
        pytest.skip(f"{DEFAULT_BODY_MODEL} absent")
    import onnx

    m = onnx.load(str(DEFAULT_BODY_MODEL))
    for p in m.metadata_props:
        if p.key == "sure_threshold":
            p.value = "-0.5"
    bad = tmp_path / "body.onnx"
    onnx.save(m, str(bad))
    with pytest.raises(ValueError, match="sure_threshold -0.5 must be above 0"):
        EvBodyClassifier(bad)
    for p in m.metadata_props:
        if p.key == "sure_threshold":
            p.value = "often"
    onnx.save(m, str(bad))
    with pytest.raises(ValueError, match="sure_threshold"):
        EvBodyClassifier(bad)
