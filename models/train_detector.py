"""Train the project's small vehicle detector on the simulator's detection set and export it to ONNX.

Model: a tiny depthwise-separable backbone + top-down FPN + YOLOX-style decoupled-free head (Ge et al.
2021) over strides 8/16/32. It exports exactly the layout ``rsu.detect.OnnxDetector`` decodes as
``"project"``: input ``[1, 3, H, W]`` float32 BGR raw 0-255 letterboxed top-left (pad 114), output
``[1, A, 7]`` rows ``cx, cy, w, h`` grid-relative (``xy = (xy + grid) * stride``, ``wh = exp(wh) *
stride``), sigmoid objectness, sigmoid p(vehicle), sigmoid p(ev).

Training (seeded): images letterboxed once to the model input and cached in memory (several export
folders can be pooled); random crops and brightness/contrast jitter (no flips by default: the cameras are
fixed and shadows fall to one side); label assignment SimOTA (YOLOX: dynamic top-k anchor points by a
class + IoU cost, any level), or the older fixed centre sampling with ``--assigner centre``; vehicles a
crop cuts below 40 % are ignore regions; losses (YOLOX): BCE objectness over all anchor points, BCE
classes with target one-hot x IoU (so the score follows the box quality), 5 x (1 - GIoU) + L1 boxes
over positives, normalised by the number of positives (``models/detector_loss.py``). Needs torch (the ``train``
extra).
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from models.detector_loss import N_CLASSES, STRIDES, detection_loss
from models.resize_detector import RSU_INPUT_HW

INPUT_HW = (384, 640)
"""Training input (h, w): the 1280x720 frame letterboxed at scale 0.5 fills 360x640 of it (the exported model is
re-declared at ``RSU_INPUT_HW``)."""
PAD_VALUE = 114


# ----------------------------------------------------------------------------- model
def conv_bn(c_in: int, c_out: int, k: int = 3, s: int = 1, groups: int = 1) -> nn.Sequential:
    return nn.Sequential(nn.Conv2d(c_in, c_out, k, s, k // 2, groups=groups, bias=False),
                         nn.BatchNorm2d(c_out), nn.SiLU(inplace=True))


class DwBlock(nn.Module):
    """Depthwise 3x3 + pointwise 1x1 (MobileNet), residual when the shape allows."""

    def __init__(self, c_in: int, c_out: int, s: int = 1) -> None:
        super().__init__()
        self.dw = conv_bn(c_in, c_in, 3, s, groups=c_in)
        self.pw = conv_bn(c_in, c_out, 1)
        self.residual = s == 1 and c_in == c_out

    def forward(self, x):
        y = self.pw(self.dw(x))
        return x + y if self.residual else y


class TinyYolox(nn.Module):
    def __init__(self, width: tuple[int, ...] = (16, 32, 64, 96, 128), neck: int = 64) -> None:
        super().__init__()
        c1, c2, c3, c4, c5 = width
        self.stem = nn.Sequential(conv_bn(3, c1, 3, 2), DwBlock(c1, c2, 2), DwBlock(c2, c2))  # /4
        self.s8 = nn.Sequential(DwBlock(c2, c3, 2), DwBlock(c3, c3), DwBlock(c3, c3))
        self.s16 = nn.Sequential(DwBlock(c3, c4, 2), DwBlock(c4, c4), DwBlock(c4, c4))
        self.s32 = nn.Sequential(DwBlock(c4, c5, 2), DwBlock(c5, c5))
        self.lat = nn.ModuleList([conv_bn(c, neck, 1) for c in (c3, c4, c5)])
        self.smooth = nn.ModuleList([DwBlock(neck, neck) for _ in STRIDES])
        self.head = nn.ModuleList([nn.Sequential(DwBlock(neck, neck), DwBlock(neck, neck)) for _ in STRIDES])
        self.pred = nn.ModuleList([nn.Conv2d(neck, 5 + N_CLASSES, 1) for _ in STRIDES])
        prior = -math.log((1 - 0.01) / 0.01)
        for p in self.pred:
            nn.init.zeros_(p.weight)
            nn.init.constant_(p.bias, 0.0)
            p.bias.data[4:] = prior
        self.register_buffer("mean", torch.tensor([PAD_VALUE] * 3, dtype=torch.float32).view(1, 3, 1, 1))

    def raw(self, x: torch.Tensor) -> list[torch.Tensor]:
        """Per level (B, 7, h, w) logits (box raw, objectness logit, class logits)."""
        x = (x - self.mean) / 64.0
        f8 = self.s8(self.stem(x))
        f16 = self.s16(f8)
        f32 = self.s32(f16)
        p32 = self.lat[2](f32)
        p16 = self.lat[1](f16) + F.interpolate(p32, size=f16.shape[-2:], mode="nearest")
        p8 = self.lat[0](f8) + F.interpolate(p16, size=f8.shape[-2:], mode="nearest")
        feats = [self.smooth[i](p) for i, p in enumerate((p8, p16, p32))]
        return [self.pred[i](self.head[i](f)) for i, f in enumerate(feats)]

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Export layout: (B, A, 7) with sigmoid objectness and classes (YOLOX inference output, not decoded)."""
        outs = []
        for o in self.raw(x):
            o = o.flatten(2).permute(0, 2, 1)
            outs.append(torch.cat([o[..., :4], o[..., 4:].sigmoid()], dim=-1))
        return torch.cat(outs, dim=1)


