"""Train the Clemson comparison's on-board nets and export them to ONNX (models/driving.md).

    /tmp/trainenv/bin/python models/train_driving.py --data datasets/driving datasets/driving_late [--out models]

Data: ``python -m studies.clemson export`` ({train,val,test}.npz). Writes:

- ``driving_seg.onnx``: the debris segmentation, a small fully convolutional net (report 2.2: FCN-based),
  trained on the label masks with a class-balanced binary cross-entropy; output: per-pixel logits.
- ``driving_case{1,2,3}.onnx``: the DAVE-2-like steering nets (report 3.3, fig. 5): in-graph normalisation
  (x / 127.5 - 1, the report's lambda layer) and a batch normalisation, five convolutions (5x5 stride 2 three
  times, 3x3 stride 1 twice; ELU), four dense layers (dropout) and one output, the steering angle
  normalised by eq. 5. Case 1 sees the camera image; cases 2 and 3 the fused image of eq. 1 with the
  radar's threat value (eq. 2-3) and the image's (eq. 4) respectively, built from the label mask (the report
  trained on LabelMe masks; at run time the car uses its own segmentation). Adam with L2 weight decay,
  MSE loss, the best epoch on validation loss kept, early stop after ``--patience`` epochs without progress
  (report 4.4).

Inputs of every graph: ``image`` float32 (N, 3, 66, 200), BGR 0-255. Runtime: onnxruntime only
(``studies.clemson.learned_steering``). Prints one JSON line with the training figures at the end.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch
from torch import nn

SEGMENTED_BGR = (255, 0, 255)
"""Colour of the hazard in I_segmented: the same as ``studies.clemson.learned_steering.SEGMENTED_BGR`` (the training venv
has torch but not the runtime's dependencies, so it is not imported; tests/driving checks they agree)."""
MANOEUVRE_RAD = 0.01
"""Frames where the teacher steers harder than this (the avoidance, the side cameras' recoveries) weigh
``--manoeuvre-weight`` times more in the loss: they are a small share of the frames."""
WIDTHS = (24, 36, 48, 64, 64)
"""DAVE-2's convolution widths."""


class Dave2(nn.Module):
    def __init__(self, width_scale: float = 1.0, dropout: float = 0.3) -> None:
        super().__init__()
        w = [max(4, int(round(c * width_scale))) for c in WIDTHS]
        act = nn.ELU
        self.norm = nn.BatchNorm2d(3)
        self.features = nn.Sequential(
            nn.Conv2d(3, w[0], 5, 2), act(), nn.Conv2d(w[0], w[1], 5, 2), act(), nn.Conv2d(w[1], w[2], 5, 2), act(),
            nn.Conv2d(w[2], w[3], 3, 1), act(), nn.Conv2d(w[3], w[4], 3, 1), act())
        with torch.no_grad():
            n = self.features(torch.zeros(1, 3, 66, 200)).numel()
        self.head = nn.Sequential(nn.Flatten(), nn.Dropout(dropout), nn.Linear(n, 100), act(), nn.Dropout(dropout),
                                  nn.Linear(100, 50), act(), nn.Dropout(dropout), nn.Linear(50, 10), act(),
                                  nn.Linear(10, 1))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.head(self.features(self.norm(x / 127.5 - 1.0)))


class SegNet(nn.Module):
    """Tiny FCN: full-resolution features, a stride-4 context branch upsampled back, per-pixel logits."""

    def __init__(self) -> None:
        super().__init__()
        self.full = nn.Sequential(nn.Conv2d(3, 8, 3, padding=1), nn.ReLU())
        self.ctx = nn.Sequential(nn.Conv2d(8, 16, 3, stride=2, padding=1), nn.ReLU(),
                                 nn.Conv2d(16, 16, 3, stride=2, padding=1), nn.ReLU(),
                                 nn.Conv2d(16, 16, 3, padding=2, dilation=2), nn.ReLU())
        self.out = nn.Sequential(nn.Conv2d(24, 8, 1), nn.ReLU(), nn.Conv2d(8, 1, 1))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        f = self.full(x / 127.5 - 1.0)
        c = nn.functional.interpolate(self.ctx(f), size=f.shape[-2:], mode="bilinear", align_corners=False)
        return self.out(torch.cat([f, c], 1))


def fused(images: np.ndarray, masks: np.ndarray, tf: np.ndarray) -> np.ndarray:
    """Eq. 1 for a batch (uint8 in, uint8 out); I_segmented = mask in SEGMENTED_BGR on black."""
    seg = masks[..., None].astype(np.float32) * np.array(SEGMENTED_BGR, np.float32)
    t = tf.astype(np.float32)[:, None, None, None]
    return np.clip(np.rint((1 - t) * images.astype(np.float32) + t * seg), 0, 255).astype(np.uint8)


def case_images(d: dict, case: int) -> np.ndarray:
    if case == 1:
        return d["images"]
    return fused(d["images"], d["masks"], d["radar_tf"] if case == 2 else d["image_tf"])


def to_tensor(images: np.ndarray) -> torch.Tensor:
    return torch.from_numpy(np.ascontiguousarray(images.transpose(0, 3, 1, 2))).float()


def export(model: nn.Module, path: Path) -> None:
    model.eval()
    torch.onnx.export(model, torch.zeros(1, 3, 66, 200), str(path), input_names=["image"], output_names=["out"],
                      dynamic_axes={"image": {0: "n"}, "out": {0: "n"}}, opset_version=17, dynamo=False)


CROP_H, CROP_W = 32, 96


def crops(images: np.ndarray, masks: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """A CROP_H x CROP_W window of each frame, around its debris when it has some (the net is fully
    convolutional: training on windows costs a quarter and sees the rare debris pixels more often)."""
    n, h, w = masks.shape
    xi, yi = np.empty((n, CROP_H, CROP_W, 3), np.uint8), np.empty((n, CROP_H, CROP_W), np.uint8)
    for i in range(n):
        rows, cols = np.nonzero(masks[i])
        if len(rows):
            k = rng.integers(len(rows))
            r0 = int(np.clip(rows[k] - rng.integers(0, CROP_H), 0, h - CROP_H))
            c0 = int(np.clip(cols[k] - rng.integers(0, CROP_W), 0, w - CROP_W))
        else:
            r0, c0 = int(rng.integers(0, h - CROP_H + 1)), int(rng.integers(0, w - CROP_W + 1))
        xi[i], yi[i] = images[i, r0:r0 + CROP_H, c0:c0 + CROP_W], masks[i, r0:r0 + CROP_H, c0:c0 + CROP_W]
    return xi, yi


def train_seg(tr: dict, va: dict, epochs: int, out: Path, log) -> dict:
    torch.manual_seed(0)
    net = SegNet()
    opt = torch.optim.Adam(net.parameters(), 3e-3)
    best, best_state = -1.0, None
    for ep in range(epochs):
        net.train()
        rng = np.random.default_rng(ep)
        x, y = crops(tr["images"], tr["masks"], rng)
        pos = float(y.mean())
        lossf = nn.BCEWithLogitsLoss(pos_weight=torch.tensor(min(5.0, (1 - pos) / max(pos, 1e-6))))
        perm = rng.permutation(len(x))
        for i in range(0, len(perm), 16):
            b = perm[i:i + 16]
            loss = lossf(net(to_tensor(x[b])), torch.from_numpy(y[b][:, None].astype(np.float32)))
            opt.zero_grad()
            loss.backward()
            opt.step()
        iou = seg_iou(net, va)
        log(f"seg epoch {ep + 1}: val IoU {iou:.3f} (loss {float(loss):.4f})")
        if iou > best:
            best, best_state = iou, {k: v.clone() for k, v in net.state_dict().items()}
    net.load_state_dict(best_state)
    # the decision threshold of best validation IoU, folded into the graph: the runtime keeps logit > 0
    ious = {thr: seg_iou(net, va, thr) for thr in (0.0, 0.5, 1.0, 1.5, 2.0, 2.5, 3.0)}
    thr = max(ious, key=ious.get)
    log(f"seg threshold {thr}: val IoU {ious[thr]:.3f}")
    export(Shifted(net, thr), out / "driving_seg.onnx")
    return {"seg_val_iou": round(ious[thr], 4), "seg_epochs": epochs, "seg_logit_threshold": thr}


class Shifted(nn.Module):
    def __init__(self, net: nn.Module, shift: float) -> None:
        super().__init__()
        self.net, self.shift = net, shift

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.net(x) - self.shift


@torch.no_grad()
def seg_iou(net: nn.Module, d: dict, threshold: float = 0.0) -> float:
    net.eval()
    inter = union = 0
    for i in range(0, len(d["images"]), 256):
        p = net(to_tensor(d["images"][i:i + 256]))[:, 0].numpy() > threshold
        m = d["masks"][i:i + 256].astype(bool)
        inter += int((p & m).sum())
        union += int((p | m).sum())
    return inter / max(union, 1)


@torch.no_grad()
def predict(net: nn.Module, x: np.ndarray) -> np.ndarray:
    net.eval()
    return np.concatenate([net(to_tensor(x[i:i + 256]))[:, 0].numpy() for i in range(0, len(x), 256)])


def train_case(case: int, tr: dict, va: dict, args, out: Path, log) -> dict:
    torch.manual_seed(case)
    net = Dave2(args.width_scale, args.dropout)
    opt = torch.optim.Adam(net.parameters(), args.lr, weight_decay=args.weight_decay)
    x, y = case_images(tr, case), tr["steer_n"].astype(np.float32)
    weight = np.where(np.abs(tr["steer_rad"]) > MANOEUVRE_RAD, args.manoeuvre_weight, 1.0).astype(np.float32)
    xv, yv = case_images(va, case), va["steer_n"]
    best, best_state, since, epochs = np.inf, None, 0, 0
    for ep in range(args.epochs):
        net.train()
        perm = np.random.default_rng(100 * case + ep).permutation(len(x))
        for i in range(0, len(perm), args.batch):
            b = perm[i:i + args.batch]
            err = net(to_tensor(x[b]))[:, 0] - torch.from_numpy(y[b])
            loss = (torch.from_numpy(weight[b]) * err * err).mean()
            opt.zero_grad()
            loss.backward()
            opt.step()
        val = float(np.mean((predict(net, xv) - yv) ** 2))
        epochs = ep + 1
        log(f"case {case} epoch {epochs}: val MSE {val:.6f}")
        if val < best:
            best, best_state, since = val, {k: v.clone() for k, v in net.state_dict().items()}, 0
        else:
            since += 1
            if since >= args.patience:
                break
    net.load_state_dict(best_state)
    export(net, out / f"driving_case{case}.onnx")
    return {f"case{case}_val_mse": best, f"case{case}_epochs": epochs,
            "params": int(sum(p.numel() for p in net.parameters()))}


def load(paths: list[Path]) -> dict:
    """The frames of one split from one or more exports, concatenated."""
    parts = []
    for path in paths:
        if not path.is_file():
            raise SystemExit(f"train_driving: {path} not found: run 'python -m studies.clemson export --out {path.parent}' first")
        with np.load(path) as z:
            parts.append({k: z[k] for k in z.files})
    return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", required=True, nargs="+", help="folder(s) written by 'python -m studies.clemson export'")
    ap.add_argument("--out", default=str(Path(__file__).resolve().parent), help="where the .onnx files go")
    ap.add_argument("--epochs", type=int, default=12)
    ap.add_argument("--seg-epochs", type=int, default=4)
    ap.add_argument("--patience", type=int, default=3)
    ap.add_argument("--batch", type=int, default=64)
    ap.add_argument("--lr", type=float, default=1e-3)
    ap.add_argument("--weight-decay", type=float, default=1e-5, help="L2 regularisation")
    ap.add_argument("--dropout", type=float, default=0.3)
    ap.add_argument("--no-flip", action="store_true", help="train the steering nets without the flipped copies")
    ap.add_argument("--manoeuvre-weight", type=float, default=3.0, help="loss weight of the steering frames")
    ap.add_argument("--width-scale", type=float, default=0.5, help="scale of DAVE-2's convolution widths")
    ap.add_argument("--seg-frames", type=int, default=3000,
                    help="train the segmentation on this many frames, half of them with debris (CPU time)")
    ap.add_argument("--max-train-frames", type=int, default=5000,
                    help="train the steering nets on a seeded random subset of this many frames (CPU time)")
    ap.add_argument("--cases", default="1,2,3", help="steering nets to train ('' for none)")
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()

    def log(msg: str) -> None:
        print(f"[{time.perf_counter() - t0:6.0f} s] {msg}", file=sys.stderr, flush=True)

    tr = load([Path(d) / "train.npz" for d in args.data])
    va = load([Path(d) / "val.npz" for d in args.data])
    log(f"train {len(tr['images'])} frames, val {len(va['images'])}")
    figures = {"train_frames": len(tr["images"]), "val_frames": len(va["images"])}
    if args.seg_epochs > 0:
        rng = np.random.default_rng(1)
        has = np.nonzero(tr["masks"].any(axis=(1, 2)))[0]
        none = np.setdiff1d(np.arange(len(tr["masks"])), has)
        n_has = min(len(has), args.seg_frames // 2)
        keep = np.sort(np.concatenate([rng.choice(has, n_has, replace=False),
                                       rng.choice(none, min(len(none), args.seg_frames - n_has), replace=False)]))
        vkeep = np.random.default_rng(2).choice(len(va["images"]), min(len(va["images"]), 1000), replace=False)
        figures.update(train_seg({k: tr[k][keep] for k in ("images", "masks")},
                                 {k: va[k][vkeep] for k in ("images", "masks")}, args.seg_epochs, out, log))
        figures["seg_train_frames"] = int(len(keep))
    if args.no_flip:  # the flipped copies mirror the road too (yellow edge line on the right): leave them out
        tr = {k: v[~tr["flipped"]] for k, v in tr.items()}
        va = {k: v[~va["flipped"]] for k, v in va.items()}
        figures["no_flip"] = True
    if len(tr["images"]) > args.max_train_frames:
        keep = np.sort(np.random.default_rng(0).choice(len(tr["images"]), args.max_train_frames, replace=False))
        tr = {k: v[keep] for k, v in tr.items()}
        figures["steering_train_frames"] = len(keep)
    for case in (int(c) for c in args.cases.split(",") if c.strip()):
        figures.update(train_case(case, tr, va, args, out, log))
    figures["train_s"] = round(time.perf_counter() - t0, 1)
    print(json.dumps(figures))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
