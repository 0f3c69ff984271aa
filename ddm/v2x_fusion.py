"""Fusion of an EV's own CAM with the cameras' tracks. Pure.

- Association (probabilistic data association, Bar-Shalom & Fortmann 1988, 6.4): the CAM's position,
  predicted to the track's time with the CAM's velocity, against each camera track predicted likewise. A track is
  a candidate when it passes three gates: position (normalised innovation ``d2 = |r|^2 / s2`` with
  ``s2 = sigma_cam^2 + sigma_track^2``, chi-square 2 dof at ``gate_p``), heading (within ``heading_gate_rad`` when
  both move faster than ``moving_mps``) and speed (within ``max(speed_gate_mps, speed_gate_frac * v)``). Its
  likelihood is the bivariate Gaussian ``L = exp(-d2 / 2) / (2 pi s2)``; the probability that the CAM's station is
  track ``i`` is ``L_i / (b + sum_j L_j)`` with ``b = clutter_density_pm2 * (1 - p_detect) / p_detect``: the
  density of a position where the cameras have no track of the station (not yet detected, or out of view). With
  the gates' tails left out this is the exact posterior under those densities (``tests`` check its calibration on
  random scenes).
- Consistency: a station's CAMs must agree with each other kinematically (``V2xFusion._streak``) for
  ``min_consistent_cams`` in a row before it is believed (``unconfirmed`` until then; a jump starts the count
  again and ends any grace): positions that hop about, or stand still while the CAM says it drives, move nothing.
- Evidence: ``vision+v2x`` when the best association has at least ``p_min`` and the station's last
  ``min_consistent_cams`` CAMs were all associated with that same track (the CAM names a car the cameras follow),
  ``v2x`` when no camera has a clear view of the CAM's position (beyond the last camera, behind a curve, a camera
  down), ``contradicted`` when a camera that reported within ``fresh_s`` looks at the position and sees no car
  there, ``ambiguous`` when it sees a car there but not one the CAMs name steadily (a claim passing through
  traffic rides on one car after another): neither of the last two is believed by itself (a compromised key
  cannot summon an EV into a camera's view by driving its claim through the cars there). A station already
  believed keeps being believed for ``grace_s`` of either, the time a camera takes to start a track on a car
  entering its view.
- Authenticity is checked before (``protocol.v2x.secure``): this module sees only verified, fresh CAMs.
- Limit: a valid EV key (stolen) whose CAMs ride on a car the cameras see is believed (``vision+v2x``): the
  cameras' own view of that car's lights is not weighed against the CAM.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

BELIEVED = ("vision+v2x", "v2x")
EVIDENCE = ("vision+v2x", "v2x", "contradicted", "ambiguous", "unconfirmed")


@dataclass(frozen=True)
class V2xFusionConfig:
    gate_p: float = 0.999
    heading_gate_rad: float = math.radians(45.0)
    moving_mps: float = 2.0
    speed_gate_mps: float = 2.0
    speed_gate_frac: float = 0.1
    """Speed gate ``max(speed_gate_mps, speed_gate_frac * v)``: a CAM's speed is the vehicle's own (CAN bus), a
    camera track's is good to well under a metre per second on a car it follows; a claim 4 m/s faster than the
    traffic matches none of it."""
    clutter_density_pm2: float = 1e-3
    p_detect: float = 0.9
    p_min: float = 0.5
    min_cam_sigma_m: float = 0.5
    fresh_s: float = 2.0
    """A camera that reported within this long watches its view (one that stutters under load keeps its say)."""
    grace_s: float = 1.0
    view_margin_m: float = 5.0
    """A position this close to the edge of a camera's view counts as out of it (a car half in view)."""
    min_consistent_cams: int = 5
    """A station is believed once this many consecutive CAMs agree kinematically (0.4 s at 10 Hz)."""
    max_cam_gap_s: float = 1.0
    window_s: float = 1.0
    max_accel_mps2: float = 4.0

    @property
    def gate_d2(self) -> float:
        return -2.0 * math.log(1.0 - self.gate_p)  # chi-square 2 dof quantile


@dataclass(frozen=True)
class CamObservation:
    """A verified CAM in the corridor frame."""

    station_id: int
    t_s: float
    x_m: float
    y_m: float
    heading_rad: float | None
    speed_mps: float | None
    sigma_m: float
    ev_on_duty: bool


@dataclass(frozen=True)
class CameraTracks:
    """The cameras' live tracks at ``t_s`` (arrays of one length)."""

    track_id: np.ndarray
    x_m: np.ndarray
    y_m: np.ndarray
    vx_mps: np.ndarray
    vy_mps: np.ndarray
    var_m2: np.ndarray
    t_s: np.ndarray

    @classmethod
    def empty(cls) -> CameraTracks:
        z = np.zeros(0)
        return cls(z.astype(np.int64), z, z, z, z, z, z)


