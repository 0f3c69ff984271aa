"""Fusion of RSU object lists into the track store: predict, associate, update, merge. Pure.

- Association (per ObjectList, vectorised): an (rsu, object id) already bound to a track updates it
  directly (checked against ``map_gate_m``; two objects of one list bound to one track: the first keeps
  it); the other objects are gated in world coordinates against the tracks near them (normalised
  innovation, chi-square 2 dof, plus a velocity gate) and assigned with the Hungarian method
  (``scipy.optimize.linear_sum_assignment``); a track already claimed in this list is no candidate (one
  RSU never sees a car twice). The objects left start tracks.
- Filter: constant-velocity Kalman filter per axis (state position, velocity; both measured),
  white-acceleration process noise (Bar-Shalom, discretised continuous model): :func:`kalman_axis`.
- Time alignment: every list is processed at its ``measurement_time``; tracks are predicted to it. A list
  older than a track's state (out of sequence) is moved forward to the track's time with its own velocity
  and its variance inflated.
- Merge: two tracks closer than ``merge_distance_m`` with compatible velocities (unless one is too young
  to know its velocity), not both seen by one RSU, are one car (:func:`duplicates`).
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass
from operator import attrgetter

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.spatial import cKDTree

from ddm.config import DdmConfig
from ddm.tracks import EV_CODE, TYPE_CODES, TrackColumns, TrackStore
from protocol.enums import EvState
from protocol.messages import DetectedObject

CANDIDATE_MARGIN_M = 15.0
"""Tracks within the list's bounding box grown by this are association candidates."""
MIN_MEAS_VAR_M2 = 1e-4
_NUMBER_FIELDS = ("pos_x_m", "pos_y_m", "vel_x_mps", "vel_y_mps", "length_m", "width_m", "age_s")
_NUMBERS = attrgetter(*_NUMBER_FIELDS)
_COV = attrgetter("pos_cov_m2")


@dataclass(frozen=True, slots=True)
class ObjectColumns:
    """An object list's objects as arrays, one per field the fusion uses."""

    object_id: np.ndarray
    x_m: np.ndarray
    y_m: np.ndarray
    vx_mps: np.ndarray
    vy_mps: np.ndarray
    length_m: np.ndarray
    width_m: np.ndarray
    age_s: np.ndarray
    """How long the RSU has tracked the object (its velocity settles after ``velocity_settle_s``)."""
    var_x_m2: np.ndarray
    var_y_m2: np.ndarray


def object_columns(objs: list[DetectedObject]) -> ObjectColumns:
    n = len(objs)
    x, y, vx, vy, length, width, age = np.array(list(map(_NUMBERS, objs)), dtype=float).reshape(n, 7).T
    var_xx, _, var_yy = np.array(list(map(_COV, objs)), dtype=float).reshape(n, 3).T
    return ObjectColumns(np.fromiter((o.object_id for o in objs), np.int64, n), x, y, vx, vy, length, width,
                         age, np.maximum(var_xx, MIN_MEAS_VAR_M2), np.maximum(var_yy, MIN_MEAS_VAR_M2))


# ---------------------------------------------------------------------------------------------- filter
def predicted(c: TrackColumns, slots: np.ndarray, t: float, accel_noise: float) -> tuple[np.ndarray, ...]:
    """Positions and their variances (x, y, var x, var y) of ``slots`` predicted to ``t``."""
    dt = t - c.t_s[slots]
    dtp = np.maximum(dt, 0.0)
    q = accel_noise
    px = c.x_m[slots] + c.vx_mps[slots] * dt
    py = c.y_m[slots] + c.vy_mps[slots] * dt
    varx = c.var_x_m2[slots] + 2 * dtp * c.cov_x_vx[slots] + dtp * dtp * c.var_vx[slots] + q * dtp**3 / 3
    vary = c.var_y_m2[slots] + 2 * dtp * c.cov_y_vy[slots] + dtp * dtp * c.var_vy[slots] + q * dtp**3 / 3
    return px, py, varx, vary


def kalman_axis(p, v, pp, pv, vv, dt, z_p, z_v, r_p, r_v, q: float) -> tuple[np.ndarray, ...]:
    """One axis of the filter, vectorised: predict (p, v; covariance pp, pv, vv) by ``dt`` under white
    acceleration noise ``q``, then update with the measured position and velocity (H = I,
    R = diag(r_p, r_v); K = P (P + R)^-1 in 2x2 closed form). Returns the new (p, v, pp, pv, vv)."""
    p = p + v * dt
    pp = pp + 2 * dt * pv + dt * dt * vv + q * dt**3 / 3
    pv = pv + dt * vv + q * dt * dt / 2
    vv = vv + q * dt
    s11, s12, s22 = pp + r_p, pv, vv + r_v
    det = s11 * s22 - s12 * s12
    i11, i12, i22 = s22 / det, -s12 / det, s11 / det
    k11, k12 = pp * i11 + pv * i12, pp * i12 + pv * i22
    k21, k22 = pv * i11 + vv * i12, pv * i12 + vv * i22
    e_p, e_v = z_p - p, z_v - v
    # P = (I - K) P
    return (p + k11 * e_p + k12 * e_v, v + k21 * e_p + k22 * e_v,
            (1 - k11) * pp - k12 * pv, (1 - k11) * pv - k12 * vv, -k21 * pv + (1 - k22) * vv)


