"""Road hazards from a fixed camera (issue 10): static objects that appear in a lane and stay. Pure core.

Dual background (Porikli, Ivanov, Haga 2008, "Robust abandoned object detection using dual
foregrounds"), per pixel at a reduced working scale:

- long-term background ``B_L``: the per-pixel median of ``init_frames`` frames spread over the first
  seconds (moving traffic drops out of a median), then a running average with the slow rate
  ``long_alpha``, learnt only where the pixel matches it (and frozen under static candidates, so a
  hazard is never absorbed);
- short-term background ``B_S``: a running average with the fast rate ``short_alpha``.

A pixel is *static foreground* when the frame differs from ``B_L`` (``> diff_threshold``, largest
channel difference) but matches ``B_S`` (``< stable_threshold``): something new that has stopped
moving. Moving traffic differs from both. An evidence image ``E`` counts static-foreground frames:
+1 per static frame, -``decay`` per frame where the pixel shows the long-term background again, held
(unchanged) while something moves over it or a tracked vehicle covers it; clipped to ``[0, evidence_max]``.

Tracked vehicles are not hazards: a track whose box centre has *moved* (more than ``moved_px`` and
``moved_fraction`` of its box since it began), or whose localised speed stayed above
``moving_speed_mps`` for ``moving_frames`` frames, is a vehicle, and its region, the union of its boxes over
the last ``stop_window_s`` grown by ``vehicle_grow`` (a slow car's uniform body looks static while a
background detector's box of it shrinks), is held. A slow or stopped vehicle's region catches new tracks
born inside it (fragments of it), and when its track ends while stopped (a queue: a background-subtraction
detector loses a car that stands still) the region is *parked*: held while its static foreground stays,
at most ``parked_hold_s``. A track that never moved (the motion detector tracks a new box of debris too)
is not a vehicle and masks nothing. A new hazard must lie mostly outside held regions.

Hazards: connected components of ``E >= off_frames`` (hysteresis) inside the watched road
(:func:`road_mask`: the carriageway and shoulder up to ``max_range_m``, projected with the camera
model); a new hazard needs ``on_pixels_min`` pixels with ``E >= on_frames`` (static that many frames)
and must not be a *ghost* (an object that was in the background and left: more edge on its outline in
the background than in the frame; ghosts are absorbed into the background). Each component is
localised on the road plane: the lowest pixel of each of its image columns (the object's ground contact
seen from above) is back-projected with the RSU's camera model (``to_ground``, e.g.
``Localizer.mapper.to_ground``); the position is the mean of those ground points, width and length
their extent across and along the road. Only components that overlap a lane (``0 < d < lanes * lane
width`` in the road frame, after the half width) and are ``min_width_m`` to ``max_width_m`` wide are
hazards. Life cycle per hazard: ``appear`` (first confirmed), ``persist`` every ``persist_period_s``,
``clear`` once no component has matched it for ``clear_after_s``.

An RSU started with debris already on the road learns it as background (the initial median); give it a
frame of the empty road (:meth:`HazardDetector.prime`, ``iea-rsu --hazard-background``) to find it.

No ground truth is read: the detector sees pixels, track boxes, the camera model and the road map.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

import cv2
import numpy as np

from protocol.corridor import CameraConfig, Road
from protocol.messages import HazardState

ToGround = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]
"""(N, 2) pixels (u, v) -> ((N, 2) ground x, y; (N,) valid)."""


@dataclass(frozen=True)
class HazardConfig:
    scale: float = 0.5
    """Working scale of the background models (1280x720 -> 640x360)."""
    init_frames: int = 9
    init_stride: int = 8
    """Long-term background: median of ``init_frames`` frames taken every ``init_stride`` frames
    (9 x 8 frames = 4.8 s at 15 fps; a car at 10 m/s moves 48 m meanwhile)."""
    long_alpha: float = 0.002
    """Long-term learning rate per frame (time constant 500 frames = 33 s at 15 fps)."""
    short_alpha: float = 0.25
    """Short-term learning rate (time constant 4 frames)."""
    diff_threshold: float = 28.0
    """Largest channel difference (0-255) from the long-term background that makes a pixel foreground
    (sensor noise in the renders is ~3 levels; asphalt texture under blur ~8)."""
    stable_threshold: float = 10.0
    """Largest channel difference from the short-term background of a still pixel."""
    on_frames: int = 15
    """A new hazard needs pixels static for this many frames (1 s at 15 fps)."""
    off_frames: int = 5
    """... and stays while its pixels keep at least this much evidence (hysteresis)."""
    evidence_max: int = 60
    """Evidence saturates here: a removed object's pixels decay back below ``off_frames`` in
    (evidence_max - off_frames) / decay frames."""
    decay: int = 3
    on_pixels_min: int = 12
    """Pixels (working scale) with E >= on_frames that a new hazard needs (a 0.5 m object at 80 m is
    about 4 x 3 working pixels; at 20 m about 15 x 10)."""
    min_area_px: int = 10
    """Smallest component (working-scale pixels) considered at all."""
    moved_px: float = 12.0
    moved_fraction: float = 0.25
    moving_speed_mps: float = 2.0
    moving_frames: int = 5
    """... or whose localised speed (when the caller gives speeds) was at least ``moving_speed_mps`` for
    ``moving_frames`` frames in a row (a slow car far away moves a few pixels a second)."""
    """A track whose box centre moved more than ``moved_px`` (full-scale pixels) and this fraction of its
    smaller box side since it began is a vehicle (a car entering at the image edge grows from the edge:
    its centre moves though its bottom stays on the border)."""
    min_parked_width_m: float = 1.2
    """A stopped track's region is parked only if its box's bottom edge spans at least this on the road
    (vehicle-sized), so a box of debris that a detector tracked is never masked for long."""
    max_vehicle_overlap: float = 0.5
    """A new hazard must have less than this fraction of its pixels inside held vehicle regions."""
    vehicle_margin_px: float = 4.0
    stop_window_s: float = 1.5
    stop_px: float = 4.0
    stop_check_s: float = 0.5
    slow_fraction: float = 0.5
    """A moved track whose bottom-centre moved less than ``stop_px`` or this fraction of its box height
    over the last ``stop_check_s`` is slow or stopped: new tracks born inside its region are fragments
    of it, and when the track ends its region is parked."""
    vehicle_grow: float = 0.2
    """A vehicle's held region is the union of its boxes over ``stop_window_s`` grown by this fraction
    of its box size on every side."""
    parked_hold_s: float = 120.0
    """A stopped vehicle's region is held at most this long after its track ended."""
    parked_release_fraction: float = 0.25
    """... and released once less than this fraction of it is static foreground (it drove off)."""
    min_width_m: float = 0.2
    """Narrower static components (a sliver along a lane line, a shadow edge) are not reported."""
    max_width_m: float = 3.0
    """Wider static components are not debris (and not a lane-blocking object one lane can pass)."""
    max_length_m: float = 6.0
    """Longer static components are not debris (a slow car far away smears to ~7 m)."""
    match_m: float = 2.0
    """A component within this distance of a known hazard (or overlapping its box) is that hazard."""
    clear_after_s: float = 1.0
    persist_period_s: float = 1.0
    position_smoothing: float = 0.2
    """Exponential smoothing weight of a new measurement of a known hazard's position and size."""
    max_range_m: float = 120.0
    """Road farther than this from the camera is not watched (a 0.5 m object there is ~3 pixels)."""
    ghost_edge_ratio: float = 1.2
    """A new static component whose outline has more edge (Sobel) in the long-term background than in
    the frame is a ghost (something that was there when the background was learnt has left): it is
    absorbed into the background instead of reported."""
    max_foreground_fraction: float = 0.4
    """A frame whose long-term foreground exceeds this (exposure jump, camera moved) is skipped."""

    def __post_init__(self) -> None:
        if not 0.05 <= self.scale <= 1.0:
            raise ValueError(f"scale must be in [0.05, 1], got {self.scale}")
        if not 0 < self.off_frames <= self.on_frames <= self.evidence_max:
            raise ValueError("need 0 < off_frames <= on_frames <= evidence_max")
        if not (0 < self.long_alpha < 1 and 0 < self.short_alpha <= 1):
            raise ValueError("learning rates must be in (0, 1]")
        if self.init_frames < 1 or self.init_stride < 1 or self.decay < 1:
            raise ValueError("init_frames, init_stride and decay must be >= 1")


