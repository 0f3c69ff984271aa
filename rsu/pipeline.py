"""One RSU camera's per-frame pipeline (thesis 3.2-3.3, Framework B), pure: no I/O, no clock but the frame's own.

detector -> SORT -> EV classifier -> localiser -> EV alert life cycle, and the hazard detector beside them. One
table (``rsu.perception.Detections``) goes through the stages and each adds its columns; ``RsuPipeline.process``
returns it in a :class:`FrameResult` with the frame's alert and hazard events, which ``rsu.service.RsuService``
publishes through ``rsu.wire`` and ``iea-rsu scan`` reports.

Classifier stage: any callable ``(frame, tracks) -> tracks`` that adds ``ev_scores`` and, optionally,
``light_states``, ``ev_states`` and ``evidence`` (:class:`rsu.classify.ev.TrackEvClassifier` plugs in here). It is
handed the frame's reported tracks and, after them, the tracks SORT matched but holds back until ``min_hits``
(``FrameworkTracker.tentative``); only reported tracks are published. A track is an EV (``ev_states`` =
``confirmed``, published as ``obj_type = ev``) when the classifier says so; a classifier that gives no state
decides by ``ev_score >= ev_threshold`` (:func:`ev_verdicts`). With a classifier the pipeline runs an
:class:`rsu.classify.alerts.EvAlertManager` on the frame times: ``active`` when a track is confirmed, refreshed at
2 Hz, ``cleared`` when its lights go off or it has left the view.

Hazards: with a :class:`rsu.hazard.HazardDetector`, static objects in a lane come out as
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

from protocol.enums import EvState
from rsu.classify.alerts import AlertEvent, EvAlertManager
from rsu.detect import EV, Detector, MotionDetector
from rsu.frames import Frame
from rsu.hazard import HazardDetector, HazardEvent
from rsu.localize import Localizer
from rsu.perception import Detections, object_column
from rsu.track.frameworks import FrameworkTracker

Classifier = Callable[[Frame, Detections], Detections]
STAGES = ("detect", "track", "classify", "localize", "hazard", "publish")


@dataclass
class FrameResult:
    """What one frame produced: its table of reported tracks with every stage's columns, the EV alert events and
    the hazard events due this frame, and the time of each stage."""

    tracks: Detections
    """The tracks SORT reported on this frame; ``published`` are those the localiser placed."""
    alerts: list[AlertEvent] = field(default_factory=list)
    hazards: list[HazardEvent] = field(default_factory=list)
    """With ``lat_deg`` / ``lon_deg`` set."""
    stage_s: dict[str, float] = field(default_factory=dict)
    """Wall-clock seconds per stage."""
    stage_cpu_s: dict[str, float] = field(default_factory=dict)
    """CPU seconds per stage (this thread: what the stage cost, whatever else the machine was doing)."""

    @property
    def published(self) -> Detections:
        """The rows that go out in the frame's ObjectList: the localised tracks."""
        return self.tracks[self.tracks.column("localized")]


def ev_verdicts(tracks: Detections, ev_threshold: float) -> Detections:
    """``tracks`` with the final EV columns: ``ev_scores`` clipped to [0, 1] (0 without a classifier),
    ``ev_states`` the classifier's state or, where it gave none, ``confirmed`` for a detector's EV class or a score
    at or above ``ev_threshold`` and ``none`` otherwise, and ``light_states`` (None: unknown)."""
    n = len(tracks)
    scores = np.zeros(n) if tracks.ev_scores is None else np.clip(np.asarray(tracks.ev_scores, float), 0.0, 1.0)
    given = tracks.ev_states if tracks.ev_states is not None else [None] * n
    states = [s if s is not None else (EvState.CONFIRMED if int(c) == EV or score >= ev_threshold else EvState.NONE)
              for s, c, score in zip(given, tracks.class_ids, scores, strict=True)]
    lights = tracks.light_states if tracks.light_states is not None else object_column([None] * n)
    return tracks.with_columns(ev_scores=scores, ev_states=object_column(states), light_states=lights)


class RsuPipeline:
    """Detector -> tracker -> classifier -> localiser (-> EV alerts, hazards) for one camera; ``process(frame)``
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
        tracks = self.tracker.update(det)
        lap()
        # the classifier also reads the tracks SORT holds back until min_hits (``FrameworkTracker.tentative``): a
        # broken track's successor keeps gathering its lamps' evidence in those frames (``rsu.classify.ev``)
        if self.classifier is not None:
            held = self.tracker.tentative()
            tracks = self.classifier(frame, Detections.concatenate([tracks, held]) if len(held) else tracks)[
                :len(tracks)]
        tracks = ev_verdicts(tracks, self.ev_threshold)
        lap()
        tracks = self.localizer.update(tracks, frame.timestamp_s, det.boxes)
        result = FrameResult(tracks)
        if self.alerts is not None:
            result.alerts = self.alerts.update(frame.timestamp_s, result.published)
        lap()
        if self.hazards is not None:
            published = result.published
            speeds = dict(zip((int(i) for i in published.column("track_ids")),
                              (float(v) for v in published.column("speeds_mps")), strict=True))
            result.hazards = [self._located(h) for h in self.hazards.update(
                frame.image, frame.timestamp_s, tracks.track_ids, tracks.boxes, speeds)]
        lap()
        names = STAGES[:5]
        result.stage_s = {k: t[i + 1] - t[i] for i, k in enumerate(names)}
        result.stage_cpu_s = {k: c[i + 1] - c[i] for i, k in enumerate(names)}
        return result

    def _located(self, h: HazardEvent) -> HazardEvent:
        lat, lon = self.localizer.corridor.to_latlon(h.x_m, h.y_m)
        return dataclasses.replace(h, lat_deg=lat, lon_deg=lon)


def annotate(image: np.ndarray, result: FrameResult) -> np.ndarray:
    """Boxes, track ids and labels drawn on a copy of the frame (thesis Fig. 2.2 / 3.7)."""
    out = image.copy()
    tr = result.tracks
    for k, (tid, box) in enumerate(zip(tr.column("track_ids"), tr.boxes, strict=True)):
        placed = bool(tr.column("localized")[k])
        is_ev = placed and tr.column("ev_states")[k] == EvState.CONFIRMED
        colour = (0, 0, 255) if is_ev else (0, 200, 0)
        x1, y1, x2, y2 = (int(round(v)) for v in box)
        cv2.rectangle(out, (x1, y1), (x2, y2), colour, 2)
        label = f"{int(tid)} {'EV' if is_ev else 'veh'}"
        if placed:
            lane = tr.column("lanes")[k]
            label += f" {float(tr.column('speeds_mps')[k]):.1f}m/s" + (f" L{lane}" if lane is not None else "")
        cv2.putText(out, label, (x1, max(12, y1 - 4)), cv2.FONT_HERSHEY_SIMPLEX, 0.45, colour, 1, cv2.LINE_AA)
    return out