# ---------------------------------------------------------------------------------------------- fusion
def fuse(store: TrackStore, ri: int, objs: list[DetectedObject], t_meas: float, now: float,
         cfg: DdmConfig) -> int:
    """Fuse one RSU's object list (RSU index ``ri``, measured at ``t_meas``) into the store; returns how
    many tracks it started."""
    obj = object_columns(objs)
    slots = match_bound(store, ri, obj, t_meas, cfg)
    unmatched = np.nonzero(slots < 0)[0]
    started = 0
    if len(unmatched):
        match_unbound(store, obj, slots, unmatched, t_meas, cfg)
        new = np.nonzero(slots < 0)[0]
        started = len(new)
        if started:
            slots[new] = store.alloc(len(new))
            store.start(slots[new], obj.x_m[new], obj.y_m[new], obj.vx_mps[new], obj.vy_mps[new],
                        obj.var_x_m2[new], obj.var_y_m2[new], 4.0 * cfg.vel_meas_var_m2ps2, t_meas, now)
        for k in unmatched.tolist():
            store.bind(ri, int(obj.object_id[k]), int(slots[k]))
    update(store.cols, slots, obj, t_meas, now, cfg)
    label(store, ri, objs, slots, now, cfg)
    return started


def match_bound(store: TrackStore, ri: int, obj: ObjectColumns, t_meas: float, cfg: DdmConfig) -> np.ndarray:
    """Per object, the slot of the live track its (rsu, object id) is bound to, within ``map_gate_m`` of
    its prediction; -1 otherwise (and for all but the first of objects bound to one track)."""
    n = len(obj.object_id)
    slots = np.full(n, -1, dtype=np.int64)
    gids = np.full(n, -1, dtype=np.int64)
    for k, oid in enumerate(obj.object_id.tolist()):
        b = store.bound(ri, oid)
        if b is not None:
            slots[k], gids[k] = b
    has = slots >= 0
    if not has.any():
        return slots
    c = store.cols
    s_h = slots[has]
    ok = c.alive[s_h] & (c.gid[s_h] == gids[has])
    px, py, _, _ = predicted(c, s_h, t_meas, cfg.accel_noise_m2ps4)
    ok &= np.hypot(obj.x_m[has] - px, obj.y_m[has] - py) <= cfg.map_gate_m
    slots[np.nonzero(has)[0][~ok]] = -1
    valid = np.nonzero(slots >= 0)[0]  # two objects bound to one track (after a merge): keep the first
    if len(valid):
        _, first = np.unique(slots[valid], return_index=True)
        keep = np.zeros(len(valid), dtype=bool)
        keep[first] = True
        slots[valid[~keep]] = -1
    return slots


def match_unbound(store: TrackStore, obj: ObjectColumns, slots: np.ndarray, unm: np.ndarray, t_meas: float,
                  cfg: DdmConfig) -> None:
    """Assign the objects ``unm`` to unclaimed tracks inside the gates (Hungarian method), in ``slots``."""
    c = store.cols
    cand = candidates(c, obj.x_m[unm], obj.y_m[unm], slots[slots >= 0])
    if not len(cand):
        return
    px, py, varx, vary = predicted(c, cand, t_meas, cfg.accel_noise_m2ps4)
    dx = obj.x_m[unm][:, None] - px[None, :]
    dy = obj.y_m[unm][:, None] - py[None, :]
    sx = np.maximum(varx[None, :] + obj.var_x_m2[unm][:, None], cfg.min_pos_var_m2)
    sy = np.maximum(vary[None, :] + obj.var_y_m2[unm][:, None], cfg.min_pos_var_m2)
    d2 = dx * dx / sx + dy * dy / sy
    dv = np.hypot(obj.vx_mps[unm][:, None] - c.vx_mps[cand][None, :], obj.vy_mps[unm][:, None] - c.vy_mps[cand][None, :])
    # an RSU track younger than velocity_settle_s has no usable velocity yet: gate on position
    dv = np.where(obj.age_s[unm][:, None] < cfg.velocity_settle_s, 0.0, dv)
    ok = (d2 <= cfg.gate_chi2) & (dv <= cfg.gate_speed_mps)
    if ok.any():
        cost = np.where(ok, d2 + (dv / cfg.gate_speed_mps) ** 2, 1e6)
        r, k = linear_sum_assignment(cost)
        good = ok[r, k]
        slots[unm[r[good]]] = cand[k[good]]