@dataclass(frozen=True)
class HazardEvent:
    """One life-cycle event of a hazard seen by this camera (corridor frame, metres)."""

    hazard_id: int
    state: HazardState
    x_m: float
    y_m: float
    lane: int | None
    length_m: float
    width_m: float
    confidence: float
    first_seen_s: float
    bbox_px: tuple[float, float, float, float]
    lat_deg: float | None = None
    lon_deg: float | None = None
    """Set by the pipeline (``rsu.pipeline.RsuPipeline``), from the corridor's origin."""


@dataclass
class Hazard:
    hazard_id: int
    x_m: float
    y_m: float
    s_m: float
    d_m: float
    lane: int | None
    length_m: float
    width_m: float
    bbox_px: tuple[float, float, float, float]
    first_seen_s: float
    last_seen_s: float
    last_event_s: float
    confidence: float
    frames: int = 1


@dataclass
class _Component:
    bbox_px: tuple[float, float, float, float]
    x_m: float
    y_m: float
    s_m: float
    d_m: float
    length_m: float
    width_m: float
    strong: bool
    confidence: float
    origin: tuple[int, int] = (0, 0)
    """(x, y) of ``sel`` in the working-scale image."""
    sel: np.ndarray | None = None


@dataclass
class _TrackMemory:
    first_uv: tuple[float, float]
    box: np.ndarray
    moved: bool = False
    last_s: float = 0.0
    fast_frames: int = 0
    history: deque = field(default_factory=deque)
    """(t_s, box) of the last ``stop_window_s``."""

    def stopped(self, cfg: HazardConfig) -> bool:
        """A vehicle that has come to rest: its bottom-centre moved less than ``stop_px`` over the window."""
        if not self.moved or len(self.history) < 2:
            return False
        t1, b1 = self.history[-1]
        b0 = next(b for t, b in self.history if t >= t1 - cfg.stop_check_s - 1e-9)
        if b0 is b1:
            return False
        du = (b1[0] + b1[2] - b0[0] - b0[2]) / 2.0
        dv = b1[3] - b0[3]
        return math.hypot(du, dv) < max(cfg.stop_px, cfg.slow_fraction * (b1[3] - b1[1]))

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


