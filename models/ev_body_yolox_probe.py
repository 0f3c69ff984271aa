"""Probe: the COCO YOLOX-Nano's features as an EV-body classifier's input, against the shipped model.

    python -m models.ev_body_yolox_probe [--data ../shared/data/real/ev_train] [--yolox YOLOX.onnx] [--threads 2]

Two pretrained backbones are available offline: ImageNet EfficientNet-Lite (what ``models/ev_body.onnx``
is fine-tuned from, and what ``models.ev_body_teacher`` probes frozen) and the COCO YOLOX-Nano the RSU already runs
on real cameras. This probes the second, frozen: each RSU-style crop (``models.train_ev_body.usable_crops``, the label
review applied), squashed to the detector's 416 x 416 input, gives its three PAFPN outputs (64 x 52 x 52,
128 x 26 x 26, 256 x 13 x 13: what YOLOX's heads read) average- and max-pooled (896 numbers), for the crop and its
mirror image. A logistic regression (standardised, balanced classes, C in ``--c``) is fitted on ``train``, alone and
with the shipped body model's logit beside the features, and scored on ``val`` and ``test`` at its ``val`` threshold
of best min(precision, recall) (``models.train_ev_body.best_threshold``); the shipped model alone is scored the same
way. Nothing is written or shipped: it prints one line per fit.

Needs scikit-learn (the ``train`` extra) and ``../shared/data/real`` (``ev_train`` and ``yolox_nano``).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from models.train_ev_body import DEFAULT_DATA, best_threshold, usable_crops  # noqa: E402
from rsu.classify.body import DEFAULT_BODY_MODEL, EvBodyClassifier  # noqa: E402
from rsu.classify.evaluation import metrics  # noqa: E402
from rsu.classify.real_data import load_ev_train, split_by_group  # noqa: E402
from rsu.scan import DEFAULT_DETECTOR  # noqa: E402

PAFPN_OUTPUTS = ("956", "990", "1024")
"""The tensor names of YOLOX-Nano's three PAFPN outputs in ``yolox_nano.onnx`` (stride 8, 16, 32: 64, 128 and 256
channels), the inputs of its detection heads."""
INPUT_PX = 416


def pafpn_session(model: str | Path, threads: int = 2):
    """An onnxruntime session of the YOLOX graph with its PAFPN outputs added as graph outputs."""
    import onnx
    import onnxruntime as ort

    graph = onnx.load(str(model))
    known = {o for n in graph.graph.node for o in n.output}
    missing = [name for name in PAFPN_OUTPUTS if name not in known]
    if missing:
        raise ValueError(f"{model}: no tensors {missing} (PAFPN_OUTPUTS name those of the shared yolox_nano.onnx)")
    graph.graph.output.extend(onnx.helper.make_tensor_value_info(n, onnx.TensorProto.FLOAT, None)
                              for n in PAFPN_OUTPUTS)
    so = ort.SessionOptions()
    so.intra_op_num_threads = threads
    return ort.InferenceSession(graph.SerializeToString(), so, providers=["CPUExecutionProvider"])


def pafpn_features(session, crop_bgr: np.ndarray) -> np.ndarray:
    """The crop squashed to the detector's input (BGR, raw 0-255, as ``rsu.detect`` feeds it), its PAFPN outputs
    average- and max-pooled: a float32 vector of 2 x (64 + 128 + 256) = 896."""
    x = cv2.resize(crop_bgr, (INPUT_PX, INPUT_PX), interpolation=cv2.INTER_AREA).transpose(2, 0, 1)[None]
    maps = session.run(list(PAFPN_OUTPUTS), {"images": x.astype(np.float32)})
    return np.concatenate([np.concatenate([m[0].mean(axis=(1, 2)), m[0].max(axis=(1, 2))]) for m in maps])


def _logit(p: np.ndarray) -> np.ndarray:
    p = np.clip(p, 1e-4, 1 - 1e-4)
    return np.log(p / (1 - p))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", default=str(DEFAULT_DATA), help="the ev_train folder")
    ap.add_argument("--yolox", default=str(DEFAULT_DETECTOR), help="the COCO YOLOX-Nano ONNX file")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--c", type=float, nargs="+", default=[0.01, 0.03, 0.1], help="logistic regression C values")
    args = ap.parse_args(argv)
    try:
        from sklearn.linear_model import LogisticRegression
    except ImportError:
        raise SystemExit("scikit-learn is needed (the train extra): pip install -e .[train]") from None
    if not Path(args.yolox).is_file():
        raise SystemExit(f"{args.yolox} not found (../shared/data/real beside the repository?)")
    session = pafpn_session(args.yolox, args.threads)
    body = EvBodyClassifier(DEFAULT_BODY_MODEL, threads=args.threads)
    split = split_by_group(load_ev_train(args.data))
    data = {}
    for part in ("train", "val", "test"):
        t0 = time.time()
        pairs = usable_crops(split[part], log=lambda *_: None)
        crops = [c for _s, c in pairs]
        feats = np.stack([np.stack([pafpn_features(session, c) for c in crops]),
                          np.stack([pafpn_features(session, np.ascontiguousarray(c[:, ::-1])) for c in crops])])
        scores = np.concatenate([body.predict(crops[i:i + 32]) for i in range(0, len(crops), 32)])
        data[part] = (np.array([s.label for s, _c in pairs], float), feats, scores)
        print(f"{part}: {len(crops)} crops ({int(data[part][0].sum())} EV), features in {time.time() - t0:.0f} s",
              flush=True)

    def show(name: str, p_val: np.ndarray, p_test: np.ndarray) -> None:
        t = best_threshold(data["val"][0], p_val)
        row = "; ".join(f"{k} P {m[1]:.3f} R {m[2]:.3f} F {m[3]:.3f}" for k, m in
                        (("val", metrics(data["val"][0], p_val, t)), ("test", metrics(data["test"][0], p_test, t))))
        print(f"{name}: threshold {t:.2f}; {row}", flush=True)

    show("shipped body model alone", data["val"][2], data["test"][2])
    y_train, f_train, s_train = data["train"]
    for with_body in (False, True):
        def x_of(feats: np.ndarray, scores: np.ndarray, w: bool = with_body) -> np.ndarray:
            return np.column_stack([feats, _logit(scores)]) if w else feats

        x = np.concatenate([x_of(f_train[0], s_train), x_of(f_train[1], s_train)])
        mu, sd = x.mean(0), x.std(0) + 1e-6
        for c in args.c:
            lr = LogisticRegression(C=c, max_iter=4000, class_weight="balanced").fit(
                (x - mu) / sd, np.concatenate([y_train, y_train]))
            p = {k: 0.5 * sum(lr.predict_proba((x_of(data[k][1][m], data[k][2]) - mu) / sd)[:, 1] for m in (0, 1))
                 for k in ("val", "test")}
            show(f"YOLOX PAFPN features{' + body logit' if with_body else ''}, C {c}", p["val"], p["test"])
    return 0


if __name__ == "__main__":
    sys.exit(main())