@dataclass(frozen=True)
class CameraView:
    """One camera's ground footprint: within ``range_m`` of ``(x_m, y_m)`` and ``half_fov_rad`` of ``yaw_rad``."""

    rsu_id: str
    x_m: float
    y_m: float
    yaw_rad: float
    half_fov_rad: float
    range_m: float
    last_report_s: float | None

    def sees(self, x: float, y: float, now_s: float, cfg: V2xFusionConfig) -> bool:
        if self.last_report_s is None or now_s - self.last_report_s > cfg.fresh_s:
            return False
        dx, dy = x - self.x_m, y - self.y_m
        d = math.hypot(dx, dy)
        if d > self.range_m - cfg.view_margin_m or d < cfg.view_margin_m:
            return False
        bearing = math.atan2(dy, dx) - self.yaw_rad
        off = abs(math.atan2(math.sin(bearing), math.cos(bearing)))
        return off <= self.half_fov_rad - cfg.view_margin_m / d


@dataclass(frozen=True)
class Association:
    track_id: int | None
    probability: float
    """Probability that the CAM's station is ``track_id`` (for None: that the cameras have no track of it)."""
    candidates: int


@dataclass(frozen=True)
class Assessment:
    evidence: str
    """``vision+v2x``, ``v2x``, ``contradicted``, ``ambiguous`` or ``unconfirmed`` (see the module docstring)."""
    association: Association
    seen_by: str | None
    """The camera (RSU id) whose view is against the CAM, for ``contradicted`` and ``ambiguous``."""

    @property
    def believed(self) -> bool:
        return self.evidence in BELIEVED


def associate(cam: CamObservation, tracks: CameraTracks, cfg: V2xFusionConfig) -> Association:
    """The camera track the CAM's station most probably is, with its probability (module docstring)."""
    n = len(tracks.track_id)
    b = cfg.clutter_density_pm2 * (1.0 - cfg.p_detect) / cfg.p_detect
    if n == 0:
        return Association(None, 1.0, 0)
    cvx = cvy = 0.0
    if cam.heading_rad is not None and cam.speed_mps is not None:
        cvx, cvy = cam.speed_mps * math.cos(cam.heading_rad), cam.speed_mps * math.sin(cam.heading_rad)
    dt = tracks.t_s - cam.t_s
    rx = tracks.x_m - (cam.x_m + cvx * dt)
    ry = tracks.y_m - (cam.y_m + cvy * dt)
    s2 = max(cam.sigma_m, cfg.min_cam_sigma_m) ** 2 + np.maximum(tracks.var_m2, 0.01)
    d2 = (rx * rx + ry * ry) / s2
    ok = d2 <= cfg.gate_d2
    if cam.speed_mps is not None:
        v_track = np.hypot(tracks.vx_mps, tracks.vy_mps)
        v_cam = abs(cam.speed_mps)
        ok &= np.abs(v_track - v_cam) <= np.maximum(cfg.speed_gate_mps, cfg.speed_gate_frac * np.maximum(v_cam, v_track))
        if cam.heading_rad is not None and v_cam > cfg.moving_mps:
            h_track = np.arctan2(tracks.vy_mps, tracks.vx_mps)
            dh = np.abs(np.arctan2(np.sin(h_track - cam.heading_rad), np.cos(h_track - cam.heading_rad)))
            ok &= (v_track <= cfg.moving_mps) | (dh <= cfg.heading_gate_rad)
    if not ok.any():
        return Association(None, 1.0, 0)
    like = np.where(ok, np.exp(-0.5 * d2) / (2.0 * math.pi * s2), 0.0)
    total = b + float(like.sum())
    k = int(np.argmax(like))
    return Association(int(tracks.track_id[k]), float(like[k] / total), int(ok.sum()))


@dataclass
class _StationTrack:
    t_s: float
    x_m: float
    y_m: float
    vx_mps: float
    vy_mps: float
    streak: int
    anchor: tuple[float, float, float]
    """(t, x, y) of the CAM the current check window started at."""
    track_id: int | None = None
    """The camera track the station's CAMs were last associated with (``p_min`` or more)."""
    track_streak: int = 0
    """How many of its consecutive CAMs were associated with ``track_id``."""
    track_t_s: float | None = None
    """The time of the last CAM counted in ``track_streak`` (a repeated CAM is not counted again)."""


