"""``Detections``: one camera frame's vehicles as one table that every stage of the RSU pipeline adds columns to.

A struct of arrays with N rows, one per vehicle, in the manner of supervision's ``Detections``:

=============  ==========================================================================================
stage          columns it fills
=============  ==========================================================================================
detector       ``boxes`` (N, 4) xyxy pixels, ``scores`` (N,), ``class_ids`` (N,) (0 vehicle, 1 EV)
tracker        keeps the rows it reports (its filtered ``boxes``; the matched detection's ``scores`` and
               ``class_ids``) and adds ``track_ids``, ``det_indices``, ``hits``, ``age_frames``,
               ``velocity_px``
EV classifier  ``ev_scores``, ``light_states``, ``ev_states`` (the verdict), ``evidence`` (each track's
               evidence record)
localiser      ``localized`` (the row has a trusted ground point), ``positions_m``, ``latlon_deg``,
               ``velocities_mps``, ``speeds_mps``, ``headings_rad``, ``pos_cov_m2``, ``lanes``,
               ``ages_s``
=============  ==========================================================================================

A column a stage has not filled is None. Indexing (``table[mask]``, ``table[indices]``, ``table[k:l]``) keeps
every filled column; ``with_columns`` adds columns, checked for length. ``rsu.wire`` turns a table into wire
messages.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

OBJECT_COLUMNS = ("ev_states", "light_states", "evidence", "lanes")
"""Columns of Python objects (enums, evidence records, optional lane numbers): numpy arrays of dtype object."""


@dataclass(slots=True)
class Detections:
    """One frame's vehicles, N rows; see the module docstring for which stage fills which column."""

    boxes: np.ndarray
    """(N, 4) float xyxy pixels of the frame."""
    scores: np.ndarray
    """(N,) float in [0, 1]: the detector's confidence (of the detection a track matched on this frame)."""
    class_ids: np.ndarray
    """(N,) int64 project classes: 0 vehicle, 1 EV (``rsu.detect``)."""
    track_ids: np.ndarray | None = None
    """(N,) int64, from 1."""
    det_indices: np.ndarray | None = None
    """(N,) int64: the row of the frame's detections that the track matched on this frame."""
    hits: np.ndarray | None = None
    """(N,) int64: updates of the track so far."""
    age_frames: np.ndarray | None = None
    """(N,) int64: predictions since the track was born."""
    velocity_px: np.ndarray | None = None
    """(N, 2) float: the tracker's centre velocity (u', v') in pixels per frame."""
    ev_scores: np.ndarray | None = None
    """(N,) float in [0, 1]: the EV evidence of the track."""
    light_states: np.ndarray | None = None
    """(N,) object: ``LightState`` or None (unknown)."""
    ev_states: np.ndarray | None = None
    """(N,) object: ``EvState``: the verdict, ``CONFIRMED`` for an EV."""
    evidence: np.ndarray | None = None
    """(N,) object: the classifier's evidence record of the track (``rsu.classify.ev.TrackInfo``) or None."""
    localized: np.ndarray | None = None
    """(N,) bool: the localiser trusted the row's ground point; the world columns hold NaN where it did not."""
    positions_m: np.ndarray | None = None
    """(N, 2) float: vehicle centre x, y in the corridor frame (m)."""
    latlon_deg: np.ndarray | None = None
    """(N, 2) float: WGS84 latitude, longitude of the position."""
    velocities_mps: np.ndarray | None = None
    """(N, 2) float: world velocity vx, vy (m/s)."""
    speeds_mps: np.ndarray | None = None
    """(N,) float (m/s)."""
    headings_rad: np.ndarray | None = None
    """(N,) float: heading from +x, counter-clockwise, wrapped to [-pi, pi)."""
    pos_cov_m2: np.ndarray | None = None
    """(N, 3) float: position covariance (xx, xy, yy) in m^2."""
    lanes: np.ndarray | None = None
    """(N,) object: lane number (0 = rightmost) or None off the lanes."""
    ages_s: np.ndarray | None = None
    """(N,) float: time since the localiser first placed the track (s)."""

    def __len__(self) -> int:
        return len(self.boxes)

    def __getitem__(self, index: int | slice | np.ndarray | list[int]) -> Detections:
        """The rows ``index`` selects (a boolean mask, indices, a slice or one row), every filled column kept."""
        if isinstance(index, (int, np.integer)):
            index = [int(index)]
        return Detections(**{f: None if (v := getattr(self, f)) is None else v[index] for f in _FIELDS})

    def with_columns(self, **columns: np.ndarray) -> Detections:
        """A table with ``columns`` added or replaced; each must have one entry per row."""
        n = len(self)
        for name, value in columns.items():
            if name not in _FIELDS:
                raise ValueError(f"Detections has no column {name!r}; columns: {', '.join(_FIELDS)}")
            if value is not None and len(value) != n:
                raise ValueError(f"column {name!r} has {len(value)} rows, the table {n}")
        return dataclasses.replace(self, **columns)

    def column(self, name: str) -> np.ndarray:
        """A filled column; ValueError naming the stage that fills it when it is not."""
        value = getattr(self, name)
        if value is None:
            raise ValueError(f"column {name!r} is not filled yet: see rsu.perception for the stage that adds it")
        return value

    @staticmethod
    def empty() -> Detections:
        """No rows: a detector's answer for an empty frame."""
        return Detections(np.zeros((0, 4), np.float32), np.zeros(0, np.float32), np.zeros(0, np.int64))

    @staticmethod
    def concatenate(parts: list[Detections]) -> Detections:
        """The rows of ``parts`` in order; a column is kept when every part has it filled."""
        if not parts:
            return Detections.empty()
        out = {}
        for f in _FIELDS:
            values = [getattr(p, f) for p in parts]
            out[f] = None if any(v is None for v in values) else np.concatenate(values)
        return Detections(**out)


_FIELDS = tuple(f.name for f in dataclasses.fields(Detections))


def object_column(values: list) -> np.ndarray:
    """A column of Python objects (enums, records, optional ints) of ``len(values)`` rows."""
    out = np.empty(len(values), dtype=object)
    out[:] = values
    return out
