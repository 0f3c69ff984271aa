"""The RSU's wire messages, made in one place: the frame's table of tracks (``rsu.perception.Detections``) as an
``ObjectList`` of ``DetectedObject`` rows, EV alert events as ``EvAlert``, hazard events as ``HazardAlert``
(``protocol.messages``, after SAE J3224 SDSM and J2735 EVA). Every number is clipped into its wire range here,
so a message the pipeline makes always validates. Pure: the caller gives ids, sequence numbers and stamps.
"""

from __future__ import annotations

import numpy as np

from protocol.enums import EvState, LightState, ObjectType
from protocol.messages import MAX_OBJECTS, DetectedObject, EvAlert, EvEvidence, HazardAlert, ObjectList
from rsu.classify.alerts import AlertEvent
from rsu.hazard import HazardEvent
from rsu.perception import Detections


def _unit(v: float) -> float:
    return float(np.clip(v, 0.0, 1.0))


def detected_objects(tracks: Detections) -> list[DetectedObject]:
    """One ``DetectedObject`` per row of a localised table with its EV verdicts (``ev_states``: ``CONFIRMED``
    is published as ``obj_type = ev``)."""
    out = []
    ids, boxes, scores = tracks.column("track_ids"), tracks.boxes, tracks.scores
    ev_scores, ev_states, lights = tracks.column("ev_scores"), tracks.column("ev_states"), tracks.column("light_states")
    pos, latlon, vel = tracks.column("positions_m"), tracks.column("latlon_deg"), tracks.column("velocities_mps")
    speeds, headings, cov = tracks.column("speeds_mps"), tracks.column("headings_rad"), tracks.column("pos_cov_m2")
    lanes, ages, hits = tracks.column("lanes"), tracks.column("ages_s"), tracks.column("hits")
    for k in range(len(tracks)):
        state = ev_states[k]
        out.append(DetectedObject(
            object_id=int(ids[k]), pos_x_m=float(pos[k, 0]), pos_y_m=float(pos[k, 1]),
            lat_deg=float(latlon[k, 0]), lon_deg=float(latlon[k, 1]),
            bbox_px=tuple(float(v) for v in boxes[k]),
            obj_type=ObjectType.EV if state == EvState.CONFIRMED else ObjectType.VEHICLE,
            obj_type_cfd=_unit(scores[k]), ev_score=float(ev_scores[k]), ev_state=state,
            light_state=lights[k] if lights[k] is not None else LightState.UNKNOWN,
            vel_x_mps=float(vel[k, 0]), vel_y_mps=float(vel[k, 1]), speed_mps=float(speeds[k]),
            heading_rad=float(headings[k]),
            pos_cov_m2=(max(float(cov[k, 0]), 0.0), float(cov[k, 1]), max(float(cov[k, 2]), 0.0)),
            lane=lanes[k], age_s=max(float(ages[k]), 0.0), hits=max(int(hits[k]), 0),
        ))
    return out


def object_list(rsu_id: str, seq: int, stamp_s: float, frame_number: int, measurement_time_s: float,
                tracks: Detections) -> ObjectList:
    """The ``ObjectList`` of one frame: its first ``MAX_OBJECTS`` localised tracks."""
    return ObjectList(src=rsu_id, seq=seq, stamp=max(stamp_s, 0.0), rsu_id=rsu_id, frame=frame_number,
                      measurement_time=max(measurement_time_s, 0.0),
                      objects=detected_objects(tracks[:MAX_OBJECTS]))


def alert_id(rsu_id: str, track_id: int) -> str:
    """An RSU's EV alert id: one per track."""
    return f"{rsu_id}-ev-{track_id}"


def ev_alert(rsu_id: str, seq: int, stamp_s: float, event: AlertEvent) -> EvAlert:
    """The ``EvAlert`` of one alert event, placed where the alerting track was last localised."""
    row = event.row
    pos, latlon, vel = row.column("positions_m")[0], row.column("latlon_deg")[0], row.column("velocities_mps")[0]
    return EvAlert(src=rsu_id, seq=seq, stamp=max(stamp_s, 0.0), alert_id=alert_id(rsu_id, event.track_id),
                   state=event.state, rsu_id=rsu_id, object_id=event.track_id, pos_x_m=float(pos[0]),
                   pos_y_m=float(pos[1]), lat_deg=float(latlon[0]), lon_deg=float(latlon[1]),
                   vel_x_mps=float(vel[0]), vel_y_mps=float(vel[1]), speed_mps=float(row.column("speeds_mps")[0]),
                   heading_rad=float(row.column("headings_rad")[0]), lane=row.column("lanes")[0],
                   confidence=_unit(event.confidence), first_seen=max(event.first_seen_s, 0.0),
                   evidence=EvEvidence(frames=event.frames, flash_hz=event.flash_hz,
                                       mean_score=_unit(event.mean_score), cues=list(event.cues),
                                       body_score=None if event.body_score is None else _unit(event.body_score)),
                   clear_reason=event.clear_reason)


def hazard_alert(rsu_id: str, seq: int, stamp_s: float, h: HazardEvent) -> HazardAlert:
    """The ``HazardAlert`` of one hazard event (its ``lat_deg`` / ``lon_deg`` set by the pipeline)."""
    return HazardAlert(src=rsu_id, seq=seq, stamp=max(stamp_s, 0.0), hazard_id=f"{rsu_id}-hz-{h.hazard_id}",
                       state=h.state, rsu_id=rsu_id, pos_x_m=h.x_m, pos_y_m=h.y_m, lat_deg=h.lat_deg,
                       lon_deg=h.lon_deg, lane=h.lane, length_m=max(h.length_m, 0.0), width_m=max(h.width_m, 0.0),
                       confidence=_unit(h.confidence), first_seen=max(h.first_seen_s, 0.0))
