"""Per-crop EV classifiers behind one interface (thesis 2.4.2), run with onnxruntime.

A classifier returns an EV probability per vehicle crop (BGR uint8, any size):
``predict(crops) -> (N,) float32`` and ``__call__(crop) -> float`` (the ``crop_score`` hook of
:class:`rsu.classify.ev.TrackEvClassifier`).

- :class:`CnnClassifier`: the project's small CNN on the pixel array (thesis 2.4.2.3: three
  conv + ReLU + max-pool blocks, a dense ReLU layer, one sigmoid unit), trained by
  ``models/train_ev_cnn.py`` and shipped as ``models/ev_cnn.onnx`` (card: ``models/ev_cnn.md``). Input
  ``crops`` ``[N, 3, S, S]`` float32, BGR scaled to [0, 1] (S from the model, 64 for the shipped one);
  output ``p_ev`` ``[N, 1]``.
- :class:`FeatureClassifier`: a feature descriptor of :mod:`rsu.classify.features` followed by a
  scikit-learn model exported to ONNX (``models/train_ev_features.py``; shipped:
  ``models/ev_hsv8_gb.onnx``, gradient boosting on the 8-element HSV feature). Input ``features``
  ``[N, D]`` float32; the probability output (``probabilities``, or the second output) column 1 is p(EV).

The runtime needs only numpy, OpenCV and onnxruntime; training needs the ``train`` extra.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Protocol, runtime_checkable

import cv2
import numpy as np

from rsu.classify.features import FEATURES, extract_batch

MODELS_DIR = Path(__file__).resolve().parents[2] / "models"
DEFAULT_CNN = MODELS_DIR / "ev_cnn.onnx"
DEFAULT_FEATURE_MODEL = MODELS_DIR / "ev_hsv8_gb.onnx"
DEFAULT_FEATURE = "hsv8"


@runtime_checkable
class CropClassifier(Protocol):
    name: str

    def predict(self, crops: Sequence[np.ndarray]) -> np.ndarray: ...

    def __call__(self, crop: np.ndarray) -> float: ...


def _session(path: str | Path, threads: int | None):
    import onnxruntime as ort

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"EV classifier model {path} not found (train it with `make models`)")
    opts = ort.SessionOptions()
    if threads:
        opts.intra_op_num_threads = int(threads)
        opts.inter_op_num_threads = 1
    return ort.InferenceSession(str(path), sess_options=opts, providers=["CPUExecutionProvider"])


def _check(crops: Sequence[np.ndarray]) -> list[np.ndarray]:
    out = []
    for c in crops:
        if not isinstance(c, np.ndarray) or c.ndim != 3 or c.shape[2] != 3 or c.dtype != np.uint8 \
                or c.shape[0] < 2 or c.shape[1] < 2:
            raise ValueError(f"expected BGR uint8 crops of at least 2x2 pixels, got "
                             f"{getattr(c, 'dtype', type(c))} {getattr(c, 'shape', '')}")
        out.append(c)
    return out


def cnn_input(crops: Sequence[np.ndarray], size: int) -> np.ndarray:
    """Crops -> ``[N, 3, size, size]`` float32 BGR in [0, 1] (the CNN's input; also used in training)."""
    batch = np.empty((len(crops), 3, size, size), np.float32)
    for i, c in enumerate(crops):
        interp = cv2.INTER_AREA if c.shape[0] > size or c.shape[1] > size else cv2.INTER_LINEAR
        batch[i] = cv2.resize(c, (size, size), interpolation=interp).transpose(2, 0, 1) / np.float32(255.0)
    return batch


class CnnClassifier:
    """The small pixel-array CNN (thesis 2.4.2.3) from an ONNX file; see the module docstring."""

    def __init__(self, path: str | Path = DEFAULT_CNN, *, threads: int | None = 1, name: str = "cnn") -> None:
        self.session = _session(path, threads)
        inp = self.session.get_inputs()[0]
        shape = inp.shape
        if len(shape) != 4 or shape[1] != 3 or not isinstance(shape[2], int) or shape[2] != shape[3]:
            raise ValueError(f"{path}: expected an input [N, 3, S, S], got {shape}")
        self.input_name, self.size, self.name = inp.name, int(shape[2]), name

    def predict(self, crops: Sequence[np.ndarray]) -> np.ndarray:
        crops = _check(crops)
        if not crops:
            return np.zeros(0, np.float32)
        out = self.session.run(None, {self.input_name: cnn_input(crops, self.size)})[0]
        return np.asarray(out, np.float32).reshape(len(crops), -1)[:, -1]

    def __call__(self, crop: np.ndarray) -> float:
        return float(self.predict([crop])[0])


class FeatureClassifier:
    """A feature descriptor + an ONNX-exported scikit-learn model; see the module docstring."""

    def __init__(self, path: str | Path = DEFAULT_FEATURE_MODEL, feature: str = DEFAULT_FEATURE, *,
                 threads: int | None = 1, name: str | None = None) -> None:
        if feature not in FEATURES:
            raise ValueError(f"unknown feature {feature!r}; choose from {sorted(FEATURES)}")
        self.session = _session(path, threads)
        self.input_name = self.session.get_inputs()[0].name
        outs = [o.name for o in self.session.get_outputs()]
        self.prob_name = "probabilities" if "probabilities" in outs else outs[-1]
        self.feature, self.name = feature, name or f"{feature}+{Path(path).stem}"

    def predict(self, crops: Sequence[np.ndarray]) -> np.ndarray:
        crops = _check(crops)
        if not crops:
            return np.zeros(0, np.float32)
        x = extract_batch(self.feature, crops).astype(np.float32)
        prob = self.session.run([self.prob_name], {self.input_name: x})[0]
        if isinstance(prob, list):  # ZipMap output: a list of {label: p}
            return np.array([float(p.get(1, p.get("1", 0.0))) for p in prob], np.float32)
        prob = np.asarray(prob, np.float32)
        return prob[:, 1] if prob.ndim == 2 and prob.shape[1] == 2 else prob.reshape(-1)

    def __call__(self, crop: np.ndarray) -> float:
        return float(self.predict([crop])[0])


def load_classifier(name: str, *, threads: int | None = 1) -> CropClassifier:
    """``cnn`` (models/ev_cnn.onnx), ``hsv8-gb`` (models/ev_hsv8_gb.onnx), or ``PATH.onnx[:FEATURE]``."""
    if name == "cnn":
        return CnnClassifier(DEFAULT_CNN, threads=threads)
    if name == "hsv8-gb":
        return FeatureClassifier(DEFAULT_FEATURE_MODEL, DEFAULT_FEATURE, threads=threads, name="hsv8-gb")
    path, _, feature = name.partition(":")
    if not path.endswith(".onnx"):
        raise ValueError(f"unknown EV classifier {name!r}: use cnn, hsv8-gb or PATH.onnx[:FEATURE]")
    return FeatureClassifier(path, feature, threads=threads) if feature else CnnClassifier(path, threads=threads)
