"""Tracked vehicles are not hazards (see ``rsu.hazard``): :class:`VehicleMask` keeps a memory per track (moved?
stopped?), the regions held for moving, slow and parked vehicles, and says whether a static component lies
inside them."""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from rsu.hazard.config import HazardConfig, ToGround


@dataclass
class _TrackMemory:
    first_uv: tuple[float, float]
    box: np.ndarray
    moved: bool = False
    last_s: float = 0.0
    fast_since_s: float | None = None
    """Since when its localised speed has stayed at least ``moving_speed_mps`` (None: it is not that fast)."""
    history: deque = field(default_factory=deque)
    """(t_s, box) of the last ``stop_window_s``."""

    def stopped(self, cfg: HazardConfig) -> bool:
        """A vehicle that has come to rest: its bottom-centre moved less than ``stop_px`` over the window."""
        if not self.moved or len(self.history) < 2:
            return False
        t1, b1 = self.history[-1]
        b0 = self._box_at(t1 - cfg.stop_check_s)
        if b0 is b1:
            return False
        du = (b1[0] + b1[2] - b0[0] - b0[2]) / 2.0
        dv = b1[3] - b0[3]
        return math.hypot(du, dv) < max(cfg.stop_px, cfg.slow_fraction * (b1[3] - b1[1]))

    def _box_at(self, t_s: float) -> np.ndarray:
        """The box at ``t_s``, interpolated between the samples around it (the oldest one if the history starts
        later): the same displacement over ``stop_check_s`` whatever rate the detector looks at."""
        older = None
        for t, b in self.history:
            if t >= t_s - 1e-9:
                if older is None or t - older[0] < 1e-9:
                    return b
                w = (t_s - older[0]) / (t - older[0])
                return older[1] + w * (b - older[1])
            older = (t, b)
        return self.history[-1][1]

    def hold_box(self, cfg: HazardConfig) -> np.ndarray:
        """Union of the vehicle's boxes over the last ``stop_window_s``, grown by ``vehicle_grow`` of its
        size: a slow or stopped car's uniform body looks static while a background detector's box of it
        shrinks to the pixels that still change."""
        bs = np.array([b for _, b in self.history]) if self.history else self.box[None]
        x1, y1, x2, y2 = bs[:, 0].min(), bs[:, 1].min(), bs[:, 2].max(), bs[:, 3].max()
        gw, gh = cfg.vehicle_grow * (self.box[2] - self.box[0]), cfg.vehicle_grow * (self.box[3] - self.box[1])
        return np.array([x1 - gw, y1 - gh, x2 + gw, y2 + gh])


@dataclass
class _Parked:
    box: np.ndarray
    since_s: float



