"""Real labelled vehicle crops for the EV-body classifier: ``../shared/data/real/ev_train``.

Three sources (README beside the data), one list of :class:`CropSample`:

- ``av_emergency_crops``: vehicle photos with ``labels.csv`` (1 = emergency). Byte-identical files are
  one photo: the group is the file's SHA-1, so duplicates never straddle the split (first label wins).
- ``openimages_vehicles``: Open Images photos with YOLO boxes; each box is a crop: class 0 Ambulance = EV,
  Bus and Motorcycle = not. Car and Truck boxes are left out: Open Images' five classes have no police
  car or fire engine, so those are labelled Car or Truck there (seen among the first model's confident
  "false positives": a red fire engine, police SUVs), while ``av_emergency_crops`` labels them emergency;
  as negatives they would teach the model the opposite of the other source. Boxes under ``MIN_BOX_PX``
  on a side are left out too. Roboflow stores each train photo twice (an augmented copy); the group is
  the source id, the name before ``.rf.``, over all three of its folders.
- ``indian_ev_photos``: web photos named by class (ambulance, fire truck, police), all EV, whole image.

**Label review** (``models/ev_train_review.csv``): every ``av_emergency_crops`` photo and every
Open Images Car or Truck box of at least ``MIN_BOX_PX`` (one Roboflow copy per photo) was looked at on contact
sheets against one written definition (EV = ambulance, fire-service or marked police vehicle). The file lists
each change (a wrong label, or ``exclude``: no single vehicle dominates, a fragment, an interior, a toy or a
drawing, or unsure) and the decision for every Car/Truck box: with the review applied, Car and Truck boxes come
in (18 of the 562 are police cars or fire engines, labelled so), and 266 reviewed items are left out.
``load_ev_train(root, review=None)`` gives the data as published.

:func:`split_by_group` cuts the groups, not the samples, into train / val / test with a seeded hash,
so the same photo is never on both sides. :func:`crop_of` reads a sample as the RSU would see it: a
box grown upwards by ``above_fraction`` of its height (a roof light bar sits above a COCO car box,
:class:`rsu.classify.ev.TrackEvClassifier`).
"""

from __future__ import annotations

import csv
import hashlib
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from rsu.classify.ev import crop_above

IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".webp", ".bmp")
OPENIMAGES_EV_CLASSES = frozenset({0})  # Ambulance; 1 Bus, 2 Car, 3 Motorcycle, 4 Truck
OPENIMAGES_NOT_EV_CLASSES = frozenset({1, 3})
OPENIMAGES_REVIEWED_CLASSES = frozenset({2, 4})  # Car and Truck include police cars and fire engines: review only
MIN_BOX_PX = 40  # the RSU measures no box smaller than this (TrackEvClassifier.min_box_px)
SPLITS = ("train", "val", "test")


@dataclass(frozen=True)
class CropSample:
    path: Path
    label: int
    """1 = emergency vehicle."""
    group: str
    """Source-photo id: samples sharing it are on the same side of the split."""
    source: str
    box_px: tuple[int, int, int, int] | None = None
    """xyxy within the image; None = the whole image."""


def read_image(path: str | Path) -> np.ndarray | None:
    """A BGR image, or None when it cannot be decoded (some ``.jpg`` files are WEBP or have odd headers:
    decoded from the bytes then)."""
    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is None and Path(path).is_file():
        data = np.frombuffer(Path(path).read_bytes(), np.uint8)
        img = cv2.imdecode(data, cv2.IMREAD_COLOR) if data.size else None
    return img


def load_av_crops(root: Path) -> list[CropSample]:
    labels_csv = root / "labels.csv"
    if not labels_csv.is_file():
        raise FileNotFoundError(f"{labels_csv} not found")
    out, seen = [], set()
    with labels_csv.open(newline="") as fh:
        for row in csv.DictReader(fh):
            path = root / "images" / row["image_names"]
            if not path.is_file():
                continue
            digest = hashlib.sha1(path.read_bytes()).hexdigest()
            if digest in seen:  # a byte-identical duplicate: one photo, counted once
                continue
            seen.add(digest)
            out.append(CropSample(path, int(row["emergency_or_not"]), f"av:{digest}", "av_emergency_crops"))
    return out


def load_openimages(root: Path, min_box_px: int = MIN_BOX_PX, with_car_truck: bool = False) -> list[CropSample]:
    """Ambulance, Bus and Motorcycle boxes; with ``with_car_truck`` also Car and Truck boxes, labelled -1 (unknown)
    until :func:`apply_review` gives them the review's label or drops them."""
    out = []
    for images in sorted(root.glob("*/images")):
        for path in sorted(images.iterdir()):
            label_file = images.parent / "labels" / (path.stem + ".txt")
            if path.suffix.lower() not in IMAGE_SUFFIXES or not label_file.is_file():
                continue
            img = read_image(path)
            if img is None:
                continue
            h, w = img.shape[:2]
            group = "oi:" + path.name.split(".rf.")[0]
            for line in label_file.read_text().splitlines():
                parts = line.split()
                if len(parts) != 5:
                    continue
                cls = int(parts[0])
                reviewed_only = with_car_truck and cls in OPENIMAGES_REVIEWED_CLASSES
                if cls not in OPENIMAGES_EV_CLASSES | OPENIMAGES_NOT_EV_CLASSES and not reviewed_only:
                    continue
                cx, cy, bw, bh = (float(v) for v in parts[1:])
                x1, y1 = int(round((cx - bw / 2) * w)), int(round((cy - bh / 2) * h))
                x2, y2 = int(round((cx + bw / 2) * w)), int(round((cy + bh / 2) * h))
                if min(x2 - x1, y2 - y1) < min_box_px:
                    continue
                label = -1 if reviewed_only else int(cls in OPENIMAGES_EV_CLASSES)
                out.append(CropSample(path, label, group, "openimages_vehicles", (x1, y1, x2, y2)))
    return out