# ----------------------------------------------------------------------------- data
def letterbox_image(image: np.ndarray, input_hw: tuple[int, int] = INPUT_HW) -> tuple[np.ndarray, float]:
    """Same letterbox as ``rsu.detect.letterbox`` but HWC uint8 (top-left, pad 114)."""
    h_in, w_in = input_hw
    ratio = min(h_in / image.shape[0], w_in / image.shape[1])
    new_w, new_h = int(image.shape[1] * ratio), int(image.shape[0] * ratio)
    canvas = np.full((h_in, w_in, 3), PAD_VALUE, dtype=np.uint8)
    canvas[:new_h, :new_w] = cv2.resize(image, (new_w, new_h), interpolation=cv2.INTER_LINEAR)
    return canvas, ratio


def load_split(det_dir: Path, split: str, input_hw=INPUT_HW, limit: int | None = None, progress: bool = True):
    """Letterboxed images (N, H, W, 3) uint8 and per-image label arrays (n, 5) [cls, x1, y1, x2, y2] in input px."""
    paths = sorted((det_dir / "images" / split).glob("*.jpg"))
    if limit:
        paths = paths[:limit]
    if not paths:
        raise FileNotFoundError(f"no images under {det_dir / 'images' / split}")
    images = np.empty((len(paths), *input_hw, 3), np.uint8)
    labels = []
    t0 = time.perf_counter()
    for i, p in enumerate(paths):
        img = cv2.imread(str(p))
        images[i], ratio = letterbox_image(img, input_hw)
        lab = np.loadtxt(det_dir / "labels" / split / f"{p.stem}.txt", ndmin=2, dtype=np.float32).reshape(-1, 5)
        h, w = img.shape[:2]
        boxes = np.column_stack([lab[:, 0], (lab[:, 1] - lab[:, 3] / 2) * w, (lab[:, 2] - lab[:, 4] / 2) * h,
                                 (lab[:, 1] + lab[:, 3] / 2) * w, (lab[:, 2] + lab[:, 4] / 2) * h])
        boxes[:, 1:] *= ratio
        labels.append(boxes.astype(np.float32))
        if progress and (i + 1) % 500 == 0:
            print(f"  loaded {i + 1}/{len(paths)} {split} images ({time.perf_counter() - t0:.0f} s)", flush=True)
    return images, labels


