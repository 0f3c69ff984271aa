"""``iea-rsu scan``: run a recorded clip through the RSU's EV recognition and say what it decided.

An operator checks a camera with it: which vehicles were recognised as emergency vehicles, when, and on
which cues. :func:`scan_video` builds the RSU's pipeline (``rsu.build``: detector -> SORT, Framework B ->
:class:`~rsu.classify.ev.TrackEvClassifier` with the EV-body classifier -> the pipeline's
:class:`~rsu.classify.alerts.EvAlertManager`), with no transport and no clock: frame times are the video's own.
A recorded clip has no calibration in the corridor file, so the corridor localiser is replaced by
:class:`ImageOnlyLocalizer`, which reports every track: the corridor's would drop the tracks it cannot put
inside an RSU's zone of responsibility (with another camera's geometry, most of them), and a dropped
track reaches neither the alert manager nor this report.

The result (:class:`ScanResult`) holds one :class:`TrackDecision` per track id that was ever
``candidate`` or ``confirmed`` and the alert *transitions* (``active`` when a track is confirmed,
``cleared``; the manager's 2 Hz refreshes are left out). A track that takes over a lost track's
evidence (SORT re-identifies the same vehicle under a new id) is alerted again under its new id;
``handed_over_from`` names the old ids.

``annotate_path`` writes an mp4 of the clip drawn by :func:`draw_scan`: every track box (green vehicle,
red EV-confirmed), the lamp band in which the lamps are measured (thin yellow) for tracks with lamp
activity or an EV state, and a label with id, state, cues and body score.
"""

from __future__ import annotations

import hashlib
import json
import pickle
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import cv2
import numpy as np

from protocol.enums import AlertState, EvState, LightState
from rsu import detect as _detect_module
from rsu.build import PipelineConfig, build_pipeline
from rsu.classify.ev import TrackEvClassifier
from rsu.frames import VideoSource
from rsu.perception import Detections, object_column
from rsu.pipeline import FrameResult

REAL_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "real"
DEFAULT_DETECTOR = REAL_DATA / "yolox_nano" / "yolox_nano.onnx"
"""The COCO YOLOX-Nano of ``../shared/data/real`` (real cameras; the project detector knows only the simulator)."""
PROGRESS_EVERY_S = 2.0
"""``progress`` is called every this many seconds of video."""
LAMP_RECENT_S = 0.5
"""A track whose lamps were lit this recently shows lamp activity (its band is drawn)."""

GREEN, RED, YELLOW, ORANGE = (0, 200, 0), (0, 0, 255), (0, 230, 255), (0, 140, 255)


@dataclass
class TrackDecision:
    """What the RSU decided about one track id (times in seconds of video)."""

    track_id: int
    state: str
    """The highest state reached: ``candidate`` or ``confirmed``."""
    first_seen_s: float
    """When this id first appeared."""
    confirmed_s: float | None = None
    """When it was first confirmed: the time of its ``active`` alert; None for a candidate only."""
    cues: tuple[str, ...] = ()
    """The cues (flash, alternation, steady_bar, ev_body) that confirmed it, then any other cue that later kept
    it confirmed, in the order first seen; empty for a candidate."""
    body_score: float | None = None
    """The latest mean EV-body score; None when the body classifier never scored it."""
    light_state: str = LightState.UNKNOWN.value
    flash_hz: float | None = None
    last_seen_s: float = 0.0
    last_box: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)
    """xyxy pixels."""
    handed_over_from: tuple[int, ...] = ()

    @property
    def is_ev(self) -> bool:
        return self.confirmed_s is not None


@dataclass(frozen=True)
class AlertRecord:
    t_s: float
    track_id: int
    state: str
    """``active`` (onset) or ``cleared``."""
    cues: tuple[str, ...]
    body_score: float | None
    clear_reason: str | None = None
    confidence: float | None = None
    """``EvAlert.confidence`` (:mod:`rsu.classify.confidence`)."""


