"""The shipped EV crop classifiers (ONNX, onnxruntime) and the Table 2 evaluation (iea-rsu eval-classifier)."""

from __future__ import annotations

import importlib.util

import cv2
import numpy as np
import pytest

from rsu.classify.classifiers import CnnClassifier, CropClassifier, FeatureClassifier, load_classifier
from rsu.classify.evaluation import evaluate_fitted, evaluate_models, format_table, metrics

HAVE_SKLEARN = importlib.util.find_spec("sklearn") is not None


def sim_crops(seed=7):
    """Well-visible vehicle crops of held-out renders (seed 7 is not in the training export): EVs with
    their lights on, and every other vehicle."""
    from sim.camera_source import SimCamera
    from sim.scenario import load_scenario
    from sim.world import World

    sc = load_scenario("rellis_ev_yield").with_overrides(seed=seed)
    world = World(sc, seed=seed)
    cams = [SimCamera(sc.corridor, r.rsu_id, seed=seed) for r in sc.corridor.rsus[:2]]
    ev, non_ev = [], []
    while world.t_s < 8.0:
        world.step(0.35)
        if world.t_s < 4.5:  # lights on at 4 s
            continue
        snap = world.snapshot()
        for cam in cams:
            img = cam.render(snap).image
            for lb in cam.renderer.labels(snap):
                x1, y1, x2, y2 = (int(v) for v in lb.bbox_px)
                if min(x2 - x1, y2 - y1) >= 24 and lb.visible_fraction >= 0.6:
                    (ev if lb.class_id == 1 else non_ev).append(img[y1:y2, x1:x2])
    return ev, non_ev


@pytest.fixture(scope="module")
def crops():
    ev, non_ev = sim_crops()
    assert len(ev) >= 4 and len(non_ev) >= 20
    return ev, non_ev


def test_shipped_cnn_separates_lit_evs_from_other_vehicles_on_held_out_renders(crops):
    ev, non_ev = crops
    cnn = load_classifier("cnn")
    assert isinstance(cnn, CropClassifier) and cnn.size == 64
    p_ev, p_non = cnn.predict(ev), cnn.predict(non_ev)
    assert p_ev.shape == (len(ev),) and p_ev.dtype == np.float32
    assert np.all((p_ev >= 0) & (p_ev <= 1)) and np.all((p_non >= 0) & (p_non <= 1))
    assert np.mean(p_ev >= 0.5) >= 0.9 and np.mean(p_non < 0.5) >= 0.95
    assert cnn(ev[0]) == pytest.approx(float(p_ev[0]), abs=1e-6)


def test_shipped_feature_classifier_ranks_evs_higher(crops):
    ev, non_ev = crops
    clf = load_classifier("hsv8-gb")
    assert isinstance(clf, FeatureClassifier) and clf.feature == "hsv8"
    assert clf.predict(ev).mean() > clf.predict(non_ev).mean() + 0.2


def test_classifiers_validate_input():
    cnn = CnnClassifier()
    assert cnn.predict([]).shape == (0,)
    with pytest.raises(ValueError, match="BGR uint8"):
        cnn.predict([np.zeros((10, 10), np.uint8)])
    with pytest.raises(FileNotFoundError, match="make models"):
        CnnClassifier("models/none.onnx")
    with pytest.raises(ValueError, match="unknown EV classifier"):
        load_classifier("svm")


def test_metrics_follow_appendix_a():
    labels = np.array([1, 1, 1, 0, 0, 0, 0, 0])
    prob = np.array([0.9, 0.8, 0.2, 0.7, 0.1, 0.1, 0.0, 0.3])  # TP 2, FN 1, FP 1, TN 4
    acc, p, r, f = metrics(labels, prob)
    assert (acc, p, r) == (pytest.approx(6 / 8), pytest.approx(2 / 3), pytest.approx(2 / 3))
    assert f == pytest.approx(2 / 3)
    assert metrics(np.array([0, 0]), np.array([0.1, 0.2]))[1:] == (0.0, 0.0, 0.0)