def augment(rng: np.random.Generator, image: np.ndarray, boxes: np.ndarray, crop_hw: tuple[int, int],
            flip: bool = False):
    """Random crop (to crop_hw, multiples of 32) of the letterboxed content, optional horizontal flip,
    brightness/contrast. -> (image, boxes (n, 5) kept, ignore boxes (m, 4)): a vehicle the crop cuts to
    less than 40 % of its box is an ignore region (its anchors get no objectness loss), not background.

    Flips are off by default: the cameras are fixed and the sun casts shadows to one side, so a flipped
    frame (road and shadows mirrored) is a view the detector never meets and teaches it to include the
    shadow in the box."""
    H, W = image.shape[:2]
    ch, cw = crop_hw
    y0 = int(rng.integers(0, H - ch + 1))
    x0 = int(rng.integers(0, W - cw + 1))
    img = image[y0:y0 + ch, x0:x0 + cw].copy()
    b = boxes.copy()
    ignore = np.zeros((0, 4), np.float32)
    if len(b):
        b[:, [1, 3]] -= x0
        b[:, [2, 4]] -= y0
        clipped = b.copy()
        clipped[:, [1, 3]] = clipped[:, [1, 3]].clip(0, cw)
        clipped[:, [2, 4]] = clipped[:, [2, 4]].clip(0, ch)
        area = (b[:, 3] - b[:, 1]) * (b[:, 4] - b[:, 2])
        carea = (clipped[:, 3] - clipped[:, 1]).clip(0) * (clipped[:, 4] - clipped[:, 2]).clip(0)
        keep = (carea >= 0.4 * area) & (carea > 1.0)
        ignore = clipped[~keep & (carea > 0), 1:]
        b = clipped[keep]
    if flip and rng.random() < 0.5:
        img = img[:, ::-1].copy()
        if len(b):
            b[:, [1, 3]] = cw - b[:, [3, 1]]
        if len(ignore):
            ignore[:, [0, 2]] = cw - ignore[:, [2, 0]]
    if rng.random() < 0.8:
        alpha, beta = rng.uniform(0.7, 1.3), rng.uniform(-25, 25)
        img = cv2.convertScaleAbs(img, alpha=alpha, beta=beta)
    return img, b, ignore


# ----------------------------------------------------------------------------- train / export
def train(det_dirs: list[Path], out_path: Path, *, iterations: int, batch: int, crop_hw: tuple[int, int], lr: float,
          seed: int, threads: int, limit: int | None = None, time_budget_s: float | None = None,
          input_hw: tuple[int, int] = INPUT_HW, flip: bool = False, assigner: str = "simota",
          neck: int = 64, rsu_input_hw: tuple[int, int] | None = None) -> nn.Module:
    """Train on ``det_dirs`` at ``input_hw``; export to ``out_path`` re-declared at ``rsu_input_hw`` (the size the
    RSUs run, ``models.resize_detector.RSU_INPUT_HW``; None: the training size)."""
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    torch.set_num_threads(threads)
    torch.set_flush_denormal(True)
    parts = [load_split(d, "train", input_hw, limit=limit) for d in det_dirs]
    images = np.concatenate([im for im, _ in parts]) if len(parts) > 1 else parts[0][0]
    labels = [lb for _, lbs in parts for lb in lbs]
    del parts
    n_boxes = sum(len(lb) for lb in labels)
    print(f"train: {len(images)} images, {n_boxes} boxes, input {input_hw}, crops {crop_hw}, assigner {assigner}, "
          f"flip {flip}", flush=True)
    model = TinyYolox(neck=neck)
    n_params = sum(p.numel() for p in model.parameters())
    print(f"model: {n_params / 1e6:.3f} M parameters", flush=True)
    opt = torch.optim.AdamW(model.parameters(), lr=lr, weight_decay=5e-4)
    warmup = max(1, iterations // 20)
    sched = torch.optim.lr_scheduler.LambdaLR(
        opt, lambda it: min(1.0, (it + 1) / warmup) * (0.05 + 0.95 * 0.5 * (1 + math.cos(math.pi * it / iterations))))
    model.train()
    t0 = time.perf_counter()
    for it in range(iterations):
        idx = rng.integers(0, len(images), batch)
        imgs, tgts, igns = [], [], []
        for k in idx:
            im, bx, ig = augment(rng, images[k], labels[k], crop_hw, flip)
            imgs.append(im)
            tgts.append(bx)
            igns.append(ig)
        x = torch.from_numpy(np.stack(imgs)).permute(0, 3, 1, 2).float().contiguous()
        loss, parts = detection_loss(model.raw(x), tgts, crop_hw, igns, assigner)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), 10.0)
        opt.step()
        sched.step()
        el = time.perf_counter() - t0
        if it % 20 == 0 or it == iterations - 1:
            print(f"it {it:5d}/{iterations} loss {float(loss):.3f} iou {parts['iou']:.3f} obj {parts['obj']:.3f} "
                  f"cls {parts['cls']:.3f} l1 {parts['l1']:.3f} fg/img {parts['fg']:.1f} lr {sched.get_last_lr()[0]:.2e} "
                  f"{el:.0f} s", flush=True)
        if it % 200 == 199:
            export_onnx(model, out_path, input_hw)
            model.train()
        if time_budget_s and el > time_budget_s:
            print(f"time budget {time_budget_s:.0f} s reached at iteration {it}", flush=True)
            break
    export_onnx(model, out_path, input_hw)
    if rsu_input_hw is not None:
        from models.resize_detector import any_size_model

        any_size_model(out_path, out_path, tuple(rsu_input_hw))
        print(f"{out_path}: any input size, {rsu_input_hw[0]}x{rsu_input_hw[1]} for a whole frame (trained at "
              f"{input_hw[0]}x{input_hw[1]}; an RSU letterboxes only its zone: rsu.detect_roi)", flush=True)
    return model


