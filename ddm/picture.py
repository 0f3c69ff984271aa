"""The DDM's picture of the corridor at one instant: what the policies read. Immutable, pure data.

:meth:`ddm.world.CorridorWorld.snapshot` takes it once per decision step (fuse, decide, command, in that
order); the policies (:mod:`ddm.policy`) turn it into intents and never reach back into the world, so
one step reads one consistent picture however the world changes afterwards.

- ``tracks``: every live corridor track predicted to ``now``, in the world's store order (slot order: the
  order the policies meet neighbours in, which names the first blocking vehicle in a reason);
- ``evs``: the tracks marked EV (an active EvAlert, or an EV detection on a track an alert named);
- ``hazards``: the corridor hazards fused from every RSU's HazardAlerts;
- ``vehicles``: the autonomous vehicles as their last state reported them (:class:`ddm.intent.Ego`, with
  the track bound to each and the time the state was received), in the order they were first heard.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from ddm.intent import Ego
from ddm.tracks import Track, TrackTable


@dataclass(frozen=True, slots=True)
class Hazard:
    """A corridor hazard: the confidence-weighted position and largest size its RSUs reported."""

    hazard_id: int
    x_m: float
    y_m: float
    length_m: float
    width_m: float
    lane: int | None
    confidence: float
    first_seen_s: float
    last_seen_s: float


@dataclass(frozen=True)
class Picture:
    """Tracks, EVs, hazards and autonomous vehicles at ``now`` (see the module docstring)."""

    now: float
    table: TrackTable
    """Every live track (copies, read-only); its records are built when read."""
    hazards: tuple[Hazard, ...] = ()
    vehicles: tuple[Ego, ...] = ()
    evs: tuple[Track, ...] = field(init=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "evs", tuple(self.table.records(np.nonzero(self.table.is_ev)[0])))

    @cached_property
    def tracks(self) -> tuple[Track, ...]:
        """Every live track, in store order."""
        return tuple(self.table.records())

    def tracks_near(self, x_m: float, y_m: float, radius_m: float) -> list[Track]:
        """The tracks within ``radius_m`` of (x, y), in store order."""
        t = self.table
        if not len(t):
            return []
        return t.records(np.nonzero(np.hypot(t.x_m - x_m, t.y_m - y_m) <= radius_m)[0])

    def track(self, track_id: int) -> Track | None:
        rows = np.nonzero(self.table.gid == track_id)[0]
        return self.table.records(rows)[0] if len(rows) else None

    def vehicle(self, vehicle_id: str) -> Ego | None:
        return next((v for v in self.vehicles if v.vehicle_id == vehicle_id), None)
