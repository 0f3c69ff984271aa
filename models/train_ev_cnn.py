"""Train the small EV crop CNN (thesis 2.4.2.3) on a RAVEV-layout crop set and export it to ONNX.

Architecture (thesis Fig. 2.8): three blocks of 3x3 convolution + ReLU + 2x2 max-pool (16, 32, 32
channels), a dense ReLU layer (32), one sigmoid unit. Input: the pixel array, here 64x64 (the thesis
uses 128x128; 64 keeps the model at ~80k parameters / ~0.3 MB and a crop at well under 1 ms on one core,
and a light bar is still several pixels tall), BGR scaled to [0, 1]. Exported with input ``crops``
``[N, 3, 64, 64]`` and output ``p_ev`` ``[N, 1]``, loaded by :class:`rsu.classify.classifiers.CnnClassifier`.

Training (seeded, 1 CPU thread): crops resized once and cached in memory; class-balanced sampling
(EV crops are ~6 % of the sim export); augmentation: horizontal flip, box jitter (random crop of the
crop, +-10 %, and an upward extension that puts sky above the roof), brightness/contrast jitter;
Adam, binary cross-entropy. Needs torch (the ``train`` extra).

    python -m models.train_ev_cnn --data datasets/det_train/cls --out models/ev_cnn.onnx
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from rsu.classify.ravev import load_split

SIZE = 64


class EvCnn(nn.Module):
    def __init__(self, size: int = SIZE, channels: tuple[int, int, int] = (16, 32, 32), dense: int = 32) -> None:
        super().__init__()
        c1, c2, c3 = channels
        self.features = nn.Sequential(
            nn.Conv2d(3, c1, 3, padding=1), nn.ReLU(inplace=True), nn.MaxPool2d(2),
            nn.Conv2d(c1, c2, 3, padding=1), nn.ReLU(inplace=True), nn.MaxPool2d(2),
            nn.Conv2d(c2, c3, 3, padding=1), nn.ReLU(inplace=True), nn.MaxPool2d(2))
        self.head = nn.Sequential(nn.Flatten(), nn.Linear(c3 * (size // 8) ** 2, dense), nn.ReLU(inplace=True),
                                  nn.Linear(dense, 1))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Logits (N, 1); the exported model ends with a sigmoid."""
        return self.head(self.features(x))


class Exported(nn.Module):
    def __init__(self, net: EvCnn) -> None:
        super().__init__()
        self.net = net

    def forward(self, crops: torch.Tensor) -> torch.Tensor:
        return torch.sigmoid(self.net(crops))


def augment(crop: np.ndarray, rng: np.random.Generator, size: int) -> np.ndarray:
    """One randomly jittered view of a crop, resized to ``size`` (BGR uint8)."""
    h, w = crop.shape[:2]
    if rng.random() < 0.3:  # some sky/road above the roof, as a detector box that is too tall
        pad = int(h * rng.uniform(0.05, 0.3))
        crop = cv2.copyMakeBorder(crop, pad, 0, 0, 0, cv2.BORDER_REPLICATE)
        h = crop.shape[0]
    dx0, dx1 = (rng.uniform(0, 0.1, 2) * w).astype(int)
    dy0, dy1 = (rng.uniform(0, 0.1, 2) * h).astype(int)
    crop = crop[dy0:max(dy0 + 2, h - dy1), dx0:max(dx0 + 2, w - dx1)]
    if rng.random() < 0.5:
        crop = crop[:, ::-1]
    out = cv2.resize(np.ascontiguousarray(crop), (size, size), interpolation=cv2.INTER_AREA).astype(np.float32)
    out = out * rng.uniform(0.7, 1.3) + rng.uniform(-20, 20)
    return np.clip(out, 0, 255).astype(np.uint8)


def to_tensor(batch: list[np.ndarray]) -> torch.Tensor:
    return torch.from_numpy(np.stack(batch).transpose(0, 3, 1, 2).astype(np.float32) / 255.0)


def evaluate(net: EvCnn, crops: list[np.ndarray], labels: np.ndarray, size: int) -> dict:
    net.eval()
    probs = []
    with torch.no_grad():
        for i in range(0, len(crops), 256):
            batch = [cv2.resize(c, (size, size), interpolation=cv2.INTER_AREA) for c in crops[i:i + 256]]
            probs.append(torch.sigmoid(net(to_tensor(batch))).numpy().ravel())
    p = np.concatenate(probs) if probs else np.zeros(0)
    pred = p >= 0.5
    tp, fp = int(np.sum(pred & (labels == 1))), int(np.sum(pred & (labels == 0)))
    fn = int(np.sum(~pred & (labels == 1)))
    return dict(accuracy=float(np.mean(pred == (labels == 1))) if len(p) else 0.0,
                precision=tp / max(tp + fp, 1), recall=tp / max(tp + fn, 1))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", required=True, help="RAVEV-layout folder (train/val/{ev,non_ev})")
    ap.add_argument("--out", default="models/ev_cnn.onnx")
    ap.add_argument("--epochs", type=int, default=12)
    ap.add_argument("--steps-per-epoch", type=int, default=150)
    ap.add_argument("--batch", type=int, default=32)
    ap.add_argument("--lr", type=float, default=2e-3)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--threads", type=int, default=1)
    a = ap.parse_args(argv)
    torch.set_num_threads(a.threads)
    torch.manual_seed(a.seed)
    rng = np.random.default_rng(a.seed)
    t0 = time.perf_counter()
    crops, labels = load_split(a.data, "train")
    val_crops, val_labels = load_split(a.data, "val")
    print(f"train {len(crops)} crops ({int(labels.sum())} EV), val {len(val_crops)} ({int(val_labels.sum())} EV); "
          f"loaded in {time.perf_counter() - t0:.0f} s", flush=True)
    if labels.sum() == 0 or (labels == 0).sum() == 0:
        print("train_ev_cnn: the train split needs both classes", file=sys.stderr)
        return 2
    pos, neg = np.flatnonzero(labels == 1), np.flatnonzero(labels == 0)
    net = EvCnn()
    opt = torch.optim.Adam(net.parameters(), lr=a.lr, weight_decay=1e-4)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, a.epochs * a.steps_per_epoch)
    for epoch in range(a.epochs):
        net.train()
        total = 0.0
        for _ in range(a.steps_per_epoch):
            idx = np.concatenate([rng.choice(pos, a.batch // 2), rng.choice(neg, a.batch - a.batch // 2)])
            x = to_tensor([augment(crops[i], rng, SIZE) for i in idx])
            y = torch.from_numpy(labels[idx].astype(np.float32)).view(-1, 1)
            loss = F.binary_cross_entropy_with_logits(net(x), y)
            opt.zero_grad()
            loss.backward()
            opt.step()
            sched.step()
            total += loss.item()
        m = evaluate(net, val_crops, val_labels, SIZE)
        print(f"epoch {epoch + 1:2d}  loss {total / a.steps_per_epoch:.3f}  val acc {m['accuracy']:.3f} "
              f"P {m['precision']:.3f} R {m['recall']:.3f}  ({time.perf_counter() - t0:.0f} s)", flush=True)
    out = Path(a.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    net.eval()
    torch.onnx.export(Exported(net), torch.zeros(1, 3, SIZE, SIZE), str(out), input_names=["crops"],
                      output_names=["p_ev"], dynamic_axes={"crops": {0: "n"}, "p_ev": {0: "n"}}, opset_version=17,
                      dynamo=False)
    n_params = sum(p.numel() for p in net.parameters())
    print(f"wrote {out} ({out.stat().st_size / 1024:.0f} KB, {n_params} parameters) in {time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
