"""The RSU's EV classifier (Framework B, thesis 2.3-2.4).

:class:`TrackEvClassifier` is the ``RsuPipeline`` classifier stage ``(frame, tracks) -> tracks``: it adds the EV
columns to the frame's table of tracks (``rsu.perception.Detections``: ``ev_scores``, ``light_states``,
``ev_states``, ``evidence``: the track's evidence record). It
keeps one :class:`~rsu.classify.temporal.TrackEvidence` per track id, measures the lamps (:func:`~rsu.classify.temporal.measure_lamps`) in each track's box crop
(clipped to the image; optionally extended upwards by ``above_fraction`` of its height, since a
detector's box can cut the light bar off the roof; 0.25 by default, as the EV-body classifier was trained),
optionally scores the same crop with the EV-body classifier (``body``: only while the track shows
lamp activity and at most once per ``body_period_s``, never on every box of every frame), optionally adds a
per-crop EV probability from any ``crop_score(crop) -> float``
callable (a trained CNN or feature classifier; None: lamps only), and skips boxes smaller than ``min_box_px`` on a side (too few pixels to resolve a light
bar: far vehicles and merged blobs of distant traffic flicker like lamps) and, with a ``box_gate`` (e.g.
:class:`rsu.classify.box_gate.SingleVehicleGate`, from the camera's calibration), boxes too wide for one vehicle at their
range (several vehicles merged into one blob), and forgets tracks unseen for
``forget_after_s`` (and never holds more than ``max_tracks``), so memory stays bounded.

Evidence survives a broken track. SORT with the reference settings (max_age 1, min_hits 3, thesis 2.2)
drops a track after one frame without a match and reports its successor only after three hits, so a
vehicle whose box changes shape faster than the filter's aspect ratio follows (an EV driving away from
the camera, seen first from the side, then from behind) gets a new id every few seconds; were each new id to
start its lamp history from nothing, an EV that is confirmed only after two flashes could lose every one of them
to such switches (Framework A's weakness, thesis 2.2, reappearing inside Framework B). So when a track id appears that the classifier has not seen, it takes over the evidence
of a track lost within the last ``handover_after_s`` whose last box, moved on at that box's own
velocity (:func:`extrapolate_box`), overlaps it by IoU >= ``handover_iou`` (SORT's own association
threshold, 0.3): one new id per lost track, matched as SORT matches (:func:`match_lost_tracks`). A new box
that holds most of a nearer vehicle's box takes over nothing: it is two vehicles merged by the detector
(:func:`rsu.classify.ownership.holds_nearer_vehicle`). The pipeline hands this classifier SORT's held-back tracks
as well as its reported ones (``rsu.track.sort.SortTracker.tentative``), so the successor takes over, and goes on
gathering, from its birth, not from the frame SORT first reports it (three matches later): an EV whose track SORT's
filter loses just as its lights come on (its area velocity, learned while the EV came into view from under the
camera, shrinking the box faster than the EV) would otherwise lose the first flash to those frames and alert one
flash period (0.5 s) later.

The EvAlert life cycle built on its verdicts is :class:`rsu.classify.alerts.EvAlertManager`.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from protocol.enums import EvState
from rsu.classify.evidence_config import EvidenceConfig, lamp_activity
from rsu.classify.lamps import BAR_COLOURED, LAMP_BRIGHT, LampColours, LampMeasurement, measure_band
from rsu.classify.ownership import (
    above_top,
    band_exclusions,
    blank_rects,
    farther_boxes,
    hidden_behind_nearer,
    holds_nearer_vehicle,
    rect_mask,
)
from rsu.classify.temporal import TrackEvidence
from rsu.frames import Frame
from rsu.perception import Detections, object_column
from rsu.track.assoc import associate

CropScore = Callable[[np.ndarray], float]
DEFAULT_ABOVE_FRACTION = 0.25
"""How far a track's crop grows above its box, as a share of the box height, when no body classifier says."""


