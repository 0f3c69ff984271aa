"""Run records and run folders: ``RunRecord`` (one row per control step: truth, estimate, errors against the
active path, commands; filled by ``record_step``) and its folder ``run.npz`` (columns + reference paths),
``run.csv`` (columns) and ``meta.json``.

Recorded and written by the lockstep runner (tests, bench) and by the service (``--record DIR``); read by
``iea-vehicle plot RUN``.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from protocol.enums import VehicleMode

if TYPE_CHECKING:
    from vehicle.simulated import SimulatedVehicle

RECORD_FIELDS = (
    "t_s", "x_m", "y_m", "yaw_rad", "speed_mps", "yaw_rate_rps", "steer_rad", "accel_mps2",
    "est_x_m", "est_y_m", "est_yaw_rad", "steer_cmd_rad", "accel_cmd_mps2", "speed_ref_mps",
    "lateral_error_m", "yaw_error_rad", "yaw_rate_error_rps",
    "est_lateral_error_m", "est_yaw_error_rad", "est_yaw_rate_error_rps",
    "curvature_1pm", "path_s_m", "mode", "path_version",
)
MODE_CODES = {m: i for i, m in enumerate(VehicleMode)}


@dataclass
class RunRecord:
    """Columns of the run (one row per control step) plus paths and events."""

    rows: list[tuple] = field(default_factory=list)
    paths: dict[int, np.ndarray] = field(default_factory=dict)
    """Reference points by path version."""
    events: list[dict] = field(default_factory=list)
    meta: dict = field(default_factory=dict)

    def columns(self) -> dict[str, np.ndarray]:
        arr = np.asarray(self.rows, dtype=float).reshape(-1, len(RECORD_FIELDS))
        return {name: arr[:, i] for i, name in enumerate(RECORD_FIELDS)}


def record_step(rec: RunRecord, sim: SimulatedVehicle, out, now_s: float) -> None:
    st, core = sim.truth, sim.core
    e, ye, yre, _ = sim.true_errors()
    lat, lon = out.lateral, out.longitudinal
    ex, ey, eyaw = core.estimator.pose
    if core.path_version not in rec.paths and core.path is not None:
        rec.paths[core.path_version] = core.path.points
    rec.rows.append((now_s, st.x_m, st.y_m, st.yaw_rad, st.vx_mps, st.yaw_rate_rps, st.steer_rad, st.accel_mps2,
                     ex, ey, eyaw, out.steer_cmd_rad, out.accel_cmd_mps2, lon.speed_ref_mps,
                     e, ye, yre, lat.lateral_error_m, lat.yaw_error_rad, lat.yaw_rate_error_rps,
                     lat.curvature_1pm, lat.s_m, MODE_CODES[out.mode], core.path_version))




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
