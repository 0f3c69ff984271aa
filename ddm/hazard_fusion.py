"""Hazard fusion: the ``HazardAlert`` streams of every RSU fused into corridor hazards. Pure: no I/O, no clock.

An alert joins the hazard whose fused position is within ``HazardConfig.fuse_m`` (RSUs 50 m apart see the
same debris, each with its own id); the fused position is the confidence-weighted mean of each source's
latest report, its size the largest reported (conservative). A source leaves on ``clear`` or when it has
not been refreshed for ``source_timeout_s`` (RSUs repeat ``persist`` at 1 Hz); a hazard without sources is
gone. The world model (:class:`ddm.world.CorridorWorld`) owns one and puts its hazards in every picture
(Clemson hazard navigation report; docs/architecture.md §DDM).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ddm.config import HazardConfig
from ddm.geometry import RoadFrame
from ddm.picture import Hazard
from protocol.enums import HazardState
from protocol.messages import HazardAlert


@dataclass
class _Source:
    x_m: float
    y_m: float
    length_m: float
    width_m: float
    confidence: float
    seen_s: float


@dataclass
class HazardTrack:
    """A hazard being fused: its sources and their fusion (mutable; a picture holds :class:`Hazard`)."""

    hazard_id: int
    x_m: float
    y_m: float
    length_m: float
    width_m: float
    lane: int | None
    confidence: float
    first_seen_s: float
    last_seen_s: float
    sources: dict[str, _Source] = field(default_factory=dict)
    """alert id -> its latest report."""

    def refuse(self) -> None:
        """Fuse the sources again: confidence-weighted position, largest size, best confidence."""
        w = np.array([max(s.confidence, 0.05) for s in self.sources.values()])
        xs = np.array([s.x_m for s in self.sources.values()])
        ys = np.array([s.y_m for s in self.sources.values()])
        self.x_m, self.y_m = float(np.average(xs, weights=w)), float(np.average(ys, weights=w))
        self.length_m = max(s.length_m for s in self.sources.values())
        self.width_m = max(s.width_m for s in self.sources.values())
        self.confidence = float(max(s.confidence for s in self.sources.values()))


class HazardFusion:
    """Corridor hazards fused from every RSU's ``HazardAlert``s (the hazard part of the world model)."""

    def __init__(self, frame: RoadFrame | None, config: HazardConfig | None = None) -> None:
        """``frame``: the road, to name each hazard's lane (None: lanes unknown)."""
        self.frame = frame
        self.cfg = config or HazardConfig()
        self.hazards: dict[int, HazardTrack] = {}
        self._by_alert: dict[str, int] = {}
        self._next_id = 1
        self.events: list[tuple[str, int]] = []
        """(what, hazard id) since the last ``drain``: appeared, cleared, expired."""

    def _lane(self, x: float, y: float) -> int | None:
        if self.frame is None:
            return None
        _, d = self.frame.to_frenet(x, y)
        lane = int(self.frame.lane_of(d)[0])
        return None if lane < 0 else lane

    def ingest(self, alert: HazardAlert, now: float) -> HazardTrack | None:
        """Apply one alert; returns the hazard it belongs to (None after a clear or an unknown clear)."""
        aid = alert.hazard_id
        if alert.state == HazardState.CLEAR:
            hid = self._by_alert.pop(aid, None)
            if hid is not None and hid in self.hazards:
                hz = self.hazards[hid]
                hz.sources.pop(aid, None)
                if hz.sources:
                    hz.refuse()
                else:
                    del self.hazards[hid]
                    self.events.append(("cleared", hid))
            return None
        src = _Source(alert.pos_x_m, alert.pos_y_m, alert.length_m, alert.width_m, alert.confidence, now)
        hid = self._by_alert.get(aid)
        if hid is None or hid not in self.hazards:
            best, best_d = None, self.cfg.fuse_m
            for h in self.hazards.values():
                dist = math.hypot(h.x_m - src.x_m, h.y_m - src.y_m)
                if dist <= best_d:
                    best, best_d = h.hazard_id, dist
            if best is None:
                best = self._next_id
                self._next_id += 1
                self.hazards[best] = HazardTrack(best, src.x_m, src.y_m, src.length_m, src.width_m, None,
                                                 src.confidence, now, now)
                self.events.append(("appeared", best))
            hid = self._by_alert[aid] = best
        hz = self.hazards[hid]
        hz.sources[aid] = src
        hz.last_seen_s = now
        hz.refuse()
        hz.lane = self._lane(hz.x_m, hz.y_m)
        return hz

    def maintain(self, now: float) -> None:
        """Drop sources not refreshed for ``source_timeout_s`` and hazards left without sources."""
        for hid in list(self.hazards):
            hz = self.hazards[hid]
            for aid in [a for a, s in hz.sources.items() if now - s.seen_s > self.cfg.source_timeout_s]:
                del hz.sources[aid]
                self._by_alert.pop(aid, None)
            if not hz.sources:
                del self.hazards[hid]
                self.events.append(("expired", hid))
            else:
                hz.refuse()

    def records(self) -> tuple[Hazard, ...]:
        """The hazards as immutable records, in the order they appeared."""
        return tuple(Hazard(h.hazard_id, h.x_m, h.y_m, h.length_m, h.width_m, h.lane, h.confidence,
                            h.first_seen_s, h.last_seen_s) for h in self.hazards.values())

    def drain(self) -> list[tuple[str, int]]:
        out, self.events = self.events, []
        return out
