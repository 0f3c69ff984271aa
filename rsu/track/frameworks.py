"""The thesis's two tracking frameworks over ``rsu.track.sort.SortTracker`` (thesis 2.2, 2.3; docs/architecture.md §Tracking).

``"B"`` (thesis 2.3, deployed) tracks every vehicle in one tracker whatever its class; ``"A"`` (thesis 2.2) runs
one tracker per detector class with a shared id counter, so a detection whose class flips starts a new track, as in
the thesis. Pure core: no I/O, no clock, deterministic.
"""

from __future__ import annotations

import itertools

import numpy as np

from rsu.perception import Detections
from rsu.track.sort import SortTracker, no_tracks

FRAMEWORKS = ("A", "B")


class FrameworkTracker:
    """Tracking per thesis framework: ``"B"`` one class-agnostic SORT; ``"A"`` one SORT per class.

    Ids are unique across the per-class trackers of framework A (one shared counter).
    """

    def __init__(self, framework: str = "B", max_age: int = 1, min_hits: int = 3,
                 iou_threshold: float = 0.3) -> None:
        if framework not in FRAMEWORKS:
            raise ValueError(f"framework must be one of {FRAMEWORKS}, got {framework!r}")
        self.framework = framework
        self._params = (max_age, min_hits, iou_threshold)
        self._ids = itertools.count(1)
        self.trackers: dict[int, SortTracker] = {}
        self._inputs: dict[int, np.ndarray] = {}
        """Framework A: per class, the indices of its detections in the last ``update``'s input."""
        if framework == "B":
            self.trackers[-1] = SortTracker(*self._params, id_source=self._ids)

    def update(self, detections: Detections) -> Detections:
        """The tracks reported on this frame of ``detections`` (``SortTracker.update``): the table's tracked rows,
        with the tracker's columns, detection indices into ``detections``."""
        boxes = np.asarray(detections.boxes, dtype=np.float64).reshape(-1, 4)
        n = len(boxes)
        scores = np.asarray(detections.scores, dtype=np.float64).reshape(n)
        class_ids = np.asarray(detections.class_ids, dtype=np.int64).reshape(n)
        if self.framework == "B":
            return self.trackers[-1].update(boxes, scores, class_ids)
        for c in np.unique(class_ids):
            if int(c) not in self.trackers:
                self.trackers[int(c)] = SortTracker(*self._params, id_source=self._ids)
        parts = []
        for c, trk in sorted(self.trackers.items()):
            sel = self._inputs[c] = np.flatnonzero(class_ids == c)
            parts.append(_with_input_indices(trk.update(boxes[sel], scores[sel], class_ids[sel]), sel))
        return Detections.concatenate(parts) if parts else no_tracks()

    def tentative(self) -> Detections:
        """The tracks the last ``update`` matched but did not report (``SortTracker.tentative``), of every
        per-class tracker; detection indices into that update's input."""
        if self.framework == "B":
            return self.trackers[-1].tentative()
        parts = [_with_input_indices(trk.tentative(), self._inputs.get(c, np.empty(0, np.int64)))
                 for c, trk in sorted(self.trackers.items())]
        return Detections.concatenate(parts) if parts else no_tracks()


def _with_input_indices(tracks: Detections, sel: np.ndarray) -> Detections:
    """``tracks`` of a tracker fed the detections ``sel`` of an input, its detection indices into that input."""
    if not len(tracks):
        return tracks
    return tracks.with_columns(det_indices=sel[tracks.det_indices])
