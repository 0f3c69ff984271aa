"""Track store of the corridor world: one named array per track attribute, indexed by slot. Pure.

Slots are reused (a free list; the arrays double when full); a track's global id (``gid``) never is. The
store also keeps what names a track: the RSU objects bound to it (``(rsu index, object id) -> (slot, gid)``
and back, with the time each object was last listed), the EV alert that marks it and the autonomous
vehicle it is. The filter and the association live in :mod:`ddm.fusion`, the alert marks and vehicle
binding in :mod:`ddm.world`; reading builds :class:`Track` records predicted to a time.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, fields
from types import MappingProxyType

import numpy as np

from protocol.enums import ObjectType

TYPES = list(ObjectType)
TYPE_CODES = {t: i for i, t in enumerate(TYPES)}
EV_CODE = TYPE_CODES[ObjectType.EV]


@dataclass(frozen=True, slots=True)
class Track:
    """A fused corridor track, predicted to the time it was read."""

    track_id: int
    x_m: float
    y_m: float
    vx_mps: float
    vy_mps: float
    length_m: float
    width_m: float
    obj_type: ObjectType
    is_ev: bool
    ev_alert_id: str | None
    lane: int | None
    """Lane reported by the last RSU (None: unknown)."""
    vehicle_id: str | None
    """The autonomous vehicle this track is (None: other traffic)."""
    hits: int
    first_seen_s: float
    last_update_s: float
    pos_var_m2: float
    rsus: tuple[str, ...] = ()
    age_s: float = 0.0
    """Since an RSU last saw it, at the time it was read (its position is predicted over that time)."""

    @property
    def speed_mps(self) -> float:
        return math.hypot(self.vx_mps, self.vy_mps)


_BOOL_COLUMNS = frozenset({"alive", "ev_suppressed", "ev_named"})
_INT_COLUMNS = frozenset({"gid", "hits", "type_code", "lane"})


@dataclass(slots=True)
class TrackColumns:
    """One array per track attribute, indexed by slot. Per axis the constant-velocity Kalman filter's
    state (position, velocity) and covariance (position variance, position-velocity covariance,
    velocity variance)."""

    alive: np.ndarray
    gid: np.ndarray
    """Global track id (never reused)."""
    x_m: np.ndarray
    vx_mps: np.ndarray
    var_x_m2: np.ndarray
    cov_x_vx: np.ndarray
    var_vx: np.ndarray
    y_m: np.ndarray
    vy_mps: np.ndarray
    var_y_m2: np.ndarray
    cov_y_vy: np.ndarray
    var_vy: np.ndarray
    t_s: np.ndarray
    """Measurement time of the filter state."""
    seen_s: np.ndarray
    """DDM time of the last update."""
    first_s: np.ndarray
    hits: np.ndarray
    length_m: np.ndarray
    width_m: np.ndarray
    type_code: np.ndarray
    """Index in ``TYPES`` of the type the last RSU reported."""
    lane: np.ndarray
    """Lane the last RSU reported (-1: unknown)."""
    ev_obj_until_s: np.ndarray
    """An object list's confirmed EV state holds the EV mark until then (see ``ev_named``)."""
    ev_alert_until_s: np.ndarray
    """An active EvAlert marks the track EV until then."""
    ev_suppressed: np.ndarray
    """A cleared alert: object lists' EV state is ignored until a new alert."""
    ev_named: np.ndarray
    """An EvAlert has named the track: object lists' EV state may hold its mark."""

    @classmethod
    def zeros(cls, n: int) -> TrackColumns:
        return cls(**{f.name: np.zeros(n, dtype=_dtype(f.name)) for f in fields(cls)})

    def grown(self, n: int) -> TrackColumns:
        """The same columns, zero-extended to ``n`` slots."""
        return TrackColumns(**{f.name: np.concatenate([getattr(self, f.name), np.zeros(n - len(self.alive),
                                                                                      dtype=_dtype(f.name))])
                               for f in fields(self)})


