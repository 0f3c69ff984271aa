"""The ``ev_train`` crops in one small file, for training where ``../shared`` is not (a GPU machine).

    python -m models.ev_crop_cache --out CACHE.npz [--data ../shared/data/real/ev_train] [--side 224] [--splits train]

Each crop is taken as the RSU takes it (:func:`rsu.classify.real_data.crop_of`: the box grown 25 % of its height
upwards), with the label review applied (:func:`rsu.classify.real_data.load_ev_train`), squashed to
``side`` x ``side`` (the RSU squashes every crop to the classifier's square input, so squashing first loses nothing
but resolution above ``side``) and stored as a JPEG (quality 85; training adds its own compression anyway). ``--splits train`` keeps the file
under 30 MB (what a GPU job can carry beside the repository).
``--detected-views`` adds, for every whole-photo sample (``av_emergency_crops``, ``indian_ev_photos``: a vehicle
photo with its background), a second crop: the largest vehicle YOLOX-Nano finds in the photo, its box grown upwards
as the RSU crops a track (:func:`detected_view`). An RSU never sees the whole photo: it sees a tight detector box
squashed to a square, so a wide car reaches the classifier stretched upright. The second view teaches that look.
The file holds, per crop: the JPEG bytes, the label, the split (``split_by_group``, seed 17), the source-photo
group, the crop's teacher key (:func:`models.train_ev_body.teacher_key`; a detected view shares its photo's key)
and its view (``given`` or ``detected``). :func:`read_crop_cache` needs only numpy and OpenCV.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

import cv2
import numpy as np

if TYPE_CHECKING:
    from rsu.classify.real_data import CropSample

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_DATA = ROOT.parent / "shared" / "data" / "real" / "ev_train"
DEFAULT_YOLOX = ROOT.parent / "shared" / "data" / "real" / "yolox_nano" / "yolox_nano.onnx"
MAX_DETECTED_AREA_FRACTION = 0.85
"""A detected box covering more of the photo than this adds nothing the whole photo does not show."""


ABOVE_FRACTION = 0.25
"""How far above its box a vehicle's crop reaches, as a fraction of the box height (the RSU's crop).
"""

def teacher_key(sample: CropSample, data_root: Path) -> str:
    """A crop's key in a teacher file (:mod:`models.ev_body_teacher`): ``path relative to ev_train|x1,y1,x2,y2``."""
    return f"{Path(sample.path).resolve().relative_to(data_root.resolve())}|{','.join(map(str, sample.box_px or ()))}"


def detected_view(image: np.ndarray, detector, above_fraction: float) -> np.ndarray | None:
    """The crop an RSU would take of this photo's vehicle: the largest box ``detector`` finds, grown upwards by
    ``above_fraction`` of its height (:func:`rsu.classify.evaluation.largest_vehicle_crop`, what the photo
    figures of ``bench/ev_real_bench.py`` classify); None when it finds none, or when the box is nearly the whole
    photo (:data:`MAX_DETECTED_AREA_FRACTION`)."""
    from rsu.classify.evaluation import largest_vehicle_crop

    crop = largest_vehicle_crop(image, detector, above_fraction)
    if crop is None or min(crop.shape[:2]) < 8:
        return None
    if crop.shape[0] * crop.shape[1] > MAX_DETECTED_AREA_FRACTION * image.shape[0] * image.shape[1]:
        return None
    return crop