@dataclass
class ScanResult:
    video: str
    frames: int
    duration_s: float
    wall_s: float
    detector: str
    body: str | None
    tracks: list[TrackDecision] = field(default_factory=list)
    alerts: list[AlertRecord] = field(default_factory=list)
    track_boxes: dict[int, list[tuple[float, float, float, float, float, bool]]] = field(default_factory=dict)
    """With ``record_boxes``: per track id, one ``(t_s, x1, y1, x2, y2, alerted)`` per frame it was reported in
    (``alerted``: its alert was active then); what per-vehicle scoring against labels needs."""

    @property
    def ev_tracks(self) -> list[TrackDecision]:
        return [t for t in self.tracks if t.is_ev]

    @property
    def first_alert_s(self) -> float | None:
        return min((t.confirmed_s for t in self.ev_tracks), default=None)

    def summary(self) -> dict:
        return dict(type="summary", video=self.video, frames=self.frames, duration_s=_r(self.duration_s),
                    ev_tracks=len(self.ev_tracks), candidate_tracks=len(self.tracks) - len(self.ev_tracks),
                    alerts=sum(a.state == AlertState.ACTIVE for a in self.alerts),
                    first_alert_s=_r(self.first_alert_s), wall_s=_r(self.wall_s),
                    fps_processed=_r(self.frames / self.wall_s if self.wall_s > 0 else None),
                    detector=self.detector, body=self.body)

    def json_lines(self) -> list[str]:
        """One JSON object per track decision, per alert transition, then the summary."""
        rows = [dict(type="track", video=self.video, **_rounded(asdict(t))) for t in self.tracks]
        rows += [dict(type="alert", video=self.video, **_rounded(asdict(a))) for a in self.alerts]
        return [json.dumps(r) for r in (*rows, self.summary())]


def _r(v: float | None, nd: int = 3) -> float | None:
    return None if v is None else round(float(v), nd)


def _rounded(d: dict) -> dict:
    out = {}
    for k, v in d.items():
        if isinstance(v, float):
            v = _r(v)
        elif isinstance(v, tuple | list):
            v = [_r(x, 1) if isinstance(x, float) else x for x in v]
        out[k] = v
    return out


class ImageOnlyLocalizer:
    """The pipeline's localiser for an uncalibrated clip: every track, in image space only (no position,
    lane or speed: zeros)."""

    def __init__(self) -> None:
        self.first_s: dict[int, float] = {}

    def update(self, tracks: Detections, timestamp_s: float, det_boxes=None) -> Detections:
        n = len(tracks)
        ages = [timestamp_s - self.first_s.setdefault(int(tid), timestamp_s) for tid in tracks.column("track_ids")]
        zeros2, zeros = np.zeros((n, 2)), np.zeros(n)
        return tracks.with_columns(localized=np.ones(n, dtype=bool), positions_m=zeros2, latlon_deg=zeros2,
                                   velocities_mps=zeros2, speeds_mps=zeros, headings_rad=zeros,
                                   pos_cov_m2=np.zeros((n, 3)), lanes=object_column([None] * n),
                                   ages_s=np.asarray(ages, float).reshape(n))


