"""Fine-tune the top of the int8 EV-body student on a CPU, with the police cars of ``lights_on_off`` among the EVs.

    python -m models.ev_body_top --base models/ev_body.onnx --out models/ev_body.onnx

The student that ``models.train_ev_body`` exports (EfficientNet-Lite0, static int8) learned the vehicle type from
``ev_train``, whose EVs are mostly ambulances and fire engines seen in full. US police cars, marked or
unmarked, lit or dark, are few there. ``lights_on_off`` holds 706 of them (crops, and whole photos cropped
as the RSU crops a track: the largest COCO YOLOX-Nano vehicle, grown upwards by ``above_fraction``), all EVs
whatever their lamps.

The student's trunk (blocks 0-14, int8) stays as it is. Its top (block 15's expand, depthwise and project
convolutions, the head convolution and the EV logit, about 50 M multiply-adds at 7 x 7) is dequantised to
float32 and trained on cached block-14 activations. They are computed once per view, the crop, its mirror image
and ``--views`` - 2 augmented copies (:func:`models.ev_body_net.augment`), so an epoch costs about 30 s on two
cores. Each is computed for:

- the ``train`` split of ``ev_train`` (label review applied, :mod:`rsu.classify.real_data`);
- the ``lights_on_off`` police crops and photos, labelled EV, except the validation ones (the number in the
  file name a multiple of 5, as ``models.train_lamp_state`` splits them), any near-duplicate of a validation one,
  and any near-duplicate of an ``ev_images`` photo (the photo test set of ``bench/ev_real_bench.py``). A
  near-duplicate is within 10 bits of a 64-bit difference hash;
- ``--negative-clips``: YOLOX vehicles at least 40 px wide, every 0.5 s, in traffic clips with no EV, as non-EVs.
  By default these are the tuning traffic clips of ``bench/ev_real_bench.py``, never its held-out ones.

Training: AdamW with a one-cycle schedule, weighted BCE, ``--epochs`` epochs. The epoch kept, and the
operating points written to the metadata, are chosen on ``val`` of ``ev_train`` together with the
``lights_on_off`` validation photos (``ev_threshold``: the best min(precision, recall); ``confident_threshold``:
the lowest with precision >= 0.95 on ``val``; ``sure_threshold``: the lowest at which no ``val`` vehicle is taken
for an EV). ``test`` and the ``ev_images`` photos are scored once at the end and never choose anything. The
output is one graph: the int8 trunk, then the float top. Needs PyTorch (the ``train`` extra) and ``../shared``.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from models.ev_crop_cache import ABOVE_FRACTION  # noqa: E402
from models.train_ev_body import (  # noqa: E402
    DEFAULT_DATA,
    best_threshold,
    confident_threshold,
    fp16_storage,
    set_metadata,
    usable_crops,
)
from models.train_lamp_state import is_validation_photo, traffic_clip_path  # noqa: E402
from rsu.classify.evaluation import metrics  # noqa: E402
from rsu.scan_labels import TUNING_TRAFFIC_CLIPS  # noqa: E402

REAL = DEFAULT_DATA.parent
TRUNK_OUTPUT = "/net/_blocks.14/Add_output_0"
"""The int8 student's block-14 output, the top's input ([N, 192, 7, 7] at 224 px)."""
TOP_CONVS = 4
"""Block 15's expand, depthwise and project convolutions and the head convolution: the graph's last 4 QLinearConv."""
NEAR_DUPLICATE_BITS = 10
SIZE = 224


def difference_hash(image: np.ndarray) -> np.ndarray:
    """64-bit difference hash of a BGR image (each pixel brighter than its left neighbour, on a 9 x 8 grey thumbnail)."""
    g = cv2.resize(cv2.cvtColor(image, cv2.COLOR_BGR2GRAY), (9, 8), interpolation=cv2.INTER_AREA)
    return (g[:, 1:] > g[:, :-1]).ravel()


def near_duplicates(hashes: np.ndarray, others: np.ndarray, bits: int = NEAR_DUPLICATE_BITS) -> np.ndarray:
    """Mask of ``hashes`` rows within ``bits`` of any row of ``others``."""
    if not len(hashes) or not len(others):
        return np.zeros(len(hashes), bool)
    return ((hashes[:, None, :] != others[None, :, :]).sum(-1) <= bits).any(1)


def police_crops(detector) -> tuple[list[np.ndarray], list[str]]:
    """Every ``lights_on_off`` police car as the RSU crops it (whole photos: the largest vehicle), with its path."""
    from rsu.classify.evaluation import largest_vehicle_crop

    crops, names = [], []
    for kind in ("police_crops", "police_scenes"):
        for sub in ("on", "off"):
            for f in sorted((REAL / "lights_on_off" / kind / sub).iterdir()):
                img = cv2.imread(str(f))
                if img is None:
                    continue
                if kind == "police_scenes":
                    img = largest_vehicle_crop(img, detector, ABOVE_FRACTION)
                if img is not None and min(img.shape[:2]) >= 8:
                    crops.append(img)
                    names.append(f"{kind}/{sub}/{f.name}")
    return crops, names


def clip_negatives(detector, clips, every_s: float = 0.5, min_width_px: float = 40.0) -> list[np.ndarray]:
    """Vehicle crops (YOLOX boxes at least ``min_width_px`` wide, every ``every_s``) of traffic clips with no EV."""
    from rsu.classify.ev import crop_above

    out = []
    for name in clips:
        cap = cv2.VideoCapture(str(traffic_clip_path(name)))
        step = max(1, int(round((cap.get(cv2.CAP_PROP_FPS) or 25.0) * every_s)))
        i = 0
        while True:
            ok, frame = cap.read()
            if not ok:
                break
            if i % step == 0:
                for b in detector.detect(frame).boxes:
                    cb = crop_above(b, frame.shape[1], frame.shape[0], ABOVE_FRACTION) if b[2] - b[0] >= min_width_px else None
                    if cb is not None:
                        out.append(frame[cb[1]:cb[3], cb[0]:cb[2]].copy())
            i += 1
        cap.release()
    return out


def with_trunk_output(base: Path):
    """``base``'s ONNX model with its block-14 activations, dequantised, as a second output ``b14``."""
    import onnx
    from onnx import helper

    m = onnx.load(str(base))
    q = TRUNK_OUTPUT + "_"
    m.graph.node.append(helper.make_node("DequantizeLinear", [q + "quantized", q + "scale", q + "zero_point"], ["b14"]))
    m.graph.output.append(helper.make_tensor_value_info("b14", onnx.TensorProto.FLOAT, None))
    return m


