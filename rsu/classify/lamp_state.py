"""Are a vehicle's warning lamps lit? A small CNN of the lamp band, trained on real photos and video
(``models/lamp_state.onnx``, ``models/train_lamp_state.py``, card ``models/lamp_state.md``).

The colour tests of :mod:`rsu.classify.lamps` count pixels over fixed thresholds: a beacon a few pixels wide on a
60-120 px vehicle seen by an elevated camera fills too little of the band to pass them, and the tail lights of a row of
cars at dusk pass them although no lamp there is a beacon. The model looks at the band's pixels instead: the band
(:func:`band_input`: squashed to ``INPUT_HW``, BGR in [0, 1], pixels of other vehicles set to the band's median
colour) goes through three small convolutions whose strongest response anywhere in the band (global max pooling:
a lit beacon is a few pixels, wherever it sits) and mean response give p(lit). Input ``bands`` [N, 3, 32, 64]
float32, output ``p_lit`` [N, 1]; the operating point ``threshold`` is in the model's metadata.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from rsu.classify.classifiers import MODELS_DIR

DEFAULT_LAMP_STATE_MODEL = MODELS_DIR / "lamp_state.onnx"
INPUT_HW = (32, 64)
"""(height, width) the band is squashed to: a 60-120 px CCTV vehicle's band is about this size, so its beacons keep
their pixels."""


def band_input(band_bgr: np.ndarray, ignore: np.ndarray | None = None) -> np.ndarray:
    """The model's input (3, H, W) float32 of one lamp band (BGR uint8); ``ignore``: the band's pixels that belong to
    other vehicles, set to the median colour of the rest first."""
    if ignore is not None and ignore.any():
        keep = ~ignore
        band_bgr = band_bgr.copy()
        band_bgr[ignore] = np.median(band_bgr[keep], axis=0).astype(band_bgr.dtype) if keep.any() else 0
    h, w = INPUT_HW
    interp = cv2.INTER_AREA if band_bgr.shape[0] > h or band_bgr.shape[1] > w else cv2.INTER_LINEAR
    x = cv2.resize(band_bgr, (w, h), interpolation=interp)
    return np.ascontiguousarray(x.transpose(2, 0, 1), np.float32) / np.float32(255.0)


class LampStateModel:
    """p(warning lamps lit) of lamp bands, from ``models/lamp_state.onnx`` (module docstring)."""

    def __init__(self, path: str | Path = DEFAULT_LAMP_STATE_MODEL) -> None:
        import onnxruntime as ort

        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"lamp-state model {str(path)!r} not found")
        opts = ort.SessionOptions()
        opts.intra_op_num_threads = 1
        opts.inter_op_num_threads = 1
        self.session = ort.InferenceSession(str(path), opts, providers=["CPUExecutionProvider"])
        meta = self.session.get_modelmeta().custom_metadata_map
        try:
            self.threshold = float(meta.get("threshold", 0.5))
        except ValueError as exc:
            raise ValueError(f"{path}: bad threshold metadata: {exc}") from exc
        self.input_name = self.session.get_inputs()[0].name

    def predict(self, inputs: np.ndarray) -> np.ndarray:
        """p(lit) of a batch of :func:`band_input` arrays (N, 3, H, W)."""
        x = np.asarray(inputs, np.float32).reshape(-1, 3, *INPUT_HW)
        return self.session.run(None, {self.input_name: x})[0].reshape(-1)

    def __call__(self, band_bgr: np.ndarray, ignore: np.ndarray | None = None) -> float:
        """p(lit) of one lamp band."""
        return float(self.predict(band_input(band_bgr, ignore)[None])[0])