def load_named_photos(root: Path) -> list[CropSample]:
    return [CropSample(p, 1, f"in:{p.stem}", "indian_ev_photos") for p in sorted(root.iterdir())
            if p.suffix.lower() in IMAGE_SUFFIXES]


REVIEW_CSV = Path(__file__).resolve().parents[2] / "models" / "ev_train_review.csv"
REVIEW_LABELS = {"ev": 1, "not": 0}


def load_review(path: str | Path) -> dict[tuple[str, str], str]:
    """``(source, item) -> 'ev' | 'not' | 'exclude'`` from a label-review CSV (module docstring)."""
    out = {}
    with Path(path).open(newline="") as fh:
        for n, row in enumerate(csv.DictReader(fh), start=2):
            if row.get("reviewed") not in ("ev", "not", "exclude") or not row.get("item"):
                raise ValueError(f"{path}:{n}: 'reviewed' must be ev, not or exclude and 'item' set, got {row}")
            out[(row["source"], row["item"])] = row["reviewed"]
    return out


def review_item(sample: CropSample) -> str:
    """The review's key of a sample: the file name, or for an Open Images box ``folder/file#x1,y1,x2,y2``."""
    if sample.box_px is None or sample.source != "openimages_vehicles":
        return sample.path.name
    return f"{sample.path.parent.parent.name}/{sample.path.name}#" + ",".join(map(str, sample.box_px))


def apply_review(samples: Sequence[CropSample], review: dict[tuple[str, str], str]) -> list[CropSample]:
    """Relabel or drop the reviewed samples; Open Images Car/Truck boxes (``reviewed_box``) only where reviewed."""
    out = []
    for s in samples:
        decision = review.get((s.source, review_item(s)))
        if decision is None:
            if s.source == "openimages_vehicles" and s.label < 0:
                continue  # a Car/Truck box nobody reviewed (the other Roboflow copy): its label is unknown
            out.append(s)
        elif decision != "exclude":
            out.append(CropSample(s.path, REVIEW_LABELS[decision], s.group, s.source, s.box_px))
    return out


def load_ev_train(root: str | Path, review: str | Path | None = REVIEW_CSV) -> list[CropSample]:
    """Every labelled crop of ``ev_train`` (module docstring), with the label review applied unless ``review`` is
    None; raises when the folder is absent."""
    root = Path(root)
    if not root.is_dir():
        raise FileNotFoundError(f"{root} not found: the real training data is ../shared/data/real/ev_train")
    out: list[CropSample] = []
    if (root / "av_emergency_crops").is_dir():
        out += load_av_crops(root / "av_emergency_crops")
    if (root / "openimages_vehicles").is_dir():
        out += load_openimages(root / "openimages_vehicles", with_car_truck=review is not None)
    if (root / "indian_ev_photos").is_dir():
        out += load_named_photos(root / "indian_ev_photos")
    if not out:
        raise FileNotFoundError(f"no labelled images under {root}")
    return apply_review(out, load_review(review)) if review is not None else out


def split_of(group: str, seed: int = 17, val: float = 0.15, test: float = 0.15) -> str:
    """``train`` / ``val`` / ``test`` for a source-photo group: a seeded hash, stable across runs and machines."""
    u = int.from_bytes(hashlib.sha1(f"{seed}:{group}".encode()).digest()[:8], "big") / 2.0 ** 64
    return "test" if u < test else "val" if u < test + val else "train"


def split_by_group(samples: Sequence[CropSample], seed: int = 17, val: float = 0.15,
                   test: float = 0.15) -> dict[str, list[CropSample]]:
    out: dict[str, list[CropSample]] = {k: [] for k in SPLITS}
    for s in samples:
        out[split_of(s.group, seed, val, test)].append(s)
    return out


def crop_of(sample: CropSample, above_fraction: float = 0.25, image: np.ndarray | None = None) -> np.ndarray | None:
    """The sample's BGR crop (its box grown upwards, as the RSU crops a track), or None if unreadable."""
    img = image if image is not None else read_image(sample.path)
    if img is None:
        return None
    if sample.box_px is None:
        return img
    b = crop_above(sample.box_px, img.shape[1], img.shape[0], above_fraction)
    return None if b is None else img[b[1]:b[3], b[0]:b[2]]
