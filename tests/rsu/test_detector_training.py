"""models/train_detector.py (issue 19): the input normalisation folded into the first convolution computes exactly
what the network was trained on, and the shipped detector's graph begins with that convolution on the raw pixels."""

import numpy as np
import pytest

from rsu.detect import PROJECT_MODEL


def test_shipped_detector_has_no_normalisation_pass_over_the_input():
    onnx = pytest.importorskip("onnx", reason="the onnx package (dev extra) is needed to read the graph")
    graph = onnx.load(str(PROJECT_MODEL)).graph
    readers = [n.op_type for n in graph.node if "images" in n.input]
    assert readers == ["Conv"], f"the raw pixels should go straight into the first convolution, not {readers}"
    ops = {n.op_type for n in graph.node}
    assert not ops & {"Sub", "Div"}, "no subtract or divide over the whole input"


def test_raw_input_conv_equals_the_normalised_convolution_and_exports_as_one_conv():
    torch = pytest.importorskip("torch", reason="torch (the train extra) is needed to build the training model")
    import torch.nn.functional as F

    from models.train_detector import PAD_VALUE, RawInputConv

    torch.manual_seed(0)
    m = RawInputConv(8).eval()
    x = torch.rand(2, 3, 20, 34) * 255
    with torch.no_grad():
        normalised = F.pad((x - PAD_VALUE) / 64.0, (1, 1, 1, 1), value=-PAD_VALUE / 64.0)  # raw 0 at the border
        want = m.act(m.bn(F.conv2d(normalised, m.conv.weight, stride=2)))
        np.testing.assert_allclose(m(x).numpy(), want.numpy(), atol=1e-4)
        np.testing.assert_allclose(m.folded()(x).numpy(), want.numpy(), atol=1e-4)