def write_ravev(root, n=12, seed=0):
    """A tiny synthetic RAVEV set: 'EVs' are grey boxes with a red and a blue lamp on the roof."""
    rng = np.random.default_rng(seed)
    for split in ("train", "val"):
        for cls in ("ev", "non_ev"):
            d = root / split / cls
            d.mkdir(parents=True)
            for i in range(n):
                img = np.full((40 + i, 60, 3), int(rng.integers(60, 200)), np.uint8)
                if cls == "ev":
                    img[2:8, 8:25] = (0, 0, 255)
                    img[2:8, 35:52] = (255, 40, 0)
                cv2.imwrite(str(d / f"{i}.png"), img)


@pytest.mark.skipif(not HAVE_SKLEARN, reason="scikit-learn (train extra) not installed")
def test_evaluate_fitted_table_on_a_synthetic_ravev_set(tmp_path):
    write_ravev(tmp_path)
    scores = evaluate_fitted(tmp_path, ["hsv8", "colour_hist"], ["logistic", "knn3"], log=lambda *_: None)
    assert [(s.feature, s.classifier) for s in scores] == [("hsv8", "logistic"), ("hsv8", "knn3"),
                                                          ("colour_hist", "logistic"), ("colour_hist", "knn3")]
    assert all(s.n_val == 24 and s.ms_per_crop > 0 and 0 <= s.accuracy <= 1 for s in scores)
    assert all(s.accuracy == 1.0 and s.f_measure == 1.0 for s in scores if s.feature == "hsv8")  # lamps: separable
    table = format_table(scores)
    assert "hsv8" in table and "f_measure" in table and "100.00" in table


def test_eval_classifier_cli_scores_the_shipped_models(tmp_path, capsys):
    from rsu.cli import main

    write_ravev(tmp_path)
    assert main(["eval-classifier", str(tmp_path), "--no-fit", "--json"]) == 0
    out = capsys.readouterr().out
    assert "onnx:cnn" in out and "onnx:hsv8-gb" in out
    assert main(["eval-classifier", str(tmp_path / "missing"), "--no-fit"]) == 2


def test_evaluate_models_times_each_crop(tmp_path):
    write_ravev(tmp_path, n=4)
    (s,) = evaluate_models(tmp_path, [FeatureClassifier()], log=lambda *_: None)
    assert s.n_val == 8 and s.ms_per_crop > 0 and 0 <= s.accuracy <= 1


def test_evaluate_scenes_classifies_the_largest_detected_vehicle(tmp_path):
    from rsu.classify.evaluation import evaluate_scenes
    from rsu.perception import Detections

    class TwoBoxes:
        name = "fake"

        def detect(self, image):  # a small box on the left, a large one on the right (the lamps' car)
            boxes = np.array([[0, 60, 20, 80], [40, 20, 100, 90]], np.float32)
            return Detections(boxes, np.ones(2, np.float32), np.zeros(2, np.int64))

    class LampProbe:
        name, feature = "probe", "lamps"

        def predict(self, crops):
            return np.array([float((c[..., 2] > 200).mean() > 0.02) for c in crops])

    for cls, lamp in (("emergency_vehicle", True), ("non_emergency", False)):
        (tmp_path / cls).mkdir()
        for i in range(3):
            img = np.full((100, 120, 3), 80, np.uint8)
            if lamp:
                img[22:30, 50:90] = (0, 0, 255)  # a red lamp on the large vehicle's roof
            cv2.imwrite(str(tmp_path / cls / f"{i}.png"), img)
    (s,), counts = evaluate_scenes(tmp_path, TwoBoxes(), [LampProbe()], log=lambda *_: None)
    assert counts == dict(images=6, ev_images=3, with_vehicle=6)
    assert (s.accuracy, s.precision, s.recall) == (1.0, 1.0, 1.0)
