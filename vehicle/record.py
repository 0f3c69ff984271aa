"""Run folders: ``run.npz`` (columns + reference paths), ``run.csv`` (columns) and ``meta.json``.

Written by the lockstep runner (tests, bench) and by the service (``--record DIR``); read by
``iea-vehicle plot RUN``.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from vehicle.lockstep import RECORD_FIELDS, RunRecord


def _jsonable(value):
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value


def write_run(run_dir: str | Path, record: RunRecord) -> Path:
    out = Path(run_dir)
    out.mkdir(parents=True, exist_ok=True)
    cols = record.columns()
    arrays = {name: cols[name] for name in RECORD_FIELDS}
    for version, pts in record.paths.items():
        arrays[f"refpath_{version}"] = np.asarray(pts, dtype=float)
    np.savez_compressed(out / "run.npz", **arrays)
    table = np.column_stack([cols[n] for n in RECORD_FIELDS]) if len(record.rows) else np.zeros((0, len(RECORD_FIELDS)))
    np.savetxt(out / "run.csv", table, delimiter=",", header=",".join(RECORD_FIELDS), comments="", fmt="%.6g")
    meta = dict(record.meta)
    meta["columns"] = list(RECORD_FIELDS)
    meta["paths"] = sorted(int(v) for v in record.paths)
    (out / "meta.json").write_text(json.dumps(_jsonable(meta), indent=2))
    return out


def read_run(run_dir: str | Path) -> tuple[dict[str, np.ndarray], dict[int, np.ndarray], dict]:
    """(columns, reference paths by version, metadata) of a run folder."""
    d = Path(run_dir)
    npz, meta_file = d / "run.npz", d / "meta.json"
    if not npz.is_file() or not meta_file.is_file():
        raise FileNotFoundError(f"{d} is not a run folder (needs run.npz and meta.json)")
    meta = json.loads(meta_file.read_text())
    with np.load(npz) as z:
        cols = {n: z[n] for n in RECORD_FIELDS if n in z}
        paths = {int(k.split("_", 1)[1]): z[k] for k in z.files if k.startswith("refpath_")}
    missing = [n for n in RECORD_FIELDS if n not in cols]
    if missing:
        raise ValueError(f"{npz}: missing columns {missing}")
    return cols, paths, meta
