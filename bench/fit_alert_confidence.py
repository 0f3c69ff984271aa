"""Fit ``EvAlert.confidence`` (rsu.classify.confidence) on the tuning clips' alerts; read its calibration on the held-out.

    python bench/ev_real_bench.py --clips-only --json > run.txt
    python bench/fit_alert_confidence.py run.txt [--l2 1.0] [--json]

Reads the last JSON line of an ``ev_real_bench.py`` run (its ``per_clip[*].alert_rows``: each alert onset with its
cues, body score, box width, the confidence the RSU gave it and whether its track was on a labelled EV), fits the
logistic model on the alerts of :data:`bench.ev_real_bench.TUNE_CLIPS` and prints the weights to put in
``rsu.classify.confidence.DEFAULT_MODEL``, then the expected calibration error of the fitted model and of the
confidence the run's RSU gave, on the tuning and on the held-out alerts, and the alerts right and wrong by the box
width at onset (what a size floor would keep and drop). Ends with one JSON line with ``--json``.
"""

from __future__ import annotations

from bench._setup import ROOT  # noqa: F401  first: one thread per numeric library, before numpy loads

# isort: split
import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from bench.ev_real_bench import HELD_OUT_CLIPS, TUNE_CLIPS  # noqa: E402
from rsu.classify.confidence import (  # noqa: E402
    ConfidenceModel,
    alert_features,
    expected_calibration_error,
    fit_logistic,
)

L2_CHOICES = (0.1, 0.3, 1.0, 3.0, 10.0)


def rows_of(run: dict, clips: tuple[str, ...]) -> list[dict]:
    return [dict(a, clip=c["clip"]) for c in run["per_clip"] if Path(c["clip"]).stem in clips
            for a in c.get("alert_rows", []) if a["width_px"] is not None]


def leave_one_clip_out_loss(x: np.ndarray, y: np.ndarray, clips: np.ndarray, l2: float) -> float:
    """Mean log loss of each tuning clip's alerts under the model fitted on the other tuning clips."""
    losses = []
    for c in sorted(set(clips)):
        held = clips == c
        if held.all():
            continue
        model = ConfidenceModel(fit_logistic(x[~held], y[~held], l2=l2))
        for f, t in zip(x[held], y[held], strict=True):
            p = min(max(model(f), 1e-6), 1 - 1e-6)
            losses.append(-np.log(p if t else 1 - p))
    return float(np.mean(losses)) if losses else float("inf")


WIDTH_BINS_PX = (0, 40, 60, 80, 120, 200, 10_000)


def width_table(rows: list[dict]) -> dict:
    """Alerts right and wrong by the alerted box's width at onset: where the size floor would separate them."""
    out = {}
    for lo, hi in zip(WIDTH_BINS_PX, WIDTH_BINS_PX[1:], strict=False):
        sel = [r for r in rows if lo <= r["width_px"] < hi]
        out[f"{lo}-{hi}"] = dict(right=sum(r["right"] for r in sel), wrong=sum(not r["right"] for r in sel))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("run", type=Path, help="output of bench/ev_real_bench.py --json (its last line is read)")
    ap.add_argument("--l2", type=float, default=None,
                    help="L2 penalty on the weights (not the intercept); default: the one of L2_CHOICES with the least "
                         "leave-one-clip-out log loss on the tuning clips")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    try:
        run = json.loads(args.run.read_text().strip().splitlines()[-1])
    except (OSError, ValueError, IndexError) as exc:
        print(f"fit_alert_confidence: cannot read a bench run from {args.run}: {exc}", file=sys.stderr)
        return 2
    tune, held = rows_of(run, TUNE_CLIPS), rows_of(run, HELD_OUT_CLIPS)
    if not tune:
        print("fit_alert_confidence: no alert on the tuning clips in that run: nothing to fit", file=sys.stderr)
        return 2

    def xy(rows):
        x = np.array([alert_features(r["cues"], r["body_score"], r["width_px"]) for r in rows]).reshape(len(rows), -1)
        return x, np.array([int(r["right"]) for r in rows])

    x, y = xy(tune)
    clip_of = np.array([r["clip"] for r in tune])
    loco = {l2: leave_one_clip_out_loss(x, y, clip_of, l2) for l2 in L2_CHOICES}
    l2 = args.l2 if args.l2 is not None else min(loco, key=loco.get)
    weights = fit_logistic(x, y, l2=l2)
    model = ConfidenceModel(weights)
    out = dict(weights=list(weights), l2=l2, loco_log_loss={str(k): round(v, 4) for k, v in loco.items()},
               tune_alerts=len(tune), tune_right=int(y.sum()), held_out_alerts=len(held),
               held_out_right=sum(int(r["right"]) for r in held))
    for name, rows in (("tune", tune), ("held_out", held)):
        if not rows:
            out[f"{name}_ece_fitted"] = out[f"{name}_ece_run"] = None
            continue
        xs, ys = xy(rows)
        out[f"{name}_ece_fitted"] = expected_calibration_error([model(f) for f in xs], ys)
        run_conf = [r["confidence"] for r in rows]
        out[f"{name}_ece_run"] = (None if any(c is None for c in run_conf)
                                  else expected_calibration_error(run_conf, ys))
    out["by_width_px"] = width_table(tune + held)
    print("alerts by box width at onset (all clips): " + ", ".join(
        f"{b}: {v['right']} right / {v['wrong']} wrong" for b, v in out["by_width_px"].items()))
    print(f"leave-one-clip-out log loss on the tuning clips by L2: {out['loco_log_loss']}; L2 {l2}")
    print(f"fitted on {len(tune)} tuning alerts ({out['tune_right']} right): weights {weights}")
    for name in ("tune", "held_out"):
        print(f"  {name}: ECE fitted {out[f'{name}_ece_fitted']}, ECE of the run's confidence {out[f'{name}_ece_run']}")
    if args.json:
        print(json.dumps(out))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
