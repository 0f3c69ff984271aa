"""Manoeuvre rules both policies use (EV, :mod:`ddm.policy.ev`; hazard, :mod:`ddm.policy.hazard`). Pure.

- Where the AV is on the road (:func:`road_pose`): station, offset, heading error and speed along the road
  in the road (Frenet) frame, and the lane it drives in.
- Which tracks are other traffic (:func:`traffic`): not the AV's own track, nor a track within
  ``SELF_RADIUS_M`` of it (an RSU track of the AV that is not bound to it).
- Gap check (lane change / merge into lane L, :func:`gap_check`): every other track in lane L needs a
  bumper-to-bumper clearance of at least ``gap_min_m + gap_time_s * v_follower + max(0, v_follower -
  v_leader) * t_change`` (the headway the follower needs plus what the speed difference eats during the
  manoeuvre); a stop in lane L (pull-over) needs room behind its leader and leaves its follower room to
  stop (:func:`leader_room_m`).
- How long a lane change takes (:func:`lane_change_time_s`) at the speed it starts with.
- Where to stop before an obstacle ahead (:func:`stop_before_s_m`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ddm.config import DdmConfig
from ddm.geometry import RoadFrame
from ddm.intent import Ego
from ddm.paths import lane_change_length, min_stop_distance_m
from ddm.tracks import Track

SELF_RADIUS_M = 2.0
"""A track whose centre is this close to the AV's is the AV itself (two cars' centres never are)."""


def wrap_angle(a: float) -> float:
    """``a`` in [-pi, pi)."""
    return (a + math.pi) % (2 * math.pi) - math.pi


@dataclass(frozen=True)
class RoadPose:
    """An AV in the road frame: station ``s_m``, offset ``d_m`` (positive left of the reference line),
    heading error to the road, speed along the road, and the lane of its offset (-1: off the carriageway)."""

    s_m: float
    d_m: float
    heading_error_rad: float
    speed_along_mps: float
    lane_raw: int


def road_pose(ego: Ego, frame: RoadFrame) -> RoadPose:
    s_arr, d_arr = frame.to_frenet(ego.x_m, ego.y_m)
    s_e, d_e = float(s_arr[0]), float(d_arr[0])
    h_err = wrap_angle(ego.heading_rad - float(frame.heading_at(s_e)))
    return RoadPose(s_e, d_e, h_err, ego.speed_mps * math.cos(h_err), int(frame.lane_of(d_e)))


def traffic(ego: Ego, others: list[Track], exclude: set[int] = frozenset()) -> list[Track]:
    """The tracks of ``others`` that are neither the AV (its bound track, or a track within
    ``SELF_RADIUS_M`` of it) nor in ``exclude``."""
    own = {o.track_id for o in others if math.hypot(o.x_m - ego.x_m, o.y_m - ego.y_m) < SELF_RADIUS_M}
    if ego.track_id is not None:
        own.add(ego.track_id)
    return [o for o in others if o.track_id not in exclude and o.track_id not in own]


def lane_change_time_s(delta_d_m: float, speed_mps: float, cfg: DdmConfig) -> float:
    """How long a lane change over ``delta_d_m`` takes at ``speed_mps`` (at least 2 m/s), on a straight road."""
    v = max(speed_mps, 2.0)
    return lane_change_length(delta_d_m, v, 0.0, cfg) / v


def stop_before_s_m(obstacle_s_m: float, obstacle_length_m: float, gap_m: float, ego_length_m: float) -> float:
    """Station of the AV's centre when its front bumper stands ``gap_m`` before an obstacle's near edge."""
    return obstacle_s_m - obstacle_length_m / 2.0 - gap_m - ego_length_m / 2.0


ENTER_FRACTION = 0.3
"""When the AV's body starts to enter the target lane, as a fraction of its lane change (quintic from one lane
centre to the next: the near side of a 1.9 m wide car crosses the line at 24 % of the shift, 35 % of the time)."""
MIN_START_GAP_M = 1.0
"""Whatever the speeds, a pull-over does not start with a follower closer than this behind the AV's rear."""


