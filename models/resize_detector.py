"""The project detector re-declared at another input size: same weights, same nodes.

``models/iea_det_tiny.onnx`` is fully convolutional (its shapes come from ``Shape`` nodes) but exported with a fixed
input. ``resized_model`` saves it with the input [1, 3, h, w] and its anchor count (``bench/detector_size_bench.py``
measures every size with it); ``input_hw`` is the input that holds the 1280x720 frame letterboxed at a scale (strides
8/16/32 need multiples of 32). ``any_size_model`` saves it with a symbolic input, as shipped: the training script
exports through it with ``RSU_INPUT_HW`` as the default, and each RSU letterboxes only its zone of responsibility at
that scale (``rsu.detect_roi``). Needs the ``onnx`` package (dev and train extras); the runtime only loads the result.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from rsu.detect import YOLOX_STRIDES

RSU_INPUT_HW = (384, 640)
"""A whole 1280x720 frame at the scale the network is trained at (0.5): the model's default input (metadata
``input_hw``). An RSU letterboxes only its zone of responsibility at that scale (``rsu.detect_roi``: 288x448 on the
RELLIS cameras). The whole frame at 0.4 (288x512: MOTA 0.923, ``bench/detector_size_bench.py``) is cheaper, but
that smaller scale misses debris falling off a truck (``bench/hazard_bench.py``, hazard_falls seed 102:
the AV drives into it), which scale 0.5 finds."""
FRAME_WH = (1280, 720)


def input_hw(scale: float, frame_wh: tuple[int, int] = FRAME_WH, multiple: int = 32) -> tuple[int, int]:
    """Model input (h, w) that holds the frame letterboxed at ``scale``, each side a multiple of ``multiple``."""
    if not 0.05 <= scale <= 1.0:
        raise ValueError(f"scale must be in [0.05, 1], got {scale}")
    return (int(math.ceil(frame_wh[1] * scale / multiple)) * multiple,
            int(math.ceil(frame_wh[0] * scale / multiple)) * multiple)


def anchors(hw: tuple[int, int], strides=YOLOX_STRIDES) -> int:
    return sum((hw[0] // s) * (hw[1] // s) for s in strides)


def _load_model(src: Path):
    """The ``onnx`` module, its ``numpy_helper``, the model at ``src`` and its input's four dimensions."""
    try:
        import onnx
    except ImportError as e:  # pragma: no cover - depends on the environment
        raise SystemExit("re-declaring the detector's input needs the onnx package (pip install onnx; dev extra)") from e
    from onnx import numpy_helper

    model = onnx.load(str(src))
    dims = model.graph.input[0].type.tensor_type.shape.dim
    if len(dims) != 4:
        raise ValueError(f"{src.name}: expected a [1, 3, h, w] input, got {len(dims)} dimensions")
    return onnx, numpy_helper, model, dims


def resized_model(src: Path, hw: tuple[int, int], folder: Path) -> Path:
    """``src`` with its declared input [1, 3, h, w] and output [1, anchors, C] (intermediate shapes dropped: the
    runtime infers them), saved in ``folder`` as ``<stem>_<h>x<w>.onnx`` (or at ``folder`` when it ends in .onnx);
    the weights and nodes are unchanged."""
    onnx, numpy_helper, model, dims = _load_model(src)
    old_hw = (dims[2].dim_value, dims[3].dim_value)
    dims[2].dim_value, dims[3].dim_value = hw
    # the FPN's upsampling (Resize) was traced with its output size as a constant [h, w] (concatenated after the
    # batch and channel dims): scale it with the input
    nodes = {out: n for n in model.graph.node for out in n.output}
    for resize in (n for n in model.graph.node if n.op_type == "Resize"):
        concat = nodes.get(resize.input[3]) if len(resize.input) > 3 else None
        for name in (concat.input if concat is not None and concat.op_type == "Concat" else ()):
            const = nodes.get(name)
            if const is None or const.op_type != "Constant":
                continue
            value = numpy_helper.to_array(const.attribute[0].t)
            if value.shape != (2,):
                continue
            new = value.copy()
            new[0], new[1] = value[0] * hw[0] // old_hw[0], value[1] * hw[1] // old_hw[1]
            const.attribute[0].t.CopyFrom(numpy_helper.from_array(new))
    model.graph.output[0].type.tensor_type.shape.dim[1].dim_value = anchors(hw)
    del model.graph.value_info[:]
    out = folder / f"{src.stem}_{hw[0]}x{hw[1]}.onnx" if folder.suffix != ".onnx" else folder
    onnx.save(model, str(out))
    return out




def any_size_model(src: Path, out: Path, default_hw: tuple[int, int] = RSU_INPUT_HW) -> Path:
    """``src`` saved with a symbolic input [1, 3, height, width] (and output [1, anchors, C]), so that one file runs
    at any input whose sides are multiples of 32: its two FPN upsamplings (``Resize``, nearest, asymmetric, floor),
    traced with a constant output size, are given the equivalent constant scale 2 instead. The RSU letterboxes only
    the part of the frame where its zone of responsibility lies (``rsu.detect_roi``) at the input that part needs;
    ``default_hw`` (metadata ``input_hw``) is the input for a whole 1280x720 frame. Same weights and the same outputs
    as :func:`resized_model` at every size (``tests/rsu/test_resize_detector.py``)."""
    onnx, numpy_helper, model, dims = _load_model(src)
    resizes = [n for n in model.graph.node if n.op_type == "Resize"]
    for k, resize in enumerate(resizes):
        modes = {a.name: a.s.decode() for a in resize.attribute if a.type == onnx.AttributeProto.STRING}
        if modes.get("mode") != "nearest" or modes.get("coordinate_transformation_mode") != "asymmetric":
            raise ValueError(f"{src.name}: Resize {resize.name} is not a nearest, asymmetric upsampling")
        if len(resize.input) == 3 and resize.input[2]:
            continue  # given by scale already (a model made by this function)
        name = f"any_size_upsample_scales_{k}"
        model.graph.initializer.append(numpy_helper.from_array(np.array([1.0, 1.0, 2.0, 2.0], np.float32), name))
        x = resize.input[0]
        del resize.input[:]
        resize.input.extend([x, "", name])
    _drop_unused_nodes(model.graph)
    dims[2].ClearField("dim_value")
    dims[3].ClearField("dim_value")
    dims[2].dim_param, dims[3].dim_param = "height", "width"
    anchors_dim = model.graph.output[0].type.tensor_type.shape.dim[1]
    anchors_dim.ClearField("dim_value")
    anchors_dim.dim_param = "anchors"
    del model.graph.value_info[:]
    meta = {p.key: p for p in model.metadata_props}
    if "input_hw" not in meta:
        meta["input_hw"] = model.metadata_props.add()
        meta["input_hw"].key = "input_hw"
    meta["input_hw"].value = f"{default_hw[0]},{default_hw[1]}"
    onnx.checker.check_model(model)
    onnx.save(model, str(out))
    return out


def _drop_unused_nodes(graph) -> None:
    """Remove the nodes whose outputs nothing reads (the traced upsampling sizes), until none is left."""
    outputs = {o.name for o in graph.output}
    while True:
        used = outputs | {i for n in graph.node for i in n.input}
        dead = [n for n in graph.node if not any(o in used for o in n.output)]
        if not dead:
            return
        for n in dead:
            graph.node.remove(n)