def _dtype(column: str) -> type:
    return bool if column in _BOOL_COLUMNS else np.int64 if column in _INT_COLUMNS else float


@dataclass(frozen=True)
class TrackTable:
    """Tracks at one instant as columns, one row per track in store (slot) order: copies, read-only.
    :class:`Track` records are built on demand (``records``), so a picture of a thousand tracks costs
    a few array copies, and the records of the few tracks a decision reads."""

    gid: np.ndarray
    x_m: np.ndarray
    """Predicted to the table's time, as ``y_m``."""
    y_m: np.ndarray
    vx_mps: np.ndarray
    vy_mps: np.ndarray
    length_m: np.ndarray
    width_m: np.ndarray
    type_code: np.ndarray
    is_ev: np.ndarray
    lane: np.ndarray
    hits: np.ndarray
    first_s: np.ndarray
    seen_s: np.ndarray
    pos_var_m2: np.ndarray
    slot: np.ndarray
    rsu_names: tuple[str, ...]
    keys_of_slot: Mapping[int, frozenset[tuple[int, int]]]
    alert_of_slot: Mapping[int, str]
    vehicle_of_slot: Mapping[int, str]
    read_s: float = math.nan
    """The time the table was read at (each record's ``age_s`` counts from ``seen_s`` to it)."""

    def __len__(self) -> int:
        return len(self.gid)

    def records(self, rows: np.ndarray | None = None) -> list[Track]:
        """The :class:`Track` of each row (``rows``: indexes, in the order given; None: every row)."""
        if rows is None:
            rows = np.arange(len(self.gid))
        if not len(rows):
            return []
        cols = zip(*(a[rows].tolist() for a in (
            self.gid, self.x_m, self.y_m, self.vx_mps, self.vy_mps, self.length_m, self.width_m, self.type_code,
            self.is_ev, self.lane, self.hits, self.first_s, self.seen_s, self.pos_var_m2, self.slot)), strict=True)
        names, keys, alerts, vehicles = self.rsu_names, self.keys_of_slot, self.alert_of_slot, self.vehicle_of_slot
        read = self.read_s
        return [
            Track(g, x, y, vx, vy, ln, wd, TYPES[ot], ev, alerts.get(s), None if lane < 0 else lane,
                  vehicles.get(s), hits, first, seen, var, tuple(sorted({names[ri] for ri, _ in keys.get(s, ())})),
                  max(0.0, read - seen) if read == read else 0.0)
            for g, x, y, vx, vy, ln, wd, ot, ev, lane, hits, first, seen, var, s in cols
        ]


