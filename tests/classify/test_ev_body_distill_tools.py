"""The GPU training job's pieces that need no PyTorch: the crop cache (with the photos' detected views),
folds by photo, the teacher mean, the student specs, the augmentation the students train on, and the teacher's
held-out figures."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from models.ev_body_distill import group_folds, mean_teacher, parse_student, student_name
from models.ev_body_net import augment
from models.ev_crop_cache import MAX_DETECTED_AREA_FRACTION, detected_view, read_crop_cache

SHARED_EV_TRAIN = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "real" / "ev_train"


def test_folds_keep_every_photo_in_one_fold_and_use_every_fold():
    groups = [f"g{i // 3}" for i in range(300)]  # three crops per photo
    folds = group_folds(groups, 5)
    for g in set(groups):
        assert len({int(f) for f, gg in zip(folds, groups, strict=True) if gg == g}) == 1
    assert set(folds.tolist()) == set(range(5))
    np.testing.assert_array_equal(folds, group_folds(groups, 5))  # stable
    assert not np.array_equal(folds, group_folds(groups, 5, seed=1))


def test_mean_teacher_averages_own_and_file_scores_and_refuses_a_file_from_other_data(tmp_path: Path):
    keys = np.array(["a.jpg|", "b.jpg|1,2,3,4"])
    f = tmp_path / "t.json"
    f.write_text(json.dumps({"a.jpg|": 0.2, "b.jpg|1,2,3,4": 1.0, "unused|": 0.5}))
    np.testing.assert_allclose(mean_teacher(keys, [np.array([0.6, 0.0])], [str(f)], log=lambda m: None), [0.4, 0.5])
    np.testing.assert_allclose(mean_teacher(keys, [], [str(f)], log=lambda m: None), [0.2, 1.0])
    g = tmp_path / "other.json"
    g.write_text(json.dumps({"a.jpg|": 0.2}))
    with pytest.raises(SystemExit, match="no score for 1 of 2"):
        mean_teacher(keys, [], [str(g)], log=lambda m: None)


def test_student_spec_is_validated():
    assert parse_student("224:0.5") == (224, 0.5, "all", 0)
    assert parse_student("224:0.5", default_seed=4) == (224, 0.5, "all", 4)
    assert parse_student("192:0.7:given:3") == (192, 0.7, "given", 3)
    for bad in ("224", "225:0.5", "224:1.5", "big:0.5", "224:0.5:sides", "224:0.5:all:x", "224:0.5:all:1:2"):
        with pytest.raises(SystemExit):
            parse_student(bad)


def test_student_names_keep_the_first_students_names_and_tell_the_others_apart():
    assert student_name(224, 0.5, "all", 0) == "student_224_w0.5.pt"
    names = {student_name(224, 0.5, v, s) for v in ("all", "given") for s in (0, 1)}
    assert len(names) == 4 and "student_224_w0.5_given_s1.pt" in names


class _Boxes:
    def __init__(self, boxes):
        self.boxes = np.asarray(boxes, float).reshape(-1, 4)


class _FixedDetector:
    """Finds the same boxes in every image (a stand-in for YOLOX)."""

    def __init__(self, boxes):
        self.result = _Boxes(boxes)

    def detect(self, image):
        return self.result


def test_detected_view_is_the_largest_box_grown_upwards_and_only_when_it_adds_something():
    img = np.random.default_rng(0).integers(0, 256, (200, 300, 3), np.uint8)
    crop = detected_view(img, _FixedDetector([[10, 100, 50, 140], [100, 80, 260, 160]]), 0.25)
    np.testing.assert_array_equal(crop, img[60:160, 100:260])  # the larger box, 25 % of its 80 px height above
    assert detected_view(img, _FixedDetector([]), 0.25) is None
    assert detected_view(img, _FixedDetector([[0, 0, 300, 200]]), 0.25) is None  # the whole photo again
    rows = int(MAX_DETECTED_AREA_FRACTION * 200) + 2  # full width: just over the area fraction
    assert detected_view(img, _FixedDetector([[0, 200 - rows, 300, 200]]), 0.0) is None
    assert detected_view(img, _FixedDetector([[0, 200 - rows + 6, 300, 200]]), 0.0) is not None


def test_augment_returns_the_network_size_in_unit_range_and_is_seeded():
    img = np.random.default_rng(0).integers(0, 256, (90, 150, 3), np.uint8)
    a = augment(img, np.random.default_rng(3), 64)
    assert a.shape == (64, 64, 3) and a.dtype == np.float32 and 0.0 <= a.min() and a.max() <= 1.0
    np.testing.assert_array_equal(a, augment(img, np.random.default_rng(3), 64))


def test_crop_cache_round_trip(tmp_path: Path):
    """A cache written from ev_train decodes to squashed crops with their labels, splits and keys."""
    if not SHARED_EV_TRAIN.is_dir():
        pytest.skip(f"no ev_train at {SHARED_EV_TRAIN} (../shared absent)")
    from models.ev_crop_cache import write_crop_cache

    out = tmp_path / "c.npz"
    n = write_crop_cache(SHARED_EV_TRAIN, out, side=48, quality=80, splits=("test",), log=lambda m: None)
    cache = read_crop_cache(out)
    assert n == len(cache["crops"]) > 100
    assert all(c.shape == (48, 48, 3) for c in cache["crops"])
    assert set(cache["split"].tolist()) == {"test"} and set(cache["label"].tolist()) == {0.0, 1.0}
    assert len(set(cache["key"].tolist())) == n  # one key per crop, as the teacher files use them
    assert set(cache["view"].tolist()) == {"given"}
    assert cv2.imencode(".jpg", cache["crops"][0])[0]


def test_crop_cache_adds_a_detected_view_of_each_whole_photo_under_its_key(tmp_path: Path):
    if not SHARED_EV_TRAIN.is_dir():
        pytest.skip(f"no ev_train at {SHARED_EV_TRAIN} (../shared absent)")
    from models.ev_crop_cache import write_crop_cache

    out = tmp_path / "c.npz"
    n = write_crop_cache(SHARED_EV_TRAIN, out, side=32, quality=80, splits=("test",), log=lambda m: None,
                         detector=_FixedDetector([[40, 60, 160, 150]]))  # inside every photo of ev_train
    cache = read_crop_cache(out)
    views, keys = cache["view"], cache["key"]
    given, detected = keys[views == "given"], keys[views == "detected"]
    assert n == len(views) and 0 < len(detected) < len(given)
    assert set(detected.tolist()) <= set(given.tolist())  # a detected view takes its photo's key (teacher score)
    assert all("|" in k and k.endswith("|") for k in detected.tolist())  # whole photos only (no box in the key)


def test_a_cache_written_before_views_reads_as_given(tmp_path: Path):
    jpeg = cv2.imencode(".jpg", np.zeros((8, 8, 3), np.uint8))[1].reshape(-1)
    np.savez(tmp_path / "old.npz", jpeg=np.concatenate([jpeg, jpeg]), offsets=np.array([0, len(jpeg), 2 * len(jpeg)]),
             label=np.array([0, 1], np.int8), split=np.array(["train"] * 2), group=np.array(["a", "b"]),
             key=np.array(["a|", "b|"]), side=np.int32(8))
    assert read_crop_cache(tmp_path / "old.npz")["view"].tolist() == ["given", "given"]


def test_teacher_holdout_figures_are_chosen_on_val_and_reported_on_test():
    pytest.importorskip("sklearn", reason="scikit-learn (train extra) not installed: pip install -e .[train]")
    from models.ev_body_teacher import holdout_figures

    rng = np.random.default_rng(0)

    def split(n):
        y = rng.integers(0, 2, n).astype(float)
        f = rng.normal(0, 1, (2, n, 6)) + 3.0 * y[None, :, None]  # separable: both mirror views carry the label
        return f, y

    feats, labels = {}, {}
    for k, n in (("train", 200), ("val", 80), ("test", 80)):
        feats[k], labels[k] = split(n)
    rows = holdout_figures(feats, labels, cs=(0.05,))
    assert len(rows) == 1 and rows[0]["C"] == 0.05 and 0.05 <= rows[0]["threshold"] <= 0.95
    assert rows[0]["val"][1] > 0.95 and rows[0]["test"][2] > 0.95  # precision on val, recall on test


def test_teacher_holdout_scores_another_set_and_its_items_without_a_crop_as_not_ev():
    pytest.importorskip("sklearn", reason="scikit-learn (train extra) not installed: pip install -e .[train]")
    from models.ev_body_teacher import holdout_figures

    rng = np.random.default_rng(1)
    feats, labels = {}, {}
    for k, n in (("train", 200), ("val", 80), ("test", 80), ("photos", 40)):
        labels[k] = rng.integers(0, 2, n).astype(float)
        if k == "photos":
            labels[k][:20] = 1.0
        feats[k] = rng.normal(0, 1, (2, n, 6)) + 6.0 * labels[k][None, :, None]  # well apart: none missed
    none = np.zeros(40, bool)
    none[:10] = True  # ten EV photos whose detector found no vehicle
    (row,) = holdout_figures(feats, labels, cs=(0.05,), missing={"photos": none})
    n_ev = labels["photos"].sum()
    assert row["photos"][2] == pytest.approx((n_ev - 10) / n_ev, abs=0.03)  # those ten are missed, no others
    (full,) = holdout_figures(feats, labels, cs=(0.05,))
    assert full["photos"][2] > row["photos"][2]