def trunk_session(base: Path, threads: int):
    """ONNX Runtime session of ``base`` with the block-14 activations as a second, dequantised output."""
    import onnxruntime as ort

    m = with_trunk_output(base)
    so = ort.SessionOptions()
    so.intra_op_num_threads = threads
    return ort.InferenceSession(m.SerializeToString(), so, providers=["CPUExecutionProvider"])


def trunk_features(session, crops: list[np.ndarray]) -> np.ndarray:
    """Block-14 activations (float16) of crops squashed as the RSU feeds them."""
    from rsu.classify.classifiers import cnn_input

    out = [session.run(["b14"], {"crops": cnn_input(crops[i:i + 64], SIZE)})[0].astype(np.float16)
           for i in range(0, len(crops), 64)]
    return np.concatenate(out) if out else np.zeros((0, 192, 7, 7), np.float16)


def make_top(base: Path, dropout: float = 0.2):
    """The student's top as a float32 PyTorch module, its weights dequantised from ``base``'s int8 graph
    (per-channel weight scales, int32 biases at input scale x weight scale)."""
    import onnx
    import torch
    from onnx import numpy_helper

    m = onnx.load(str(base))
    init = {i.name: numpy_helper.to_array(i) for i in m.graph.initializer}
    convs = [n for n in m.graph.node if n.op_type == "QLinearConv"][-TOP_CONVS:]
    gemm = [n for n in m.graph.node if n.op_type == "QGemm"]
    if len(convs) != TOP_CONVS or len(gemm) != 1:
        raise SystemExit(f"{base} is not an int8 EV-body student from models.train_ev_body (QLinearConv / QGemm top)")

    def dequantised(n, in_scale: str, w: int, bias: int) -> tuple[np.ndarray, np.ndarray]:
        q, scale, zero = (init[n.input[w + k]] for k in range(3))
        shape = (-1,) + (1,) * (q.ndim - 1)
        wf = (q.astype(np.float32) - zero.astype(np.float32).reshape(shape)) * scale.reshape(shape)
        return wf, init[n.input[bias]].astype(np.float32) * init[in_scale] * scale

    class Top(torch.nn.Module):
        """Block 15 (expand 192 -> 1152, ReLU6, depthwise 3 x 3, ReLU6, project -> 320), head 320 -> 1280, ReLU6,
        mean pool, dropout, EV logit."""

        def __init__(self) -> None:
            super().__init__()
            self.expand = torch.nn.Conv2d(192, 1152, 1)
            self.depthwise = torch.nn.Conv2d(1152, 1152, 3, padding=1, groups=1152)
            self.project = torch.nn.Conv2d(1152, 320, 1)
            self.head = torch.nn.Conv2d(320, 1280, 1)
            self.drop = torch.nn.Dropout(dropout)
            self.fc = torch.nn.Linear(1280, 1)

        def logits(self, x):
            x = torch.clamp(self.depthwise(torch.clamp(self.expand(x), 0.0, 6.0)), 0.0, 6.0)
            x = torch.clamp(self.head(self.project(x)), 0.0, 6.0)
            return self.fc(self.drop(x.mean(dim=(2, 3)))).view(-1)

        def forward(self, x):
            return torch.sigmoid(self.logits(x)).view(-1, 1)

    top = Top()
    with torch.no_grad():
        for layer, n in zip((top.expand, top.depthwise, top.project, top.head), convs, strict=True):
            w, b = dequantised(n, n.input[1], 3, 8)
            layer.weight.copy_(torch.from_numpy(w))
            layer.bias.copy_(torch.from_numpy(b))
        g = gemm[0]
        w, _ = dequantised(g, g.input[1], 3, 6)
        top.fc.weight.copy_(torch.from_numpy(w.reshape(1, -1)))
        top.fc.bias.copy_(torch.from_numpy(
            (init[g.input[6]].astype(np.float32) * init[g.input[1]] * init[g.input[4]]).reshape(1)))
    return top