def _velocity(cam: CamObservation) -> tuple[float, float]:
    if cam.heading_rad is None or cam.speed_mps is None:
        return 0.0, 0.0
    return cam.speed_mps * math.cos(cam.heading_rad), cam.speed_mps * math.sin(cam.heading_rad)


@dataclass
class V2xFusion:
    """Per-station state over time: its CAMs' kinematic consistency and when it was last believed (``grace_s``)."""

    config: V2xFusionConfig = field(default_factory=V2xFusionConfig)
    believed_until_s: dict[int, float] = field(default_factory=dict)
    stations: dict[int, _StationTrack] = field(default_factory=dict)

    def _streak(self, cam: CamObservation) -> int:
        """How many consecutive CAMs of the station agree kinematically: each within the step gate of the previous
        one moved on with its velocity, and within the window gate of the window's first CAM moved on with the
        current velocity (a claim that stands still while saying it drives fails this one within 0.4 s). Gates:
        ``3 sqrt(2) sigma`` (two GNSS fixes) + 1 m, the window's + ``a_max dt^2 / 2``; windows of ``window_s``."""
        cfg = self.config
        vx, vy = _velocity(cam)
        noise_m = 3.0 * math.sqrt(2.0) * max(cam.sigma_m, cfg.min_cam_sigma_m)
        prev = self.stations.get(cam.station_id)
        streak, anchor = 1, (cam.t_s, cam.x_m, cam.y_m)
        if prev is not None:
            dt = cam.t_s - prev.t_s
            if dt <= 0.0:
                return prev.streak  # an older or repeated CAM: no new evidence
            if dt <= cfg.max_cam_gap_s:
                step = math.hypot(cam.x_m - (prev.x_m + prev.vx_mps * dt), cam.y_m - (prev.y_m + prev.vy_mps * dt))
                ta, xa, ya = prev.anchor
                da = cam.t_s - ta
                drift = math.hypot(cam.x_m - (xa + vx * da), cam.y_m - (ya + vy * da))
                if step <= noise_m + 1.0 and drift <= noise_m + 1.0 + 0.5 * cfg.max_accel_mps2 * da * da:
                    streak = prev.streak + 1
                    anchor = prev.anchor if da < cfg.window_s else (cam.t_s, cam.x_m, cam.y_m)
        self.stations[cam.station_id] = _StationTrack(cam.t_s, cam.x_m, cam.y_m, vx, vy, streak, anchor,
                                                      *((prev.track_id, prev.track_streak, prev.track_t_s)
                                                        if prev is not None else ()))
        if len(self.stations) > 1024:
            del self.stations[min(self.stations, key=lambda k: self.stations[k].t_s)]
        return streak

    def _track_streak(self, cam: CamObservation, assoc: Association) -> int:
        """How many consecutive CAMs of the station (this one included) were associated, with ``p_min`` or more,
        with the track this one is (0 when this one is not)."""
        st = self.stations.get(cam.station_id)
        if st is None:
            return 0
        if st.track_t_s is not None and cam.t_s <= st.track_t_s:
            return st.track_streak if assoc.track_id == st.track_id else 0
        st.track_t_s = cam.t_s
        if assoc.track_id is None or assoc.probability < self.config.p_min:
            st.track_id, st.track_streak = None, 0
        elif assoc.track_id == st.track_id:
            st.track_streak += 1
        else:
            st.track_id, st.track_streak = assoc.track_id, 1
        return st.track_streak

    def assess(self, cam: CamObservation, tracks: CameraTracks, views: list[CameraView], now_s: float) -> Assessment:
        cfg = self.config
        consistent = self._streak(cam) >= cfg.min_consistent_cams
        assoc = associate(cam, tracks, cfg)
        steady = self._track_streak(cam, assoc) >= cfg.min_consistent_cams
        if not consistent:
            out = Assessment("unconfirmed", assoc, None)
            self.believed_until_s.pop(cam.station_id, None)  # a jump ends any grace
            return out
        seer = next((v.rsu_id for v in views if v.sees(cam.x_m, cam.y_m, now_s, cfg)), None)
        if steady:
            out = Assessment("vision+v2x", assoc, None)
        elif seer is None:
            out = Assessment("v2x", assoc, None)
        elif now_s <= self.believed_until_s.get(cam.station_id, float("-inf")):
            return Assessment("v2x", assoc, None)  # a car entering the view: the camera's track is coming
        else:
            out = Assessment("contradicted" if assoc.track_id is None else "ambiguous", assoc, seer)
        if out.believed:
            self.believed_until_s[cam.station_id] = now_s + cfg.grace_s
        if len(self.believed_until_s) > 1024:
            oldest = min(self.believed_until_s, key=self.believed_until_s.__getitem__)
            del self.believed_until_s[oldest]
        return out
