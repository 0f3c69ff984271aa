"""The GPU training job's pieces that need no PyTorch (issue 17): the crop cache, folds by photo, the teacher mean,
the student specs, and the augmentation the students train on."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from models.ev_body_distill import group_folds, mean_teacher, parse_student
from models.ev_body_net import augment
from models.ev_crop_cache import read_crop_cache

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
    assert parse_student("224:0.5") == (224, 0.5)
    for bad in ("224", "225:0.5", "224:1.5", "big:0.5"):
        with pytest.raises(SystemExit):
            parse_student(bad)


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
    assert cv2.imencode(".jpg", cache["crops"][0])[0]
