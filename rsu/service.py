"""RSU service (thesis 3.2-3.3, Framework B): frame source -> :class:`rsu.pipeline.RsuPipeline` (detector -> SORT
-> classifier -> localiser -> EV alerts, hazards) -> ``ObjectList`` every frame, ``EvAlert`` / ``HazardAlert``
when due and ``Health`` at 1 Hz over a ``Transport``.

:class:`RsuService` is the imperative shell: it pulls frames, times every stage, publishes, writes the optional annotated
video (boxes over the corridor's lanes, road edges, coverage limit and 10 m grid drawn through the
camera: ``rsu.calibration.overlay.CalibrationOverlay``) and reports health. Frames never queue without bound: live
sources keep at most ``queue_size`` frames and drop the oldest (counted as ``drops.source``); a stalled source is
reported in Health (``degraded``) and the service keeps waiting for it.

Latest frame, not a queue: the simulated camera holds its newest ``queue_size`` frames (2, as a live
source), renders the oldest of them when the RSU asks for a frame and counts the camera frames pushed out while
the RSU was busy (``drops.source``). Health reports the processed rate
(``rates_hz.frames``, beside the camera's ``rates_hz.camera``), per stage the mean wall-clock and CPU (``{stage}_cpu``)
milliseconds per frame (``render`` when the camera renders in this process), and, for sources stamped with the
capture time, the frame's age when its ObjectList went out (``latency_ms.frame_age`` mean, ``frame_age_max``).

EV alerts (the pipeline's alert events, when it has a classifier) are published as ``EvAlert`` on
``iea/{c}/rsu/{rsu}/ev``, ``alert_id = f"{rsu_id}-ev-{track_id}"``; hazards (when it has a hazard detector) as
``HazardAlert`` on ``iea/{c}/rsu/{rsu}/hazard``, ``hazard_id = f"{rsu_id}-hz-{n}"``.

Signing: with a ``signer`` every EvAlert/HazardAlert this service publishes carries an
Ed25519 signature (``protocol.security.SecureTransport`` wraps the transport).

Presence and state: the service declares its liveliness token ``iea/{c}/alive/rsu/{rsu}`` and
answers queries on ``iea/{c}/rsu/{rsu}/*``: its latest ``objects`` and ``health``, the latest message of
each active EV alert and hazard (a DDM that starts late is EV-aware at once), and ``state``, a JSON
summary (tracks, frames, configuration) for ``iea status``.
"""

from __future__ import annotations

import json
import logging
import time
from collections import Counter

import cv2
import numpy as np

from protocol import metrics, presence
from protocol.clock import Clock, WallClock
from protocol.codec import encode
from protocol.corridor import Corridor
from protocol.enums import AlertState, EvState, HazardState, HealthStatus, LightState, Role
from protocol.keys import rsu_key, rsu_state_key
from protocol.messages import Health
from protocol.ranges import MAX_LATENCY_MS
from protocol.runtime import freeze_startup_heap
from protocol.security import SecureTransport, Signer
from protocol.transport import Transport
from rsu import wire
from rsu.calibration.overlay import CalibrationOverlay
from rsu.camera_feed import CameraFeed, default_rate_hz
from rsu.classify.alerts import AlertEvent
from rsu.frames import Frame, FrameSource, SourceError, SourceStalled
from rsu.hazard import HazardEvent
from rsu.pipeline import STAGES, FrameResult, RsuPipeline, annotate
from rsu.uplink import ShapedTransport, UplinkBudget

log = logging.getLogger(__name__)