def top_scores(top, x: np.ndarray) -> np.ndarray:
    import torch

    top.eval()
    with torch.no_grad():
        return np.concatenate([top(torch.from_numpy(x[i:i + 256].astype(np.float32))).numpy().ravel()
                               for i in range(0, len(x), 256)]) if len(x) else np.zeros(0)


def train_top(top, x: np.ndarray, y: np.ndarray, x_val: np.ndarray, y_val: np.ndarray, epochs: int, lr: float,
              seed: int, log=print) -> dict:
    """AdamW, one cycle, BCE weighted to balance the classes; the weights of the epoch with the best min(P, R)
    on (``x_val``, ``y_val``) at its own best threshold are kept (ties: the later epoch)."""
    import copy

    import torch

    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    pos_weight = torch.tensor(float((y == 0).sum()) / max(float((y == 1).sum()), 1.0))
    opt = torch.optim.AdamW(top.parameters(), lr=lr, weight_decay=1e-3)
    batches = int(np.ceil(len(x) / 128))
    sched = torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=lr, total_steps=epochs * batches, pct_start=0.2)
    best = {"score": -1.0}
    for epoch in range(epochs):
        top.train()
        t0, total = time.time(), 0.0
        for b in np.array_split(rng.permutation(len(x)), batches):
            loss = torch.nn.functional.binary_cross_entropy_with_logits(
                top.logits(torch.from_numpy(x[b].astype(np.float32))), torch.from_numpy(y[b].astype(np.float32)),
                pos_weight=pos_weight)
            opt.zero_grad()
            loss.backward()
            opt.step()
            sched.step()
            total += loss.item() * len(b)
        p = top_scores(top, x_val)
        t = best_threshold(y_val, p)
        _, prec, rec, _ = metrics(y_val, p, t)
        log(f"epoch {epoch + 1}/{epochs}: loss {total / len(x):.4f}, validation P {prec:.3f} R {rec:.3f} at {t:.2f} "
            f"({time.time() - t0:.0f} s)")
        if min(prec, rec) >= best["score"]:
            best = {"score": min(prec, rec), "epoch": epoch + 1, "state": copy.deepcopy(top.state_dict())}
    top.load_state_dict(best["state"])
    return {"epoch": best["epoch"], "validation_min_pr": round(best["score"], 4)}