def clip_box(box: Iterable[float], width: int, height: int) -> tuple[int, int, int, int] | None:
    """Integer crop bounds of an xyxy box clipped to the image; None when nothing of it is inside."""
    x1, y1, x2, y2 = (float(v) for v in box)
    if not (math.isfinite(x1) and math.isfinite(y1) and math.isfinite(x2) and math.isfinite(y2)):
        return None
    # plain floats: numpy's per-call cost on four scalars was most of the classify stage's clipping
    xa, ya = min(max(math.floor(x1), 0), width), min(max(math.floor(y1), 0), height)
    xb, yb = min(max(math.ceil(x2), 0), width), min(max(math.ceil(y2), 0), height)
    if xb - xa < 2 or yb - ya < 2:
        return None
    return xa, ya, xb, yb


def crop_above(box: Iterable[float], width: int, height: int, above_fraction: float) -> tuple[int, int, int, int] | None:
    """:func:`clip_box` of an xyxy box grown upwards by ``above_fraction`` of its height: the crop the RSU takes
    of a vehicle (a light bar sits on the roof, often outside a COCO "car" box)."""
    x1, y1, x2, y2 = (float(v) for v in box)
    return clip_box((x1, y1 - above_fraction * (y2 - y1), x2, y2), width, height)


class LostEvs(NamedTuple):
    """Tracks lost a moment ago whose lamps may still light the vehicles around them (``TrackEvClassifier._lost_evs``):
    their boxes (N, 4), moved on at their own velocity, and which of them were confirmed EVs."""

    boxes: np.ndarray
    confirmed: np.ndarray


@dataclass
class TrackInfo:
    evidence: TrackEvidence
    first_seen_s: float
    last_seen_s: float
    box: np.ndarray | None = None
    """Last xyxy box (pixels)."""
    centre_velocity_pxps: np.ndarray | None = None
    """Velocity (u', v') of the box centre in pixels per second, smoothed over the track's frames."""
    handed_over_from: tuple[int, ...] = ()
    """Ids whose evidence this track took over (oldest first, the last 8)."""
    last_body_s: float | None = None
    """When the EV-body classifier last scored this track."""


def _may_own_flashes(info: TrackInfo) -> bool:
    """Could the flashes seen around this track be its own: a confirmed EV, or a track whose own band gave a flash or
    alternation cue within ``clear_after_s``, such as an EV whose track SORT started again and whose evidence is
    building up anew. A steady bar alone does not count: it is no flash, and confirms nothing without a confident
    body (a blue object on the roof line of a van in the Japanese clip, a steady-bar cue, held back the body scores of
    the ambulance just behind it for 1.5 s)."""
    return info.evidence.state == EvState.CONFIRMED or info.evidence.flashed_recently


def crop_share_within(crop: tuple[int, int, int, int], other: tuple[int, int, int, int]) -> float:
    """The share of the xyxy rectangle ``crop``'s area inside the rectangle ``other``."""
    iw = min(crop[2], other[2]) - max(crop[0], other[0])
    ih = min(crop[3], other[3]) - max(crop[1], other[1])
    area = (crop[2] - crop[0]) * (crop[3] - crop[1])
    return float(iw * ih) / area if iw > 0 and ih > 0 and area > 0 else 0.0


def reaches_into(box, crop) -> bool:
    """Do the box and the crop (both x1, y1, x2, y2) overlap?"""
    return box[0] < crop[2] and box[2] > crop[0] and box[1] < crop[3] and box[3] > crop[1]


def lit_beside(crop, box, reach_share: float) -> bool:
    """Is the xyxy rectangle ``crop`` level with ``box`` (their rows overlap) and at most ``reach_share`` of ``box``'s
    width away from it sideways (or overlapping it)?"""
    if crop[1] >= box[3] or crop[3] <= box[1]:
        return False
    gap = max(crop[0] - box[2], box[0] - crop[2], 0.0)
    return gap <= reach_share * (box[2] - box[0])