class TrackStore:
    """Slots, global ids and the RSU object bindings of the corridor's tracks."""

    def __init__(self, capacity: int = 256) -> None:
        self.cols = TrackColumns.zeros(capacity)
        self._free: list[int] = list(range(capacity - 1, -1, -1))
        self._next_gid = 1
        self._slot_of_gid: dict[int, int] = {}
        self._rsu_index: dict[str, int] = {}
        self.rsu_names: list[str] = []
        self.lists_per_rsu: list[int] = []
        self._bound: list[dict[int, tuple[int, int]]] = []  # per RSU: object id -> (slot, gid)
        self._listed_s: list[dict[int, float]] = []  # per RSU: object id -> last time it was in a list
        self._keys_of_slot: dict[int, frozenset[tuple[int, int]]] = {}  # slot -> {(rsu index, object id)}
        """Frozen sets, replaced on change: a table (``table``) keeps a shallow copy that later binds leave alone."""
        self.alert_of_slot: dict[int, str] = {}
        self.vehicle_of_slot: dict[int, str] = {}

    # ------------------------------------------------------------------ slots
    @property
    def track_count(self) -> int:
        return int(self.cols.alive.sum())

    def live_slots(self) -> np.ndarray:
        return np.nonzero(self.cols.alive)[0]

    def slot_of(self, gid: int) -> int | None:
        return self._slot_of_gid.get(gid)

    def alloc(self, n: int) -> np.ndarray:
        """``n`` free slots (the columns double until there are)."""
        while len(self._free) < n:
            old = len(self.cols.alive)
            self.cols = self.cols.grown(2 * old)
            self._free.extend(range(2 * old - 1, old - 1, -1))
        return np.array([self._free.pop() for _ in range(n)], dtype=np.int64)

    def start(self, slots: np.ndarray, x_m, y_m, vx_mps, vy_mps, var_x_m2, var_y_m2, var_v: float,
              t_meas: float, now: float) -> None:
        """New tracks in ``slots`` (from ``alloc``) with their first state and a new global id each."""
        c = self.cols
        c.alive[slots] = True
        c.ev_suppressed[slots] = False
        c.ev_named[slots] = False
        c.x_m[slots], c.y_m[slots], c.vx_mps[slots], c.vy_mps[slots] = x_m, y_m, vx_mps, vy_mps
        c.var_x_m2[slots], c.var_y_m2[slots] = var_x_m2, var_y_m2
        c.cov_x_vx[slots] = 0.0
        c.cov_y_vy[slots] = 0.0
        c.var_vx[slots] = var_v
        c.var_vy[slots] = var_v
        c.t_s[slots] = t_meas
        c.seen_s[slots] = now
        c.first_s[slots] = now
        c.hits[slots] = 0
        c.ev_obj_until_s[slots] = 0.0
        c.ev_alert_until_s[slots] = 0.0
        c.lane[slots] = -1
        for s in slots.tolist():
            g = self._next_gid
            self._next_gid += 1
            c.gid[s] = g
            self._slot_of_gid[g] = s

    def delete(self, slot: int) -> str | None:
        """Free the slot and forget what names it; returns the autonomous vehicle it was (if any)."""
        self.cols.alive[slot] = False
        self._slot_of_gid.pop(int(self.cols.gid[slot]), None)
        for ri, oid in self._keys_of_slot.pop(slot, ()):
            entry = self._bound[ri].get(oid)
            if entry is not None and entry[0] == slot:
                del self._bound[ri][oid]
        self.alert_of_slot.pop(slot, None)
        self._free.append(slot)
        return self.vehicle_of_slot.pop(slot, None)

    def absorb(self, keep: int, drop: int) -> str | None:
        """Merge track ``drop`` into ``keep`` (its bindings, hits, age, EV marks and alert; the caller
        deletes ``drop``); returns the alert id that moved to ``keep`` (if any)."""
        c = self.cols
        for ri, oid in list(self._keys_of_slot.get(drop, ())):
            self.bind(ri, oid, keep)
        c.hits[keep] += c.hits[drop]
        c.first_s[keep] = min(c.first_s[keep], c.first_s[drop])
        c.ev_alert_until_s[keep] = max(c.ev_alert_until_s[keep], c.ev_alert_until_s[drop])
        c.ev_obj_until_s[keep] = max(c.ev_obj_until_s[keep], c.ev_obj_until_s[drop])
        c.ev_named[keep] |= c.ev_named[drop]
        aid = self.alert_of_slot.pop(drop, None)
        if aid is not None:
            self.alert_of_slot[keep] = aid
        return aid

    # ------------------------------------------------------------------ RSUs and their objects
    def rsu(self, rsu_id: str) -> int:
        """The RSU's index (registered on first use)."""
        i = self._rsu_index.get(rsu_id)
        if i is None:
            i = len(self.rsu_names)
            self._rsu_index[rsu_id] = i
            self.rsu_names.append(rsu_id)
            self._bound.append({})
            self._listed_s.append({})
            self.lists_per_rsu.append(0)
        return i

    def knows_rsu(self, rsu_id: str) -> bool:
        return rsu_id in self._rsu_index

    def bound(self, ri: int, oid: int) -> tuple[int, int] | None:
        """(slot, gid) the RSU's object was bound to (the slot may have been reused since: check gid)."""
        return self._bound[ri].get(oid)

    def bound_live_slot(self, rsu_id: str, oid: int) -> int | None:
        """The live track the RSU's object is bound to."""
        ri = self._rsu_index.get(rsu_id)
        b = None if ri is None else self._bound[ri].get(oid)
        if b is not None and self.cols.alive[b[0]] and self.cols.gid[b[0]] == b[1]:
            return b[0]
        return None

    def bind(self, ri: int, oid: int, slot: int) -> None:
        old = self._bound[ri].get(oid)
        if old is not None and old[0] != slot:
            self._unkey(old[0], (ri, oid))
        self._bound[ri][oid] = (slot, int(self.cols.gid[slot]))
        keys = self._keys_of_slot.get(slot, frozenset())
        if (ri, oid) not in keys:
            self._keys_of_slot[slot] = keys | {(ri, oid)}

    def _unkey(self, slot: int, key: tuple[int, int]) -> None:
        keys = self._keys_of_slot.get(slot)
        if keys is not None and key in keys:
            self._keys_of_slot[slot] = keys - {key}

    def note_listed(self, ri: int, oids: list[int], now: float) -> None:
        listed = self._listed_s[ri]
        for oid in oids:
            listed[oid] = now

    def prune_bindings(self, ri: int, horizon_s: float) -> None:
        """Forget the RSU's objects not listed since ``horizon_s`` (it lost them)."""
        listed, bound = self._listed_s[ri], self._bound[ri]
        for oid in [o for o, t in listed.items() if t < horizon_s]:
            del listed[oid]
            b = bound.pop(oid, None)
            if b is not None:
                self._unkey(b[0], (ri, oid))

    def share_an_rsu(self, slot_a: int, slot_b: int) -> bool:
        """Objects of one RSU are bound to both tracks (that RSU sees two cars)."""
        keys = self._keys_of_slot
        return bool({ri for ri, _ in keys.get(slot_a, ())} & {ri for ri, _ in keys.get(slot_b, ())})

    # ------------------------------------------------------------------ reading
    def table(self, slots: np.ndarray, now: float, is_ev: np.ndarray) -> TrackTable:
        """The tracks of ``slots`` predicted to ``now``, as a table of copies (later updates leave it alone)."""
        c = self.cols
        dt = now - c.t_s[slots]
        cols = (c.gid[slots], c.x_m[slots] + c.vx_mps[slots] * dt, c.y_m[slots] + c.vy_mps[slots] * dt, c.vx_mps[slots],
                c.vy_mps[slots], c.length_m[slots], c.width_m[slots], c.type_code[slots], np.array(is_ev, dtype=bool),
                c.lane[slots], c.hits[slots], c.first_s[slots], c.seen_s[slots],
                0.5 * (c.var_x_m2[slots] + c.var_y_m2[slots]), np.array(slots, dtype=np.int64))
        for a in cols:
            a.setflags(write=False)
        return TrackTable(*cols, tuple(self.rsu_names), MappingProxyType(dict(self._keys_of_slot)),
                          MappingProxyType(dict(self.alert_of_slot)), MappingProxyType(dict(self.vehicle_of_slot)),
                          float(now))

    def records(self, slots: np.ndarray, now: float, is_ev: np.ndarray) -> list[Track]:
        """Track records for ``slots`` predicted to ``now``."""
        return self.table(slots, now, is_ev).records()

    def sizes(self) -> dict[str, int]:
        """How much the store holds (slots, bindings, listed objects)."""
        return {"track_slots": len(self.cols.alive), "bindings": sum(len(m) for m in self._bound),
                "bind_seen": sum(len(m) for m in self._listed_s)}
