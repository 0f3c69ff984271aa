"""``EvAlert.confidence`` as a calibrated probability that the alerted track is an emergency vehicle with its lights on.

The evidence state's own score (the log-odds level of :class:`rsu.classify.temporal.TrackEvidence`, squashed) says
how long the lamps have flashed, not how often such an alert is right. The confidence is instead a logistic model
(Platt scaling, Platt 1999) of what the alert rests on (:func:`alert_features`):

    p = 1 / (1 + exp(-(w0 + w . x)))

with ``x`` = [a flash or alternation cue, a steady bar as the only lamp cue, the mean EV-body score (0 when never
scored), never body-scored, log2 of the box width / 100 px]. The weights (:data:`DEFAULT_MODEL`) are fitted by
``bench/fit_alert_confidence.py`` with :func:`fit_logistic` on the alerts of the tuning clips of
``bench/ev_real_bench.py`` (an alert is right when its track is on a labelled EV, ``rsu.scan_labels``), and its
reliability is read on the held-out clips as the expected calibration error (:func:`expected_calibration_error`).
So the DDM can weigh one camera's weak alert against two cameras' agreement on a probability scale.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np

from protocol.enums import EvCue

FEATURES = ("flash_cue", "steady_bar_only", "body_score", "body_missing", "log2_width_100px")


def alert_features(cues: Iterable[EvCue | str], body_score: float | None, width_px: float) -> np.ndarray:
    """The features of one alert (:data:`FEATURES`) from its cues, mean EV-body score and box width (pixels)."""
    names = {c.value if isinstance(c, EvCue) else str(c) for c in cues}
    flash = bool(names & {EvCue.FLASH.value, EvCue.ALTERNATION.value})
    steady_only = EvCue.STEADY_BAR.value in names and not flash
    body = 0.0 if body_score is None else float(np.clip(body_score, 0.0, 1.0))
    return np.array([float(flash), float(steady_only), body, float(body_score is None),
                     math.log2(max(float(width_px), 1.0) / 100.0)])


@dataclass(frozen=True)
class ConfidenceModel:
    """Intercept then one weight per :data:`FEATURES` entry."""

    weights: tuple[float, ...]

    def __post_init__(self) -> None:
        if len(self.weights) != len(FEATURES) + 1:
            raise ValueError(f"a confidence model needs {len(FEATURES) + 1} weights, got {len(self.weights)}")

    def __call__(self, features: np.ndarray) -> float:
        z = self.weights[0] + float(np.dot(self.weights[1:], features))
        return float(1.0 / (1.0 + math.exp(-min(max(z, -50.0), 50.0))))


def fit_logistic(x: np.ndarray, y: np.ndarray, l2: float = 1.0, iterations: int = 50) -> tuple[float, ...]:
    """Weights (intercept first) of an L2-regularised logistic regression of ``y`` (0/1) on the rows of ``x``, by
    Newton's method (IRLS); the intercept is not penalised. Deterministic."""
    x = np.asarray(x, float).reshape(len(y), -1)
    y = np.asarray(y, float)
    a = np.hstack([np.ones((len(y), 1)), x])
    w = np.zeros(a.shape[1])
    penalty = np.full(a.shape[1], float(l2))
    penalty[0] = 0.0
    for _ in range(iterations):
        p = 1.0 / (1.0 + np.exp(-np.clip(a @ w, -50, 50)))
        grad = a.T @ (p - y) + penalty * w
        hess = a.T @ (a * (p * (1 - p))[:, None]) + np.diag(penalty) + 1e-9 * np.eye(len(w))
        step = np.linalg.solve(hess, grad)
        w -= step
        if np.max(np.abs(step)) < 1e-8:
            break
    return tuple(round(float(v), 4) for v in w)


def expected_calibration_error(p: Sequence[float], y: Sequence[int], bins: int = 5) -> float | None:
    """ECE (Naeini et al. 2015): over ``bins`` equal-width confidence bins, the share of alerts in the bin times
    |their mean confidence - the share of them that were right|. None without alerts."""
    p = np.asarray(p, float)
    y = np.asarray(y, float)
    if not len(p):
        return None
    idx = np.minimum((p * bins).astype(int), bins - 1)
    ece = 0.0
    for b in range(bins):
        m = idx == b
        if m.any():
            ece += m.mean() * abs(p[m].mean() - y[m].mean())
    return float(ece)


DEFAULT_MODEL = ConfidenceModel((0.9859, -0.5303, 0.5303, 0.5661, 0.0, 0.5303))
"""Fitted by ``bench/fit_alert_confidence.py`` (L2 1.0, the least leave-one-clip-out log loss of 0.1-10) on the 15
alerts (12 right) of the tuning clips of ``bench/ev_real_bench.py`` (``TUNE_CLIPS``). A flash alone weighs less than
a steady bar with its body score, a wider box more; no tuning alert lacked a body score, so that weight is 0.
Expected calibration error (5 bins): 0.10 on those alerts; on the 8 alerts of the held-out clips 0.21, where the
evidence level the alert carried before read 0.23 (eight alerts: a coarse measure)."""