def export_merged(base: Path, top, out: Path) -> None:
    """``base``'s int8 trunk up to block 14, dequantised, then ``top`` in float32 arithmetic with its weights stored
    as float16 (:func:`models.train_ev_body.fp16_storage`): one graph, ``crops`` -> ``p_ev``."""
    import onnx
    import torch
    from onnx import compose
    from onnx.utils import Extractor

    m = with_trunk_output(base)
    trunk = Extractor(m).extract_model(["crops"], ["b14"])
    opset = next(o.version for o in m.opset_import if o.domain in ("", "ai.onnx"))
    top.eval()
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "top.onnx"
        torch.onnx.export(top, torch.zeros(1, 192, 7, 7), str(path), input_names=["b14"], output_names=["p_ev"],
                          dynamic_axes={"b14": {0: "n"}, "p_ev": {0: "n"}}, opset_version=opset, dynamo=False)
        fp16_storage(path, path)
        head = onnx.load(str(path))
    head.ir_version = trunk.ir_version
    merged = compose.merge_models(trunk, compose.add_prefix(head, "top/", rename_inputs=False, rename_outputs=False),
                                  io_map=[("b14", "b14")])
    onnx.checker.check_model(merged)
    onnx.save(merged, str(out))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--base", required=True, help="an int8 EV-body student exported by models.train_ev_body")
    ap.add_argument("--out", required=True, help="where to write the fine-tuned model (may be --base)")
    ap.add_argument("--data", default=str(DEFAULT_DATA), help="the ev_train folder")
    ap.add_argument("--epochs", type=int, default=3)
    ap.add_argument("--lr", type=float, default=5e-5)
    ap.add_argument("--views", type=int, default=6, help="views per training crop: itself, mirrored, and augmented")
    ap.add_argument("--negative-clips", nargs="*", default=list(TUNING_TRAFFIC_CLIPS),
                    help="traffic clips (no EV) whose vehicles train as non-EVs; none: leave them out")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    if args.epochs < 1 or args.views < 1 or args.lr <= 0:
        raise SystemExit("--epochs and --views must be at least 1 and --lr positive")
    base, out = Path(args.base), Path(args.out)
    for need in (base, Path(args.data), REAL / "lights_on_off", REAL / "yolox_nano" / "yolox_nano.onnx"):
        if not need.exists():
            raise SystemExit(f"{need} is missing: this needs the int8 student and ../shared/data/real")
    import torch

    from models.ev_body_net import augment
    from rsu.build import PipelineConfig, build_detector
    from rsu.classify.evaluation import load_scene_crops
    from rsu.classify.real_data import load_ev_train, split_by_group

    torch.set_num_threads(args.threads)
    t_start = time.time()

    def log(msg: str) -> None:
        print(f"[{time.time() - t_start:5.0f} s] {msg}", flush=True)

    detector = build_detector(PipelineConfig(detector=str(REAL / "yolox_nano" / "yolox_nano.onnx")))
    split = split_by_group(load_ev_train(args.data))
    pairs = {k: usable_crops(split[k], log=lambda *_: None) for k in ("train", "val", "test")}
    crops = {k: [c for _s, c in v] for k, v in pairs.items()}
    labels = {k: np.array([s.label for s, _c in v], np.float32) for k, v in pairs.items()}
    photos, labels["photos"] = load_scene_crops(REAL / "ev_images", detector, above_fraction=ABOVE_FRACTION)
    police, names = police_crops(detector)
    hashes = np.array([difference_hash(c) for c in police])
    photo_hashes = np.array([difference_hash(c) for c in photos if c is not None])
    val_mask = np.array([is_validation_photo(n) for n in names])
    leak = near_duplicates(hashes, photo_hashes) | (~val_mask & near_duplicates(hashes, hashes[val_mask]))
    police_train = [c for c, v, bad in zip(police, val_mask, leak, strict=True) if not v and not bad]
    police_val = [c for c, v, bad in zip(police, val_mask, leak, strict=True) if v and not bad]
    negatives = clip_negatives(detector, args.negative_clips) if args.negative_clips else []
    log(f"ev_train: train {len(crops['train'])}, val {len(crops['val'])}, test {len(crops['test'])}; police "
        f"{len(police)} ({len(police_train)} train, {len(police_val)} validation, {int(leak.sum())} left out as "
        f"near-duplicates); {len(negatives)} traffic-clip vehicles")

    session = trunk_session(base, args.threads)
    rng = np.random.default_rng(args.seed)
    sources = [(crops["train"], labels["train"]), (police_train, np.ones(len(police_train), np.float32)),
               (negatives, np.zeros(len(negatives), np.float32))]
    xs, ys = [], []
    for view in range(args.views):
        for cs, y in sources:
            if view == 1:
                cs = [c[:, ::-1] for c in cs]
            elif view > 1:
                cs = [(augment(c, rng, SIZE) * 255.0).astype(np.uint8) for c in cs]
            xs.append(trunk_features(session, list(cs)))
            ys.append(y)
        log(f"block-14 activations, view {view + 1}/{args.views}")
    x, y = np.concatenate(xs), np.concatenate(ys)
    x_val = np.concatenate([trunk_features(session, crops["val"]), trunk_features(session, police_val)])
    y_val = np.concatenate([labels["val"], np.ones(len(police_val), np.float32)])

    top = make_top(base)
    chosen = train_top(top, x, y, x_val, y_val, args.epochs, args.lr, args.seed, log=log)
    export_merged(base, top, out)

    from rsu.classify.classifiers import CnnClassifier

    model = CnnClassifier(out, threads=None)  # the exported file, as the runtime loads it

    def run(cs):
        return np.concatenate([model.predict(cs[i:i + 64]) for i in range(0, len(cs), 64)])

    p_val = run(crops["val"])
    p_choice = np.concatenate([p_val, run(police_val)])
    thr = best_threshold(y_val, p_choice)
    confident = confident_threshold(labels["val"], p_val)
    negatives_val = p_val[labels["val"] == 0]
    sure = float(np.ceil((negatives_val.max() + 1e-6) * 100) / 100) if len(negatives_val) else 0.5
    p_photos = np.array([0.0 if c is None else float(model.predict([c])[0]) for c in photos])
    report = {"chosen": chosen, "threshold": thr, "confident_threshold": confident, "sure_threshold": sure}
    for k, (yy, pp) in {"validation": (y_val, p_choice), "val": (labels["val"], p_val),
                        "test": (labels["test"], run(crops["test"])), "photos": (labels["photos"], p_photos)}.items():
        acc, prec, rec, f = metrics(yy, pp, thr)
        report[k] = {"n": len(yy), "ev": int(yy.sum()), "accuracy": acc, "precision": prec, "recall": rec, "f": f}
    set_metadata(out, {"ev_threshold": f"{thr:.2f}", "confident_threshold": f"{confident:.2f}",
                       "sure_threshold": f"{sure:.2f}", "above_fraction": f"{ABOVE_FRACTION}",
                       "trained_on": "ev_train split seed 17 (train 70 %); top: + lights_on_off police (number % 5 != 0)"
                                     + (f", + vehicles of {' '.join(args.negative_clips)} as non-EVs"
                                        if args.negative_clips else "")})
    log(json.dumps(report))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