@dataclass
class HazardStats:
    frames: int = 0
    skipped_frames: int = 0
    components: int = 0
    off_lane: int = 0
    too_large: int = 0
    unlocalised: int = 0
    ghosts: int = 0
    too_small: int = 0
    vehicle_parts: int = 0
    extra: dict = field(default_factory=dict)


def road_mask(camera: CameraConfig, road: Road, scale: float = 1.0, *, right_margin_m: float | None = None,
              left_margin_m: float = 1.0, step_m: float = 2.0, min_depth_m: float = 2.0,
              max_range_m: float = 120.0) -> np.ndarray:
    """bool (h, w) mask at ``scale`` of the pixels that see the carriageway and its margins: every
    road piece of ``step_m`` from the right shoulder edge (``right_margin_m`` right of lane 0, default
    the shoulder width) to ``left_margin_m`` left of the last lane, at most ``max_range_m`` from the
    camera, projected with the camera model."""
    h, w = int(round(camera.height_px * scale)), int(round(camera.width_px * scale))
    mask = np.zeros((h, w), np.uint8)
    d0 = -(road.shoulder_width_m if right_margin_m is None else right_margin_m)
    d1 = road.lanes * road.lane_width_m + left_margin_m
    s = np.arange(0.0, road.length_m + step_m, step_m)
    s = np.minimum(s, road.length_m)
    r = camera.rotation_world_to_camera
    k = camera.intrinsic_matrix
    edges = []
    for d in (d0, d1):
        x, y, _ = road.pose_at(s, d)
        pc = (r @ (np.column_stack([x, y, np.zeros_like(x)]) - camera.centre_world).T).T
        edges.append(pc)
    for i in range(len(s) - 1):
        quad = np.array([edges[0][i], edges[0][i + 1], edges[1][i + 1], edges[1][i]])
        if np.any(quad[:, 2] < min_depth_m) or np.any(np.linalg.norm(quad, axis=1) > max_range_m):
            continue
        uv = (k @ quad.T).T
        uv = uv[:, :2] / uv[:, 2:3] * scale
        if np.all(uv[:, 0] < -w) or np.all(uv[:, 0] > 2 * w) or np.all(uv[:, 1] < -h) or np.all(uv[:, 1] > 2 * h):
            continue
        cv2.fillConvexPoly(mask, np.round(uv * 16).astype(np.int32), 1, cv2.LINE_8, 4)
    return mask.astype(bool)


