"""Train ``models/lamp_state.onnx``: p(warning lamps lit) of a lamp band (:mod:`rsu.classify.lamp_state`; card
``models/lamp_state.md``).

    python -m models.train_lamp_state [--out models/lamp_state.onnx] [--epochs 40] [--json]

Data (``../shared/data/real``), every band through :func:`rsu.classify.lamp_state.band_input`:
- ``lights_on_off/police_crops/{on,off}``: police cars with the light bar lit / dark; the band is the crop's top
  ``CROP_BAND`` (the bar is inside these crops);
- ``lights_on_off/police_scenes/{on,off}``: whole photos of the same kind; the largest COCO YOLOX-Nano vehicle box,
  its band taken as the RSU takes it (the box grown by ``ABOVE_FRACTION`` of its height, the top ``BAND_FRACTION``);
- both at their own size and scaled down to the widths of ``SCALES_PX`` (JPEG quality ``JPEG_Q``): a bar from 30 m to
  150 m, as a CCTV camera sees it;
- negatives from video: every vehicle box (>= 40 px wide) every ``FRAME_STEP_S`` of the *tuning* traffic clips of
  ``bench/ev_real_bench.py`` (``rsu.scan_labels.TUNING_TRAFFIC_CLIPS``: dense day traffic, rows of tail lights at dusk,
  motorway cameras),
  the band as the RSU takes it.

Split: a photo whose number is a multiple of ``VAL_EVERY`` (at every scale), and every ``VAL_EVERY``-th sampled frame
of each clip, is validation; the rest trains. The operating point ``threshold`` is the lowest whose validation
precision is at least ``TARGET_PRECISION``. The shipped model is trained on train only (validation picks the
threshold and reports). Needs ``torch`` and ``onnx`` (the ``train`` extra); CPU, about a minute.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from rsu.classify.lamp_state import INPUT_HW, band_input  # noqa: E402
from rsu.scan_labels import TUNING_TRAFFIC_CLIPS  # noqa: E402

REAL = ROOT.parent / "shared" / "data" / "real"
CROP_BAND = 0.45
SCALES_PX = (None, 160, 100, 64, 44)
JPEG_Q = 60
EV_CLIPS = ("closeup_police_lightbar_cycle.mp4", "elevated_police_nyc_redbars.mp4",
            "handheld_ambulance_florence_blue.mp4", "handheld_night_fire_engines.mp4",
            "incar_night_ambulance_ahead_blue.mp4", "india_ambulance_police_escort.mp4",
            "news_ambulances_australia_redblue.mp4", "street_ambulance_japan_red.mp4")
FRAME_STEP_S = 0.25
MIN_WIDTH_PX = 40.0
ABOVE_FRACTION = 0.25
BAND_FRACTION = (0.25 + 0.4) / 1.25
VAL_EVERY = 5
TARGET_PRECISION = 0.9
SEED = 7


def is_validation_photo(name: str) -> bool:
    """A ``lights_on_off`` photo of the validation side: the first number in its file name is a multiple of
    ``VAL_EVERY`` (``models.ev_body_top`` splits the same photos the same way)."""
    m = re.search(r"(\d+)", Path(name).stem)
    return m is not None and int(m.group(1)) % VAL_EVERY == 0


def _detector():
    from rsu.build import PipelineConfig, build_detector

    return build_detector(PipelineConfig(detector=str(REAL / "yolox_nano" / "yolox_nano.onnx")))


def _rsu_band(image: np.ndarray, box) -> np.ndarray | None:
    from rsu.classify.ev import crop_above

    b = crop_above(box, image.shape[1], image.shape[0], ABOVE_FRACTION)
    if b is None:
        return None
    crop = image[b[1]:b[3], b[0]:b[2]]
    return crop[: max(2, round(crop.shape[0] * BAND_FRACTION))]


def _scaled(img: np.ndarray, w: int | None) -> np.ndarray:
    if w is None or w >= img.shape[1]:
        return img
    small = cv2.resize(img, (w, max(2, round(img.shape[0] * w / img.shape[1]))), interpolation=cv2.INTER_AREA)
    ok, buf = cv2.imencode(".jpg", small, [cv2.IMWRITE_JPEG_QUALITY, JPEG_Q])
    return cv2.imdecode(buf, cv2.IMREAD_COLOR) if ok else small


def photo_samples(det) -> tuple[list[np.ndarray], list[int], list[bool], list[str]]:
    """Inputs, labels (1 lit), validation flags and sources of the police crops and scenes, at every scale."""
    x, y, val, src = [], [], [], []
    for kind in ("police_crops", "police_scenes"):
        for label, sub in ((1, "on"), (0, "off")):
            for f in sorted((REAL / "lights_on_off" / kind / sub).iterdir()):
                img = cv2.imread(str(f))
                if img is None:
                    continue
                is_val = is_validation_photo(f.name)
                if kind == "police_scenes":
                    boxes = det.detect(img).boxes
                    if not len(boxes):
                        continue
                    box = max(boxes, key=lambda b: (b[2] - b[0]) * (b[3] - b[1]))
                    x0, x1 = max(0, int(box[0])), int(np.ceil(box[2]))
                    top = max(0, int(box[1] - ABOVE_FRACTION * (box[3] - box[1])))
                    img = img[top:int(np.ceil(box[3])), x0:x1]
                    band_share = BAND_FRACTION
                else:
                    band_share = CROP_BAND
                if img.shape[0] < 8 or img.shape[1] < 8:
                    continue
                for w in SCALES_PX:
                    im = _scaled(img, w)
                    x.append(band_input(im[: max(2, round(im.shape[0] * band_share))]))
                    y.append(label)
                    val.append(is_val)
                    src.append(kind)
    return x, y, val, src


def traffic_clip_path(stem: str) -> Path:
    """The video of the traffic clip ``stem`` (any suffix)."""
    paths = sorted((REAL / "traffic_videos").glob(f"{stem}.*"))
    if not paths:
        raise SystemExit(f"no traffic clip {stem} in {REAL / 'traffic_videos'}")
    return paths[0]


def _sampled_frames(path: Path):
    """(time s, frame, index among the sampled frames) of the video every ``FRAME_STEP_S``."""
    cap = cv2.VideoCapture(str(path))
    fps = cap.get(cv2.CAP_PROP_FPS) or 25.0
    step = max(1, round(FRAME_STEP_S * fps))
    i = sampled = 0
    try:
        while True:
            ok, frame = cap.read()
            if not ok:
                return
            if i % step == 0:
                yield i / fps, frame, sampled
                sampled += 1
            i += 1
    finally:
        cap.release()


def _add_band(out: tuple[list, list, list, list], frame: np.ndarray, box, label: int, sampled: int, clip: str) -> None:
    """The box's lamp band as one input of ``out`` (inputs, labels, validation flags, clip names), if it has one."""
    band = _rsu_band(frame, box)
    if band is not None and band.shape[0] >= 2 and band.shape[1] >= 2:
        for column, value in zip(out, (band_input(band), label, sampled % VAL_EVERY == 0, clip), strict=True):
            column.append(value)