class VehicleMask:
    """The pixels held for tracked vehicles, at the working scale, updated per frame."""

    def __init__(self, config: HazardConfig, to_ground: ToGround) -> None:
        self.cfg = config
        self.to_ground = to_ground
        self._tracks: dict[int, _TrackMemory] = {}
        self._parked: list[_Parked] = []
        self.hold: np.ndarray | None = None
        """bool mask of the held pixels this frame (None: none)."""
        self._held_ids: list[int] = []
        """The moving tracks of the last frame observed, in its order: their hold boxes are made only when a mask is
        (the detector looks at 2 of 15 frames a second; the track memory is kept on every one)."""

    def observe(self, t_s: float, track_ids, boxes, speeds: dict[int, float] | None) -> None:
        """This frame's tracks (ids, xyxy boxes, localised speeds by id) into the track memory: every frame, also
        those the hazard detector does not look at (a track that lives between two looks still moved)."""
        self._held_ids = self._observe_tracks(t_s, track_ids, boxes, speeds)

    def mask(self, shape: tuple[int, int]) -> np.ndarray | None:
        """The held mask of ``shape`` from the last frame observed."""
        self.hold = self._box_mask(shape, self._held_boxes())
        return self.hold

    def _held_boxes(self) -> list[np.ndarray]:
        """The hold boxes of the last frame's moving tracks, then the parked regions."""
        return [self._tracks[tid].hold_box(self.cfg) for tid in self._held_ids] + [p.box for p in self._parked]

    def update(self, t_s: float, track_ids, boxes, speeds: dict[int, float] | None,
               shape: tuple[int, int]) -> np.ndarray | None:
        """``observe`` then ``mask``."""
        self.observe(t_s, track_ids, boxes, speeds)
        return self.mask(shape)

    def covers(self, origin: tuple[int, int], sel: np.ndarray | None) -> bool:
        """Does the component ``sel`` (a bool patch at ``origin``, working scale) lie mostly inside held pixels?"""
        if self.hold is None or sel is None:
            return False
        x, y = origin
        h, w = sel.shape
        inside = np.count_nonzero(self.hold[y:y + h, x:x + w] & sel)
        return inside >= self.cfg.max_vehicle_overlap * max(1, np.count_nonzero(sel))

    def _observe_tracks(self, t_s: float, track_ids, boxes, speeds: dict[int, float] | None = None) -> list[int]:
        """The track memory updated with this frame; returns the ids of its moving tracks, in order."""
        cfg = self.cfg
        ids = [int(t) for t in np.asarray(track_ids).reshape(-1)]
        boxes = np.asarray(boxes, dtype=float).reshape(-1, 4)
        # regions of stopped vehicles (before this frame): a new track starting inside one is a fragment
        stopped_regions = []
        if any(tid not in self._tracks for tid in ids):
            stopped_regions = [m.hold_box(cfg) for m in self._tracks.values() if m.stopped(cfg)]
            stopped_regions += [p.box for p in self._parked]
        present = set()
        out = []
        for tid, b in zip(ids, boxes, strict=True):
            present.add(tid)
            uv = ((b[0] + b[2]) / 2.0, (b[1] + b[3]) / 2.0)
            mem = self._tracks.get(tid)
            if mem is None:
                mem = self._tracks[tid] = _TrackMemory(uv, b.copy(), last_s=t_s)
                cu, cv = (b[0] + b[2]) / 2.0, (b[1] + b[3]) / 2.0
                if any(r[0] <= cu <= r[2] and r[1] <= cv <= r[3] for r in stopped_regions):
                    mem.moved = True  # a fragment of a stopped vehicle
            mem.box, mem.last_s = b.copy(), t_s
            mem.history.append((t_s, b.copy()))
            while mem.history and t_s - mem.history[0][0] > cfg.stop_window_s:
                mem.history.popleft()
            if speeds is not None:
                if speeds.get(tid, 0.0) < cfg.moving_speed_mps:
                    mem.fast_since_s = None
                elif mem.fast_since_s is None:
                    mem.fast_since_s = t_s
            if not mem.moved:
                moved = math.hypot(uv[0] - mem.first_uv[0], uv[1] - mem.first_uv[1])
                fast_s = t_s - mem.fast_since_s if mem.fast_since_s is not None else -1.0
                mem.moved = (moved > max(cfg.moved_px, cfg.moved_fraction * min(b[2] - b[0], b[3] - b[1]))
                             or fast_s >= cfg.moving_s - 1e-3)
            if mem.moved:
                out.append(tid)
        for tid in [t for t in self._tracks if t not in present]:
            mem = self._tracks.pop(tid)
            if mem.stopped(cfg) and self._ground_width(mem.box) >= cfg.min_parked_width_m:
                self._parked.append(_Parked(mem.hold_box(cfg), t_s))
        self._parked = [p for p in self._parked if t_s - p.since_s <= cfg.parked_hold_s]
        return out

    def _ground_width(self, box: np.ndarray) -> float:
        xy, valid = self.to_ground(np.array([[box[0], box[3]], [box[2], box[3]]], dtype=float))
        if not np.all(valid) or not np.isfinite(xy).all():
            return 0.0
        return float(np.hypot(*(xy[1] - xy[0])))

    def _box_mask(self, shape: tuple[int, int], boxes: list[np.ndarray]) -> np.ndarray | None:
        if not boxes:
            return None
        s, m = self.cfg.scale, self.cfg.vehicle_margin_px
        mask = np.zeros(shape, bool)
        h, w = shape
        for b in boxes:
            x1, y1 = max(0, int((b[0] - m) * s)), max(0, int((b[1] - m) * s))
            x2, y2 = min(w, int(math.ceil((b[2] + m) * s))), min(h, int(math.ceil((b[3] + m) * s)))
            if x2 > x1 and y2 > y1:
                mask[y1:y2, x1:x2] = True
        return mask

    def release_parked(self, static: np.ndarray | None) -> None:
        """Parked regions stay held only while their static foreground (``static``, working scale) stays."""
        if static is None or not self._parked:
            return
        s = self.cfg.scale
        keep = []
        for p in self._parked:
            x1, y1, x2, y2 = (int(v * s) for v in p.box)
            roi = static[max(0, y1):max(0, y2), max(0, x1):max(0, x2)]
            if roi.size and np.count_nonzero(roi) >= self.cfg.parked_release_fraction * roi.size:
                keep.append(p)
        self._parked = keep
