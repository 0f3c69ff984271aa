"""One RSU camera's per-frame pipeline (thesis 3.2-3.3, Framework B), pure: no I/O, no clock but the frame's own.

detector -> SORT -> classifier hook -> localiser -> EV alert life cycle, and the hazard detector beside them;
``RsuPipeline.process(frame)`` returns one :class:`FrameResult` that ``rsu.service.RsuService`` publishes as it is
and ``iea-rsu scan`` reports.

Classifier hook: any callable ``(frame, tracks) -> {track_id: EvVerdict}`` (:class:`rsu.classify.ev.EvVerdict`;
:class:`rsu.classify.ev.TrackEvClassifier` plugs in here), handed the frame's reported tracks and, after them, the
tracks SORT matched but holds back until ``min_hits`` (``FrameworkTracker.tentative``); only reported tracks are
published. With an ``ev_state`` an object is published as
``obj_type = ev`` while its state is ``confirmed``; without one, when ``ev_score >= ev_threshold``. With a
classifier the pipeline runs an :class:`rsu.classify.alerts.EvAlertManager` on the frame times: ``active`` when a
track is confirmed, refreshed at 2 Hz, ``cleared`` when its lights go off or it has left the view.

Hazards (issue 10): with a :class:`rsu.hazard.HazardDetector`, static objects in a lane come out as
:class:`rsu.hazard.HazardEvent` (``appear``, ``persist`` at 1 Hz, ``clear``), placed on the corridor's
latitude and longitude here.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import cv2
import numpy as np

from protocol.enums import EvState, LightState, ObjectType
from protocol.messages import DetectedObject
from rsu.classify.alerts import AlertEvent, EvAlertManager
from rsu.classify.ev import EvVerdict
from rsu.detect import EV, Detector, MotionDetector
from rsu.frames import Frame
from rsu.hazard import HazardDetector, HazardEvent
from rsu.localize import LocalizedObject, Localizer
from rsu.track.frameworks import FrameworkTracker
from rsu.track.sort import TrackSet

Classifier = Callable[[Frame, TrackSet], dict[int, EvVerdict]]
STAGES = ("detect", "track", "classify", "localize", "hazard", "publish")


@dataclass
class FrameResult:
    """What one frame produced: the objects to publish (wire type), the tracks they came from, the classifier's
    verdicts, the EV alert events and the hazard events due this frame, and the time of each stage."""

    objects: list[DetectedObject]
    tracks: TrackSet
    verdicts: dict[int, EvVerdict] = field(default_factory=dict)
    alerts: list[AlertEvent] = field(default_factory=list)
    hazards: list[HazardEvent] = field(default_factory=list)
    """With ``lat_deg`` / ``lon_deg`` set."""
    stage_s: dict[str, float] = field(default_factory=dict)
    """Wall-clock seconds per stage."""
    stage_cpu_s: dict[str, float] = field(default_factory=dict)
    """CPU seconds per stage (this thread: what the stage cost, whatever else the machine was doing)."""


class RsuPipeline:
    """Detector -> tracker -> classifier hook -> localiser (-> EV alerts, hazards) for one camera; ``process(frame)``
    per frame. The localiser's corridor places hazards on latitude and longitude."""

    def __init__(self, detector: Detector, tracker: FrameworkTracker, localizer: Localizer,
                 classifier: Classifier | None = None, ev_threshold: float = 0.5,
                 hazards: HazardDetector | None = None) -> None:
        self.detector, self.tracker, self.localizer = detector, tracker, localizer
        self.classifier = classifier
        self.alerts = EvAlertManager() if classifier is not None else None
        self.ev_threshold = ev_threshold
        self.hazards = hazards

    @property
    def learns_the_road(self) -> bool:
        """Does a model of the road learn from the frames (a motion detector's background, the hazard
        detector's backgrounds)?"""
        return isinstance(self.detector, MotionDetector) or self.hazards is not None

    def learn_road(self, image: np.ndarray) -> None:
        """A frame from before the watch starts (``sim.warmup``: an RSU that has been running): the road models
        learn it; nothing is tracked or reported."""
        if isinstance(self.detector, MotionDetector):
            self.detector.detect(image)
        if self.hazards is not None:
            self.hazards.learn_background(image)

    def process(self, frame: Frame) -> FrameResult:
        t = [time.perf_counter()]
        c = [time.thread_time()]

        def lap() -> None:
            t.append(time.perf_counter())
            c.append(time.thread_time())

        det = self.detector.detect(frame.image)
        lap()
        tracks = self.tracker.update(det.boxes, det.scores, det.classes)
        lap()
        # the classifier also reads the tracks SORT holds back until min_hits (``FrameworkTracker.tentative``): a
        # broken track's successor keeps gathering its lamps' evidence in those frames (``rsu.classify.ev``)
        verdicts = {}
        if self.classifier is not None:
            held = self.tracker.tentative()
            verdicts = self.classifier(frame, TrackSet.concatenate([tracks, held]) if len(held) else tracks)
        lap()
        localized = self.localizer.update(tracks, frame.timestamp_s, det.boxes)
        objects = [self._to_message(o, verdicts.get(o.track_id)) for o in localized]
        alerts = self.alerts.update(frame.timestamp_s, objects, verdicts) if self.alerts is not None else []
        lap()
        hazards = []
        if self.hazards is not None:
            hazards = [self._located(h) for h in self.hazards.update(
                frame.image, frame.timestamp_s, tracks.track_ids, tracks.boxes,
                {o.track_id: o.speed_mps for o in localized})]
        lap()
        names = STAGES[:5]
        return FrameResult(objects, tracks, verdicts, alerts, hazards,
                           {k: t[i + 1] - t[i] for i, k in enumerate(names)},
                           {k: c[i + 1] - c[i] for i, k in enumerate(names)})

    def _located(self, h: HazardEvent) -> HazardEvent:
        lat, lon = self.localizer.corridor.to_latlon(h.x_m, h.y_m)
        return dataclasses.replace(h, lat_deg=lat, lon_deg=lon)

    def _to_message(self, o: LocalizedObject, verdict: EvVerdict | None) -> DetectedObject:
        """The wire object of one localised track with its EV verdict, every number within its wire range."""
        ev_score = float(np.clip(verdict.ev_score, 0.0, 1.0)) if verdict is not None else 0.0
        ev_state = verdict.ev_state if verdict is not None else None
        if ev_state is not None:
            is_ev = ev_state == EvState.CONFIRMED
        else:
            is_ev = o.class_id == EV or ev_score >= self.ev_threshold
        light = verdict.light_state if verdict is not None else None
        return DetectedObject(
            object_id=o.track_id, pos_x_m=o.x_m, pos_y_m=o.y_m, lat_deg=o.lat_deg, lon_deg=o.lon_deg,
            bbox_px=o.bbox_px, obj_type=ObjectType.EV if is_ev else ObjectType.VEHICLE,
            obj_type_cfd=float(np.clip(o.score, 0.0, 1.0)), ev_score=ev_score,
            ev_state=ev_state if ev_state is not None else (EvState.CONFIRMED if is_ev else EvState.NONE),
            light_state=light if light is not None else LightState.UNKNOWN,
            vel_x_mps=o.vel_x_mps, vel_y_mps=o.vel_y_mps, speed_mps=o.speed_mps, heading_rad=o.heading_rad,
            pos_cov_m2=(max(o.pos_cov_m2[0], 0.0), o.pos_cov_m2[1], max(o.pos_cov_m2[2], 0.0)),
            lane=o.lane, age_s=max(o.age_s, 0.0), hits=max(o.hits, 0),
        )


def annotate(image: np.ndarray, result: FrameResult) -> np.ndarray:
    """Boxes, track ids and labels drawn on a copy of the frame (thesis Fig. 2.2 / 3.7)."""
    out = image.copy()
    by_id = {o.object_id: o for o in result.objects}
    for tid, box in zip(result.tracks.track_ids, result.tracks.boxes, strict=True):
        obj = by_id.get(int(tid))
        is_ev = obj is not None and obj.obj_type == ObjectType.EV
        colour = (0, 0, 255) if is_ev else (0, 200, 0)
        x1, y1, x2, y2 = (int(round(v)) for v in box)
        cv2.rectangle(out, (x1, y1), (x2, y2), colour, 2)
        label = f"{int(tid)} {'EV' if is_ev else 'veh'}"
        if obj is not None:
            label += f" {obj.speed_mps:.1f}m/s" + (f" L{obj.lane}" if obj.lane is not None else "")
        cv2.putText(out, label, (x1, max(12, y1 - 4)), cv2.FONT_HERSHEY_SIMPLEX, 0.45, colour, 1, cv2.LINE_AA)
    return out
