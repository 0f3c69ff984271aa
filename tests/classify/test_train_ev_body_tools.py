"""The EV-body training script's distillation targets and int8 export, without PyTorch."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from models.train_ev_body import distilled_targets, quantise_int8
from rsu.classify.real_data import CropSample


def test_distilled_targets_mix_teacher_and_label_and_keep_the_label_without_a_teacher(tmp_path: Path):
    root = tmp_path / "ev_train"
    a = CropSample(root / "av_emergency_crops" / "images" / "1.jpg", 1, "g1", "av_emergency_crops")
    b = CropSample(root / "openimages_vehicles" / "train" / "images" / "p.jpg", 0, "g2", "openimages_vehicles",
                   (1, 2, 30, 40))
    c = CropSample(root / "indian_ev_photos" / "x.jpg", 1, "g3", "indian_ev_photos")
    teacher = {"av_emergency_crops/images/1.jpg|": 0.6, "openimages_vehicles/train/images/p.jpg|1,2,30,40": 0.2}
    out = distilled_targets([a, b, c], np.array([1.0, 0.0, 1.0]), teacher, root, weight=0.5)
    np.testing.assert_allclose(out, [0.8, 0.1, 1.0])


def test_int8_export_runs_and_stays_close_to_the_float_graph(tmp_path: Path):
    onnx = pytest.importorskip("onnx")
    import onnxruntime as ort
    from onnx import TensorProto, helper, numpy_helper

    rng = np.random.default_rng(0)
    w = numpy_helper.from_array(rng.normal(0, 0.3, (4, 3, 3, 3)).astype(np.float32), "w")
    fc = numpy_helper.from_array(rng.normal(0, 0.3, (4, 1)).astype(np.float32), "fc")
    graph = helper.make_graph(
        [helper.make_node("Conv", ["crops", "w"], ["c"], pads=[1, 1, 1, 1]),
         helper.make_node("Relu", ["c"], ["r"]),
         helper.make_node("GlobalAveragePool", ["r"], ["g"]),
         helper.make_node("Flatten", ["g"], ["f"]),
         helper.make_node("MatMul", ["f", "fc"], ["z"]),
         helper.make_node("Sigmoid", ["z"], ["p_ev"])],
        "tiny", [helper.make_tensor_value_info("crops", TensorProto.FLOAT, ["n", 3, 16, 16])],
        [helper.make_tensor_value_info("p_ev", TensorProto.FLOAT, ["n", 1])], [w, fc])
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    src, dst = tmp_path / "fp32.onnx", tmp_path / "int8.onnx"
    onnx.save(model, str(src))
    calibration = rng.integers(0, 256, (16, 16, 16, 3), dtype=np.uint8)
    quantise_int8(src, dst, calibration)
    x = calibration[:4].astype(np.float32).transpose(0, 3, 1, 2) / 255.0
    p32 = ort.InferenceSession(str(src), providers=["CPUExecutionProvider"]).run(None, {"crops": x})[0]
    p8 = ort.InferenceSession(str(dst), providers=["CPUExecutionProvider"]).run(None, {"crops": x})[0]
    assert p8.shape == (4, 1)
    assert np.abs(p8 - p32).max() < 0.05
    assert any(n.op_type.startswith("QLinear") or n.op_type == "ConvInteger" for n in onnx.load(str(dst)).graph.node)