class GapCheck(tuple):
    """``(ok, explanation)`` of ``gap_check``; ``blocker_speed_mps`` is the speed along the road of the
    vehicle that makes the gap unsafe (None when the gap is safe)."""

    def __new__(cls, ok: bool, why: str, blocker_speed_mps: float | None = None,
                room_ahead_m: float | None = None, blocker_role: str | None = None) -> GapCheck:
        self = super().__new__(cls, (ok, why))
        self.blocker_speed_mps = blocker_speed_mps
        self.blocker_role = blocker_role
        """``leader`` or ``follower``: where the vehicle that makes the gap unsafe is (None when safe)."""
        self.room_ahead_m = room_ahead_m
        """``stopping`` checks: how far the AV may travel before it must be stopped behind the leader
        (None: no leader in the lane)."""
        return self


def _lane_neighbours(ego_s: float, ego_len: float, others: list[Track], frame: RoadFrame,
                     lane: int) -> list[tuple[Track, float, float, float]]:
    """(track, station offset from the AV m, bumper-to-bumper clearance m less the track's
    ``staleness_margin_m``, speed along the road m/s) of every track whose width overlaps ``lane``."""
    if not others:
        return []
    s, d = frame.to_frenet(np.array([o.x_m for o in others]), np.array([o.y_m for o in others]))
    vl = frame.longitudinal_speed(s, [o.vx_mps for o in others], [o.vy_mps for o in others])
    lo = lane * frame.lane_width_m
    hi = lo + frame.lane_width_m
    out = []
    for k, o in enumerate(others):
        half_w = max(o.width_m, 1.5) / 2.0
        if d[k] + half_w <= lo or d[k] - half_w >= hi:
            continue  # not in that lane
        ds = float(s[k]) - ego_s
        out.append((o, ds, abs(ds) - (ego_len + max(o.length_m, 3.0)) / 2.0 - staleness_margin_m(o.age_s),
                    float(vl[k])))
    return out


STALE_DECEL_MPS2 = 2.0
"""How hard a vehicle may have braked or sped up since an RSU last saw it (a driver slowing for an EV)."""
STALE_AGE_MAX_S = 3.0


def staleness_margin_m(age_s: float) -> float:
    """How far a track seen ``age_s`` ago may be from its constant-velocity prediction: 0.5 a t^2 with
    ``STALE_DECEL_MPS2``, ``age_s`` clamped to ``STALE_AGE_MAX_S``. A picture 0.1 s old costs 1 cm; one that a
    saturated backhaul delivers every 2.5 s, 6 m of every gap."""
    t = min(max(age_s, 0.0), STALE_AGE_MAX_S)
    return 0.5 * STALE_DECEL_MPS2 * t * t


def _room_behind_m(clearance_m: float, leader_speed_mps: float, cfg: DdmConfig) -> float:
    """How far the AV may travel before standing gap_min behind a leader that brakes now at the comfort
    deceleration: clearance + v_l^2 / (2 comfort) - gap_min (a leader moving backwards counts as stopped)."""
    v_l = max(leader_speed_mps, 0.0)
    return clearance_m + v_l * v_l / (2.0 * cfg.comfort_decel_mps2) - cfg.gap_min_m