def traffic_samples(det) -> tuple[list[np.ndarray], list[int], list[bool], list[str]]:
    """Inputs (label 0) of the vehicles of the tuning traffic clips, validation flags and clip names."""
    out: tuple[list, list, list, list] = ([], [], [], [])
    for clip in TUNING_TRAFFIC_CLIPS:
        for _t, frame, sampled in _sampled_frames(traffic_clip_path(clip)):
            for box in det.detect(frame).boxes:
                if box[2] - box[0] >= MIN_WIDTH_PX:
                    _add_band(out, frame, box, 0, sampled, clip)
    return out


def ev_clip_samples(det) -> tuple[list[np.ndarray], list[int], list[bool], list[str]]:
    """Inputs of the vehicles of the tuning EV clips (``EV_CLIPS``) every ``FRAME_STEP_S``: label 1 for a detector
    box on a labelled EV whose lights are on (IoU >= 0.3), 0 for one on no EV (IoU < 0.05 with every EV); boxes of
    EVs with their lights off, or half on one, are left out. A flashing lamp is dark in some of the lit frames: those
    labels are noisy, the photos are not."""
    from rsu.scan_labels import iou, load_labels

    out: tuple[list, list, list, list] = ([], [], [], [])
    for clip in EV_CLIPS:
        labels = load_labels(ROOT / "bench" / "labels" / f"{Path(clip).stem}.json")
        for t, frame, sampled in _sampled_frames(REAL / "ev_videos" / clip):
            evs = [a for a in (v.at(t) for v in labels.evs) if a is not None]
            for box in det.detect(frame).boxes:
                if box[2] - box[0] < MIN_WIDTH_PX:
                    continue
                overlaps = [(iou(box, a[0]), a[1]) for a in evs]
                best = max(overlaps, default=(0.0, False))
                if best[0] >= 0.3 and best[1]:
                    label = 1
                elif best[0] < 0.05:
                    label = 0
                else:
                    continue
                _add_band(out, frame, box, label, sampled, clip)
    return out


