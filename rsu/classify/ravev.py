"""Crop datasets in the RAVEV folder layout (thesis 2.1): ``ROOT/{train,val}/{ev,non_ev}/*.(png|jpg)``.

``iea-sim export-dataset --out DIR --frames N`` writes one from simulator renders under ``DIR/cls``
(positives: EVs with their lights on; negatives: every other vehicle, lookalikes included).
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

SPLITS = ("train", "val")
CLASSES = ("non_ev", "ev")
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".webp")


def list_split(root: str | Path, split: str) -> tuple[list[Path], np.ndarray]:
    """Image paths and labels (1 = ev) of one split, sorted by name; raises if the layout is wrong."""
    root = Path(root)
    if split not in SPLITS:
        raise ValueError(f"split must be one of {SPLITS}, got {split!r}")
    paths: list[Path] = []
    labels: list[int] = []
    for label, cls in enumerate(CLASSES):
        d = root / split / cls
        if not d.is_dir():
            raise FileNotFoundError(f"{d} missing: expected the RAVEV layout {root}/{{train,val}}/{{ev,non_ev}}/")
        files = sorted(p for p in d.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
        paths += files
        labels += [label] * len(files)
    return paths, np.asarray(labels, np.int64)


def load_split(root: str | Path, split: str, limit_per_class: int | None = None,
               seed: int = 0) -> tuple[list[np.ndarray], np.ndarray]:
    """BGR uint8 crops and labels of one split (``limit_per_class``: a seeded random subset per class)."""
    paths, labels = list_split(root, split)
    if limit_per_class is not None:
        rng = np.random.default_rng(seed)
        keep = np.concatenate([rng.permutation(np.flatnonzero(labels == c))[:limit_per_class] for c in (0, 1)])
        keep.sort()
        paths, labels = [paths[i] for i in keep], labels[keep]
    crops, out = [], []
    for p, y in zip(paths, labels, strict=True):
        img = cv2.imread(str(p), cv2.IMREAD_COLOR)
        if img is None or img.shape[0] < 2 or img.shape[1] < 2:
            continue  # unreadable file: skipped, not fatal
        crops.append(img)
        out.append(int(y))
    return crops, np.asarray(out, np.int64)
