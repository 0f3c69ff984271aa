"""Corridor world model: the RSUs' object lists fused into corridor tracks with global ids.

Pure core (no I/O, no clock: every call takes ``now``, the DDM's time of reception).

- Association (per ObjectList, vectorised): an (rsu, object id) already bound to a track updates it
  directly (checked against a loose gate); the other objects are gated in world coordinates against
  the tracks near them (normalised innovation, chi-square 2 dof, plus a velocity gate) and assigned
  with the Hungarian method (``scipy.optimize.linear_sum_assignment``). A track already claimed in
  this message by another object of the same RSU is not a candidate (one RSU never sees a car twice).
  Overlapping fields of view therefore give one track per car, and a car handed over from one RSU to
  the next (seen by both, or coasting across a gap) keeps its global id.
- Filter: constant-velocity Kalman filter per axis (state position, velocity; position and velocity
  both measured), white-acceleration process noise (Bar-Shalom, discretised continuous model).
- Time alignment: every list is processed at its ``measurement_time``; tracks are predicted to it. A
  list older than a track's state (out of sequence) is moved forward to the track's time with its own
  velocity and its variance inflated. Lists older than ``max_measurement_age_s`` are dropped.
- EVs (issue 18: only authenticated evidence moves a car): an active EvAlert (signed, in a signed
  corridor: the DDM verifies alerts) marks the track it names (via the RSU's object id, else by
  position) until cleared or not refreshed for ``ev_alert_timeout_s``. An object list's unsigned
  ``obj_type=ev`` / ``ev_state=confirmed`` only holds the mark for ``ev_object_hold_s`` on a track an
  EvAlert has named (``ev_named``), never makes an EV on its own (``DdmConfig.ev_from_objects_alone``
  restores that, to measure the cost); a cleared alert removes the
  mark and suppresses the object-level mark on that track until a new alert; an alert cleared because
  the EV left that RSU's view (``clear_reason=out_of_view``) leaves the mark to time out, so the EV
  stays an EV while the next RSU gathers its own evidence.
- RSU liveness: last object list and last health per RSU; ``stale_rsus(now)``.
- Autonomous vehicles: each VehicleState is bound to the nearest track (``vehicle_gate_m``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from operator import attrgetter

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.spatial import cKDTree

from ddm.config import DdmConfig
from protocol.messages import AlertState, ClearReason, EvAlert, EvState, ObjectList, ObjectType, VehicleState

_OBJ_FIELDS = attrgetter(
    "object_id", "pos_x_m", "pos_y_m", "vel_x_mps", "vel_y_mps", "length_m", "width_m", "ev_score", "age_s"
)
_OBJ_COV = attrgetter("pos_cov_m2")
_TYPE_CODES = {t: i for i, t in enumerate(ObjectType)}
_TYPES = list(ObjectType)
_EV_CODE = _TYPE_CODES[ObjectType.EV]


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

    @property
    def speed_mps(self) -> float:
        return math.hypot(self.vx_mps, self.vy_mps)


@dataclass(slots=True)
class AlertRecord:
    alert_id: str
    rsu_id: str
    object_id: int
    state: AlertState
    x_m: float
    y_m: float
    vx_mps: float
    vy_mps: float
    lane: int | None
    stamp_s: float
    last_seen_s: float
    track_id: int | None = None


@dataclass(slots=True)
class VehicleRecord:
    state: VehicleState
    received_s: float
    track_id: int | None = None


@dataclass
class IngestStats:
    lists: int = 0
    objects: int = 0
    dropped_old: int = 0
    new_tracks: int = 0
    merged: int = 0
    deleted: int = 0


class CorridorWorld:
    """All tracks of the corridor in numpy arrays indexed by slot (slots are reused)."""

    _FLOAT = ("x", "y", "vx", "vy", "pxx", "pxv", "pvv_x", "pyy", "pyv", "pvv_y", "t", "seen", "first",
              "length", "width", "ev_obj_until", "ev_alert_until")
    _INT = ("gid", "hits", "otype", "lane", "last_rsu")

    def __init__(self, config: DdmConfig | None = None, rsu_ids: tuple[str, ...] = (), capacity: int = 256) -> None:
        self.config = config or DdmConfig()
        self._cap = 0
        self.alive = np.zeros(0, dtype=bool)
        self.ev_suppressed = np.zeros(0, dtype=bool)
        self.ev_named = np.zeros(0, dtype=bool)
        """An EvAlert has named the track: object lists' EV state may hold its mark."""
        for name in self._FLOAT:
            setattr(self, name, np.zeros(0))
        for name in self._INT:
            setattr(self, name, np.zeros(0, dtype=np.int64))
        self._grow(capacity)
        self._free: list[int] = list(range(capacity - 1, -1, -1))
        self._next_gid = 1
        self._slot_of_gid: dict[int, int] = {}
        self._rsu_index: dict[str, int] = {}
        self._rsu_names: list[str] = []
        self._maps: list[dict[int, tuple[int, int]]] = []  # per RSU: object id -> (slot, gid)
        self._bind_seen: list[dict[int, float]] = []  # per RSU: object id -> last time it was in a list
        self._lists_per_rsu: list[int] = []
        self._slot_keys: dict[int, set[tuple[int, int]]] = {}  # slot -> {(rsu index, object id)}
        self.rsu_last_objects: dict[str, float] = {}
        self.rsu_last_health: dict[str, float] = {}
        self.rsu_expected: tuple[str, ...] = tuple(rsu_ids)
        self.started_s: float | None = None
        self.alerts: dict[str, AlertRecord] = {}
        self._alert_of_slot: dict[int, str] = {}
        self.vehicles: dict[str, VehicleRecord] = {}
        self._vehicle_of_slot: dict[int, str] = {}
        self.stats = IngestStats()
        for r in rsu_ids:
            self._rsu(r)

    # ------------------------------------------------------------------ storage
    def _grow(self, new_cap: int) -> None:
        old = self._cap
        self.alive = np.concatenate([self.alive, np.zeros(new_cap - old, dtype=bool)])
        self.ev_suppressed = np.concatenate([self.ev_suppressed, np.zeros(new_cap - old, dtype=bool)])
        self.ev_named = np.concatenate([self.ev_named, np.zeros(new_cap - old, dtype=bool)])
        for name in self._FLOAT:
            setattr(self, name, np.concatenate([getattr(self, name), np.zeros(new_cap - old)]))
        for name in self._INT:
            setattr(self, name, np.concatenate([getattr(self, name), np.zeros(new_cap - old, dtype=np.int64)]))
        self._cap = new_cap
        if hasattr(self, "_free"):
            self._free.extend(range(new_cap - 1, old - 1, -1))

    def _alloc(self, n: int) -> np.ndarray:
        while len(self._free) < n:
            self._grow(self._cap * 2)
        return np.array([self._free.pop() for _ in range(n)], dtype=np.int64)

    def _rsu(self, rsu_id: str) -> int:
        i = self._rsu_index.get(rsu_id)
        if i is None:
            i = len(self._rsu_names)
            self._rsu_index[rsu_id] = i
            self._rsu_names.append(rsu_id)
            self._maps.append({})
            self._bind_seen.append({})
            self._lists_per_rsu.append(0)
        return i

    def _delete(self, slot: int) -> None:
        self.alive[slot] = False
        self._slot_of_gid.pop(int(self.gid[slot]), None)
        for ri, oid in self._slot_keys.pop(slot, ()):
            entry = self._maps[ri].get(oid)
            if entry is not None and entry[0] == slot:
                del self._maps[ri][oid]
        self._alert_of_slot.pop(slot, None)
        veh = self._vehicle_of_slot.pop(slot, None)
        if veh is not None and veh in self.vehicles:
            self.vehicles[veh].track_id = None
        self._free.append(slot)

    def _bind(self, ri: int, oid: int, slot: int) -> None:
        old = self._maps[ri].get(oid)
        if old is not None and old[0] != slot:
            self._slot_keys.get(old[0], set()).discard((ri, oid))
        self._maps[ri][oid] = (slot, int(self.gid[slot]))
        self._slot_keys.setdefault(slot, set()).add((ri, oid))

    @property
    def track_count(self) -> int:
        return int(self.alive.sum())

    # ------------------------------------------------------------------ filter
    def _kf_axis(self, slots: np.ndarray, dt: np.ndarray, z_p: np.ndarray, z_v: np.ndarray,
                 r_p: np.ndarray, axis: str, r_v: np.ndarray | float | None = None) -> None:
        """Predict by dt then update with (position, velocity) measurements, one axis, vectorised."""
        pos, vel = (self.x, self.vx) if axis == "x" else (self.y, self.vy)
        npp, npv, nvv = ("pxx", "pxv", "pvv_x") if axis == "x" else ("pyy", "pyv", "pvv_y")
        app, apv, avv = getattr(self, npp), getattr(self, npv), getattr(self, nvv)
        q = self.config.accel_noise_m2ps4
        p, v = pos[slots], vel[slots]
        pp, pv, vv = app[slots], apv[slots], avv[slots]
        # predict (constant velocity, white acceleration noise)
        p = p + v * dt
        pp = pp + 2 * dt * pv + dt * dt * vv + q * dt**3 / 3
        pv = pv + dt * vv + q * dt * dt / 2
        vv = vv + q * dt
        # update: H = I, R = diag(r_p, r_v); K = P (P + R)^-1 (2x2 closed form)
        r_v = self.config.vel_meas_var_m2ps2 if r_v is None else r_v
        s11, s12, s22 = pp + r_p, pv, vv + r_v
        det = s11 * s22 - s12 * s12
        i11, i12, i22 = s22 / det, -s12 / det, s11 / det
        k11, k12 = pp * i11 + pv * i12, pp * i12 + pv * i22
        k21, k22 = pv * i11 + vv * i12, pv * i12 + vv * i22
        e_p, e_v = z_p - p, z_v - v
        pos[slots] = p + k11 * e_p + k12 * e_v
        vel[slots] = v + k21 * e_p + k22 * e_v
        # P = (I - K) P
        app[slots] = (1 - k11) * pp - k12 * pv
        apv[slots] = (1 - k11) * pv - k12 * vv
        avv[slots] = -k21 * pv + (1 - k22) * vv

    def _predicted(self, slots: np.ndarray, t: float) -> tuple[np.ndarray, ...]:
        dt = t - self.t[slots]
        dtp = np.maximum(dt, 0.0)
        q = self.config.accel_noise_m2ps4
        px = self.x[slots] + self.vx[slots] * dt
        py = self.y[slots] + self.vy[slots] * dt
        varx = self.pxx[slots] + 2 * dtp * self.pxv[slots] + dtp * dtp * self.pvv_x[slots] + q * dtp**3 / 3
        vary = self.pyy[slots] + 2 * dtp * self.pyv[slots] + dtp * dtp * self.pvv_y[slots] + q * dtp**3 / 3
        return px, py, varx, vary

    # ------------------------------------------------------------------ ingest
    def ingest_objects(self, msg: ObjectList, now: float) -> int:
        """Fuse one RSU frame; returns how many objects were absorbed (0 when the list was dropped)."""
        cfg = self.config
        if self.started_s is None:
            self.started_s = now
        ri = self._rsu(msg.rsu_id)
        self.rsu_last_objects[msg.rsu_id] = now
        self.stats.lists += 1
        t_meas = float(msg.measurement_time)
        if now - t_meas > cfg.max_measurement_age_s:
            self.stats.dropped_old += len(msg.objects)
            return 0
        self._lists_per_rsu[ri] += 1
        if self._lists_per_rsu[ri] % 16 == 0:
            self._prune_bindings(ri, now)
        objs = msg.objects
        n = len(objs)
        if n == 0:
            return 0
        rows = np.array(list(map(_OBJ_FIELDS, objs)), dtype=float).reshape(n, 9)
        cov = np.array(list(map(_OBJ_COV, objs)), dtype=float).reshape(n, 3)
        ids = rows[:, 0].astype(np.int64)
        zx, zy, zvx, zvy = rows[:, 1], rows[:, 2], rows[:, 3], rows[:, 4]
        rxx = np.maximum(cov[:, 0], 1e-4)
        ryy = np.maximum(cov[:, 2], 1e-4)
        bindings = self._maps[ri]
        slot_arr = np.full(n, -1, dtype=np.int64)
        gid_arr = np.full(n, -1, dtype=np.int64)
        for k, oid in enumerate(ids.tolist()):
            b = bindings.get(oid)
            if b is not None:
                slot_arr[k], gid_arr[k] = b
        has = slot_arr >= 0
        if has.any():
            s_h = slot_arr[has]
            ok = self.alive[s_h] & (self.gid[s_h] == gid_arr[has])
            px, py, _, _ = self._predicted(s_h, t_meas)
            ok &= np.hypot(zx[has] - px, zy[has] - py) <= cfg.map_gate_m
            idx = np.nonzero(has)[0]
            slot_arr[idx[~ok]] = -1
            # two objects of one frame bound to one track (after a merge): keep the first
            valid = slot_arr >= 0
            if valid.any():
                _, first = np.unique(slot_arr[valid], return_index=True)
                keep = np.zeros(int(valid.sum()), dtype=bool)
                keep[first] = True
                vidx = np.nonzero(valid)[0]
                slot_arr[vidx[~keep]] = -1
        matched = slot_arr >= 0
        unm = np.nonzero(~matched)[0]
        if len(unm):
            claimed = slot_arr[matched]
            cand = self._candidates(zx[unm], zy[unm], claimed)
            if len(cand):
                px, py, varx, vary = self._predicted(cand, t_meas)
                dx = zx[unm][:, None] - px[None, :]
                dy = zy[unm][:, None] - py[None, :]
                sx = np.maximum(varx[None, :] + rxx[unm][:, None], cfg.min_pos_var_m2)
                sy = np.maximum(vary[None, :] + ryy[unm][:, None], cfg.min_pos_var_m2)
                d2 = dx * dx / sx + dy * dy / sy
                dv = np.hypot(zvx[unm][:, None] - self.vx[cand][None, :], zvy[unm][:, None] - self.vy[cand][None, :])
                # an RSU track younger than velocity_settle_s has no usable velocity yet: gate on position
                dv = np.where(rows[unm, 8][:, None] < cfg.velocity_settle_s, 0.0, dv)
                ok = (d2 <= cfg.gate_chi2) & (dv <= cfg.gate_speed_mps)
                if ok.any():
                    cost = np.where(ok, d2 + (dv / cfg.gate_speed_mps) ** 2, 1e6)
                    r, c = linear_sum_assignment(cost)
                    good = ok[r, c]
                    slot_arr[unm[r[good]]] = cand[c[good]]
            new = np.nonzero(slot_arr < 0)[0]
            if len(new):
                slots = self._alloc(len(new))
                self._init_tracks(slots, zx[new], zy[new], zvx[new], zvy[new], rxx[new], ryy[new], t_meas, now)
                slot_arr[new] = slots
            for k in unm.tolist():
                self._bind(ri, int(ids[k]), int(slot_arr[k]))
        # filter update (out-of-sequence lists are moved forward to the track time)
        st = slot_arr
        dt = t_meas - self.t[st]
        late = dt < 0
        if late.any():
            lag = np.where(late, -dt, 0.0)
            zx = zx + zvx * lag
            zy = zy + zvy * lag
            infl = lag * lag * cfg.vel_meas_var_m2ps2
            rxx, ryy = rxx + infl, ryy + infl
            dt = np.maximum(dt, 0.0)
        # a young RSU track's velocity is still converging from zero: barely trust it
        young = rows[:, 8] < cfg.velocity_settle_s
        r_v = np.where(young, cfg.young_vel_meas_var_m2ps2, cfg.vel_meas_var_m2ps2)
        fresh = self.hits[st] == 0
        if (fresh & young).any():  # tracks born from young objects: velocity unknown
            f = st[fresh & young]
            self.pvv_x[f] = self.pvv_y[f] = cfg.young_vel_meas_var_m2ps2
        self._kf_axis(st, dt, zx, zvx, rxx, "x", r_v)
        self._kf_axis(st, dt, zy, zvy, ryy, "y", r_v)
        self.t[st] = np.maximum(self.t[st], t_meas)
        self.seen[st] = now
        self.hits[st] += 1
        self.length[st] = rows[:, 5]
        self.width[st] = rows[:, 6]
        self.last_rsu[st] = ri
        # per-object attributes that are not numbers: a short loop over the frame
        seen_map = self._bind_seen[ri]
        for k, o in enumerate(objs):
            s = int(st[k])
            seen_map[o.object_id] = now
            code = _TYPE_CODES[o.obj_type]
            self.otype[s] = code
            self.lane[s] = -1 if o.lane is None else o.lane
            if o.ev_state == EvState.CONFIRMED and code == _EV_CODE:
                self.ev_obj_until[s] = now + cfg.ev_object_hold_s
            elif o.ev_state == EvState.CLEARED:
                self.ev_obj_until[s] = 0.0
        self.stats.objects += n
        return n

    def _prune_bindings(self, ri: int, now: float) -> None:
        """Forget (rsu, object id) bindings the RSU has not reported for ``track_timeout_s``: the RSU lost
        the object, and ``Track.rsus`` lists only the RSUs that currently see a track."""
        seen_map, bindings = self._bind_seen[ri], self._maps[ri]
        horizon = now - self.config.track_timeout_s
        for oid in [o for o, t in seen_map.items() if t < horizon]:
            del seen_map[oid]
            b = bindings.pop(oid, None)
            if b is not None:
                self._slot_keys.get(b[0], set()).discard((ri, oid))

    def _candidates(self, zx: np.ndarray, zy: np.ndarray, claimed: np.ndarray) -> np.ndarray:
        """Alive, unclaimed tracks inside the measurements' bounding box grown by a generous margin."""
        margin = 15.0
        live = self.alive.copy()
        if len(claimed):
            live[claimed] = False
        m = live & (self.x >= zx.min() - margin) & (self.x <= zx.max() + margin)
        m &= (self.y >= zy.min() - margin) & (self.y <= zy.max() + margin)
        return np.nonzero(m)[0]

    def _init_tracks(self, slots, zx, zy, zvx, zvy, rxx, ryy, t_meas: float, now: float) -> None:
        self.alive[slots] = True
        self.ev_suppressed[slots] = False
        self.ev_named[slots] = False
        self.x[slots], self.y[slots], self.vx[slots], self.vy[slots] = zx, zy, zvx, zvy
        self.pxx[slots], self.pyy[slots] = rxx, ryy
        self.pxv[slots] = 0.0
        self.pyv[slots] = 0.0
        self.pvv_x[slots] = 4.0 * self.config.vel_meas_var_m2ps2
        self.pvv_y[slots] = 4.0 * self.config.vel_meas_var_m2ps2
        self.t[slots] = t_meas
        self.seen[slots] = now
        self.first[slots] = now
        self.hits[slots] = 0
        self.ev_obj_until[slots] = 0.0
        self.ev_alert_until[slots] = 0.0
        self.lane[slots] = -1
        for s in slots.tolist():
            g = self._next_gid
            self._next_gid += 1
            self.gid[s] = g
            self._slot_of_gid[g] = s
        self.stats.new_tracks += len(slots)

    def ingest_rsu_health(self, rsu_id: str, now: float) -> None:
        self._rsu(rsu_id)
        self.rsu_last_health[rsu_id] = now
        if self.started_s is None:
            self.started_s = now

    def ingest_ev_alert(self, alert: EvAlert, now: float) -> int | None:
        """Mark (active) or unmark (cleared) the EV track the alert names; returns its track id."""
        cfg = self.config
        if self.started_s is None:
            self.started_s = now
        rec = self.alerts.get(alert.alert_id)
        if rec is None:
            rec = AlertRecord(alert.alert_id, alert.rsu_id, alert.object_id, alert.state, alert.pos_x_m,
                              alert.pos_y_m, alert.vel_x_mps, alert.vel_y_mps, alert.lane, alert.stamp, now)
            self.alerts[alert.alert_id] = rec
        else:
            rec.rsu_id, rec.object_id, rec.state = alert.rsu_id, alert.object_id, alert.state
            rec.x_m, rec.y_m, rec.vx_mps, rec.vy_mps = alert.pos_x_m, alert.pos_y_m, alert.vel_x_mps, alert.vel_y_mps
            rec.lane, rec.stamp_s, rec.last_seen_s = alert.lane, alert.stamp, now
        slot = self._resolve_alert_slot(alert)
        if alert.state == AlertState.CLEARED:
            if slot is None and rec.track_id is not None:
                slot = self._slot_of_gid.get(rec.track_id)
            if alert.clear_reason == ClearReason.OUT_OF_VIEW:
                # the EV left this RSU's view, it did not stop being an EV: its mark runs out on its own
                # (ev_alert_timeout_s after the last refresh) unless the next RSU alerts on it first
                if slot is not None and self._alert_of_slot.get(slot) == alert.alert_id:
                    self._alert_of_slot.pop(slot, None)
                rec.track_id = None if slot is None else int(self.gid[slot])
                return rec.track_id
            if slot is not None:
                self.ev_alert_until[slot] = 0.0
                self.ev_obj_until[slot] = 0.0
                self.ev_suppressed[slot] = True
                self.ev_named[slot] = False
                self._alert_of_slot.pop(slot, None)
            rec.track_id = None if slot is None else int(self.gid[slot])
            return rec.track_id
        if slot is None:
            # the EV is known only from its alert: start a track from it
            slot = int(self._alloc(1)[0])
            var = np.array([1.0])
            self._init_tracks(np.array([slot]), np.array([alert.pos_x_m]), np.array([alert.pos_y_m]),
                              np.array([alert.vel_x_mps]), np.array([alert.vel_y_mps]), var, var,
                              min(alert.stamp, now), now)
            self.otype[slot] = _EV_CODE
            self.lane[slot] = -1 if alert.lane is None else alert.lane
            self.length[slot], self.width[slot] = 5.5, 2.0
        self.ev_alert_until[slot] = now + cfg.ev_alert_timeout_s
        self.ev_suppressed[slot] = False
        self.ev_named[slot] = True
        self._alert_of_slot[slot] = alert.alert_id
        rec.track_id = int(self.gid[slot])
        return rec.track_id

    def _resolve_alert_slot(self, alert: EvAlert) -> int | None:
        ri = self._rsu_index.get(alert.rsu_id)
        if ri is not None:
            b = self._maps[ri].get(alert.object_id)
            if b is not None and self.alive[b[0]] and self.gid[b[0]] == b[1]:
                return b[0]
        rec = self.alerts.get(alert.alert_id)
        if rec is not None and rec.track_id is not None:
            s = self._slot_of_gid.get(rec.track_id)
            if s is not None:
                return s
        live = np.nonzero(self.alive)[0]
        if not len(live):
            return None
        px, py, _, _ = self._predicted(live, alert.stamp)
        d = np.hypot(px - alert.pos_x_m, py - alert.pos_y_m)
        dv = np.hypot(self.vx[live] - alert.vel_x_mps, self.vy[live] - alert.vel_y_mps)
        d = np.where(dv <= self.config.gate_speed_mps, d, np.inf)
        k = int(np.argmin(d))
        return int(live[k]) if d[k] <= self.config.vehicle_gate_m else None

    def ingest_vehicle_state(self, vs: VehicleState, now: float) -> int | None:
        """Record an AV's own state and bind it to its corridor track; returns the track id."""
        rec = self.vehicles.get(vs.vehicle_id)
        if rec is None:
            rec = self.vehicles[vs.vehicle_id] = VehicleRecord(vs, now)
        rec.state, rec.received_s = vs, now
        live = np.nonzero(self.alive)[0]
        old_slot = None if rec.track_id is None else self._slot_of_gid.get(rec.track_id)
        new_slot = None
        if len(live):
            px, py, _, _ = self._predicted(live, vs.stamp)
            d = np.hypot(px - vs.pos_x_m, py - vs.pos_y_m)
            k = int(np.argmin(d))
            if d[k] <= self.config.vehicle_gate_m:
                new_slot = int(live[k])
        if old_slot is not None and old_slot != new_slot:
            self._vehicle_of_slot.pop(old_slot, None)
        if new_slot is not None:
            self._vehicle_of_slot[new_slot] = vs.vehicle_id
        rec.track_id = None if new_slot is None else int(self.gid[new_slot])
        return rec.track_id

    # ------------------------------------------------------------------ maintenance
    def maintain(self, now: float) -> None:
        """Delete tracks not updated for ``track_timeout_s``, merge duplicates, forget old alerts."""
        cfg = self.config
        dead = np.nonzero(self.alive & (now - self.seen > cfg.track_timeout_s))[0]
        for s in dead.tolist():
            self._delete(s)
        self.stats.deleted += len(dead)
        self._merge_duplicates(now)
        for aid in [a for a, r in self.alerts.items() if now - r.last_seen_s > cfg.ev_alert_timeout_s]:
            del self.alerts[aid]

    def _merge_duplicates(self, now: float) -> None:
        live = np.nonzero(self.alive)[0]
        if len(live) < 2:
            return
        px, py, _, _ = self._predicted(live, now)
        pairs = cKDTree(np.column_stack([px, py])).query_pairs(self.config.merge_distance_m, output_type="ndarray")
        for a, b in pairs.tolist():
            sa, sb = int(live[a]), int(live[b])
            if not (self.alive[sa] and self.alive[sb]):
                continue
            young = min(now - self.first[sa], now - self.first[sb]) < self.config.velocity_settle_s
            if not young and math.hypot(self.vx[sa] - self.vx[sb], self.vy[sa] - self.vy[sb]) > self.config.gate_speed_mps:
                continue  # (a young track's velocity is not known yet: position decides)
            ra = {k[0] for k in self._slot_keys.get(sa, ())}
            rb = {k[0] for k in self._slot_keys.get(sb, ())}
            if ra & rb:
                continue  # one RSU sees both: two cars
            keep, drop = (sa, sb) if self.gid[sa] < self.gid[sb] else (sb, sa)
            for ri, oid in list(self._slot_keys.get(drop, ())):
                self._bind(ri, oid, keep)
            self.hits[keep] += self.hits[drop]
            self.first[keep] = min(self.first[keep], self.first[drop])
            self.ev_alert_until[keep] = max(self.ev_alert_until[keep], self.ev_alert_until[drop])
            self.ev_obj_until[keep] = max(self.ev_obj_until[keep], self.ev_obj_until[drop])
            self.ev_named[keep] |= self.ev_named[drop]
            if drop in self._alert_of_slot:
                aid = self._alert_of_slot.pop(drop)
                self._alert_of_slot[keep] = aid
                if aid in self.alerts:
                    self.alerts[aid].track_id = int(self.gid[keep])
            self._delete(drop)
            self.stats.merged += 1

    def stale_rsus(self, now: float) -> list[str]:
        """RSUs whose object stream (or health) has stopped; expected RSUs never heard count after the
        first ``rsu_stale_s`` of listening."""
        cfg = self.config
        out = []
        for name in self._rsu_names:
            last = self.rsu_last_objects.get(name)
            h = self.rsu_last_health.get(name)
            if last is None:
                ref = h if h is not None else self.started_s
                if ref is not None and now - ref > cfg.rsu_stale_s:
                    out.append(name)
                continue
            if now - last > cfg.rsu_stale_s or (h is not None and now - h > cfg.rsu_health_stale_s):
                out.append(name)
        return out

    @property
    def rsu_ids(self) -> list[str]:
        return list(self._rsu_names)

    def knows_rsu(self, rsu_id: str) -> bool:
        return rsu_id in self._rsu_index

    # ------------------------------------------------------------------ reading
    def is_ev_mask(self, slots: np.ndarray, now: float) -> np.ndarray:
        by_objects = (self.ev_obj_until[slots] > now) & ~self.ev_suppressed[slots]
        if not self.config.ev_from_objects_alone:
            by_objects &= self.ev_named[slots]
        return (self.ev_alert_until[slots] > now) | by_objects

    def _tracks(self, slots: np.ndarray, now: float) -> list[Track]:
        """Track records for ``slots`` predicted to ``now`` (columns gathered once, vectorised)."""
        if not len(slots):
            return []
        dt = now - self.t[slots]
        cols = zip(
            self.gid[slots].tolist(), (self.x[slots] + self.vx[slots] * dt).tolist(),
            (self.y[slots] + self.vy[slots] * dt).tolist(), self.vx[slots].tolist(), self.vy[slots].tolist(),
            self.length[slots].tolist(), self.width[slots].tolist(), self.otype[slots].tolist(),
            self.is_ev_mask(slots, now).tolist(), self.lane[slots].tolist(), self.hits[slots].tolist(),
            self.first[slots].tolist(), self.seen[slots].tolist(), (0.5 * (self.pxx[slots] + self.pyy[slots])).tolist(),
            slots.tolist(), strict=True)
        names, keys, alerts, vehicles = self._rsu_names, self._slot_keys, self._alert_of_slot, self._vehicle_of_slot
        return [
            Track(g, x, y, vx, vy, ln, wd, _TYPES[ot], ev, alerts.get(s), None if lane < 0 else lane,
                  vehicles.get(s), hits, first, seen, var, tuple(sorted({names[ri] for ri, _ in keys.get(s, ())})))
            for g, x, y, vx, vy, ln, wd, ot, ev, lane, hits, first, seen, var, s in cols
        ]

    def tracks(self, now: float) -> list[Track]:
        """Every live track, predicted to ``now``, ordered by id."""
        return sorted(self._tracks(np.nonzero(self.alive)[0], now), key=lambda t: t.track_id)

    def track(self, track_id: int, now: float) -> Track | None:
        s = self._slot_of_gid.get(track_id)
        return None if s is None else self._tracks(np.array([s]), now)[0]

    def tracks_near(self, x_m: float, y_m: float, radius_m: float, now: float) -> list[Track]:
        live = np.nonzero(self.alive)[0]
        if not len(live):
            return []
        dt = now - self.t[live]
        d = np.hypot(self.x[live] + self.vx[live] * dt - x_m, self.y[live] + self.vy[live] * dt - y_m)
        return self._tracks(live[d <= radius_m], now)

    def ev_tracks(self, now: float) -> list[Track]:
        """Tracks currently marked EV (by an active alert or a confirmed detection)."""
        live = np.nonzero(self.alive)[0]
        return self._tracks(live[self.is_ev_mask(live, now)], now)

    def vehicle_track_id(self, vehicle_id: str) -> int | None:
        rec = self.vehicles.get(vehicle_id)
        return None if rec is None else rec.track_id
