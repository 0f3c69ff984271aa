"""The real EV training data loader: the label review relabels, drops, and lets reviewed Open Images Car and
Truck boxes in; without the review the data is as published."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from rsu.classify.real_data import REVIEW_CSV, load_ev_train, load_review, split_by_group

SHARED_EV_TRAIN = Path(__file__).resolve().parents[3] / "shared" / "data" / "real" / "ev_train"


def _image(path: Path, value: int) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), np.full((120, 160, 3), value, np.uint8))


@pytest.fixture
def ev_train(tmp_path: Path) -> Path:
    root = tmp_path / "ev_train"
    av = root / "av_emergency_crops"
    for name, value in (("1.jpg", 10), ("2.jpg", 20), ("3.jpg", 30), ("4.jpg", 10)):  # 4.jpg duplicates 1.jpg
        _image(av / "images" / name, value)
    (av / "labels.csv").write_text("image_names,emergency_or_not\n1.jpg,1\n2.jpg,0\n3.jpg,0\n4.jpg,1\n")
    oi = root / "openimages_vehicles" / "train"
    _image(oi / "images" / "p1_jpg.rf.abc.jpg", 40)
    # ambulance, car (reviewed: a police car), car (reviewed: excluded), truck (not reviewed), bus, tiny car
    (oi / "labels").mkdir(parents=True)
    (oi / "labels" / "p1_jpg.rf.abc.txt").write_text(
        "0 0.25 0.25 0.4 0.4\n2 0.75 0.25 0.4 0.4\n2 0.25 0.75 0.4 0.4\n4 0.75 0.75 0.4 0.4\n1 0.5 0.5 0.5 0.5\n"
        "2 0.5 0.5 0.1 0.1\n")
    review = root / "review.csv"
    review.write_text(
        "source,item,given,reviewed,reason\n"
        "av_emergency_crops,2.jpg,not,ev,a marked police car\n"
        "av_emergency_crops,3.jpg,not,exclude,a car interior\n"
        'openimages_vehicles,"train/p1_jpg.rf.abc.jpg#88,6,152,54",car,ev,police car\n'
        'openimages_vehicles,"train/p1_jpg.rf.abc.jpg#8,66,72,114",car,exclude,fragment\n')
    return root


def test_review_relabels_drops_and_admits_only_reviewed_car_truck_boxes(ev_train: Path):
    published = load_ev_train(ev_train, review=None)
    by_source = {}
    for s in published:
        by_source.setdefault(s.source, []).append(s)
    assert sorted((s.path.name, s.label) for s in by_source["av_emergency_crops"]) == [
        ("1.jpg", 1), ("2.jpg", 0), ("3.jpg", 0)]  # the duplicate 4.jpg is one photo with 1.jpg
    assert sorted(s.label for s in by_source["openimages_vehicles"]) == [0, 1]  # the bus and the ambulance only

    reviewed = load_ev_train(ev_train, review=ev_train / "review.csv")
    av = sorted((s.path.name, s.label) for s in reviewed if s.source == "av_emergency_crops")
    assert av == [("1.jpg", 1), ("2.jpg", 1)]
    oi = sorted((s.box_px, s.label) for s in reviewed if s.source == "openimages_vehicles")
    # the ambulance, the bus, and the one reviewed car (a police car); the excluded car and the unreviewed truck
    # are out, and so is the car under 40 px
    assert [label for _box, label in oi].count(1) == 2 and len(oi) == 3
    assert ((88, 6, 152, 54), 1) in oi
    assert all(s.label in (0, 1) for s in reviewed)
    # every sample of a photo is on one side of the split
    sides = {k: {s.group for s in v} for k, v in split_by_group(reviewed).items()}
    assert not (sides["train"] & sides["val"] or sides["train"] & sides["test"] or sides["val"] & sides["test"])


def test_a_malformed_review_row_is_refused_with_its_line(tmp_path: Path):
    bad = tmp_path / "review.csv"
    bad.write_text("source,item,given,reviewed,reason\nav_emergency_crops,1.jpg,ev,maybe,?\n")
    with pytest.raises(ValueError, match=r"review.csv:2: 'reviewed' must be ev, not or exclude"):
        load_review(bad)


def test_the_committed_review_parses_and_names_the_police_cars_among_open_images_cars():
    review = load_review(REVIEW_CSV)
    oi = [d for (source, _item), d in review.items() if source == "openimages_vehicles"]
    assert len(oi) == 562 and oi.count("ev") == 18
    assert review[("av_emergency_crops", "1011.jpg")] == "ev"  # a marked NYPD SUV labelled 0 in the published data


@pytest.mark.skipif(not SHARED_EV_TRAIN.is_dir(), reason="../shared/data/real/ev_train is not here")
def test_the_review_applies_to_the_shared_data():
    published, reviewed = load_ev_train(SHARED_EV_TRAIN, review=None), load_ev_train(SHARED_EV_TRAIN)
    assert len(published) == 2339 and len(reviewed) == 2636
    assert sum(s.label for s in reviewed if s.source == "openimages_vehicles") == sum(
        s.label for s in published if s.source == "openimages_vehicles") + 18
