"""Train the EV feature classifier (thesis 2.4.2.1): gradient boosting on the 8-element HSV feature,
exported to ONNX with skl2onnx so that the RSU runs it with onnxruntime.

    python -m models.train_ev_features --data datasets/det_train/cls --out models/ev_hsv8_gb.onnx

The exported graph takes ``features`` ``[N, 8]`` float32 (``rsu.classify.features.hsv_custom``) and
returns ``label`` and ``probabilities`` ``[N, 2]`` (column 1 = EV); it is loaded by
:class:`rsu.classify.classifiers.FeatureClassifier`. Needs scikit-learn and skl2onnx (the ``train``
extra). Seeded.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from rsu.classify.evaluation import metrics
from rsu.classify.features import FEATURES, extract_batch
from rsu.classify.ravev import load_split


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", required=True, help="RAVEV-layout folder (train/val/{ev,non_ev})")
    ap.add_argument("--out", default="models/ev_hsv8_gb.onnx")
    ap.add_argument("--feature", default="hsv8", choices=sorted(FEATURES))
    ap.add_argument("--trees", type=int, default=150)
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args(argv)
    from skl2onnx import to_onnx
    from sklearn.ensemble import GradientBoostingClassifier

    t0 = time.perf_counter()
    crops, y = load_split(a.data, "train")
    val, y_val = load_split(a.data, "val")
    x = extract_batch(a.feature, crops).astype(np.float32)
    x_val = extract_batch(a.feature, val).astype(np.float32)
    # balance the classes by sample weight (EV crops are a few % of the export)
    w = np.where(y == 1, (y == 0).sum() / max((y == 1).sum(), 1), 1.0)
    model = GradientBoostingClassifier(n_estimators=a.trees, max_depth=3, learning_rate=0.1, subsample=0.8,
                                       random_state=a.seed)
    model.fit(x, y, sample_weight=w)
    acc, p, r, f = metrics(y_val, model.predict_proba(x_val)[:, 1])
    print(f"{a.feature} + gradient boosting: val acc {acc:.4f} P {p:.4f} R {r:.4f} F {f:.4f} "
          f"({len(val)} crops, {int(y_val.sum())} EV)")
    onx = to_onnx(model, x[:1], options={id(model): {"zipmap": False}}, target_opset={"": 17, "ai.onnx.ml": 3},
                  initial_types=None)
    onx.graph.input[0].name = "features" if onx.graph.input[0].name == "X" else onx.graph.input[0].name
    for node in onx.graph.node:
        node.input[:] = ["features" if i == "X" else i for i in node.input]
    out = Path(a.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_bytes(onx.SerializeToString())
    print(f"wrote {out} ({out.stat().st_size / 1024:.0f} KB) in {time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