def write_crop_cache(data_root: str | Path, out: str | Path, side: int = 224, quality: int = 85,
                     splits: tuple[str, ...] = ("train", "val", "test"), log=print, detector=None) -> int:
    """Write the cache of the crops in ``splits`` (with ``detector``: and the detected view of each whole photo,
    :func:`detected_view`); returns the number of crops stored."""
    if str(ROOT) not in sys.path:
        sys.path.insert(0, str(ROOT))
    from rsu.classify.real_data import crop_of, load_ev_train, read_image, split_of

    data_root = Path(data_root)
    if not data_root.is_dir():
        raise SystemExit(f"no ev_train folder at {data_root}: pass --data")
    samples = load_ev_train(data_root)
    blobs, labels, split_names, groups, keys, views = [], [], [], [], [], []
    t0 = time.time()
    for i, s in enumerate(samples):
        if split_of(s.group) not in splits:
            continue
        image = read_image(s.path)
        if image is None:
            continue
        crops = [("given", crop_of(s, ABOVE_FRACTION, image=image))]
        if detector is not None and s.box_px is None:
            crops.append(("detected", detected_view(image, detector, ABOVE_FRACTION)))
        for view, c in crops:
            if c is None or min(c.shape[:2]) < 8:
                continue
            sq = cv2.resize(c, (side, side), interpolation=cv2.INTER_AREA)
            ok, enc = cv2.imencode(".jpg", sq, [cv2.IMWRITE_JPEG_QUALITY, quality])
            if not ok:
                continue
            blobs.append(enc.reshape(-1))
            labels.append(s.label)
            split_names.append(split_of(s.group))
            groups.append(s.group)
            keys.append(teacher_key(s, data_root))
            views.append(view)
        if (i + 1) % 500 == 0:
            log(f"  {i + 1}/{len(samples)} samples, {len(blobs)} crops ({time.time() - t0:.0f} s)")
    offsets = np.cumsum([0] + [len(b) for b in blobs]).astype(np.int64)
    np.savez(out, jpeg=np.concatenate(blobs), offsets=offsets, label=np.asarray(labels, np.int8),
             split=np.asarray(split_names), group=np.asarray(groups), key=np.asarray(keys), view=np.asarray(views),
             side=np.int32(side))
    log(f"{len(blobs)} crops ({views.count('detected')} detected views) -> {out} "
        f"({Path(out).stat().st_size / 1e6:.1f} MB)")
    return len(blobs)


def read_crop_cache(path: str | Path) -> dict[str, np.ndarray | list[np.ndarray]]:
    """``crops`` (uint8 BGR side x side), ``label``, ``split``, ``group``, ``key``, ``view`` per crop (a cache
    written before views existed reads as all ``given``)."""
    z = np.load(path, allow_pickle=False)
    jpeg, off = z["jpeg"], z["offsets"]
    crops = [cv2.imdecode(jpeg[off[i]:off[i + 1]], cv2.IMREAD_COLOR) for i in range(len(off) - 1)]
    if any(c is None for c in crops):
        raise ValueError(f"{path}: a crop does not decode: write the cache again")
    return {"crops": crops, "label": z["label"].astype(np.float32), "split": z["split"], "group": z["group"],
            "key": z["key"], "view": z["view"] if "view" in z.files else np.full(len(crops), "given")}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", default=str(DEFAULT_DATA), help="the ev_train folder")
    ap.add_argument("--out", required=True, help="the .npz to write")
    ap.add_argument("--side", type=int, default=224, help="the square side each crop is stored at (pixels)")
    ap.add_argument("--quality", type=int, default=85, help="JPEG quality (1-100)")
    ap.add_argument("--splits", nargs="+", default=["train", "val", "test"], choices=["train", "val", "test"])
    ap.add_argument("--detected-views", action="store_true",
                    help="also store each whole photo's largest YOLOX vehicle, cropped as the RSU crops a track")
    ap.add_argument("--yolox", default=str(DEFAULT_YOLOX), help="the YOLOX-Nano ONNX file for --detected-views")
    args = ap.parse_args(argv)
    if not 32 <= args.side <= 1024:
        raise SystemExit(f"--side must be 32-1024 pixels, got {args.side}")
    if not 1 <= args.quality <= 100:
        raise SystemExit(f"--quality must be 1-100, got {args.quality}")
    detector = None
    if args.detected_views:
        if not Path(args.yolox).is_file():
            raise SystemExit(f"no YOLOX model at {args.yolox}: pass --yolox, or leave out --detected-views")
        if str(ROOT) not in sys.path:
            sys.path.insert(0, str(ROOT))
        from rsu.build import PipelineConfig, build_detector

        detector = build_detector(PipelineConfig(detector=str(args.yolox)))
    write_crop_cache(args.data, args.out, args.side, args.quality, tuple(args.splits), detector=detector)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
