"""The project detector re-declared at another input size (issue 19, point 3): same weights, same nodes.

``models/iea_det_tiny.onnx`` is fully convolutional (its shapes come from ``Shape`` nodes) but exported with a fixed
input. ``resized_model`` saves it with the input [1, 3, h, w] and its anchor count; ``input_hw`` is the input that
holds the 1280x720 frame letterboxed at a scale (strides 8/16/32 need multiples of 32). The training script
exports through it at ``RSU_INPUT_HW``, the size ``bench/detector_size_bench.py`` chose; the bench measures every
size with it. Needs the ``onnx`` package (dev and train extras); the runtime only loads the result.
"""

from __future__ import annotations

import math
from pathlib import Path

from rsu.detect import YOLOX_STRIDES

RSU_INPUT_HW = (288, 512)
"""The input the RSUs run: the frame letterboxed at scale 0.4, the smallest whose MOTA stays >= 0.9
(``bench/detector_size_bench.py``; the network is trained at 384x640)."""
FRAME_WH = (1280, 720)


def input_hw(scale: float, frame_wh: tuple[int, int] = FRAME_WH, multiple: int = 32) -> tuple[int, int]:
    """Model input (h, w) that holds the frame letterboxed at ``scale``, each side a multiple of ``multiple``."""
    if not 0.05 <= scale <= 1.0:
        raise ValueError(f"scale must be in [0.05, 1], got {scale}")
    return (int(math.ceil(frame_wh[1] * scale / multiple)) * multiple,
            int(math.ceil(frame_wh[0] * scale / multiple)) * multiple)


def anchors(hw: tuple[int, int], strides=YOLOX_STRIDES) -> int:
    return sum((hw[0] // s) * (hw[1] // s) for s in strides)


def resized_model(src: Path, hw: tuple[int, int], folder: Path) -> Path:
    """``src`` with its declared input [1, 3, h, w] and output [1, anchors, C] (intermediate shapes dropped: the
    runtime infers them), saved in ``folder`` as ``<stem>_<h>x<w>.onnx`` (or at ``folder`` when it ends in .onnx);
    the weights and nodes are unchanged."""
    try:
        import onnx
    except ImportError as e:  # pragma: no cover - depends on the environment
        raise SystemExit("re-declaring the detector's input needs the onnx package (pip install onnx; dev extra)") from e
    from onnx import numpy_helper

    model = onnx.load(str(src))
    dims = model.graph.input[0].type.tensor_type.shape.dim
    if len(dims) != 4:
        raise ValueError(f"{src.name}: expected a [1, 3, h, w] input, got {len(dims)} dimensions")
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


