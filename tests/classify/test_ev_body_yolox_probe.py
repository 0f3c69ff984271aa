"""The YOLOX-feature probe (``models.ev_body_yolox_probe``): the detector graph's PAFPN outputs pooled per
crop. Skips without ``../shared/data/real``."""

from __future__ import annotations

import numpy as np
import pytest

from models.ev_body_yolox_probe import pafpn_features, pafpn_session
from rsu.scan import DEFAULT_DETECTOR


@pytest.mark.shared
def test_pafpn_features_pool_the_three_head_inputs_of_a_crop():
    if not DEFAULT_DETECTOR.is_file():
        pytest.skip(f"{DEFAULT_DETECTOR} absent (../shared/data/real not beside the repository)")
    session = pafpn_session(DEFAULT_DETECTOR, threads=1)
    rng = np.random.default_rng(0)
    flat = np.full((60, 90, 3), 114, np.uint8)
    busy = rng.integers(0, 256, (60, 90, 3), dtype=np.uint8)
    a, b = pafpn_features(session, flat), pafpn_features(session, busy)
    assert a.shape == b.shape == (2 * (64 + 128 + 256),)
    assert np.isfinite(a).all() and np.isfinite(b).all()
    assert not np.allclose(a, b)  # the features read the crop
    np.testing.assert_allclose(pafpn_features(session, busy), b, rtol=1e-5)  # deterministic


def test_a_graph_without_the_named_tensors_is_refused(tmp_path):
    onnx = pytest.importorskip("onnx")
    x = onnx.helper.make_tensor_value_info("images", onnx.TensorProto.FLOAT, [1, 3, 4, 4])
    y = onnx.helper.make_tensor_value_info("output", onnx.TensorProto.FLOAT, [1, 3, 4, 4])
    graph = onnx.helper.make_graph([onnx.helper.make_node("Relu", ["images"], ["output"])], "g", [x], [y])
    path = tmp_path / "other.onnx"
    onnx.save(onnx.helper.make_model(graph, opset_imports=[onnx.helper.make_opsetid("", 17)]), str(path))
    with pytest.raises(ValueError, match="no tensors"):
        pafpn_session(path)
