"""EvAlert.confidence as a calibrated probability (rsu.classify.confidence): features, fit, ECE."""

from __future__ import annotations

import numpy as np
import pytest

from protocol.enums import EvCue
from rsu.classify.confidence import (
    DEFAULT_MODEL,
    FEATURES,
    ConfidenceModel,
    alert_features,
    expected_calibration_error,
    fit_logistic,
)


def test_features_name_what_the_alert_rests_on():
    f = alert_features((EvCue.ALTERNATION, EvCue.EV_BODY), 0.8, 200.0)
    assert f.tolist() == [1.0, 0.0, 0.8, 0.0, 1.0] and len(f) == len(FEATURES)
    f = alert_features(("steady_bar",), None, 50.0)
    assert f.tolist() == [0.0, 1.0, 0.0, 1.0, -1.0]


def test_fit_recovers_a_separating_direction_and_is_calibrated_on_its_data():
    rng = np.random.default_rng(0)
    x = rng.normal(size=(400, 1))
    p_true = 1 / (1 + np.exp(-(0.5 + 2.0 * x[:, 0])))
    y = (rng.random(400) < p_true).astype(int)
    w = fit_logistic(x, y, l2=0.01)
    assert w[0] == pytest.approx(0.5, abs=0.35) and w[1] == pytest.approx(2.0, abs=0.5)
    p = 1 / (1 + np.exp(-(w[0] + w[1] * x[:, 0])))
    assert expected_calibration_error(p, y, bins=5) < 0.08


def test_ece_of_perfect_and_wrong_confidences():
    assert expected_calibration_error([1.0, 1.0, 0.0], [1, 1, 0]) == pytest.approx(0.0)
    assert expected_calibration_error([0.9, 0.9], [0, 0]) == pytest.approx(0.9)
    assert expected_calibration_error([], []) is None


def test_model_is_a_probability_and_checks_its_size():
    for feats in (alert_features(("flash",), 0.9, 300.0), alert_features(("steady_bar",), None, 40.0)):
        assert 0.0 < DEFAULT_MODEL(feats) < 1.0
    with pytest.raises(ValueError, match="weights"):
        ConfidenceModel((0.0, 1.0))


def test_alert_manager_gives_the_models_probability():
    from protocol.enums import AlertState, EvState
    from rsu.classify.alerts import EvAlertManager
    from rsu.perception import Detections, object_column

    one = np.ones(1)
    row = Detections(np.array([[0.0, 0.0, 200.0, 100.0]]), one, np.zeros(1, np.int64), track_ids=np.array([4]),
                     ev_scores=np.array([0.99]), ev_states=object_column([EvState.CONFIRMED]),
                     localized=np.ones(1, bool), positions_m=np.array([[1.0, 2.0]]), lanes=object_column([1]))
    model = ConfidenceModel((0.0, 0.0, 0.0, 0.0, -2.0, 1.0))  # no body score: -2; width 200 px: +1
    (e,) = EvAlertManager(confidence_model=model).update(0.0, row)
    assert e.state == AlertState.ACTIVE
    assert e.confidence == pytest.approx(1 / (1 + np.exp(1.0)))  # not the evidence score 0.99
