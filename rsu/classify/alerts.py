"""EvAlert life cycle per track (thesis 2.4): :class:`EvAlertManager` turns the EV verdicts of the frame's
localised tracks (the ``ev_states`` and ``evidence`` columns of ``rsu.perception.Detections``) into alert events
(pure: the caller gives the frame time): ``active`` when a track becomes confirmed, a refresh every
``refresh_period_s`` (2 Hz) while active, ``cleared`` when its evidence clears (lights off) or the track has not
been seen for ``leave_after_s`` (it left the view). ``rsu.wire.ev_alert`` makes the wire message of an event. Each
event's ``confidence`` is the calibrated probability of :mod:`rsu.classify.confidence` that the track is an EV with
its lights on, from the cues, body score and box width it rests on.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from protocol.enums import AlertState, ClearReason, EvCue, EvState
from rsu.classify.confidence import DEFAULT_MODEL, ConfidenceModel, alert_features
from rsu.perception import Detections


@dataclass(frozen=True)
class AlertEvent:
    """One EvAlert to publish: state, the alerting track's latest localised row and its evidence summary."""

    state: AlertState
    track_id: int
    row: Detections
    """The track's row (one) of the last frame that localised it."""
    first_seen_s: float
    confidence: float
    frames: int
    flash_hz: float | None
    mean_score: float
    clear_reason: ClearReason | None = None
    """With ``CLEARED``: lights off (the track is still seen) or out of view (it was not seen for
    ``leave_after_s``)."""
    cues: tuple[EvCue, ...] = ()
    """The cues that confirmed the track (flash, alternation, steady bar, EV body)."""
    body_score: float | None = None
    """The track's mean EV-body score, when the body classifier scored it."""


@dataclass
class _Active:
    row: Detections
    first_seen_s: float
    last_seen_s: float
    last_sent_s: float
    confidence: float
    frames: int
    flash_hz: float | None
    mean_score: float
    cues: tuple[EvCue, ...] = ()
    body_score: float | None = None


@dataclass
class EvAlertManager:
    """EvAlert life cycle per track (see the module docstring); ``update`` once per processed frame."""

    refresh_period_s: float = 0.5
    leave_after_s: float = 1.0
    confidence_model: ConfidenceModel = DEFAULT_MODEL
    active: dict[int, _Active] = field(default_factory=dict)

    def update(self, now_s: float, tracks: Detections) -> list[AlertEvent]:
        """``tracks``: this frame's localised tracks with their EV verdicts (``ev_states``, ``ev_scores`` in [0, 1])
        and evidence records (``evidence``, None for a classifier that keeps none)."""
        events: list[AlertEvent] = []
        seen: set[int] = set()
        ids, states, scores = tracks.column("track_ids"), tracks.column("ev_states"), tracks.column("ev_scores")
        records = tracks.evidence if tracks.evidence is not None else [None] * len(tracks)
        for k in range(len(tracks)):
            tid = int(ids[k])
            seen.add(tid)
            info = records[k]
            a = self.active.get(tid)
            if states[k] == EvState.CONFIRMED:
                row = tracks[k]
                ev = info.evidence if info is not None else None
                frames = ev.frames if ev is not None else 0
                hz = ev.flash_hz if ev is not None else None
                mean = ev.mean_crop_score if ev is not None and ev.score_sum > 0 else float(scores[k])
                cues = ev.cues if ev is not None else ()
                body = ev.body_score if ev is not None else None
                box = row.boxes[0]
                conf = self.confidence_model(alert_features(cues, body, float(box[2]) - float(box[0])))
                if a is None:
                    first = info.first_seen_s if info is not None else now_s
                    a = self.active[tid] = _Active(row, first, now_s, now_s, conf, frames, hz, mean, cues, body)
                    events.append(self._event(AlertState.ACTIVE, tid, a))
                else:
                    a.row, a.last_seen_s, a.confidence, a.frames, a.flash_hz, a.mean_score = (
                        row, now_s, conf, frames, hz, mean)
                    a.cues, a.body_score = cues, body
            elif a is not None:  # evidence cleared (lights off) or fell back
                a.row = tracks[k]
                events.append(self._event(AlertState.CLEARED, tid, a, ClearReason.LIGHTS_OFF))
                del self.active[tid]
        for tid, a in list(self.active.items()):
            if tid not in seen and now_s - a.last_seen_s >= self.leave_after_s:
                events.append(self._event(AlertState.CLEARED, tid, a, ClearReason.OUT_OF_VIEW))
                del self.active[tid]
            elif now_s - a.last_sent_s >= self.refresh_period_s - 1e-9 and not any(
                    e.track_id == tid for e in events):
                events.append(self._event(AlertState.ACTIVE, tid, a))
        for e in events:
            if e.state == AlertState.ACTIVE:
                self.active[e.track_id].last_sent_s = now_s
        return events

    @staticmethod
    def _event(state: AlertState, tid: int, a: _Active, reason: ClearReason | None = None) -> AlertEvent:
        return AlertEvent(state, tid, a.row, a.first_seen_s, a.confidence, a.frames, a.flash_hz, a.mean_score,
                          reason, a.cues, a.body_score)