def export_onnx(model: nn.Module, out_path: Path, input_hw: tuple[int, int] = INPUT_HW) -> Path:
    model.eval()
    out_path.parent.mkdir(parents=True, exist_ok=True)
    dummy = torch.full((1, 3, *input_hw), float(PAD_VALUE))
    with torch.no_grad():
        torch.onnx.export(model, (dummy,), str(out_path), input_names=["images"], output_names=["output"],
                          opset_version=17, dynamo=False)
    return out_path


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description="Train the project's tiny YOLOX-layout vehicle detector and export ONNX.")
    p.add_argument("--data", nargs="+", default=["datasets/det_train"],
                   help="export-dataset output folder(s) (each holds det/); their train splits are pooled")
    p.add_argument("--out", default="models/iea_det_tiny.onnx")
    p.add_argument("--iterations", type=int, default=3000)
    p.add_argument("--batch", type=int, default=8)
    p.add_argument("--input", type=int, nargs=2, default=INPUT_HW, metavar=("H", "W"),
                   help="training input (multiples of 32); the frame is letterboxed into it")
    p.add_argument("--rsu-input", type=int, nargs=2, default=RSU_INPUT_HW, metavar=("H", "W"),
                   help="input of the exported model, the size the RSUs run (default %(default)s: the smallest with "
                        "MOTA >= 0.9, bench/detector_size_bench.py)")
    p.add_argument("--crop", type=int, nargs=2, default=(256, 320), metavar=("H", "W"))
    p.add_argument("--lr", type=float, default=4e-3)
    p.add_argument("--flip", action="store_true", help="random horizontal flips (off: fixed cameras, one-sided shadows)")
    p.add_argument("--assigner", choices=("simota", "centre"), default="simota",
                   help="label assignment: YOLOX SimOTA (default) or fixed centre sampling")
    p.add_argument("--neck", type=int, default=64, help="FPN/head channels")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--threads", type=int, default=1, help="torch threads (1 is fastest on a shared 2-core box)")
    p.add_argument("--limit", type=int, default=None, help="use at most this many training images")
    p.add_argument("--time-budget-s", type=float, default=None, help="stop (and export) after this long")
    a = p.parse_args(argv)
    if a.crop[0] % 32 or a.crop[1] % 32 or a.input[0] % 32 or a.input[1] % 32:
        p.error("--crop and --input sides must be multiples of 32")
    if a.rsu_input[0] % 32 or a.rsu_input[1] % 32:
        p.error("--rsu-input sides must be multiples of 32")
    train([Path(d) / "det" for d in a.data], Path(a.out), iterations=a.iterations, batch=a.batch,
          crop_hw=tuple(a.crop), lr=a.lr, seed=a.seed, threads=a.threads, limit=a.limit,
          time_budget_s=a.time_budget_s, input_hw=tuple(a.input), flip=a.flip, assigner=a.assigner, neck=a.neck,
          rsu_input_hw=tuple(a.rsu_input))
    print(f"exported {a.out} ({Path(a.out).stat().st_size / 1e6:.2f} MB)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