def gap_check(ego_s: float, ego_v: float, ego_v_after: float, ego_len: float, target_lane: int,
              others: list[Track], frame: RoadFrame, change_time_s: float, cfg: DdmConfig,
              exclude: set[int] = frozenset(), stopping: bool = False, av_stop_m: float | None = None) -> GapCheck:
    """Is there a safe gap for the AV in ``target_lane``? (ok, explanation).

    ``stopping``: the AV will stop in that lane (pull-over), so a leader only has to leave it room
    to stop behind it even if the leader brakes too: clearance + v_l^2 / (2 comfort) >= gap_min +
    v_AV^2 / (2 max_decel); the room left is returned (``room_ahead_m``) to place the stop point. A
    follower needs a gap that does not close during the change (a slower one: ``gap_min_m`` by the time the
    AV's body enters its lane, ``ENTER_FRACTION``) and room to stop behind the AV's stop
    (``av_stop_m`` ahead: a held-speed pull-over's lane change and comfort stop; default the shortest stop
    at ``max_decel_mps2``)."""
    cand = [o for o in others if o.track_id not in exclude]
    if not cand:
        return GapCheck(True, f"lane {target_lane} empty")
    worst = ""
    room: float | None = None
    for o, ds, clearance, v_long in _lane_neighbours(ego_s, ego_len, cand, frame, target_lane):
        if ds >= 0 and stopping:  # leader of a stop: room to stop behind it
            v_l = max(v_long, 0.0)
            r = _room_behind_m(clearance, v_l, cfg)
            need_m = min_stop_distance_m(frame.lane_width_m, ego_v, 0.0, cfg)
            if r < need_m or clearance < cfg.gap_min_m:
                return GapCheck(False, f"no room to stop in lane {target_lane}: leader track {o.track_id} "
                                f"{clearance:.1f} m ahead, {r:.1f} m < {need_m:.1f} m needed", v_l,
                                blocker_role="leader")
            room = r if room is None else min(room, r)
            worst = worst or f"room to stop in lane {target_lane}"
            continue
        if ds >= 0:  # leader: the AV follows it
            v_f, v_l = ego_v, v_long
            role = "leader"
        else:  # lag: it follows the AV, which slows during the manoeuvre
            v_f, v_l = v_long, ego_v_after
            role = "follower"
        need = cfg.gap_min_m + cfg.gap_time_s * max(v_f, 0.0) + max(0.0, v_f - v_l) * change_time_s
        if stopping and role == "follower":
            # the AV ends stopped at least v^2 / (2 max_decel) ahead: the follower needs room to stop
            # behind that (reacting after gap_time_s), and a gap that does not close during the change
            v_f = max(v_f, 0.0)
            av_stop = ego_v * ego_v / (2.0 * cfg.max_decel_mps2) if av_stop_m is None else av_stop_m
            follower_stop_m = v_f * cfg.gap_time_s + v_f * v_f / (2.0 * cfg.comfort_decel_mps2)
            # a slower follower drops back while the AV crosses: gap_min is needed when the AV's body enters
            # the lane (ENTER_FRACTION of the change), not when the change starts
            grows = max(0.0, v_l - v_f) * ENTER_FRACTION * change_time_s
            need = max(cfg.gap_min_m + max(0.0, v_f - v_l) * change_time_s - grows,
                       cfg.gap_min_m + follower_stop_m - av_stop, MIN_START_GAP_M)
        if clearance < need:
            return GapCheck(False, f"unsafe gap in lane {target_lane}: {role} track {o.track_id} "
                            f"{clearance:.1f} m < {need:.1f} m needed", v_long, blocker_role=role)
        worst = worst or f"gaps in lane {target_lane} ok"
    return GapCheck(True, worst or f"lane {target_lane} clear", None, room)


def leader_room_m(ego_s: float, ego_len: float, lane: int, others: list[Track], frame: RoadFrame,
                  cfg: DdmConfig) -> float | None:
    """How far the AV may still travel in ``lane`` before it must stand behind the nearest vehicle ahead
    there, should that vehicle brake now at the comfort deceleration: min over leaders of clearance +
    v_l^2 / (2 comfort) - gap_min (the room of ``gap_check(stopping=True)``, also when it is short or
    negative). None: nobody ahead in that lane."""
    rooms = [_room_behind_m(clearance, v_long, cfg)
             for _, ds, clearance, v_long in _lane_neighbours(ego_s, ego_len, others, frame, lane) if ds >= 0]
    return min(rooms) if rooms else None
