"""The hazard life cycle (see ``rsu.hazard``): static-evidence components localised on the road plane, matched to
the hazards already known, ``appear`` / ``persist`` / ``clear``."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np

from protocol.corridor import CameraConfig
from protocol.enums import HazardState
from protocol.road import Road
from rsu.hazard.background import StaticForeground, road_mask
from rsu.hazard.config import HazardConfig, HazardEvent, ToGround
from rsu.hazard.vehicles import VehicleMask


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
class HazardStats:
    frames: int = 0
    skipped_frames: int = 0
    components: int = 0
    off_lane: int = 0
    too_large: int = 0
    unlocalised: int = 0
    cut_by_border: int = 0
    ghosts: int = 0
    too_small: int = 0
    vehicle_parts: int = 0
    extra: dict = field(default_factory=dict)


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
        self.vehicles = VehicleMask(self.cfg, to_ground)
        self.stats = HazardStats()
        self.last_components: list[_Component] = []
        self._last_t_s: float | None = None
        """Time of the last frame looked at (``update``)."""
        self._first_t_s: float | None = None
        """Time of the first frame (``update``; again after a new clock): the looks start ``phase_s`` after it."""
        self._learn_t_s: float | None = None
        """Time of the last warm-up frame learnt (``learn_background``)."""
        self._learn_frames = 0
        """Untimed warm-up frames seen."""


    # ------------------------------------------------------------------ components
    def _components(self) -> list[_Component]:
        cfg = self.cfg
        e = self.fg.evidence
        mask = (e >= cfg.off_s).astype(np.uint8)
        mask = cv2.dilate(mask, np.ones((3, 3), np.uint8))
        n, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
        out = []
        s = cfg.scale
        for k in range(1, n):
            x, y, w, h, _area = stats[k]
            sel = labels[y:y + h, x:x + w] == k
            sel &= e[y:y + h, x:x + w] >= cfg.off_s
            area = int(np.count_nonzero(sel))
            if area < cfg.min_area_px:
                continue
            self.stats.components += 1
            if y + h >= e.shape[0]:
                # cut by the image's bottom edge: its ground contact is out of view (the lowest pixels are the
                # border, not where it stands), so it cannot be placed; a vehicle stopping half in view is one
                self.stats.cut_by_border += 1
                continue
            ev = e[y:y + h, x:x + w][sel]
            strong = int(np.count_nonzero(ev >= cfg.on_s)) >= cfg.on_pixels_min
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
            conf = float(np.clip(ev.mean() / cfg.evidence_max_s, 0.05, 1.0))
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

    def learn_background(self, image: np.ndarray, t_s: float | None = None) -> None:
        """A frame from before the watch starts (full-size BGR, e.g. ``sim.warmup``) at ``t_s`` (None: one
        ``warmup_fps`` frame after the last): learnt into the backgrounds (initial median, then the running
        averages) at most ``rate_hz`` times a second, with no static evidence kept and no hazard raised, so traffic
        that stood still during the warm-up is not a hazard later. After the initial median, what stands still in
        a look (static foreground) is the road as it is and goes into the long-term background: a vehicle the
        median kept (one that covered a pixel in most of its frames: light traffic in platoons, far from the
        camera where a car hides a long stretch of road) leaves no ghost there for the watch to report."""
        if t_s is None:
            self._learn_frames += 1
            t_s = (self._learn_frames - 1) / self.cfg.warmup_fps
        dt = self._due(self._learn_t_s, t_s)
        if dt is None:
            return
        self._learn_t_s = t_s
        if self.fg.update(self.fg.small(image), dt_s=dt):
            self.fg.absorb_static()
        if self.fg.evidence is not None:
            self.fg.evidence[:] = 0

    def _due(self, last_t_s: float | None, t_s: float) -> float | None:
        """Seconds this frame counts for (since the last one looked at, at most ``max_update_gap_s``), or None
        when it comes sooner than ``1 / rate_hz`` after it. The first frame, or one from before the last (a
        new clock), counts one period."""
        period = self.cfg.period_s
        if last_t_s is None or t_s < last_t_s:
            return period if period > 0 else 1.0 / self.cfg.warmup_fps
        if t_s - last_t_s < period - 1e-3:
            return None
        return min(t_s - last_t_s, self.cfg.max_update_gap_s)

    # ------------------------------------------------------------------ per frame
    def update(self, image: np.ndarray, t_s: float, track_ids=(), boxes=(),
               speeds: dict[int, float] | None = None) -> list[HazardEvent]:
        """One frame (BGR, full size) at time ``t_s`` with this frame's track ids and xyxy boxes (and,
        optionally, each track's localised speed in m/s by track id). Frames sooner than ``1 / rate_hz`` after the
        last one looked at are passed over (their tracks only go into the vehicle memory; no events)."""
        cfg = self.cfg
        self.vehicles.observe(t_s, track_ids, boxes, speeds)  # every frame: cheap, and short tracks count
        if self._first_t_s is None or t_s < self._first_t_s:
            self._first_t_s = t_s
        if self._last_t_s is None and t_s - self._first_t_s < cfg.phase_s - 1e-3:
            return []
        dt = self._due(self._last_t_s, t_s)
        if dt is None:
            return []
        self._last_t_s = t_s
        self.stats.frames += 1
        small = self.fg.small(image)
        hold = self.vehicles.mask(small.shape[:2])
        if not self.fg.update(small, hold, dt_s=dt):
            if self.fg.ready:
                self.stats.skipped_frames += 1
            return []
        self.vehicles.release_parked(self.fg.last_static)
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
            elif c.strong and self.vehicles.covers(c.origin, c.sel):
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

    @staticmethod
    def _event(hz: Hazard, state: HazardState) -> HazardEvent:
        return HazardEvent(hz.hazard_id, state, hz.x_m, hz.y_m, hz.lane, max(hz.length_m, 0.0),
                           max(hz.width_m, 0.0), float(np.clip(hz.confidence, 0.0, 1.0)), hz.first_seen_s,
                           hz.bbox_px)



def _overlap(a, b) -> bool:
    return a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3]

