"""The DDM's V2X input: the EV CAMs that RSU radios pass on, verified, fused with the cameras, acted on.

``V2xInput(service).start()`` subscribes to ``iea/{c}/v2x/rsu/*/rx``. Each relay is verified end to end
(``protocol.v2x.secure.verify_relayed_cam``: the RSU's signature, the EV's inside it, station scope, freshness,
replay); a refusal is counted in the service's ``rejected`` under ``v2x_<reason>``. A verified CAM is put in the
corridor frame and assessed against the cameras' live tracks and views (``ddm.v2x_fusion``). A believed CAM of an
EV on duty (emergency role, light bar or siren on) becomes an ``EvAlert`` of the DDM's own
(``alert_id`` ``v2x-<station>``; confidence: the association's probability, or 0.9 from the CAM alone) handed to
the service's EV-alert path, which decides at once as for a camera alert; when the station's lights go off, the
alert is cleared (``lights_off``). ``evidence`` holds each station's latest ``vision+v2x`` / ``v2x`` /
``contradicted`` / ``ambiguous``; camera alerts are ``vision``.
"""

from __future__ import annotations

import logging
import math
import time
from collections import Counter
from typing import Any

import numpy as np

from ddm.v2x_fusion import CameraTracks, CameraView, CamObservation, V2xFusion, V2xFusionConfig
from protocol.enums import AlertState, ClearReason
from protocol.messages import EvAlert
from protocol.security import AuthError, TrustList
from protocol.v2x.codec import V2xError
from protocol.v2x.keys import v2x_rsu_expr
from protocol.v2x.secure import CamReplayGuard, RelayedCam, verify_relayed_cam

log = logging.getLogger(__name__)

DEFAULT_VIEW_RANGE_M = 120.0
"""Ground range of a camera's view when the corridor gives its RSU no ``max_range_m``."""
CAM_ONLY_CONFIDENCE = 0.9
COUNTER_OF_EVIDENCE = {"vision+v2x": "v2x_with_vision", "v2x": "v2x_alone", "contradicted": "v2x_contradicted",
                       "ambiguous": "v2x_ambiguous", "unconfirmed": "v2x_unconfirmed"}
"""The service's counter of each evidence (names that are key chunks, as Health's)."""
NO_OBJECT_ID = 2**31 - 1
"""The object id of a V2X alert: no RSU object (the DDM's track is found by position)."""


def camera_views(corridor: Any, last_report: dict[str, float]) -> list[CameraView]:
    out = []
    for r in corridor.rsus:
        cam = r.camera
        half_fov = math.atan2(cam.width_px / 2.0, cam.fx_px)
        out.append(CameraView(r.rsu_id, cam.x_m, cam.y_m, cam.yaw_rad, half_fov,
                              r.max_range_m or DEFAULT_VIEW_RANGE_M, last_report.get(r.rsu_id)))
    return out


class V2xInput:
    def __init__(self, service: Any, config: V2xFusionConfig | None = None) -> None:
        self.service = service
        self.trust = TrustList.from_corridor(service.corridor)
        self.fusion = V2xFusion(config or V2xFusionConfig())
        self.replay = CamReplayGuard()
        self.evidence: dict[int, str] = {}
        self.active: dict[int, str] = {}
        self.counts: Counter = Counter()
        self._seq: dict[str, int] = {}
        self._sub = None

    def start(self) -> V2xInput:
        self._sub = self.service.transport.subscribe_bytes(v2x_rsu_expr(self.service.corridor_id, "rx"), self.on_bytes)
        return self

    def close(self) -> None:
        if self._sub is not None:
            self._sub.close()
            self._sub = None

    def _tracks(self) -> CameraTracks:
        store = self.service.world.store
        live = store.live_slots()
        if not len(live):
            return CameraTracks.empty()
        c = store.cols
        keep = live[c.hits[live] > 0]  # a track only an alert started (no camera has updated it) is no camera evidence
        var = 0.5 * (c.var_x_m2[keep] + c.var_y_m2[keep])
        return CameraTracks(c.gid[keep].astype(np.int64), c.x_m[keep], c.y_m[keep], c.vx_mps[keep], c.vy_mps[keep],
                            var, c.t_s[keep])

    def on_bytes(self, key: str, payload: bytes) -> None:
        t0 = time.perf_counter()
        svc = self.service
        now = svc.clock.now()
        try:
            relayed = verify_relayed_cam(key, payload, self.trust, now, self.replay)
        except AuthError as e:
            self.counts[f"refused_{e.reason}"] += 1
            svc._reject(f"v2x_{e.reason}", f"{key}: {e}")
            return
        except V2xError as e:
            self.counts["refused_bad_bytes"] += 1
            svc._reject("v2x_bad_bytes", f"{key}: {e}")
            return
        if relayed is None:
            self.counts["duplicate"] += 1
            return
        with svc._lock:
            self._on_cam(key, relayed, now, t0)

    def observation(self, relayed: RelayedCam) -> CamObservation | None:
        info = relayed.info
        if info.lat_deg is None or info.lon_deg is None:
            return None
        x, y = self.service.corridor.from_latlon(info.lat_deg, info.lon_deg)
        sigma = (info.position_semi_major_m or 5.0) / 2.45
        return CamObservation(info.station_id, relayed.rx_time_s, x, y, info.heading_rad, info.speed_mps, sigma,
                              info.ev_on_duty)

    def _on_cam(self, key: str, relayed: RelayedCam, now: float, t0: float) -> None:
        svc = self.service
        obs = self.observation(relayed)
        if obs is None:
            self.counts["no_position"] += 1
            return
        self.counts["cams"] += 1
        station = obs.station_id
        if not obs.ev_on_duty:
            if station in self.active:
                self._alert(key, relayed, obs, AlertState.CLEARED, 1.0, now, t0)
                del self.active[station]
            return
        views = camera_views(svc.corridor, svc.world.rsu_last_objects)
        a = self.fusion.assess(obs, self._tracks(), views, now)
        self.evidence[station] = a.evidence
        self.counts[a.evidence] += 1
        svc.counters[COUNTER_OF_EVIDENCE[a.evidence]] += 1
        if not a.believed:
            return
        conf = a.association.probability if a.evidence == "vision+v2x" else CAM_ONLY_CONFIDENCE
        self.active[station] = f"v2x-{station}"
        self._alert(key, relayed, obs, AlertState.ACTIVE, conf, now, t0)

    def _alert(self, key: str, relayed: RelayedCam, obs: CamObservation, state: AlertState, confidence: float,
               now: float, t0: float) -> None:
        speed = obs.speed_mps or 0.0
        heading = obs.heading_rad or 0.0
        seq = self._seq[key] = self._seq.get(key, -1) + 1  # per key: the service counts gaps per key
        alert = EvAlert(
            src=f"v2x-{relayed.rsu_id}", seq=seq, stamp=now, alert_id=f"v2x-{obs.station_id}", state=state,
            rsu_id=relayed.rsu_id, object_id=NO_OBJECT_ID, pos_x_m=obs.x_m, pos_y_m=obs.y_m,
            lat_deg=relayed.info.lat_deg, lon_deg=relayed.info.lon_deg, vel_x_mps=speed * math.cos(heading),
            vel_y_mps=speed * math.sin(heading), speed_mps=abs(speed), heading_rad=heading,
            confidence=min(1.0, max(0.0, confidence)), first_seen=relayed.signed_from_s,
            clear_reason=ClearReason.LIGHTS_OFF if state == AlertState.CLEARED else None)
        self.counts[f"alerts_{state.value}"] += 1
        self.service._on_ev_alert(key, alert, now, t0)
