"""Ground truth for real clips and per-vehicle scoring of EV alerts against it (scoring only: never perceives).

**Label file** (one JSON object per clip, ``bench/labels/<clip stem>.json``)::

    {"clip": "x.mp4", "folder": "ev_videos", "viewpoint": "elevated", "width": 1280, "height": 720,
     "fps": 25.0, "duration_s": 11.5, "note": "...",
     "vehicles": [{"name": "amb", "role": "ev", "kind": "ambulance",
                   "frames": [[t_s, x1, y1, x2, y2, lit], ...]}, ...]}

``role`` is ``ev`` (an emergency vehicle) or ``flasher`` (hazard or turn flashers, an amber beacon: never an
EV); ``frames`` hold the vehicle's box (the clip's pixels) at least every 0.5 s while it is in view and
whether its warning lights are visibly on then. Between two frames at most :data:`MAX_GAP_S` apart the box
is interpolated linearly (and the lamps take the nearer frame's state); a longer gap means out of view. A
clip with no ``ev`` vehicle has no EV: every alert on it is false.

**Scoring** (:func:`score_clip`, pure) takes the scan's tracks (per track id, one ``(t_s, x1, y1, x2, y2,
alerted)`` per frame; ``rsu.scan.ScanResult.track_boxes``):

- an EV is *found* at the first frame where an alerted track that is *on* an EV (below) overlaps its box
  with IoU >= :data:`FOUND_IOU` while its lights are on;
- it is *scorable* (counted by ``ev_recall``) when its lights are on and its box at least
  :data:`MIN_EV_WIDTH_PX` wide for at least :data:`MIN_SCORABLE_S` without a break; the alert delay runs
  from the first frame of that stretch to the frame it is found (0 when found earlier);
- an alerted track is *on* an EV when its box overlaps one (IoU >= :data:`FOUND_IOU`) in at least half of the
  frames it is alerted in while an EV is in view; any other alerted track is a wrong-vehicle alert
  (``flasher_alerts`` counts those that sit on a labelled flasher); on a clip with no EV every alerted
  track is a false alert;
- a scorable EV's ``tracked_share`` is the share of its lit frames (from its scorable start, wide enough) in
  which any track box overlaps it (IoU >= :data:`FOUND_IOU`): it tells a miss of the detector and tracker (the EV
  is in no track's box) from a miss of the recogniser (it is, and raised no alert).

:func:`summarize` adds the clips up: ``ev_recall``, ``alert_delay_median_s``, ``alert_delay_max_s``,
``wrong_vehicle_alerts``, ``traffic_false_alerts`` (clips with no EV), their rate per hour of such video,
overall and per viewpoint (:data:`VIEWPOINTS`).
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

VIEWPOINTS = ("elevated", "roadside", "in-car", "broadcast")
"""elevated: CCTV, footbridge, overpass (an RSU's view); roadside: street level, handheld; in-car: through a
windscreen; broadcast: edited TV footage."""
ROLES = ("ev", "flasher")
MAX_GAP_S = 1.0
"""Frames further apart than this are not interpolated between (the vehicle is out of view there)."""
EDGE_S = 0.25
"""A vehicle's first / last labelled box also stands this long before / after it (half a 0.5 s step)."""
FOUND_IOU = 0.3
MIN_EV_WIDTH_PX = 40.0
MIN_SCORABLE_S = 1.0

TUNING_TRAFFIC_CLIPS = ("ambdet_video_3", "elevated_dense_day_dhaka", "haarcascades_video1", "overpass_dusk_taillights")
"""The traffic clips (no EV; stems of ``../shared/data/real/traffic_videos``) that may tune the recogniser and train
its models as non-EVs: dense day traffic, rows of tail lights at dusk, motorway cameras. The other traffic clips are
held out (``bench/ev_real_bench.py``)."""

TrackRows = Mapping[int, Sequence[tuple[float, float, float, float, float, bool]]]


class LabelError(ValueError):
    """A label file that does not follow the format (the message names the file and what is wrong)."""


@dataclass(frozen=True)
class LabelledVehicle:
    name: str
    role: str
    kind: str
    frames: tuple[tuple[float, float, float, float, float, bool], ...]
    """``(t_s, x1, y1, x2, y2, lit)``, in time order."""

    def at(self, t_s: float) -> tuple[np.ndarray, bool] | None:
        """The box (xyxy) and lamp state at ``t_s``, or None when the vehicle is not in view then."""
        ts = [f[0] for f in self.frames]
        k = int(np.searchsorted(ts, t_s, side="right"))  # frames[k-1].t <= t_s < frames[k].t
        if k == 0:
            f = self.frames[0]
            return (np.array(f[1:5]), bool(f[5])) if f[0] - t_s <= EDGE_S else None
        a = self.frames[k - 1]
        if k == len(self.frames):
            return (np.array(a[1:5]), bool(a[5])) if t_s - a[0] <= EDGE_S else None
        b = self.frames[k]
        if b[0] - a[0] > MAX_GAP_S:
            if t_s - a[0] <= EDGE_S:
                return np.array(a[1:5]), bool(a[5])
            if b[0] - t_s <= EDGE_S:
                return np.array(b[1:5]), bool(b[5])
            return None
        w = (t_s - a[0]) / (b[0] - a[0])
        box = (1 - w) * np.array(a[1:5]) + w * np.array(b[1:5])
        return box, bool(a[5] if w < 0.5 else b[5])


@dataclass(frozen=True)
class ClipLabels:
    clip: str
    folder: str
    viewpoint: str
    width: int
    height: int
    fps: float
    duration_s: float
    vehicles: tuple[LabelledVehicle, ...] = ()
    note: str = ""

    @property
    def evs(self) -> list[LabelledVehicle]:
        return [v for v in self.vehicles if v.role == "ev"]

    @property
    def has_ev(self) -> bool:
        return bool(self.evs)

    def frame_times(self) -> np.ndarray:
        return np.arange(int(round(self.duration_s * self.fps)) + 1) / self.fps


def labels_to_json(labels: ClipLabels) -> dict:
    return dict(clip=labels.clip, folder=labels.folder, viewpoint=labels.viewpoint, width=labels.width,
                height=labels.height, fps=labels.fps, duration_s=labels.duration_s, note=labels.note,
                vehicles=[dict(name=v.name, role=v.role, kind=v.kind,
                               frames=[[round(f[0], 3), *(round(float(x), 1) for x in f[1:5]), bool(f[5])]
                                       for f in v.frames]) for v in labels.vehicles])


def labels_from_json(d: dict, source: str = "labels") -> ClipLabels:
    """Validated :class:`ClipLabels` (:class:`LabelError` naming ``source`` and the field that is wrong)."""
    def bad(what: str) -> LabelError:
        return LabelError(f"{source}: {what} (format: rsu.scan_labels)")

    for key in ("clip", "folder", "viewpoint", "width", "height", "fps", "duration_s", "vehicles"):
        if key not in d:
            raise bad(f"missing {key!r}")
    if d["viewpoint"] not in VIEWPOINTS:
        raise bad(f"viewpoint {d['viewpoint']!r} is not one of {VIEWPOINTS}")
    if not float(d["fps"]) > 0 or not float(d["duration_s"]) > 0:
        raise bad("fps and duration_s must be > 0")
    vehicles = []
    for v in d["vehicles"]:
        name = v.get("name", "?")
        if v.get("role") not in ROLES:
            raise bad(f"vehicle {name!r}: role {v.get('role')!r} is not one of {ROLES}")
        frames = []
        for f in v.get("frames", []):
            if len(f) != 6 or not isinstance(f[5], bool):
                raise bad(f"vehicle {name!r}: frame {f!r} is not [t_s, x1, y1, x2, y2, lit(bool)]")
            t, x1, y1, x2, y2 = (float(x) for x in f[:5])
            if not (x2 > x1 and y2 > y1):
                raise bad(f"vehicle {name!r}: box at {t} s has x2 <= x1 or y2 <= y1")
            frames.append((t, x1, y1, x2, y2, f[5]))
        if not frames:
            raise bad(f"vehicle {name!r} has no frames")
        if any(b[0] <= a[0] for a, b in zip(frames, frames[1:], strict=False)):
            raise bad(f"vehicle {name!r}: frame times not strictly increasing")
        vehicles.append(LabelledVehicle(name, v["role"], str(v.get("kind", "")), tuple(frames)))
    return ClipLabels(d["clip"], d["folder"], d["viewpoint"], int(d["width"]), int(d["height"]), float(d["fps"]),
                      float(d["duration_s"]), tuple(vehicles), str(d.get("note", "")))


def load_labels(path: str | Path) -> ClipLabels:
    path = Path(path)
    try:
        d = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise LabelError(f"{path}: not JSON ({exc})") from None
    return labels_from_json(d, str(path))


def write_labels(labels: ClipLabels, path: str | Path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    d = labels_to_json(labels)
    lines = [json.dumps({k: v for k, v in d.items() if k != "vehicles"})[:-1] + ', "vehicles": [']
    for k, v in enumerate(d["vehicles"]):
        head = json.dumps({kk: vv for kk, vv in v.items() if kk != "frames"})[:-1] + ', "frames": ['
        rows = ",\n    ".join(json.dumps(f) for f in v["frames"])
        lines.append(f"  {head}\n    {rows}]}}" + ("," if k < len(d["vehicles"]) - 1 else ""))
    lines.append("]}")
    path.write_text("\n".join(lines) + "\n")
    labels_from_json(json.loads(path.read_text()), str(path))  # what was written reads back
    return path


def iou(a: Sequence[float], b: Sequence[float]) -> float:
    ix = max(0.0, min(a[2], b[2]) - max(a[0], b[0]))
    iy = max(0.0, min(a[3], b[3]) - max(a[1], b[1]))
    inter = ix * iy
    union = (a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter
    return inter / union if union > 0 else 0.0


@dataclass
class EvScore:
    name: str
    scorable: bool
    scorable_from_s: float | None
    """First frame of the first stretch lit and wide enough for long enough (None: never)."""
    found_s: float | None
    found_track: int | None
    max_width_px: float
    tracked_share: float | None = None
    """Share of the EV's frames from ``scorable_from_s`` on, lit and wide enough, in which a track box (alerted or
    not) overlaps it at IoU >= ``FOUND_IOU``: under 1, the detector and tracker lost it for that share, whatever the
    recogniser does (None: not scorable)."""

    @property
    def delay_s(self) -> float | None:
        if self.found_s is None or self.scorable_from_s is None:
            return None
        return max(0.0, self.found_s - self.scorable_from_s)


@dataclass
class ClipScore:
    clip: str
    viewpoint: str
    has_ev: bool
    duration_s: float
    evs: list[EvScore] = field(default_factory=list)
    alerted_tracks: list[int] = field(default_factory=list)
    on_ev_tracks: list[int] = field(default_factory=list)
    wrong_tracks: list[int] = field(default_factory=list)
    """Alerted tracks on no EV (on a clip with no EV: every alerted track)."""
    flasher_tracks: list[int] = field(default_factory=list)

    def to_json(self) -> dict:
        return dict(clip=self.clip, viewpoint=self.viewpoint, has_ev=self.has_ev, duration_s=self.duration_s,
                    alerted_tracks=self.alerted_tracks, on_ev_tracks=self.on_ev_tracks,
                    wrong_tracks=self.wrong_tracks, flasher_tracks=self.flasher_tracks,
                    evs=[dict(name=e.name, scorable=e.scorable, scorable_from_s=_r(e.scorable_from_s),
                              found_s=_r(e.found_s), found_track=e.found_track, delay_s=_r(e.delay_s),
                              max_width_px=round(e.max_width_px, 1), tracked_share=_r(e.tracked_share))
                         for e in self.evs])


def _r(v: float | None) -> float | None:
    return None if v is None else round(float(v), 3)


def scorable_from(vehicle: LabelledVehicle, times: Iterable[float], min_width_px: float = MIN_EV_WIDTH_PX,
                  min_s: float = MIN_SCORABLE_S) -> tuple[float | None, float]:
    """(first frame of the first stretch with lights on and width >= ``min_width_px`` lasting >= ``min_s``,
    the widest box seen)."""
    start, widest, last = None, 0.0, None
    for t in times:
        at = vehicle.at(float(t))
        ok = False
        if at is not None:
            box, lit = at
            widest = max(widest, float(box[2] - box[0]))
            ok = lit and box[2] - box[0] >= min_width_px
        if ok:
            start = float(t) if start is None else start
            last = float(t)
            if last - start >= min_s - 1e-9:
                return start, max(widest, _widest(vehicle))
        else:
            start = None
    return None, max(widest, _widest(vehicle))


def _widest(vehicle: LabelledVehicle) -> float:
    return max(f[3] - f[1] for f in vehicle.frames)


def score_clip(labels: ClipLabels, tracks: TrackRows, *, min_width_px: float = MIN_EV_WIDTH_PX) -> ClipScore:
    """Per-vehicle score of one clip's scan against its labels (see the module docstring)."""
    out = ClipScore(labels.clip, labels.viewpoint, labels.has_ev, labels.duration_s)
    flashers = [v for v in labels.vehicles if v.role == "flasher"]
    for tid, rows in sorted(tracks.items()):
        alerted = [r for r in rows if r[5]]
        if not alerted:
            continue
        out.alerted_tracks.append(int(tid))
        on_ev = in_view = on_flasher = 0
        for t, x1, y1, x2, y2, _ in alerted:
            evs_now = [a for a in (v.at(t) for v in labels.evs) if a is not None]
            in_view += bool(evs_now)
            on_ev += any(iou((x1, y1, x2, y2), a[0]) >= FOUND_IOU for a in evs_now)
            on_flasher += any(a is not None and iou((x1, y1, x2, y2), a[0]) >= FOUND_IOU
                              for a in (v.at(t) for v in flashers))
        if in_view and on_ev >= 0.5 * in_view:
            out.on_ev_tracks.append(int(tid))
        else:
            out.wrong_tracks.append(int(tid))
            if on_flasher >= 0.5 * len(alerted):
                out.flasher_tracks.append(int(tid))
    times = labels.frame_times()
    by_frame = _boxes_by_frame(tracks, labels.fps)
    for ev in labels.evs:
        start, widest = scorable_from(ev, times, min_width_px)
        found_s, found_track = None, None
        for tid in out.on_ev_tracks:  # a wrong-vehicle track that brushes the EV does not find it
            for t, x1, y1, x2, y2, alerted in tracks[tid]:
                if not alerted or (found_s is not None and t >= found_s):
                    continue
                at = ev.at(t)
                if at is not None and at[1] and iou((x1, y1, x2, y2), at[0]) >= FOUND_IOU:
                    found_s, found_track = float(t), int(tid)
                    break
        share = None if start is None else _tracked_share(ev, by_frame, times[times >= start - 1e-9], labels.fps,
                                                          min_width_px)
        out.evs.append(EvScore(ev.name, start is not None, start, found_s, found_track, widest, share))
    return out


def _boxes_by_frame(tracks: TrackRows, fps: float) -> dict[int, list[tuple[float, float, float, float]]]:
    out: dict[int, list] = {}
    for rows in tracks.values():
        for t, x1, y1, x2, y2, _ in rows:
            out.setdefault(int(round(t * fps)), []).append((x1, y1, x2, y2))
    return out


def _tracked_share(ev: LabelledVehicle, by_frame: dict[int, list], times: np.ndarray, fps: float,
                   min_width_px: float) -> float | None:
    """See :attr:`EvScore.tracked_share`."""
    seen = tracked = 0
    for t in times:
        at = ev.at(float(t))
        if at is None or not at[1] or at[0][2] - at[0][0] < min_width_px:
            continue
        seen += 1
        tracked += any(iou(b, at[0]) >= FOUND_IOU for b in by_frame.get(int(round(t * fps)), ()))
    return tracked / seen if seen else None


def summarize(scores: Sequence[ClipScore]) -> dict:
    """The figures over ``scores``, then the same per viewpoint under ``by_viewpoint``."""
    out = _figures(scores)
    out["by_viewpoint"] = {vp: _figures([s for s in scores if s.viewpoint == vp]) for vp in VIEWPOINTS
                           if any(s.viewpoint == vp for s in scores)}
    return out


def _figures(scores: Sequence[ClipScore]) -> dict:
    evs = [e for s in scores for e in s.evs if e.scorable]
    found = [e for e in evs if e.found_s is not None]
    delays = [e.delay_s for e in found]
    traffic = [s for s in scores if not s.has_ev]
    traffic_s = sum(s.duration_s for s in traffic)
    false = sum(len(s.wrong_tracks) for s in traffic)
    return dict(
        ev_clips=sum(s.has_ev for s in scores), evs_labelled=sum(len(s.evs) for s in scores),
        evs_scorable=len(evs), evs_found=len(found), ev_recall=_r(len(found) / len(evs)) if evs else None,
        alert_delay_median_s=_r(float(np.median(delays))) if delays else None,
        alert_delay_max_s=_r(max(delays)) if delays else None,
        wrong_vehicle_alerts=sum(len(s.wrong_tracks) for s in scores if s.has_ev),
        flasher_alerts=sum(len(s.flasher_tracks) for s in scores),
        traffic_clips=len(traffic), traffic_video_s=round(traffic_s, 2), traffic_false_alerts=false,
        traffic_false_alerts_per_hour=round(false * 3600.0 / traffic_s, 1) if traffic_s > 0 else None)