class StaticForeground:
    """The dual background and the static-evidence image (see the module docstring). Working scale."""

    def __init__(self, config: HazardConfig, roi: np.ndarray | None = None) -> None:
        self.cfg = config
        self.roi = roi
        """bool mask at working scale of the pixels watched (the road); None: all."""
        self.long_bg: np.ndarray | None = None
        self.short_bg: np.ndarray | None = None
        self.evidence: np.ndarray | None = None
        self._init: list[np.ndarray] = []
        self._seen = 0
        self.last_static: np.ndarray | None = None
        self.last_frame: np.ndarray | None = None

    @property
    def ready(self) -> bool:
        return self.long_bg is not None

    def small(self, image: np.ndarray) -> np.ndarray:
        s = self.cfg.scale
        return image if s == 1.0 else cv2.resize(image, None, fx=s, fy=s, interpolation=cv2.INTER_AREA)

    def prime(self, small: np.ndarray) -> None:
        """Take a frame of the empty road as both backgrounds (an RSU that has been running)."""
        f = small.astype(np.float32)
        self.long_bg, self.short_bg = f.copy(), f.copy()
        self.evidence = np.zeros(f.shape[:2], np.int16)
        self._init = []

    def update(self, small: np.ndarray, hold: np.ndarray | None = None) -> bool:
        """One frame at working scale (uint8 BGR or grey); ``hold``: bool mask of pixels covered by
        vehicles (evidence unchanged there). Returns False while initialising or on a skipped frame."""
        cfg = self.cfg
        f = small.astype(np.float32)
        self._seen += 1
        if self.long_bg is None:
            if (self._seen - 1) % cfg.init_stride == 0:
                self._init.append(f)
            if self.short_bg is None:
                self.short_bg = f.copy()
            else:
                cv2.accumulateWeighted(f, self.short_bg, cfg.short_alpha)
            if len(self._init) >= cfg.init_frames:
                self.long_bg = np.median(np.stack(self._init), axis=0).astype(np.float32)
                self.evidence = np.zeros(f.shape[:2], np.int16)
                self._init = []
            return False
        d_long = cv2.absdiff(f, self.long_bg)
        d_short = cv2.absdiff(f, self.short_bg)
        if d_long.ndim == 3:
            d_long, d_short = _channel_max(d_long), _channel_max(d_short)
        fg_long = d_long > cfg.diff_threshold
        cv2.accumulateWeighted(f, self.short_bg, cfg.short_alpha)
        if np.count_nonzero(fg_long) > cfg.max_foreground_fraction * fg_long.size:
            return False
        stable = d_short < cfg.stable_threshold
        static = fg_long & stable
        static = cv2.morphologyEx(static.astype(np.uint8), cv2.MORPH_OPEN, np.ones((2, 2), np.uint8)).astype(bool)
        free = np.ones_like(static) if hold is None else ~hold
        if self.roi is not None:
            static &= self.roi
        e = self.evidence
        e[static & free] += 1
        e[~fg_long & free] -= cfg.decay
        np.clip(e, 0, cfg.evidence_max, out=e)
        learn = ((~fg_long) & (e == 0)).view(np.uint8)
        cv2.accumulateWeighted(f, self.long_bg, cfg.long_alpha, mask=learn)
        self.last_static = static
        self.last_frame = f
        return True

    def is_ghost(self, x: int, y: int, sel: np.ndarray) -> bool:
        """Edge test of a component (``sel`` at offset x, y, working scale): more edge on its outline in
        the long-term background than in the frame means the object is in the background, not the frame."""
        h, w = sel.shape
        pad = 3
        H, W = self.evidence.shape
        x0, y0, x1, y1 = max(0, x - pad), max(0, y - pad), min(W, x + w + pad), min(H, y + h + pad)
        mask = np.zeros((y1 - y0, x1 - x0), np.uint8)
        mask[y - y0:y - y0 + h, x - x0:x - x0 + w] = sel
        k = np.ones((3, 3), np.uint8)
        ring = cv2.dilate(mask, k).astype(bool) & ~cv2.erode(mask, k).astype(bool)
        if not ring.any():
            return False

        def edge(img: np.ndarray) -> float:
            g = img[y0:y1, x0:x1]
            g = cv2.cvtColor(g, cv2.COLOR_BGR2GRAY) if g.ndim == 3 else g
            mag = np.abs(cv2.Sobel(g, cv2.CV_32F, 1, 0)) + np.abs(cv2.Sobel(g, cv2.CV_32F, 0, 1))
            return float(mag[ring].mean())

        return edge(self.long_bg) > self.cfg.ghost_edge_ratio * edge(self.last_frame)

    def absorb(self, x: int, y: int, sel: np.ndarray) -> None:
        """Take the frame's pixels of a component into the long-term background and forget their evidence."""
        h, w = sel.shape
        region = (slice(y, y + h), slice(x, x + w))
        self.long_bg[region][sel] = self.last_frame[region][sel]
        self.evidence[region][sel] = 0