def extrapolate_box(box: np.ndarray, centre_velocity_pxps: np.ndarray | None, dt_s: float) -> np.ndarray:
    """An xyxy box moved ``dt_s`` seconds on at its centre's constant velocity, its size kept: the size of
    a track that was just lost is the least trustworthy part of it (SORT's aspect ratio lags a vehicle that
    turns its side or back to the camera, which is often why the track was lost), and over the half
    second of a hand-over a vehicle's apparent size changes far less than its position."""
    box = np.asarray(box, float)
    if centre_velocity_pxps is None:
        return box
    vx, vy = (float(v) * dt_s for v in centre_velocity_pxps)
    return box + np.array([vx, vy, vx, vy])


def match_lost_tracks(new_boxes: np.ndarray, lost_boxes: np.ndarray, min_iou: float) -> list[tuple[int, int]]:
    """Pairs (new index, lost index) with IoU >= ``min_iou``, each box used once: SORT's own association
    (:func:`rsu.track.sort.associate`, the reference's shortcut or Hungarian on IoU), with lost boxes as tracks."""
    new_boxes = np.asarray(new_boxes, float).reshape(-1, 4)
    lost_boxes = np.asarray(lost_boxes, float).reshape(-1, 4)
    rows, cols, _ = associate(new_boxes, lost_boxes, min_iou)
    return [(int(i), int(j)) for i, j in zip(rows, cols, strict=True)]