def _file_digest(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def detections_key(video: Path, detector_model: str | Path, config: PipelineConfig, max_s: float | None) -> str:
    """The key of a clip's kept detections: the video's and the detector model's bytes, the detector's code and
    the settings that change its boxes; any change gives a new key, so a kept file never goes stale silently."""
    h = hashlib.sha256()
    model = Path(detector_model)
    for part in (_file_digest(video), _file_digest(model) if model.is_file() else str(detector_model),
                 _file_digest(Path(_detect_module.__file__)), repr((config.score_threshold, config.framework, max_s))):
        h.update(part.encode())
    return h.hexdigest()[:20]


class DetectionsReplay:
    """A detector that gives the detections kept for each frame in turn (``rows``), or, with ``inner``, runs that
    detector and keeps what it gives (``rows`` then fills)."""

    def __init__(self, inner=None, rows: list | None = None, name: str = "detector") -> None:
        self.inner, self.rows, self.index = inner, [] if rows is None else rows, 0
        self.name = getattr(inner, "name", name)

    def detect(self, image: np.ndarray) -> Detections:
        if self.inner is not None:
            out = self.inner.detect(image)
            self.rows.append(out)
            return out
        if self.index >= len(self.rows):
            raise ValueError("kept detections end before the video: its key should have changed")
        self.index += 1
        return self.rows[self.index - 1]


def scan_video(path: str | Path, *, detector_model: str | Path = DEFAULT_DETECTOR, body: str | None = "default",
               max_s: float | None = None, annotate_path: str | Path | None = None, threads: int | None = 1,
               progress: Callable[[float, int, int], None] | None = None,
               record_boxes: bool = False, detections_dir: str | Path | None = None,
               score_threshold: float | None = None) -> ScanResult:
    """Run ``path`` (a video file) through the RSU's EV recognition; see the module docstring.

    ``detector_model``: an ONNX detector or ``motion``; ``body``: ``default`` (models/ev_body.onnx),
    ``none`` or a path; ``max_s``: stop after this much video; ``threads``: onnxruntime threads of the
    detector and the body classifier; ``progress(t_s, frames, ev_tracks)``: called every
    :data:`PROGRESS_EVERY_S` of video; ``record_boxes``: keep every track's box per frame
    (:attr:`ScanResult.track_boxes`); ``detections_dir``: a folder where each clip's detector output is kept under
    :func:`detections_key` and read back on the next scan (the detector is most of a scan's cost; the tracker and
    the EV recognition always run); ``score_threshold``: the detector's score threshold (default: the RSU's,
    ``PipelineConfig.score_threshold``). Raises FileNotFoundError (video or model missing), ValueError
    (no frame could be decoded, or the annotated video cannot be written) and rsu.frames.SourceError.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"video {str(path)!r} not found")
    config = PipelineConfig(detector=str(detector_model), threads=threads, max_age=3, ev_body=body)
    if score_threshold is not None:
        if not 0.0 < score_threshold < 1.0:
            raise ValueError(f"score_threshold must lie in (0, 1), got {score_threshold}")
        config = replace(config, score_threshold=float(score_threshold))
    pipeline = build_pipeline(config, localizer=ImageOnlyLocalizer())
    kept = None
    if detections_dir is not None:
        kept = Path(detections_dir) / f"{path.stem}-{detections_key(path, detector_model, config, max_s)}.pkl"
        pipeline.detector = (DetectionsReplay(rows=pickle.loads(kept.read_bytes()), name=pipeline.detector.name)
                             if kept.is_file() else DetectionsReplay(pipeline.detector))
    detector, clf = pipeline.detector, pipeline.classifier
    decisions: dict[int, TrackDecision] = {}
    first_seen: dict[int, float] = {}
    alerts: list[AlertRecord] = []
    active: set[int] = set()
    track_boxes: dict[int, list[tuple[float, float, float, float, float, bool]]] = {}
    writer = None
    frames, last_t, next_progress = 0, 0.0, PROGRESS_EVERY_S
    t0 = time.perf_counter()
    with VideoSource(path, read_timeout_s=30.0) as source:
        try:
            for frame in source:
                now = float(frame.timestamp_s)
                if max_s is not None and now > max_s:
                    break
                result = pipeline.process(frame)
                _record(now, result, first_seen, decisions)
                for e in result.alerts:
                    if e.state == AlertState.ACTIVE and e.track_id in active:
                        continue  # a 2 Hz refresh of an alert already raised
                    (active.add if e.state == AlertState.ACTIVE else active.discard)(e.track_id)
                    alerts.append(AlertRecord(now, e.track_id, e.state.value, tuple(c.value for c in e.cues),
                                              e.body_score, e.clear_reason.value if e.clear_reason else None,
                                              float(e.confidence)))
                if record_boxes:
                    published = result.published
                    for tid, box in zip(published.column("track_ids"), published.boxes, strict=True):
                        track_boxes.setdefault(int(tid), []).append(
                            (now, *(float(v) for v in box), int(tid) in active))
                if annotate_path is not None:
                    writer = writer or _open_writer(annotate_path, source.fps, frame.image.shape)
                    writer.write(draw_scan(frame.image, result, clf, now))
                frames, last_t = frames + 1, now
                if progress is not None and now >= next_progress:
                    progress(now, frames, sum(d.is_ev for d in decisions.values()))
                    while next_progress <= now:
                        next_progress += PROGRESS_EVERY_S
        finally:
            if writer is not None:
                writer.release()
    if frames == 0:
        raise ValueError(f"{path}: no frame could be decoded (not a video, or an unsupported codec)")
    if kept is not None and detector.inner is not None:
        kept.parent.mkdir(parents=True, exist_ok=True)
        kept.write_bytes(pickle.dumps(detector.rows))
    tracks = sorted(decisions.values(), key=lambda d: (d.confirmed_s is None, d.confirmed_s or d.first_seen_s))
    return ScanResult(str(path), frames, last_t, time.perf_counter() - t0, getattr(detector, "name", "detector"),
                      None if clf.body is None else str(body), tracks, alerts, track_boxes)


def _record(now: float, result: FrameResult, first_seen: dict[int, float],
            decisions: dict[int, TrackDecision]) -> None:
    """Update the decision of every track of this frame that is (or was) candidate or confirmed."""
    tracks = result.published
    records = tracks.evidence if tracks.evidence is not None else [None] * len(tracks)
    for tid, state, box, info in zip(tracks.column("track_ids"), tracks.column("ev_states"), tracks.boxes, records,
                                     strict=True):
        tid = int(tid)
        first_seen.setdefault(tid, now)
        d = decisions.get(tid)
        if d is None and state not in (EvState.CANDIDATE, EvState.CONFIRMED):
            continue
        if d is None:
            d = decisions[tid] = TrackDecision(tid, EvState.CANDIDATE.value, first_seen[tid])
        ev = info.evidence if info is not None else None
        if state == EvState.CONFIRMED:
            d.state = EvState.CONFIRMED.value
            if d.confirmed_s is None:
                d.confirmed_s = now
            if ev is not None:
                d.cues = (*d.cues, *(c.value for c in ev.cues if c.value not in d.cues))
        if ev is not None:
            d.body_score = ev.body_score if ev.body_score is not None else d.body_score
            d.flash_hz = ev.flash_hz if ev.flash_hz is not None else d.flash_hz
            d.light_state = ev.light_state.value
            d.handed_over_from = tuple(info.handed_over_from)
        d.last_seen_s = now
        d.last_box = tuple(float(v) for v in box)


def _open_writer(path: str | Path, fps: float | None, shape: tuple[int, ...]) -> cv2.VideoWriter:
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps or 15.0, (shape[1], shape[0]))
    if not writer.isOpened():
        raise ValueError(f"cannot write the annotated video {str(path)!r}")
    return writer


def draw_scan(image: np.ndarray, result: FrameResult, clf: TrackEvClassifier, now_s: float) -> np.ndarray:
    """A copy of the frame with every track: box (green vehicle, red EV-confirmed), lamp band (thin yellow,
    for tracks with lamp activity or an EV state) and a label ``id state cues body``; the time top left."""
    out = image.copy()
    h, w = out.shape[:2]
    tracks = result.tracks
    records = tracks.evidence if tracks.evidence is not None else [None] * len(tracks)
    for tid, box, state, placed, info in zip(tracks.column("track_ids"), tracks.boxes, tracks.column("ev_states"),
                                             tracks.column("localized"), records, strict=True):
        tid = int(tid)
        ev = info.evidence if info is not None else None
        if not placed:
            state = ev.state if ev is not None else EvState.NONE
        colour = RED if state == EvState.CONFIRMED else GREEN
        x1, y1, x2, y2 = (int(round(float(v))) for v in box)
        cv2.rectangle(out, (x1, y1), (x2, y2), colour, 2)
        lamps_active = ev is not None and (
            ev.light_state in (LightState.FLASHING, LightState.STEADY)
            or (ev.last_lamp_on_s is not None and now_s - ev.last_lamp_on_s <= LAMP_RECENT_S))
        if lamps_active or state in (EvState.CANDIDATE, EvState.CONFIRMED):
            band = clf.lamp_band(box, w, h)
            if band is not None:
                cv2.rectangle(out, band[:2], band[2:], YELLOW, 1)
        label = f"{tid} {state.value}"
        if ev is not None and ev.cues and state == EvState.CONFIRMED:
            label += " " + "+".join(c.value for c in ev.cues)
        if ev is not None and ev.body_score is not None:
            label += f" b{ev.body_score:.2f}"
        _text(out, label, (x1, max(12, y1 - 4)), RED if state == EvState.CONFIRMED else
              ORANGE if state == EvState.CANDIDATE else GREEN)
    _text(out, f"{now_s:6.2f} s", (4, 14), (255, 255, 255))
    return out


def _text(image: np.ndarray, text: str, org: tuple[int, int], colour: tuple[int, int, int]) -> None:
    """Text with a dark outline, readable on any background."""
    cv2.putText(image, text, org, cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 3, cv2.LINE_AA)
    cv2.putText(image, text, org, cv2.FONT_HERSHEY_SIMPLEX, 0.45, colour, 1, cv2.LINE_AA)