def make_net():
    import torch
    from torch import nn

    class LampNet(nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.features = nn.Sequential(
                nn.Conv2d(3, 12, 3, padding=1), nn.ReLU(),
                nn.Conv2d(12, 16, 3, padding=1, stride=2), nn.ReLU(),
                nn.Conv2d(16, 24, 3, padding=1, stride=2), nn.ReLU())
            self.head = nn.Linear(48, 1)

        def forward(self, x):
            f = self.features(x)
            pooled = torch.cat([torch.amax(f, dim=(2, 3)), torch.mean(f, dim=(2, 3))], dim=1)
            return torch.sigmoid(self.head(pooled))

    return LampNet()


def train(x: np.ndarray, y: np.ndarray, epochs: int):
    import torch

    torch.manual_seed(SEED)
    rng = np.random.default_rng(SEED)
    net = make_net()
    opt = torch.optim.Adam(net.parameters(), lr=3e-3, weight_decay=1e-4)
    pos_w = float((y == 0).sum()) / max(float((y == 1).sum()), 1.0)
    for _ in range(epochs):
        order = rng.permutation(len(y))
        for k in range(0, len(order), 64):
            idx = order[k:k + 64]
            xb = x[idx].copy()
            flip = rng.random(len(idx)) < 0.5
            xb[flip] = xb[flip][..., ::-1]
            xb = np.clip(xb * rng.uniform(0.7, 1.2, (len(idx), 1, 1, 1)).astype(np.float32), 0, 1)
            xt, yt = torch.from_numpy(np.ascontiguousarray(xb)), torch.from_numpy(y[idx].astype(np.float32))[:, None]
            p = net(xt).clamp(1e-6, 1 - 1e-6)
            weight = torch.where(yt > 0, torch.tensor(pos_w), torch.tensor(1.0))
            loss = torch.nn.functional.binary_cross_entropy(p, yt, weight=weight)
            opt.zero_grad()
            loss.backward()
            opt.step()
    return net.eval()


def predict(net, x: np.ndarray) -> np.ndarray:
    import torch

    with torch.no_grad():
        return np.concatenate([net(torch.from_numpy(x[k:k + 256])).numpy().reshape(-1)
                               for k in range(0, len(x), 256)]) if len(x) else np.zeros(0)


def operating_point(p: np.ndarray, y: np.ndarray) -> float:
    for t in np.arange(0.3, 0.96, 0.01):
        pred = p >= t
        if pred.any() and (y[pred] == 1).mean() >= TARGET_PRECISION:
            return round(float(t), 2)
    return 0.95


def metrics(p: np.ndarray, y: np.ndarray, t: float) -> dict:
    pred = p >= t
    tp, fp, fn = int((pred & (y == 1)).sum()), int((pred & (y == 0)).sum()), int((~pred & (y == 1)).sum())
    a, b = p[y == 1][:, None], p[y == 0][None, :]
    auc = float((a > b).mean() + 0.5 * (a == b).mean()) if a.size and b.size else None
    return dict(n=int(len(y)), lit=int(y.sum()), precision=round(tp / max(tp + fp, 1), 3),
                recall=round(tp / max(tp + fn, 1), 3), auc=None if auc is None else round(auc, 3))


def export(net, path: Path, threshold: float) -> None:
    import onnx
    import torch

    dummy = torch.zeros(1, 3, *INPUT_HW)
    torch.onnx.export(net, dummy, str(path), input_names=["bands"], output_names=["p_lit"],
                      dynamic_axes={"bands": {0: "N"}, "p_lit": {0: "N"}}, opset_version=13, dynamo=False)
    model = onnx.load(str(path))
    model.metadata_props.append(onnx.StringStringEntryProto(key="threshold", value=str(threshold)))
    onnx.save(model, str(path))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=ROOT / "models" / "lamp_state.onnx")
    ap.add_argument("--epochs", type=int, default=40)
    ap.add_argument("--no-ev-clips", dest="ev_clips", action="store_false",
                    help="train on the photos and traffic clips only (not on the tuning EV clips' vehicles)")
    ap.add_argument("--exclude", default="", help="comma-separated clip stems left out of training (a held-back fold)")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    import torch

    torch.set_num_threads(1)
    det = _detector()
    px, py, pv, ps = photo_samples(det)
    tx, ty, tv, ts = traffic_samples(det)
    ex, ey, ev, es = ev_clip_samples(det) if args.ev_clips else ([], [], [], [])
    x, y = np.stack(px + tx + ex).astype(np.float32), np.array(py + ty + ey)
    val, src = np.array(pv + tv + ev), np.array(ps + ts + es)
    left_out = np.isin(np.array([Path(c).stem for c in src]), [c for c in args.exclude.split(",") if c])
    net = train(x[~val & ~left_out], y[~val & ~left_out], args.epochs)
    p = predict(net, x[val])
    t = operating_point(p, y[val])
    out = dict(threshold=t, train=int((~val & ~left_out).sum()), train_lit=int(y[~val & ~left_out].sum()),
               val=int(val.sum()),
               val_all=metrics(p, y[val], t))
    for s in ("police_crops", "police_scenes"):
        m = src[val] == s
        out[f"val_{s}"] = metrics(p[m], y[val][m], t)
    m = np.isin(src[val], EV_CLIPS)
    if m.any():
        out["val_ev_clips"] = metrics(p[m], y[val][m], t)
    for clip in TUNING_TRAFFIC_CLIPS:
        m = src[val] == clip
        out[f"val_false_lit_{clip}"] = round(float((p[m] >= t).mean()), 3) if m.any() else None
    export(net, args.out, t)
    out["model"] = str(args.out)
    for k, v in out.items():
        print(f"{k}: {v}")
    if args.json:
        print(json.dumps(out))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