class HazardDetector:
    """Static-object hazards of one fixed camera; ``update`` per frame returns life-cycle events."""

    def __init__(self, road: Road, to_ground: ToGround, config: HazardConfig | None = None, *,
                 camera: CameraConfig | None = None) -> None:
        self.cfg = config or HazardConfig()
        self.road = road
        self.to_ground = to_ground
        roi = road_mask(camera, road, self.cfg.scale, max_range_m=self.cfg.max_range_m) if camera is not None else None
        self.fg = StaticForeground(self.cfg, roi)
        self.hazards: dict[int, Hazard] = {}
        self._next_id = 1
        self._tracks: dict[int, _TrackMemory] = {}
        self._parked: list[_Parked] = []
        self.stats = HazardStats()
        self._hold: np.ndarray | None = None
        self.last_components: list[_Component] = []

    # ------------------------------------------------------------------ vehicles
    def _vehicle_boxes(self, t_s: float, track_ids, boxes, speeds: dict[int, float] | None = None
                       ) -> list[np.ndarray]:
        cfg = self.cfg
        ids = [int(t) for t in np.asarray(track_ids).reshape(-1)]
        boxes = np.asarray(boxes, dtype=float).reshape(-1, 4)
        # regions of stopped vehicles (before this frame): a new track starting inside one is a fragment
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
                fast = speeds.get(tid, 0.0) >= cfg.moving_speed_mps
                mem.fast_frames = mem.fast_frames + 1 if fast else 0
            if not mem.moved:
                moved = math.hypot(uv[0] - mem.first_uv[0], uv[1] - mem.first_uv[1])
                mem.moved = (moved > max(cfg.moved_px, cfg.moved_fraction * min(b[2] - b[0], b[3] - b[1]))
                             or mem.fast_frames >= cfg.moving_frames)
            if mem.moved:
                out.append(mem.hold_box(cfg))
        for tid in [t for t in self._tracks if t not in present]:
            mem = self._tracks.pop(tid)
            if mem.stopped(cfg) and self._ground_width(mem.box) >= cfg.min_parked_width_m:
                self._parked.append(_Parked(mem.hold_box(cfg), t_s))
        self._parked = [p for p in self._parked if t_s - p.since_s <= cfg.parked_hold_s]
        return out + [p.box for p in self._parked]

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

    def _release_parked(self) -> None:
        static = self.fg.last_static
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

    # ------------------------------------------------------------------ components
    def _components(self) -> list[_Component]:
        cfg = self.cfg
        e = self.fg.evidence
        mask = (e >= cfg.off_frames).astype(np.uint8)
        mask = cv2.dilate(mask, np.ones((3, 3), np.uint8))
        n, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
        out = []
        s = cfg.scale
        for k in range(1, n):
            x, y, w, h, _area = stats[k]
            sel = labels[y:y + h, x:x + w] == k
            sel &= e[y:y + h, x:x + w] >= cfg.off_frames
            area = int(np.count_nonzero(sel))
            if area < cfg.min_area_px:
                continue
            self.stats.components += 1
            ev = e[y:y + h, x:x + w][sel]
            strong = int(np.count_nonzero(ev >= cfg.on_frames)) >= cfg.on_pixels_min
            cols = np.flatnonzero(sel.any(axis=0))
            lowest = h - 1 - np.argmax(sel[::-1, cols], axis=0)  # lowest selected row per column
            uv = np.column_stack([(x + cols + 0.5) / s, (y + lowest + 1.0) / s])
            xy, valid = self.to_ground(uv)
            valid = np.asarray(valid, bool) & np.isfinite(xy).all(axis=1)
            if not valid.any():
                self.stats.unlocalised += 1
                continue
            xy = xy[valid]
            cx, cy = xy.mean(axis=0)
            s_c, d_c = self.road.to_frenet(float(cx), float(cy))
            heading = float(self.road.pose_at(s_c, 0.0)[2])
            along = (xy[:, 0] - cx) * math.cos(heading) + (xy[:, 1] - cy) * math.sin(heading)
            across = -(xy[:, 0] - cx) * math.sin(heading) + (xy[:, 1] - cy) * math.cos(heading)
            length = float(np.ptp(along)) if len(along) > 1 else 0.0
            width = float(np.ptp(across)) if len(across) > 1 else 0.0
            if width > cfg.max_width_m or length > cfg.max_length_m:
                self.stats.too_large += 1
                continue
            if width < cfg.min_width_m:
                self.stats.too_small += 1
                continue
            road_w = self.road.lanes * self.road.lane_width_m
            if d_c + width / 2.0 <= 0.0 or d_c - width / 2.0 >= road_w:
                self.stats.off_lane += 1
                continue
            bbox = (x / s, y / s, (x + w) / s, (y + h) / s)
            conf = float(np.clip(ev.mean() / cfg.evidence_max, 0.05, 1.0))
            out.append(_Component(bbox, float(cx), float(cy), float(s_c), float(d_c), length, width, strong, conf,
                                  (int(x), int(y)), sel))
        return out

    def _lane(self, d_m: float) -> int | None:
        lane = self.road.lane_of_offset(d_m)
        if lane is None:  # centre on the shoulder but overlapping lane 0, or past the last lane
            lane = 0 if d_m < 0 else self.road.lanes - 1
        return lane

    def prime(self, empty_road: np.ndarray) -> None:
        """Start from a known empty-road frame instead of the initial median (full-size BGR)."""
        self.fg.prime(self.fg.small(empty_road))

    def learn_background(self, image: np.ndarray) -> None:
        """A frame from before the watch starts (full-size BGR, e.g. ``sim.warmup``): learnt into the
        backgrounds (initial median, then the running averages) with no static evidence kept and no
        hazard raised, so traffic that stood still during the warm-up is not a hazard later."""
        self.fg.update(self.fg.small(image))
        if self.fg.evidence is not None:
            self.fg.evidence[:] = 0

    # ------------------------------------------------------------------ per frame
    def update(self, image: np.ndarray, t_s: float, track_ids=(), boxes=(),
               speeds: dict[int, float] | None = None) -> list[HazardEvent]:
        """One frame (BGR, full size) at time ``t_s`` with this frame's track ids and xyxy boxes (and,
        optionally, each track's localised speed in m/s by track id)."""
        cfg = self.cfg
        self.stats.frames += 1
        small = self.fg.small(image)
        vboxes = self._vehicle_boxes(t_s, track_ids, boxes, speeds)
        hold = self._box_mask(small.shape[:2], vboxes)
        self._hold = hold
        if not self.fg.update(small, hold):
            if self.fg.ready:
                self.stats.skipped_frames += 1
            return []
        self._release_parked()
        comps = self._components()
        self.last_components = comps
        events: list[HazardEvent] = []
        matched: set[int] = set()
        for c in sorted(comps, key=lambda c: -c.confidence):
            best, best_d = None, cfg.match_m
            for hid, hz in self.hazards.items():
                if hid in matched:
                    continue
                dist = math.hypot(c.x_m - hz.x_m, c.y_m - hz.y_m)
                if dist <= best_d or _overlap(c.bbox_px, hz.bbox_px):
                    best, best_d = hid, min(dist, best_d)
            if best is not None:
                hz = self.hazards[best]
                a = cfg.position_smoothing
                hz.x_m += a * (c.x_m - hz.x_m)
                hz.y_m += a * (c.y_m - hz.y_m)
                hz.s_m += a * (c.s_m - hz.s_m)
                hz.d_m += a * (c.d_m - hz.d_m)
                hz.length_m += a * (c.length_m - hz.length_m)
                hz.width_m += a * (c.width_m - hz.width_m)
                hz.lane = self._lane(hz.d_m)
                hz.bbox_px, hz.last_seen_s, hz.confidence = c.bbox_px, t_s, c.confidence
                hz.frames += 1
                matched.add(best)
                if t_s - hz.last_event_s >= cfg.persist_period_s - 1e-9:
                    hz.last_event_s = t_s
                    events.append(self._event(hz, HazardState.PERSIST))
            elif c.strong and self._in_vehicle(c):
                self.stats.vehicle_parts += 1
            elif c.strong and self.fg.is_ghost(*c.origin, c.sel):
                self.fg.absorb(*c.origin, c.sel)
                self.stats.ghosts += 1
            elif c.strong:
                hz = Hazard(self._next_id, c.x_m, c.y_m, c.s_m, c.d_m, self._lane(c.d_m), c.length_m, c.width_m,
                            c.bbox_px, t_s, t_s, t_s, c.confidence)
                self._next_id += 1
                self.hazards[hz.hazard_id] = hz
                matched.add(hz.hazard_id)
                events.append(self._event(hz, HazardState.APPEAR))
        for hid in [h for h, hz in self.hazards.items() if h not in matched and t_s - hz.last_seen_s > cfg.clear_after_s]:
            events.append(self._event(self.hazards.pop(hid), HazardState.CLEAR))
        return events

    def _in_vehicle(self, c: _Component) -> bool:
        hold = getattr(self, "_hold", None)
        if hold is None or c.sel is None:
            return False
        x, y = c.origin
        h, w = c.sel.shape
        inside = np.count_nonzero(hold[y:y + h, x:x + w] & c.sel)
        return inside >= self.cfg.max_vehicle_overlap * max(1, np.count_nonzero(c.sel))

    @staticmethod
    def _event(hz: Hazard, state: HazardState) -> HazardEvent:
        return HazardEvent(hz.hazard_id, state, hz.x_m, hz.y_m, hz.lane, max(hz.length_m, 0.0),
                           max(hz.width_m, 0.0), float(np.clip(hz.confidence, 0.0, 1.0)), hz.first_seen_s,
                           hz.bbox_px)


def _channel_max(img: np.ndarray) -> np.ndarray:
    """Largest channel of an (h, w, c) image (cv2: numpy's reduction over the last axis is slow)."""
    ch = cv2.split(img)
    out = ch[0]
    for c in ch[1:]:
        out = cv2.max(out, c)
    return out


def _overlap(a, b) -> bool:
    return a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3]
