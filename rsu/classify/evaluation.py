"""``iea-rsu eval-classifier``: the thesis's Table 2.2 comparison rerun on a RAVEV-layout crop set.

For every feature descriptor (:mod:`rsu.classify.features`) x classifier pair, the classifier is fitted
on ``train`` and scored on ``val`` with the App. A metrics: accuracy, precision, recall, F-measure
(eqs. A.1-A.4; EV is the positive class, threshold 0.5), plus milliseconds per crop (feature extraction
+ prediction, one thread). The classifiers are the thesis's scikit-learn set (SVM, AdaBoost, random
forest, gradient boosting, k-NN with k = 3) and logistic regression; ``HistGradientBoosting`` stands in
for XGBoost (same algorithm family; XGBoost is not a project dependency). Fitting needs scikit-learn
(the ``train`` extra); without it only the shipped ONNX models are scored. The shipped models
(``models/ev_cnn.onnx``: the CNN on the pixel array; ``models/ev_hsv8_gb.onnx``: gradient boosting on
the 8-element HSV feature) are always scored on ``val`` through onnxruntime, as the RSU runs them.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from rsu.classify.features import FEATURES, extract_batch
from rsu.classify.ravev import load_split

CLASSIFIERS = ("svm", "adaboost", "random_forest", "gradient_boosting", "hist_gb", "knn3", "logistic")


@dataclass(frozen=True)
class Score:
    feature: str
    classifier: str
    accuracy: float
    precision: float
    recall: float
    f_measure: float
    ms_per_crop: float
    n_val: int


def metrics(labels: np.ndarray, prob: np.ndarray, threshold: float = 0.5) -> tuple[float, float, float, float]:
    """(accuracy, precision, recall, F-measure), thesis App. A eqs. A.1-A.4 (EV = positive)."""
    labels = np.asarray(labels).astype(bool)
    pred = np.asarray(prob) >= threshold
    tp = int(np.sum(pred & labels))
    fp = int(np.sum(pred & ~labels))
    fn = int(np.sum(~pred & labels))
    acc = float(np.mean(pred == labels)) if len(labels) else 0.0
    p = tp / (tp + fp) if tp + fp else 0.0
    r = tp / (tp + fn) if tp + fn else 0.0
    f = 2 * p * r / (p + r) if p + r else 0.0
    return acc, p, r, f


def ms_per_crop(model, crops: Sequence[np.ndarray], calls: int) -> float:
    """Median milliseconds of one ``model.predict([crop])`` call over ``calls`` calls cycling through
    ``crops`` (after one warm-up call): the cost of classifying one crop, as the RSU classifies them. Counted
    in this process's CPU time (the model runs on one thread), so a machine busy with other jobs does not
    inflate it: one core's cost, as ``rsu_bench``'s processed fps."""
    model.predict([crops[0]])
    times = []
    for k in range(calls):
        crop = crops[k % len(crops)]
        t0 = time.process_time()
        model.predict([crop])
        times.append(time.process_time() - t0)
    return 1000.0 * float(np.median(times))


def make_classifier(name: str, seed: int = 0):
    """A scikit-learn estimator (needs the ``train`` extra); hyper-parameters as thesis App. C."""
    try:
        from sklearn.ensemble import (
            AdaBoostClassifier,
            GradientBoostingClassifier,
            HistGradientBoostingClassifier,
            RandomForestClassifier,
        )
        from sklearn.linear_model import LogisticRegression
        from sklearn.neighbors import KNeighborsClassifier
        from sklearn.pipeline import make_pipeline
        from sklearn.preprocessing import StandardScaler
        from sklearn.svm import SVC
    except ImportError as exc:  # pragma: no cover - depends on the installed extras
        raise RuntimeError("fitting the Table 2 classifiers needs scikit-learn: pip install -e .[train]") from exc
    return {
        "svm": lambda: make_pipeline(StandardScaler(), SVC(kernel="rbf", C=1.0, gamma="scale",
                                                          random_state=seed)),
        "adaboost": lambda: AdaBoostClassifier(n_estimators=50, random_state=seed),
        "random_forest": lambda: RandomForestClassifier(n_estimators=100, n_jobs=1, random_state=seed),
        "gradient_boosting": lambda: GradientBoostingClassifier(n_estimators=100, random_state=seed),
        "hist_gb": lambda: HistGradientBoostingClassifier(max_iter=100, random_state=seed),
        "knn3": lambda: KNeighborsClassifier(n_neighbors=3),
        "logistic": lambda: make_pipeline(StandardScaler(), LogisticRegression(max_iter=500, C=1.0)),
    }[name]()


def _positive_prob(model, x: np.ndarray) -> np.ndarray:
    if hasattr(model, "predict_proba"):
        try:
            return model.predict_proba(x)[:, 1]
        except AttributeError:
            pass
    return model.predict(x).astype(float)


def evaluate_fitted(root: str | Path, features: Sequence[str], classifiers: Sequence[str], *,
                    max_train_per_class: int | None = 1500, seed: int = 0, log=print) -> list[Score]:
    """Fit every classifier on every feature of ``root/train`` and score it on ``root/val``."""
    train, y_train = load_split(root, "train", max_train_per_class, seed)
    val, y_val = load_split(root, "val")
    log(f"train {len(train)} crops ({int(y_train.sum())} EV), val {len(val)} ({int(y_val.sum())} EV)")
    out = []
    for feat in features:
        if feat not in FEATURES:
            raise ValueError(f"unknown feature {feat!r}; choose from {sorted(FEATURES)}")
        x_train = extract_batch(feat, train)
        t0 = time.perf_counter()
        x_val = extract_batch(feat, val)
        extract_ms = 1000 * (time.perf_counter() - t0) / max(len(val), 1)
        for name in classifiers:
            model = make_classifier(name, seed)
            log(f"  {feat:12s} {name:18s} fitting on {x_train.shape[0]} x {x_train.shape[1]} features ...")
            t_fit = time.perf_counter()
            model.fit(x_train, y_train)
            t_fit = time.perf_counter() - t_fit
            t0 = time.perf_counter()
            prob = _positive_prob(model, x_val)
            pred_ms = 1000 * (time.perf_counter() - t0) / max(len(val), 1)
            s = Score(feat, name, *metrics(y_val, prob), extract_ms + pred_ms, len(val))
            log(f"  {feat:12s} {name:18s} acc {s.accuracy:.4f} P {s.precision:.4f} R {s.recall:.4f} "
                f"F {s.f_measure:.4f}  {s.ms_per_crop:.2f} ms/crop  (fit {t_fit:.0f} s)")
            out.append(s)
    return out


def evaluate_models(root: str | Path, models: Sequence, log=print) -> list[Score]:
    """Score ready classifiers (``predict(crops) -> p``; e.g. the shipped ONNX ones) on ``root/val``."""
    val, y_val = load_split(root, "val")
    out = []
    for m in models:
        m.predict(val[:2])  # warm-up
        t0 = time.perf_counter()
        prob = np.concatenate([m.predict([c]) for c in val]) if val else np.zeros(0)
        ms = 1000 * (time.perf_counter() - t0) / max(len(val), 1)
        feature = getattr(m, "feature", "pixels")
        s = Score(feature, f"onnx:{m.name}", *metrics(y_val, prob), ms, len(val))
        log(f"  {s.feature:12s} {s.classifier:18s} acc {s.accuracy:.4f} P {s.precision:.4f} R {s.recall:.4f} "
            f"F {s.f_measure:.4f}  {s.ms_per_crop:.2f} ms/crop")
        out.append(s)
    return out


def evaluate_table(root: str | Path, features: Sequence[str], classifiers: Sequence[str], *, fit: bool = True,
                   max_train_per_class: int | None = 1500, warn=print) -> list[Score]:
    """``iea-rsu eval-classifier``'s scores: the shipped ONNX classifiers (``warn`` names one that is missing),
    then, when ``fit``, every feature x classifier pair fitted here."""
    from rsu.classify.classifiers import load_classifier

    shipped = []
    for name in ("cnn", "hsv8-gb"):
        try:
            shipped.append(load_classifier(name))
        except FileNotFoundError as exc:
            warn(str(exc))
    scores = evaluate_models(root, shipped)
    if fit:
        scores += evaluate_fitted(root, features, classifiers, max_train_per_class=max_train_per_class)
    return scores


def format_table(scores: Sequence[Score]) -> str:
    """Table 2.2 layout: one row per (feature, metric), one column per classifier (percent)."""
    clfs = list(dict.fromkeys(s.classifier for s in scores))
    feats = list(dict.fromkeys(s.feature for s in scores))
    by = {(s.feature, s.classifier): s for s in scores}
    width = max(10, *(len(c) + 1 for c in clfs))
    lines = [f"{'feature':12s} {'score':10s}" + "".join(f"{c:>{width}s}" for c in clfs)]
    for f in feats:
        for metric, scale, fmt in (("accuracy", 100, ".2f"), ("precision", 100, ".2f"), ("recall", 100, ".2f"),
                                   ("f_measure", 100, ".2f"), ("ms_per_crop", 1, ".3f")):
            cells = []
            for c in clfs:
                s = by.get((f, c))
                cells.append(f"{getattr(s, metric) * scale:>{width}{fmt}}" if s else f"{'-':>{width}s}")
            lines.append(f"{f:12s} {metric:10s}" + "".join(cells))
    return "\n".join(lines)


def scores_json(scores: Sequence[Score]) -> list[dict]:
    return [asdict(s) for s in scores]


SCENE_CLASSES = {"emergency_vehicle": 1, "ev": 1, "non_emergency": 0, "non_ev": 0}
"""Folder names of whole-scene photo sets (``../shared/data/real/ev_images``) and their labels."""


def largest_vehicle_crop(image: np.ndarray, detector, above_fraction: float = 0.1) -> np.ndarray | None:
    """The largest detected vehicle of a whole scene, its box grown upwards by ``above_fraction`` of its
    height (a light bar on the roof is often cut off by a COCO box); None when no vehicle is found."""
    boxes = detector.detect(image).boxes
    if len(boxes) == 0:
        return None
    area = (boxes[:, 2] - boxes[:, 0]) * (boxes[:, 3] - boxes[:, 1])
    from rsu.classify.ev import crop_above

    b = crop_above(boxes[int(np.argmax(area))], image.shape[1], image.shape[0], above_fraction)
    return None if b is None else image[b[1]:b[3], b[0]:b[2]]


def load_scene_crops(root: str | Path, detector, above_fraction: float = 0.1
                     ) -> tuple[list[np.ndarray | None], np.ndarray]:
    """Whole-scene photos in ``root/{emergency_vehicle,non_emergency}`` (or ``ev``/``non_ev``) -> the
    largest detected vehicle of each, grown upwards by ``above_fraction`` (None when the detector finds
    none), and the labels (1 = EV)."""
    from rsu.classify.ravev import IMAGE_SUFFIXES
    from rsu.classify.real_data import read_image

    root = Path(root)
    crops: list[np.ndarray | None] = []
    labels = []
    if root.is_dir():
        for d in sorted(p for p in root.iterdir() if p.is_dir() and p.name in SCENE_CLASSES):
            for f in sorted(p for p in d.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES):
                img = read_image(f)
                if img is None:
                    continue
                crops.append(largest_vehicle_crop(img, detector, above_fraction))
                labels.append(SCENE_CLASSES[d.name])
    if not labels:
        raise FileNotFoundError(f"no photos under {root}/{{emergency_vehicle,non_emergency}}")
    return crops, np.asarray(labels)


def evaluate_scenes(root: str | Path, detector, models: Sequence, log=print,
                    scene_crops: tuple[list, np.ndarray] | None = None) -> tuple[list[Score], dict]:
    """Detect the vehicles of each whole-scene photo (:func:`load_scene_crops`, or ``scene_crops``
    already loaded), classify the largest one with each model; an image without a detected vehicle
    counts as predicted non-EV. Returns the scores (ms per crop: classification only) and counts."""
    crops, y = scene_crops if scene_crops is not None else load_scene_crops(root, detector)
    found = [i for i, c in enumerate(crops) if c is not None]
    counts = dict(images=len(y), ev_images=int(y.sum()), with_vehicle=len(found))
    out = []
    for m in models:
        prob = np.zeros(len(y))
        t0 = time.perf_counter()
        for i in found:
            prob[i] = float(m.predict([crops[i]])[0])
        ms = 1000 * (time.perf_counter() - t0) / max(len(found), 1)
        s = Score(getattr(m, "feature", "pixels"), m.name, *metrics(y, prob), ms, len(y))
        log(f"  {s.classifier:18s} acc {s.accuracy:.4f} P {s.precision:.4f} R {s.recall:.4f} F {s.f_measure:.4f}  "
            f"{s.ms_per_crop:.2f} ms/crop")
        out.append(s)
    return out, counts


def cross_validate_scenes(crops: Sequence[np.ndarray | None], labels: np.ndarray, features: Sequence[str],
                          classifiers: Sequence[str], folds: int = 5, seed: int = 0, log=print) -> list[Score]:
    """Stratified k-fold accuracy/precision/recall/F of feature x classifier pairs fitted on the real
    crops themselves (what a classifier trained on real photos reaches, next to the sim-trained ones);
    photos without a vehicle count as predicted non-EV. Needs scikit-learn (``train`` extra)."""
    from sklearn.model_selection import StratifiedKFold

    labels = np.asarray(labels)
    idx = np.array([i for i, c in enumerate(crops) if c is not None])
    out = []
    for feat in features:
        x = extract_batch(feat, [crops[i] for i in idx])
        for name in classifiers:
            prob = np.zeros(len(labels))
            skf = StratifiedKFold(n_splits=folds, shuffle=True, random_state=seed)
            for tr, te in skf.split(x, labels[idx]):
                model = make_classifier(name, seed).fit(x[tr], labels[idx][tr])
                prob[idx[te]] = _positive_prob(model, x[te])
            s = Score(feat, f"cv:{name}", *metrics(labels, prob), 0.0, len(labels))
            log(f"  {feat:12s} {s.classifier:18s} acc {s.accuracy:.4f} P {s.precision:.4f} R {s.recall:.4f} "
                f"F {s.f_measure:.4f}  ({folds}-fold on the real crops)")
            out.append(s)
    return out