class TrackEvClassifier:
    """Per-track temporal EV classifier (the RSU's classifier hook); see the module docstring."""

    def __init__(self, config: EvidenceConfig | None = None, crop_score: CropScore | None = None, *,
                 body: CropScore | None = None, body_period_s: float = 0.25, top_fraction: float = 0.4,
                 colours: LampColours = LAMP_BRIGHT, bar_colours: LampColours = BAR_COLOURED, above_fraction: float | None = None, min_box_px: float = 40.0,
                 forget_after_s: float = 2.0, max_tracks: int = 512,
                 box_gate: Callable[[Iterable[float], int, int], bool] | None = None,
                 handover_after_s: float = 0.5, handover_iou: float = 0.3, bright_above_fraction: float = 0.1,
                 occluded_hold_s: float = 2.0, fill_view_fraction: float = 0.85, lamp_state: Callable[[np.ndarray, np.ndarray | None], float] | None = None
                 ) -> None:
        if forget_after_s <= 0 or max_tracks < 1:
            raise ValueError("forget_after_s must be > 0 and max_tracks >= 1")
        if handover_after_s < 0 or not 0.0 < handover_iou <= 1.0:
            raise ValueError("handover_after_s must be >= 0 and handover_iou in (0, 1]")
        self.handover_after_s = float(handover_after_s)
        """A new id takes over a lost track's evidence only if that track was seen this recently (0.5 s:
        SORT's 1 missed frame plus 3 hits before a new id is reported is 4-5 frames at 15 fps)."""
        self.handover_iou = float(handover_iou)
        if occluded_hold_s < 0:
            raise ValueError(f"occluded_hold_s must be >= 0, got {occluded_hold_s}")
        self.occluded_hold_s = float(occluded_hold_s)
        """How long a lost flashing track, its moved-on box's bottom edge hidden behind a nearer vehicle, still owns
        the flashes around it (``_lost_evs``)."""
        self.nearer_owner_share = 0.25
        """A track whose crop lies this much (area share) within the crop of a *nearer* confirmed EV sees that EV's
        lamps (a second box on the EV's roof): its flashes confirm only with a confident body (``_ev_ahead``). Only a
        confirmed one: a farther EV whose flashes light a nearer car's roof makes that car flash too, and two tracks
        that each held the other's flashes back would never confirm."""
        self.glow_reach_share = 1.0
        """A track whose crop comes within this share of a confirmed EV's box width of that box, beside it and level with
        it, is lit by the EV's lamps: at night a beacon's light flashes on everything around it (the car beside an
        ambulance, its band blue in step with the ambulance's beacon: tuning clip ``roadside_night_ambulance_india_redblue``,
        a wrong-vehicle alert 0.6 s after the ambulance's), so its flashes confirm only with a confident body
        (``_ev_ahead``)."""
        self.config = config or EvidenceConfig()
        confident = getattr(body, "confident_threshold", None)
        if confident is not None and config is None:  # the body model's own confident operating point
            self.config = dataclasses.replace(self.config, body_threshold=float(confident))
        sure = getattr(body, "sure_threshold", None)
        if sure is not None and config is None:  # ... and its own sure one
            self.config = dataclasses.replace(self.config, body_sure_threshold=float(sure))
        self.crop_score = crop_score
        self.body = body
        self.lamp_state = lamp_state
        """p(warning lamps lit) of a lamp band (``band, ignore_mask -> p``: :class:`rsu.classify.lamp_state.LampStateModel`),
        measured on every measured track each frame; None: no lamp-state evidence (the colour tests alone)."""
        if above_fraction is None:  # as the body classifier was trained (its metadata), else 0.25
            above_fraction = float(getattr(body, "above_fraction", DEFAULT_ABOVE_FRACTION))
        if body_period_s < 0:
            raise ValueError("body_period_s must be >= 0")
        self.body_period_s = float(body_period_s)
        if not 0.0 <= above_fraction <= 1.0 or not 0.0 < top_fraction <= 1.0:
            raise ValueError("above_fraction must be in [0, 1] and top_fraction in (0, 1]")
        self.above_fraction = above_fraction
        if not 0.0 <= bright_above_fraction <= 1.0:
            raise ValueError(f"bright_above_fraction must be in [0, 1], got {bright_above_fraction}")
        self.bright_above_fraction = float(bright_above_fraction)
        """The lamp-bright colours (whose flash pattern confirms an EV alone) are measured in a band that reaches
        only this share of the box height above the box (the light-bar colours: ``above_fraction``). A lit bar
        sits on the roof, at the box's top edge; a lamp-bright flash 0.2-0.3 box heights above a bus or truck is
        the light bar of a vehicle ahead that the detector does not see (the EV itself, half hidden behind the
        bus: simulator tuning seeds 31372/91468, 2 false alerts on night_ev)."""
        # the band is the box's top ``top_fraction`` plus ``above_fraction`` of its height above the box
        self.band_fraction = min(1.0, (above_fraction + top_fraction) / (1.0 + above_fraction))
        self.colours, self.bar_colours = colours, bar_colours
        self.min_box_px = float(min_box_px)
        self.border_px = 2.0
        """A box whose side is within this of the image's left or right edge (or whose lamp band leaves the
        top) is cut by the border and not measured, unless it fills the view (``fill_view_fraction``)."""
        if not 0.0 < fill_view_fraction <= 1.0:
            raise ValueError(f"fill_view_fraction must be in (0, 1], got {fill_view_fraction}")
        self.fill_view_fraction = float(fill_view_fraction)
        """A box cut by the border that spans at least this share of the image's width or height is measured all the
        same: the vehicle is so near that it is larger than the view (a roadside camera beside an EV, a close-up of its
        light bar), and the part in view is all there is to see; its lamp band is the top of that part, clipped to the
        image. A vehicle entering or leaving the view at its side or far end is a fraction of it and stays
        unmeasured; no box of the tuning clips' elevated and CCTV views fills the view. Swept on the tuning clips of
        ``bench/ev_real_bench.py``: at 0.6-0.7 a vehicle beside the broadcast ambulance, cut by the frame's side, its
        box 0.76 of the image's height and lit by the ambulance's lamps, alerts (1 wrong-vehicle alert); at 0.8-0.85
        none does, and the close-up and broadcast EVs alert 2.5 s and 0.6 s after their lights are in view; at 0.9 the
        broadcast one 0.8 s after, at 0.95 2.2 s. 0.85: between the wrong alert and the late one."""
        self.box_gate = box_gate
        self.forget_after_s = forget_after_s
        self.max_tracks = max_tracks
        self.tracks: dict[int, TrackInfo] = {}

    def crop_bounds(self, box, width: int, height: int) -> tuple[int, int, int, int] | None:
        """The track's crop: its box grown upwards by ``above_fraction`` (light bars sit on the roof, often
        outside a COCO "car" box), clipped to the image."""
        return crop_above(box, width, height, self.above_fraction)

    def lamp_band(self, box, width: int, height: int) -> tuple[int, int, int, int] | None:
        """The xyxy pixels of the band in which the lamps are measured (for drawing)."""
        b = self.crop_bounds(box, width, height)
        if b is None:
            return None
        return b[0], b[1], b[2], b[1] + max(1, int(round((b[3] - b[1]) * self.band_fraction)))

    def measure(self, image: np.ndarray, box) -> tuple[LampMeasurement, float | None]:
        """Lamp-bright measurement of a box's band and the crop score (when a crop classifier is set)."""
        lamps, _, score, _ = self._measure(image, self.crop_bounds(box, image.shape[1], image.shape[0]))
        return lamps, score

    def _measure(self, image: np.ndarray, bounds: tuple[int, int, int, int] | None,
                 occluders: Iterable[tuple[int, int, int, int]] = (),
                 bar_occluders: list[tuple[int, int, int, int]] | tuple = ()
                 ) -> tuple[LampMeasurement, LampMeasurement, float | None, np.ndarray | None]:
        """(lamp-bright, light-bar colour) measurements of the band of the crop ``bounds``, the crop score and
        the crop. ``occluders``: rectangles of the crop left out of the band (:func:`band_exclusions`);
        ``bar_occluders``: rectangles left out of the light-bar measurement only (:func:`farther_boxes`)."""
        if bounds is None:
            return LampMeasurement(0.0, 0.0), LampMeasurement(0.0, 0.0), None, None
        xa, ya, xb, yb = bounds
        crop = image[ya:yb, xa:xb]
        ignore = rect_mask(bounds, occluders)
        bar_ignore = ignore
        if bar_occluders:
            extra = rect_mask(bounds, bar_occluders)
            bar_ignore = extra if ignore is None else ignore if extra is None else ignore | extra
        score = None
        if self.crop_score is not None:
            score = float(np.clip(self.crop_score(crop), 0.0, 1.0))
        offset = int(round(max(0.0, self.above_fraction - self.bright_above_fraction) * crop.shape[0]
                           / (1.0 + self.above_fraction)))
        if offset == 0 and bar_ignore is ignore:
            lamps, bar = measure_band(crop, self.band_fraction, (self.colours, self.bar_colours), ignore)
        else:  # the lamp-bright band starts lower (``bright_above_fraction``), the light-bar one leaves out more
            (bar,) = measure_band(crop, self.band_fraction, (self.bar_colours,), bar_ignore)
            rows = max(1, int(round(crop.shape[0] * self.band_fraction)))
            if rows > offset:
                (lamps,) = measure_band(crop[offset:], (rows - offset) / (crop.shape[0] - offset), (self.colours,),
                                        None if ignore is None else ignore[offset:])
            else:
                lamps = LampMeasurement(0.0, 0.0)
        return lamps, bar, score, crop

    def _lit(self, crop: np.ndarray | None, bounds: tuple[int, int, int, int] | None,
             exclusions: list[tuple[int, int, int, int]]) -> float | None:
        """The lamp-state model's p(lit) of the crop's lamp band, other vehicles' pixels left out; None without a
        model or a crop."""
        if self.lamp_state is None or crop is None or bounds is None:
            return None
        rows = max(2, int(round(crop.shape[0] * self.band_fraction)))
        ignore = rect_mask(bounds, exclusions)
        if ignore is not None and ignore[:rows].all():
            return None
        return float(self.lamp_state(crop[:rows], None if ignore is None else ignore[:rows]))

    def _body_score(self, info: TrackInfo, now_s: float, lamps: LampMeasurement, bar: LampMeasurement,
                    crop: np.ndarray | None, bounds: tuple[int, int, int, int] | None,
                    others: Iterable[tuple[int, int, int, int]]) -> float | None:
        """The EV-body score of this frame's crop (at ``bounds``), its pixels in the rectangles ``others``
        (farther vehicles' boxes above its top) blanked (:func:`~rsu.classify.ownership.blank_rects`), when the
        band shows lamp activity (:func:`~rsu.classify.evidence_config.lamp_activity`) and the last score is at least
        ``body_period_s`` old; else None. A confirmed EV is not scored again: confirmation is what the body score is
        for, and only the lamps keep or clear it (on the corridor's two cores, scoring every confirmed EV 4 times a second
        on four RSUs at once halved their processed fps while the EV was in view)."""
        if self.body is None or crop is None or bounds is None or info.evidence.state == EvState.CONFIRMED:
            return None
        cue_s = info.evidence.last_lamp_cue_s  # e.g. a white strobe's flashes, which lamp_activity does not see
        if not lamp_activity(lamps, bar, self.config) and (cue_s is None or now_s - cue_s > self.config.steady_window_s):
            return None
        if info.last_body_s is not None and now_s - info.last_body_s < self.body_period_s:
            return None
        info.last_body_s = now_s
        return float(np.clip(self.body(blank_rects(crop, rect_mask(bounds, others))), 0.0, 1.0))

    def __call__(self, frame: Frame, tracks: Detections) -> Detections:
        """``tracks`` with the EV columns of this frame (``ev_scores``, ``light_states``, ``ev_states``,
        ``evidence``)."""
        now = float(frame.timestamp_s)
        image = frame.image
        ids = [int(t) for t in tracks.column("track_ids")]
        scores, lights, states, records = [], [], [], []
        boxes = np.asarray(tracks.boxes, float).reshape(-1, 4)
        if self.handover_after_s > 0 and any(tid not in self.tracks for tid in ids):
            self._hand_over(now, ids, boxes)
        h, w = image.shape[:2]
        bounds = [self.crop_bounds(b, w, h) for b in boxes]  # each track's crop, once per frame
        lost_evs = None  # EVs lost within the hand-over time (their moved-on boxes), found when needed
        for k, (tid, box) in enumerate(zip(ids, boxes, strict=True)):
            info = self.tracks.get(tid)
            if info is None:
                info = self.tracks[tid] = TrackInfo(TrackEvidence(self.config), now, now)
            if info.box is not None and now > info.last_seen_s:
                v = (box[:2] + box[2:] - info.box[:2] - info.box[2:]) / (2.0 * (now - info.last_seen_s))
                info.centre_velocity_pxps = v if info.centre_velocity_pxps is None else 0.5 * (
                    info.centre_velocity_pxps + v)
            info.box = box.copy()
            info.last_seen_s = now
            ev = info.evidence
            if min(box[2] - box[0], box[3] - box[1]) < self.min_box_px or self._cut_by_border(box, image) or (
                    self.box_gate is not None and not self.box_gate(box, image.shape[1], image.shape[0])):
                # too few pixels to see a light bar (a far vehicle), or a box too big for one vehicle
                # (several merged into one blob): no measurement this frame, the evidence keeps its state
                state = ev.state
            else:
                farther = farther_boxes(k, boxes)
                exclusions = band_exclusions(k, boxes, bounds)
                lamps, bar, score, crop = self._measure(image, bounds[k], exclusions, farther)
                lit = self._lit(crop, bounds[k], exclusions)
                if lost_evs is None:
                    lost_evs = self._lost_evs(now, ids, boxes)
                ahead = self._ev_ahead(k, ids, boxes, bounds, lost_evs)
                # with a flashing vehicle just ahead, this crop (grown above the box) holds part of that
                # vehicle too, and its body score says as much about it as about this one: none taken now
                body = None if ahead else self._body_score(info, now, lamps, bar, crop,
                                                           bounds[k], above_top(farther, box))
                state = ev.update(now, lamps, score, body, bar, lamps_alone=not ahead, lit_p=lit)
            scores.append(ev.ev_score)
            lights.append(ev.light_state)
            states.append(state)
            records.append(info)
        self._forget(now)
        return tracks.with_columns(ev_scores=np.asarray(scores, float).reshape(len(ids)),
                                   light_states=object_column(lights), ev_states=object_column(states),
                                   evidence=object_column(records))

    def _lost_evs(self, now_s: float, ids: list[int], boxes: np.ndarray | None = None) -> LostEvs:
        """The boxes (N, 4), moved on at their own velocity, of tracks not in this frame's ``ids`` that were
        confirmed EVs or flashing themselves (``_may_own_flashes``), lost within ``handover_after_s``, or within
        ``occluded_hold_s`` while the moved-on box's bottom edge is hidden behind a nearer vehicle's box of this
        frame (``boxes``; ``hidden_behind_nearer``): SORT drops a track after one missed detection, and an EV just ahead is
        still there (simulator tuning seed 44077: the EV's track lost for one frame, the bus behind it, its roof lit
        by the EV's strobe, confirmed in that frame); an EV that drives on hidden behind a truck nearer the camera
        is there for longer, its light bar above the truck's roof (tuning seed 52609, ``ev_two_lanes_dense``,
        rsu4: the truck confirmed on the EV's flashes 0.67 s after the EV's track was lost); and which of them are
        confirmed EVs (whose lamps light the vehicles beside them: ``_ev_ahead``)."""
        current = set(ids)
        hold_s = max(self.handover_after_s, self.occluded_hold_s)
        out, confirmed = [], []
        for tid, i in self.tracks.items():
            age_s = now_s - i.last_seen_s
            if tid in current or i.box is None or not 0.0 < age_s <= hold_s or not _may_own_flashes(i):
                continue
            moved = extrapolate_box(i.box, i.centre_velocity_pxps, age_s)
            if age_s <= self.handover_after_s or (boxes is not None and hidden_behind_nearer(moved, boxes,
                                                                                           max_iou=self.handover_iou)):
                out.append(moved)
                confirmed.append(i.evidence.state == EvState.CONFIRMED)
        return LostEvs(np.asarray(out, float).reshape(-1, 4), np.asarray(confirmed, bool))

    def _ev_ahead(self, k: int, ids: list[int], boxes: np.ndarray, bounds: list,
                  lost_evs: LostEvs | None = None) -> bool:
        """May the lamps in track ``k``'s band be those of a vehicle just ahead of it: a farther track (bottom edge
        higher) whose box reaches into ``k``'s crop and that is either a confirmed EV or a track with lamp cues of
        its own (``_may_own_flashes``; or one of those lost within the hand-over time: ``lost_evs``) or too small for
        its own lamps to be measured (``min_box_px``) while it rises above ``k``'s roof? Its flashes light this
        vehicle's roof and the band above it (a bus behind the EV, nearer the camera: the bar's glow on the bus
        roof, outside the EV's box, flashed in step with it; simulator tuning seeds 91468, and 44077, where the
        EV, 28 px tall, was never measured and its strobe confirmed the bus; ev_bench seed 51100, ``night_ev``, rsu2: the EV's track
        started again after the EV passed a truck, its new evidence not yet confirmed while its flashes, seen in the
        truck's band just behind it, confirmed the truck), so ``k``'s flash pattern then confirms only with a
        confident body (``TrackEvidence.update``), scored while no such vehicle was ahead: its crop, grown above
        the box, would hold part of the vehicle ahead (ev_bench seeds 16790 and 36545: a car 11-13 m behind the
        EV, its crop scored 0.40-0.68 with the EV in it). Also a confirmed EV beside ``k``, seen or lost within the
        hand-over time (``lost_evs.confirmed``), whose lamps light it (``glow_reach_share``)."""
        box, crop = boxes[k], bounds[k]
        if crop is None:
            return False
        for j, other in enumerate(boxes):
            if j == k:
                continue
            info = self.tracks.get(ids[j])
            confirmed = info is not None and info.evidence.state == EvState.CONFIRMED
            if confirmed and lit_beside(crop, other, self.glow_reach_share):
                return True
            if other[3] > box[3]:  # a nearer confirmed EV: its lamps when this crop lies largely within its crop
                if confirmed and bounds[j] is not None and crop_share_within(crop, bounds[j]) >= self.nearer_owner_share:
                    return True
                continue
            if not reaches_into(other, crop):
                continue
            if info is not None and _may_own_flashes(info):
                return True
            if other[1] < box[1] and min(other[2] - other[0], other[3] - other[1]) < self.min_box_px:
                return True
        for other, confirmed in () if lost_evs is None else zip(*lost_evs, strict=True):
            if confirmed and lit_beside(crop, other, self.glow_reach_share):
                return True
            if other[3] <= box[3] and reaches_into(other, crop):
                return True
        return False

    def _cut_by_border(self, box, image: np.ndarray) -> bool:
        """Does the image border cut the box's sides or its lamp band (grown above the box)? Then only part of
        the vehicle and of its roof is in view: neither the lamp band nor the body crop means what it should."""
        x1, y1, x2, y2 = (float(v) for v in box)
        h, w = image.shape[:2]
        top = y1 - self.above_fraction * (y2 - y1)
        if not (x1 < self.border_px or x2 > w - self.border_px or top < 0.0):
            return False
        return not (x2 - x1 >= self.fill_view_fraction * w or y2 - y1 >= self.fill_view_fraction * h)

    def _hand_over(self, now_s: float, ids: list[int], boxes: np.ndarray) -> None:
        """New ids take over the evidence of recently lost tracks they overlap (module docstring)."""
        current = set(ids)
        lost = [tid for tid, i in self.tracks.items() if tid not in current and i.box is not None
                and 0.0 < now_s - i.last_seen_s <= self.handover_after_s]
        if not lost:
            return
        new = [k for k, tid in enumerate(ids) if tid not in self.tracks and not holds_nearer_vehicle(k, boxes)]
        if not new:
            return
        predicted = np.array([extrapolate_box(self.tracks[t].box, self.tracks[t].centre_velocity_pxps,
                                              now_s - self.tracks[t].last_seen_s) for t in lost])
        for i, j in match_lost_tracks(boxes[new], predicted, self.handover_iou):
            info = self.tracks.pop(lost[j])
            info.evidence.handed_over()
            info.last_body_s = None  # score the new box on its first frame with lamp activity
            info.handed_over_from = (*info.handed_over_from, lost[j])[-8:]
            self.tracks[ids[new[i]]] = info

    def _forget(self, now_s: float) -> None:
        gone = [tid for tid, i in self.tracks.items() if now_s - i.last_seen_s > self.forget_after_s]
        for tid in gone:
            del self.tracks[tid]
        if len(self.tracks) > self.max_tracks:  # oldest-seen first
            for tid, _ in sorted(self.tracks.items(), key=lambda kv: kv[1].last_seen_s)[:len(self.tracks) - self.max_tracks]:
                del self.tracks[tid]
