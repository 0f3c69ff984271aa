"""The EV-body classifier trained on real vehicles: is this vehicle crop an emergency vehicle?

``models/ev_body.onnx`` is EfficientNet-Lite0 (ImageNet) fine-tuned on the real photos of
``../shared/data/real/ev_train`` (ambulances, fire engines, police vs other vehicles) by
``models/train_ev_body.py`` (int8), its top fine-tuned again with the police cars of ``lights_on_off`` by
``models/ev_body_top.py`` (float); card: ``models/ev_body.md``. It takes the crop the RSU
takes of a track (the box grown upwards by ``above_fraction`` of its height, where a roof light bar
sits) and returns p(EV). It knows the vehicle's *type*, not its lamps: the per-track fusion
(:class:`rsu.classify.temporal.TrackEvidence`) alerts only on a confident body *and* lamp activity.

Three operating points are read from the ONNX metadata, all chosen on validation data:
``threshold`` (EV vs not for a single crop: min(precision, recall) highest), ``confident_threshold``
(the lowest with precision >= 0.95), which the per-track fusion requires before a steady light bar
counts, and ``sure_threshold`` (the lowest at which no validation vehicle is taken for an EV; None in a model
without it); and ``above_fraction``. The model file carries its own operating points.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from rsu.classify.classifiers import MODELS_DIR, CnnClassifier

DEFAULT_BODY_MODEL = MODELS_DIR / "ev_body.onnx"


class EvBodyClassifier(CnnClassifier):
    """p(EV body) per crop from ``models/ev_body.onnx``; ``threshold``, ``confident_threshold``, ``sure_threshold``
    and ``above_fraction`` from its metadata."""

    def __init__(self, path: str | Path = DEFAULT_BODY_MODEL, *, threads: int | None = 1,
                 threshold: float | None = None) -> None:
        super().__init__(path, threads=threads, name="ev-body")
        meta = self.session.get_modelmeta().custom_metadata_map
        try:
            self.threshold = float(threshold if threshold is not None else meta.get("ev_threshold", 0.5))
            self.confident_threshold = float(meta.get("confident_threshold", max(self.threshold, 0.5)))
            self.above_fraction = float(meta.get("above_fraction", 0.25))
            self.sure_threshold = float(meta["sure_threshold"]) if "sure_threshold" in meta else None
        except ValueError as exc:
            raise ValueError(f"{path}: bad ev_threshold / confident_threshold / sure_threshold / above_fraction "
                             f"metadata: {exc}") from exc
        if not 0.0 < self.threshold < 1.0 or not 0.0 <= self.above_fraction <= 1.0:
            raise ValueError(f"{path}: threshold {self.threshold} must be in (0, 1) and above_fraction in [0, 1]")
        if self.sure_threshold is not None and not self.sure_threshold > 0.0:
            raise ValueError(f"{path}: sure_threshold {self.sure_threshold} must be above 0 (above 1: never sure)")

    def is_ev(self, crops: Sequence[np.ndarray]) -> np.ndarray:
        return self.predict(crops) >= self.threshold


def load_body_classifier(name: str | None = "default", *, threads: int | None = 1) -> EvBodyClassifier | None:
    """``default`` (models/ev_body.onnx), ``none`` / None, or a path to another model of the same layout."""
    if name in (None, "none"):
        return None
    return EvBodyClassifier(DEFAULT_BODY_MODEL if name == "default" else name, threads=threads)
