"""models/resize_detector.py (bench/detector_size_bench.py): the project detector re-declared at
another input size runs through the RSU's OnnxDetector; at the shipped size it is the shipped model."""

import numpy as np
import pytest

from models.resize_detector import RSU_INPUT_HW, anchors, input_hw, resized_model
from rsu.detect import PROJECT_MODEL, OnnxDetector

pytest.importorskip("onnx", reason="the onnx package (dev extra) is needed to re-declare the model's input size")


def test_input_sizes_hold_the_letterboxed_frame_in_multiples_of_32():
    assert input_hw(0.5) == (384, 640) and anchors((384, 640)) == 5040  # the training size
    assert input_hw(0.5) == RSU_INPUT_HW  # a whole frame at the training scale: the shipped model's default input
    assert input_hw(0.4) == (288, 512) and input_hw(0.3) == (224, 384)
    with pytest.raises(ValueError):
        input_hw(0.0)


def test_resized_model_detects_like_the_shipped_one_at_its_size_and_runs_smaller(tmp_path):
    rng = np.random.default_rng(0)
    image = np.clip(110 + rng.normal(0, 8, (720, 1280, 3)), 0, 255).astype(np.uint8)
    image[400:470, 500:640] = (40, 60, 160)  # a car-sized block
    shipped = OnnxDetector(PROJECT_MODEL, score_threshold=0.01)
    assert shipped.input_hw == RSU_INPUT_HW
    same = OnnxDetector(resized_model(PROJECT_MODEL, RSU_INPUT_HW, tmp_path), score_threshold=0.01)
    a, b = shipped.detect(image), same.detect(image)
    np.testing.assert_allclose(a.boxes, b.boxes, atol=1e-3)
    np.testing.assert_allclose(a.scores, b.scores, atol=1e-5)
    small = OnnxDetector(resized_model(PROJECT_MODEL, (224, 384), tmp_path), score_threshold=0.01)
    assert small.input_hw == (224, 384)
    blob = np.full((1, 3, 224, 384), 114.0, np.float32)
    assert small.raw_output(blob).shape == (anchors((224, 384)), 7)
    small.detect(image)  # decodes with its own grid
    trained = OnnxDetector(resized_model(PROJECT_MODEL, (384, 640), tmp_path), score_threshold=0.01)
    assert trained.raw_output(np.full((1, 3, 384, 640), 114.0, np.float32)).shape == (5040, 7)
    assert len(trained.detect(image))  # back at the training size, the same weights still find the block


def test_the_any_size_model_gives_the_outputs_of_the_model_re_declared_at_each_size(tmp_path):
    """The shipped model takes any input (models.resize_detector.any_size_model: the FPN's traced upsampling sizes
    given as scale 2): at every size it computes what the model re-declared at that size computes."""
    from models.resize_detector import any_size_model

    again = OnnxDetector(any_size_model(PROJECT_MODEL, tmp_path / "any.onnx"), warmup_runs=0)
    assert again.any_input_size and again.input_hw == RSU_INPUT_HW
    rng = np.random.default_rng(3)
    for hw in ((288, 512), (224, 352), (384, 640)):
        fixed = OnnxDetector(resized_model(PROJECT_MODEL, hw, tmp_path), warmup_runs=0)
        assert not fixed.any_input_size
        blob = rng.uniform(0, 255, (1, 3, *hw)).astype(np.float32)
        np.testing.assert_allclose(again.raw_output(blob), fixed.raw_output(blob), atol=1e-5)