def candidates(c: TrackColumns, zx: np.ndarray, zy: np.ndarray, claimed: np.ndarray) -> np.ndarray:
    """Alive, unclaimed tracks inside the measurements' bounding box grown by ``CANDIDATE_MARGIN_M``."""
    m = CANDIDATE_MARGIN_M
    live = c.alive.copy()
    if len(claimed):
        live[claimed] = False
    live &= (c.x_m >= zx.min() - m) & (c.x_m <= zx.max() + m)
    live &= (c.y_m >= zy.min() - m) & (c.y_m <= zy.max() + m)
    return np.nonzero(live)[0]


def update(c: TrackColumns, st: np.ndarray, obj: ObjectColumns, t_meas: float, now: float, cfg: DdmConfig) -> None:
    """The filter update of the tracks ``st`` with their objects (a list older than a track's state is
    moved forward to the track's time, its variance inflated); size and bookkeeping."""
    zx, zy, rxx, ryy = obj.x_m, obj.y_m, obj.var_x_m2, obj.var_y_m2
    dt = t_meas - c.t_s[st]
    late = dt < 0
    if late.any():
        lag = np.where(late, -dt, 0.0)
        zx, zy = zx + obj.vx_mps * lag, zy + obj.vy_mps * lag
        infl = lag * lag * cfg.vel_meas_var_m2ps2
        rxx, ryy = rxx + infl, ryy + infl
        dt = np.maximum(dt, 0.0)
    # a young RSU track's velocity is still converging from zero: barely trust it
    young = obj.age_s < cfg.velocity_settle_s
    r_v = np.where(young, cfg.young_vel_meas_var_m2ps2, cfg.vel_meas_var_m2ps2)
    fresh = c.hits[st] == 0
    if (fresh & young).any():  # tracks born from young objects: velocity unknown
        f = st[fresh & young]
        c.var_vx[f] = c.var_vy[f] = cfg.young_vel_meas_var_m2ps2
    q = cfg.accel_noise_m2ps4
    c.x_m[st], c.vx_mps[st], c.var_x_m2[st], c.cov_x_vx[st], c.var_vx[st] = kalman_axis(
        c.x_m[st], c.vx_mps[st], c.var_x_m2[st], c.cov_x_vx[st], c.var_vx[st], dt, zx, obj.vx_mps, rxx, r_v, q)
    c.y_m[st], c.vy_mps[st], c.var_y_m2[st], c.cov_y_vy[st], c.var_vy[st] = kalman_axis(
        c.y_m[st], c.vy_mps[st], c.var_y_m2[st], c.cov_y_vy[st], c.var_vy[st], dt, zy, obj.vy_mps, ryy, r_v, q)
    c.t_s[st] = np.maximum(c.t_s[st], t_meas)
    c.seen_s[st] = now
    c.hits[st] += 1
    c.length_m[st] = obj.length_m
    c.width_m[st] = obj.width_m


def label(store: TrackStore, ri: int, objs: list[DetectedObject], st: np.ndarray, now: float,
          cfg: DdmConfig) -> None:
    """Per-object attributes that are not numbers (type, lane, EV state): a short loop over the list."""
    c = store.cols
    store.note_listed(ri, [o.object_id for o in objs], now)
    for s, o in zip(st.tolist(), objs, strict=True):
        code = TYPE_CODES[o.obj_type]
        c.type_code[s] = code
        c.lane[s] = -1 if o.lane is None else o.lane
        if o.ev_state == EvState.CONFIRMED and code == EV_CODE:
            c.ev_obj_until_s[s] = now + cfg.ev_object_hold_s
        elif o.ev_state == EvState.CLEARED:
            c.ev_obj_until_s[s] = 0.0


# ---------------------------------------------------------------------------------------------- merge
def duplicates(store: TrackStore, now: float, cfg: DdmConfig) -> Iterator[tuple[int, int]]:
    """(keep, drop) slots of close tracks that are one car: predicted within ``merge_distance_m`` at
    ``now``, both alive, velocities within ``gate_speed_mps`` (unless one is younger than
    ``velocity_settle_s``: position decides), no RSU sees both; the older id keeps. Judged a pair at a
    time: the caller merges each (``TrackStore.absorb``, then deletes ``drop``) before the next."""
    live = store.live_slots()
    if len(live) < 2:
        return
    c = store.cols
    px, py, _, _ = predicted(c, live, now, cfg.accel_noise_m2ps4)
    pairs = cKDTree(np.column_stack([px, py])).query_pairs(cfg.merge_distance_m, output_type="ndarray")
    alive, first_s, vx, vy, gid = c.alive, c.first_s, c.vx_mps, c.vy_mps, c.gid  # changed in place only
    for a, b in pairs.tolist():
        sa, sb = int(live[a]), int(live[b])
        if not (alive[sa] and alive[sb]):
            continue
        young = min(now - first_s[sa], now - first_s[sb]) < cfg.velocity_settle_s
        if not young and math.hypot(vx[sa] - vx[sb], vy[sa] - vy[sb]) > cfg.gate_speed_mps:
            continue
        if store.share_an_rsu(sa, sb):
            continue  # one RSU sees both: two cars
        yield (sa, sb) if gid[sa] < gid[sb] else (sb, sa)