class RsuService:
    """Runs one RSU until its source ends (or ``max_frames``/``stop()``); returns an exit code from ``run``."""

    def __init__(self, corridor: Corridor, rsu_id: str, source: FrameSource, pipeline: RsuPipeline,
                 transport: Transport, clock: Clock | None = None, *, corridor_id: str | None = None,
                 annotate_path: str | None = None, max_frames: int | None = None,
                 read_timeout_s: float = 5.0, max_stall_s: float | None = None,
                 health_period_s: float = 1.0, signer: Signer | None = None,
                 camera_rate_hz: float | None = None, uplink_bit_s: float | None = None) -> None:
        self.corridor = corridor
        corridor.road.prepare()  # its first road query would cost 0.4 s at the scenario's start
        self.rsu_id = rsu_id
        self.clock = clock or WallClock()
        self.uplink: UplinkBudget | None = None
        if uplink_bit_s is not None:  # bulk thinned to fit the uplink, alerts never (rsu.uplink)
            self.uplink = UplinkBudget(uplink_bit_s)
            transport = ShapedTransport(transport, self.uplink, self.clock)
        if signer is not None:  # alerts are signed on publication
            transport = SecureTransport(transport, self.clock, signer=signer)
        self.source, self.pipeline, self.transport = source, pipeline, transport
        cid = corridor_id or corridor.corridor_id
        self.objects_key = rsu_key(cid, rsu_id, "objects")
        self.health_key = rsu_key(cid, rsu_id, "health")
        self.ev_key = rsu_key(cid, rsu_id, "ev")
        self.hazard_key = rsu_key(cid, rsu_id, "hazard")
        self.hazards_published = Counter()
        self.alerts_published = Counter()
        self.annotate_path = annotate_path
        self.max_frames = max_frames
        self.read_timeout_s = read_timeout_s
        self.max_stall_s = max_stall_s
        self.health_period_s = health_period_s
        self._next_health_s: float | None = None
        self._seq = {"objects": 0, "health": 0, "ev": 0, "hazard": 0}
        self._writer: cv2.VideoWriter | None = None
        self._overlay: CalibrationOverlay | None = None
        # annotated frames on the corridor for Foxglove (rsu.camera_feed): None picks by source kind
        self.camera_feed = CameraFeed(transport, cid, rsu_id, default_rate_hz(source, camera_rate_hz))
        # first-use costs paid now, not in the first frames' time (a 15 fps camera's frames would be passed over):
        # PROJ's transformer for the objects' WGS84 (~25 ms), the corridor overlay of annotated frames (~70 ms)
        mast = corridor.rsu(rsu_id)
        corridor.to_latlon(mast.camera.x_m, mast.camera.y_m)
        if annotate_path or self.camera_feed.rate_hz > 0:
            self._overlay = self._calibration_overlay()
        self._stop = False
        self.frames = 0
        self.stalls = 0
        self.errors = 0
        self.last_error = ""
        self._start_s = self.clock.now()
        self._period_frames = 0
        self._period_start_s = self._start_s
        self._period_stage_s = dict.fromkeys(STAGES, 0.0)
        self._period_stage_cpu_s = dict.fromkeys(STAGES, 0.0)
        self._period_ages_s: list[float] = []
        self._stalled = False
        self.state_key = rsu_state_key(cid, rsu_id)
        self._latest: dict[str, object] = {}  # "objects" / "health" -> the last message published
        self._active: dict[str, tuple[str, object]] = {}  # alert or hazard id -> (key, its last message)
        self._handles = [presence.serve(transport, rsu_key(cid, rsu_id, "objects").rsplit("/", 1)[0] + "/*",
                                        self._answer),
                         presence.announce(transport, cid, "rsu", rsu_id)]

    def _answer(self, _query: str) -> list[tuple[str, bytes]]:
        """Replies to a query on this RSU's keys (the transport keeps those matching the query)."""
        out = [(self.objects_key if k == "objects" else self.health_key, encode(m))
               for k, m in list(self._latest.items())]
        out += [(key, encode(m)) for key, m in list(self._active.values())]
        objs = getattr(self._latest.get("objects"), "objects", [])
        summary = {"rsu_id": self.rsu_id, "frames": self.frames, "uptime_s": round(self.clock.now() - self._start_s, 2),
                   "stalled": self._stalled, "errors": self.errors, "last_error": self.last_error,
                   "source": self.source.source_id, "fps": self.source.fps,
                   "ev_alerts_active": sorted(k for k, (key, _) in self._active.items() if key == self.ev_key),
                   "hazards_active": sorted(k for k, (key, _) in self._active.items() if key == self.hazard_key),
                   "tracks": [{"id": o.object_id, "type": str(o.obj_type.value), "x_m": round(o.pos_x_m, 2),
                               "y_m": round(o.pos_y_m, 2), "speed_mps": round(o.speed_mps, 2), "lane": o.lane,
                               "ev_state": str(o.ev_state.value)} for o in objs]}
        out.append((self.state_key, json.dumps(summary, default=str).encode()))
        return out

    def close(self) -> None:
        """Withdraw the liveliness token and the queryable (the session's end does it too)."""
        presence.close_all(self._handles)

    def stop(self) -> None:
        self._stop = True

    # ------------------------------------------------------------------ loop
    def run(self) -> int:
        freeze_startup_heap()  # full GC passes scan only what the service makes from now on
        stall_started: float | None = None
        code = 0
        try:
            while not self._stop and (self.max_frames is None or self.frames < self.max_frames):
                try:
                    frame = self.source.read(self.read_timeout_s)
                except SourceStalled as exc:
                    self.stalls += 1
                    self._stalled = True
                    self.last_error = str(exc)
                    stall_started = stall_started if stall_started is not None else self.clock.now()
                    log.warning("%s", exc)
                    self._maybe_health(force=True)
                    if self.max_stall_s is not None and self.clock.now() - stall_started > self.max_stall_s:
                        log.error("source stalled for more than %.1f s: giving up", self.max_stall_s)
                        code = 3
                        break
                    continue
                except SourceError as exc:
                    self.last_error = str(exc)
                    log.error("%s", exc)
                    code = 2
                    break
                if frame is None:
                    log.info("source %s ended after %d frames", self.source.source_id, self.frames)
                    break
                stall_started, self._stalled = None, False
                self._process(frame)
                self._maybe_health()
        finally:
            self._maybe_health(force=True, final_error=code != 0)
            if self._writer is not None:
                self._writer.release()
        return code

    def process_frame(self, frame: Frame) -> None:
        """Process one frame pushed by the caller (lockstep runner) and publish what is due."""
        self._process(frame)
        self._maybe_health()

    def close_outputs(self) -> None:
        """Finish the annotated video (``run`` does this itself when its source ends)."""
        if self._writer is not None:
            self._writer.release()
            self._writer = None

    def _process(self, frame: Frame) -> None:
        try:
            result = self.pipeline.process(frame)
        except Exception as exc:  # a bad frame must not kill the RSU
            self.errors += 1
            self.last_error = f"frame {frame.frame_number}: {exc}"
            log.exception("processing frame %d failed", frame.frame_number)
            return
        t0, c0 = time.perf_counter(), time.thread_time()
        msg = wire.object_list(self.rsu_id, self._seq["objects"], self.clock.now(), frame.frame_number,
                               frame.timestamp_s, result.published)
        self.transport.publish(self.objects_key, msg)
        if self.source.stamps_capture_time:  # the frame's age when its objects went out
            self._period_ages_s.append(max(self.clock.now() - frame.timestamp_s, 0.0))
        self._latest["objects"] = msg
        self._seq["objects"] += 1
        if log.isEnabledFor(logging.DEBUG):
            for o in msg.objects:
                if o.ev_state != EvState.NONE or o.light_state == LightState.FLASHING:
                    log.debug("frame %d t %.3f: track %d ev %s lights %s score %.2f", frame.frame_number,
                              frame.timestamp_s, o.object_id, o.ev_state, o.light_state, o.ev_score)
        for event in result.alerts:
            self._publish_alert(event)
        for h in result.hazards:
            self._publish_hazard(h)
        if self.annotate_path:
            self._write_annotated(frame, result)
        self.camera_feed.offer(self.clock.now(), lambda: self._annotated(frame, result))
        result.stage_s["publish"] = time.perf_counter() - t0
        result.stage_cpu_s["publish"] = time.thread_time() - c0
        render = self.source.last_render_times_s  # a simulated camera renders in this process
        if render is not None:
            result.stage_s["render"], result.stage_cpu_s["render"] = render
        metrics.observe_stages(result.stage_s)
        for k, v in result.stage_s.items():
            self._period_stage_s[k] = self._period_stage_s.get(k, 0.0) + v
        for k, v in result.stage_cpu_s.items():
            self._period_stage_cpu_s[k] = self._period_stage_cpu_s.get(k, 0.0) + v
        self.frames += 1
        self._period_frames += 1

    def _publish_alert(self, e: AlertEvent) -> None:
        msg = wire.ev_alert(self.rsu_id, self._seq["ev"], self.clock.now(), e)
        self._publish_alert_message("ev", self.ev_key, msg.alert_id, msg, msg.state == AlertState.CLEARED)
        self.alerts_published[str(e.state)] += 1
        log.info("EvAlert %s %s (track %d, lane %s, x %.1f m, cues %s)", msg.alert_id, e.state, e.track_id, msg.lane,
                 msg.pos_x_m, "+".join(e.cues) or "-")

    def _publish_alert_message(self, kind: str, key: str, alert_id: str, msg, ended: bool) -> None:
        """Publish an EvAlert or HazardAlert and keep the latest message of each active one (queries answer them)."""
        self.transport.publish(key, msg)
        if ended:
            self._active.pop(alert_id, None)
        else:
            self._active[alert_id] = (key, msg)
        self._seq[kind] += 1

    def _publish_hazard(self, h: HazardEvent) -> None:
        msg = wire.hazard_alert(self.rsu_id, self._seq["hazard"], self.clock.now(), h)
        self._publish_alert_message("hazard", self.hazard_key, msg.hazard_id, msg, msg.state == HazardState.CLEAR)
        self.hazards_published[str(h.state)] += 1
        if h.state != "persist":
            log.info("HazardAlert %s %s (lane %s, x %.1f y %.1f m, %.1f x %.1f m)", msg.hazard_id, h.state, h.lane,
                     h.x_m, h.y_m, h.length_m, h.width_m)

    def _calibration_overlay(self) -> CalibrationOverlay:
        """The corridor drawn through the camera: drift shows as misfit lines."""
        rsu = self.corridor.rsu(self.rsu_id)
        return CalibrationOverlay(rsu.camera, self.corridor.road, max_range_m=rsu.max_range_m,
                                  calibration=rsu.calibration)

    def _annotated(self, frame: Frame, result: FrameResult) -> np.ndarray:
        if self._overlay is None:
            self._overlay = self._calibration_overlay()
        return annotate(self._overlay.apply(frame.image), result)

    def _write_annotated(self, frame: Frame, result: FrameResult) -> None:
        image = self._annotated(frame, result)
        if self._writer is None:
            fps = float(self.source.fps or 15.0)
            h, w = image.shape[:2]
            self._writer = cv2.VideoWriter(self.annotate_path, cv2.VideoWriter_fourcc(*"mp4v"), fps, (w, h))
            if not self._writer.isOpened():
                raise SourceError(f"cannot write annotated video to {self.annotate_path!r}")
        self._writer.write(image)

    # ------------------------------------------------------------------ health
    def _health_due(self, now: float) -> bool:
        """1 Hz schedule that skips missed periods. (protocol.clock.RateTimer can fire twice in a row
        when ``now`` lies within its 1e-9 s tolerance below the due time: floor of a tiny negative
        number is -1, so the next due time does not move.)"""
        nxt = self._next_health_s
        if nxt is not None and now + 1e-9 < nxt:
            return False
        nxt = now if nxt is None else nxt
        while nxt <= now + 1e-9:
            nxt += self.health_period_s
        self._next_health_s = nxt
        return True

    def _maybe_health(self, force: bool = False, final_error: bool = False) -> None:
        now = self.clock.now()
        if not (self._health_due(now) or force):
            return
        period = max(now - self._period_start_s, 1e-9)
        n = self._period_frames
        latency_ms = {k: (1000.0 * v / n if n else 0.0) for k, v in self._period_stage_s.items()}
        latency_ms.update({f"{k}_cpu": (1000.0 * v / n if n else 0.0) for k, v in self._period_stage_cpu_s.items()})
        ages = self._period_ages_s
        if ages:
            latency_ms["frame_age"] = min(1000.0 * sum(ages) / len(ages), MAX_LATENCY_MS)
            latency_ms["frame_age_max"] = min(1000.0 * max(ages), MAX_LATENCY_MS)
        status = HealthStatus.OK
        if final_error:
            status = HealthStatus.ERROR
        elif self._stalled or self.errors:
            status = HealthStatus.DEGRADED
        drops = {"source": int(self.source.drops)}
        if self.uplink is not None:
            drops["uplink_budget"] = self.uplink.skipped
        rates_hz = {"frames": n / period if n else 0.0}
        if self.source.fps:
            rates_hz["camera"] = float(self.source.fps)
        msg = Health(src=self.rsu_id, seq=self._seq["health"], stamp=max(now, 0.0), role=Role.RSU, status=status,
                     uptime_s=max(now - self._start_s, 0.0),
                     rates_hz=rates_hz,
                     latency_ms=latency_ms, drops=drops,
                     rejected={"frame_errors": self.errors, "stalls": self.stalls},
                     detail=self.last_error[:256])
        self.transport.publish(self.health_key, msg)
        self._latest["health"] = msg
        self._seq["health"] += 1
        self._period_frames = 0
        self._period_start_s = now
        self._period_stage_s = dict.fromkeys(STAGES, 0.0)
        self._period_stage_cpu_s = dict.fromkeys(STAGES, 0.0)
        self._period_ages_s = []
