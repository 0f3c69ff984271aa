"""Corridor world model: everything the DDM knows of the corridor, in one place. Pure core (no I/O, no
clock: every call takes ``now``, the DDM's time of reception).

Inputs (``ingest_*``) update it; :meth:`CorridorWorld.snapshot` returns the immutable
:class:`ddm.picture.Picture` the policies decide on (fuse, decide, command, in that order: nothing
downstream writes back into the world).

- Object lists (``ingest_objects``): lists older than ``max_measurement_age_s`` are dropped; the others
  are fused at their ``measurement_time`` (:mod:`ddm.fusion`, into the :class:`ddm.tracks.TrackStore`);
  overlapping fields of view give one track per car, and a car handed over from one RSU to the next
  keeps its global id.
- EVs (``ingest_ev_alert``; only authenticated evidence moves a car): an active EvAlert (signed, in a
  signed corridor: the DDM verifies alerts) marks the track it names (via the RSU's object id, else by
  position) until cleared or not refreshed for ``ev_alert_timeout_s``. An object list's unsigned
  ``obj_type=ev`` / ``ev_state=confirmed`` only holds the mark for ``ev_object_hold_s`` on a track an
  EvAlert has named (``ev_named``), never makes an EV on its own (``DdmConfig.ev_from_objects_alone``
  allows it, to measure the cost); a cleared alert removes the mark and suppresses the object-level
  mark on that track until a new alert; an alert cleared because the EV left that RSU's view
  (``clear_reason=out_of_view``) leaves the mark to time out, so the EV stays an EV while the next RSU
  gathers its own evidence.
- Hazards (``ingest_hazard_alert``): every RSU's HazardAlerts fused into corridor hazards
  (:class:`ddm.hazard_fusion.HazardFusion`).
- Autonomous vehicles (``ingest_vehicle_state``): each VehicleState is bound to the nearest track
  (``vehicle_gate_m``).
- RSU liveness: last object list and last health per RSU; ``stale_rsus(now)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ddm import fusion
from ddm.config import DdmConfig, HazardConfig
from ddm.geometry import RoadFrame
from ddm.hazard_fusion import HazardFusion
from ddm.intent import Ego
from ddm.picture import Picture
from ddm.tracks import EV_CODE, Track, TrackStore
from protocol.enums import AlertState, ClearReason
from protocol.messages import EvAlert, HazardAlert, ObjectList, VehicleState

EV_ALERT_LENGTH_M, EV_ALERT_WIDTH_M = 5.5, 2.0
"""Size of a track started from an EvAlert alone (no RSU object of it yet)."""


@dataclass(slots=True)
class AlertRecord:
    """The latest of one EvAlert and the track it named."""

    alert_id: str
    rsu_id: str
    object_id: int
    state: AlertState
    x_m: float
    y_m: float
    vx_mps: float
    vy_mps: float
    lane: int | None
    stamp_s: float
    last_seen_s: float
    track_id: int | None = None


@dataclass(slots=True)
class VehicleRecord:
    """An autonomous vehicle's latest state, when it came, and the track bound to it."""

    state: VehicleState
    received_s: float
    track_id: int | None = None


@dataclass
class IngestStats:
    """Counts of what the object lists brought (for Health and the benches)."""

    lists: int = 0
    objects: int = 0
    dropped_old: int = 0
    new_tracks: int = 0
    merged: int = 0
    deleted: int = 0


EGO_PREDICTION_MAX_S = 3.0
"""A vehicle's last state is carried forward at most this long (beyond, the decider no longer plans for it)."""


def ego_position_now(state: VehicleState, now: float) -> tuple[float, float]:
    """Where an AV is at ``now`` by its last state, measured at ``state.stamp``: carried forward at its speed
    along its heading (constant velocity) for the state's age, clamped to [0, ``EGO_PREDICTION_MAX_S``]. On a
    clean link the age is a control period and this moves the car by a metre; on a lossy TCP link states arrive
    in bursts seconds late, and a path planned from where the car was would start behind it (the car rejects a
    path that starts more than ``vehicle.commands.CommandLimits.max_start_behind_m`` behind it)."""
    return state.position_after(min(now - state.stamp, EGO_PREDICTION_MAX_S))


class CorridorWorld:
    """The corridor's fused tracks, EV alerts, hazards, autonomous vehicles and RSU liveness."""

    def __init__(self, config: DdmConfig | None = None, rsu_ids: tuple[str, ...] = (), capacity: int = 256, *,
                 frame: RoadFrame | None = None, hazard_config: HazardConfig | None = None) -> None:
        """``frame``: the road, to name each hazard's lane (None: hazard lanes unknown)."""
        self.config = config or DdmConfig()
        self.hazards = HazardFusion(frame, hazard_config)
        self.store = TrackStore(capacity)
        self.rsu_last_objects: dict[str, float] = {}
        self.rsu_last_health: dict[str, float] = {}
        self.rsu_expected: tuple[str, ...] = tuple(rsu_ids)
        self.started_s: float | None = None
        self.alerts: dict[str, AlertRecord] = {}
        self.vehicles: dict[str, VehicleRecord] = {}
        self.stats = IngestStats()
        for r in rsu_ids:
            self.store.rsu(r)

    @property
    def track_count(self) -> int:
        return self.store.track_count

    @property
    def rsu_ids(self) -> list[str]:
        return list(self.store.rsu_names)

    def knows_rsu(self, rsu_id: str) -> bool:
        return self.store.knows_rsu(rsu_id)

    def sizes(self) -> dict[str, int]:
        """How much the world holds (tracks, slots, alerts, vehicles, RSUs, object bindings)."""
        return {"tracks": self.track_count, "alerts": len(self.alerts), "vehicles": len(self.vehicles),
                "rsus": len(self.store.rsu_names), "hazards": len(self.hazards.hazards), **self.store.sizes()}

    def _heard(self, now: float) -> None:
        if self.started_s is None:
            self.started_s = now

    # ------------------------------------------------------------------ object lists
    def ingest_objects(self, msg: ObjectList, now: float) -> int:
        """Fuse one RSU frame; returns how many objects were absorbed (0 when the list was dropped)."""
        self._heard(now)
        store = self.store
        ri = store.rsu(msg.rsu_id)
        self.rsu_last_objects[msg.rsu_id] = now
        self.stats.lists += 1
        t_meas = float(msg.measurement_time)
        if now - t_meas > self.config.max_measurement_age_s:
            self.stats.dropped_old += len(msg.objects)
            return 0
        store.lists_per_rsu[ri] += 1
        if store.lists_per_rsu[ri] % 16 == 0:
            # Track.rsus lists only the RSUs that currently see a track: forget what the RSU lost
            store.prune_bindings(ri, now - self.config.track_timeout_s)
        if not msg.objects:
            return 0
        self.stats.new_tracks += fusion.fuse(store, ri, msg.objects, t_meas, now, self.config)
        self.stats.objects += len(msg.objects)
        return len(msg.objects)

    def ingest_rsu_health(self, rsu_id: str, now: float) -> None:
        self.store.rsu(rsu_id)
        self.rsu_last_health[rsu_id] = now
        self._heard(now)

    # ------------------------------------------------------------------ EV alerts
    def ingest_ev_alert(self, alert: EvAlert, now: float) -> int | None:
        """Mark (active) or unmark (cleared) the EV track the alert names; returns its track id."""
        self._heard(now)
        rec = self._record_alert(alert, now)
        slot = self._resolve_alert_slot(alert)
        if alert.state != AlertState.CLEARED:
            if slot is None:  # the EV is known only from its alert: start a track from it
                slot = self._start_from_alert(alert, now)
            self._mark_ev(slot, alert.alert_id, now)
        else:
            if slot is None and rec.track_id is not None:
                slot = self.store.slot_of(rec.track_id)
            if slot is not None:
                self._unmark_ev(slot, alert)
        rec.track_id = None if slot is None else int(self.store.cols.gid[slot])
        return rec.track_id

    def _record_alert(self, alert: EvAlert, now: float) -> AlertRecord:
        rec = self.alerts.get(alert.alert_id)
        if rec is None:
            rec = AlertRecord(alert.alert_id, alert.rsu_id, alert.object_id, alert.state, alert.pos_x_m,
                              alert.pos_y_m, alert.vel_x_mps, alert.vel_y_mps, alert.lane, alert.stamp, now)
            self.alerts[alert.alert_id] = rec
        else:
            rec.rsu_id, rec.object_id, rec.state = alert.rsu_id, alert.object_id, alert.state
            rec.x_m, rec.y_m, rec.vx_mps, rec.vy_mps = alert.pos_x_m, alert.pos_y_m, alert.vel_x_mps, alert.vel_y_mps
            rec.lane, rec.stamp_s, rec.last_seen_s = alert.lane, alert.stamp, now
        return rec

    def _mark_ev(self, slot: int, alert_id: str, now: float) -> None:
        c = self.store.cols
        c.ev_alert_until_s[slot] = now + self.config.ev_alert_timeout_s
        c.ev_suppressed[slot] = False
        c.ev_named[slot] = True
        self.store.alert_of_slot[slot] = alert_id

    def _unmark_ev(self, slot: int, alert: EvAlert) -> None:
        """A cleared alert: the EV left the RSU's view (its mark runs out on its own, ``ev_alert_timeout_s``
        after the last refresh, unless the next RSU alerts on it first), or it is no EV any more."""
        alert_of_slot = self.store.alert_of_slot
        if alert.clear_reason == ClearReason.OUT_OF_VIEW:
            if alert_of_slot.get(slot) == alert.alert_id:
                alert_of_slot.pop(slot, None)
            return
        c = self.store.cols
        c.ev_alert_until_s[slot] = 0.0
        c.ev_obj_until_s[slot] = 0.0
        c.ev_suppressed[slot] = True
        c.ev_named[slot] = False
        alert_of_slot.pop(slot, None)

    def _start_from_alert(self, alert: EvAlert, now: float) -> int:
        slots = self.store.alloc(1)
        var = np.array([1.0])
        self.store.start(slots, np.array([alert.pos_x_m]), np.array([alert.pos_y_m]), np.array([alert.vel_x_mps]),
                         np.array([alert.vel_y_mps]), var, var, 4.0 * self.config.vel_meas_var_m2ps2,
                         min(alert.stamp, now), now)
        self.stats.new_tracks += 1
        slot, c = int(slots[0]), self.store.cols
        c.type_code[slot] = EV_CODE
        c.lane[slot] = -1 if alert.lane is None else alert.lane
        c.length_m[slot], c.width_m[slot] = EV_ALERT_LENGTH_M, EV_ALERT_WIDTH_M
        return slot

    def _resolve_alert_slot(self, alert: EvAlert) -> int | None:
        """The track the alert names: the RSU object's, else the one it named before, else the nearest
        within ``vehicle_gate_m`` of its position with a velocity within ``gate_speed_mps``."""
        slot = self.store.bound_live_slot(alert.rsu_id, alert.object_id)
        if slot is not None:
            return slot
        rec = self.alerts.get(alert.alert_id)
        if rec is not None and rec.track_id is not None:
            s = self.store.slot_of(rec.track_id)
            if s is not None:
                return s
        live = self.store.live_slots()
        if not len(live):
            return None
        c = self.store.cols
        px, py, _, _ = fusion.predicted(c, live, alert.stamp, self.config.accel_noise_m2ps4)
        d = np.hypot(px - alert.pos_x_m, py - alert.pos_y_m)
        dv = np.hypot(c.vx_mps[live] - alert.vel_x_mps, c.vy_mps[live] - alert.vel_y_mps)
        d = np.where(dv <= self.config.gate_speed_mps, d, np.inf)
        k = int(np.argmin(d))
        return int(live[k]) if d[k] <= self.config.vehicle_gate_m else None

    # ------------------------------------------------------------------ hazards
    def ingest_hazard_alert(self, alert: HazardAlert, now: float) -> int | None:
        """Fuse one HazardAlert; returns the id of the hazard it belongs to (None after a clear)."""
        hz = self.hazards.ingest(alert, now)
        return None if hz is None else hz.hazard_id

    def drain_hazard_events(self) -> list[tuple[str, int]]:
        """(what, hazard id) since the last drain: appeared, cleared, expired."""
        return self.hazards.drain()

    # ------------------------------------------------------------------ autonomous vehicles
    def ingest_vehicle_state(self, vs: VehicleState, now: float) -> int | None:
        """Record an AV's own state and bind it to its corridor track; returns the track id."""
        rec = self.vehicles.get(vs.vehicle_id)
        if rec is None:
            rec = self.vehicles[vs.vehicle_id] = VehicleRecord(vs, now)
        rec.state, rec.received_s = vs, now
        store = self.store
        live = store.live_slots()
        old_slot = None if rec.track_id is None else store.slot_of(rec.track_id)
        new_slot = None
        if len(live):
            px, py, _, _ = fusion.predicted(store.cols, live, vs.stamp, self.config.accel_noise_m2ps4)
            d = np.hypot(px - vs.pos_x_m, py - vs.pos_y_m)
            k = int(np.argmin(d))
            if d[k] <= self.config.vehicle_gate_m:
                new_slot = int(live[k])
        if old_slot is not None and old_slot != new_slot:
            store.vehicle_of_slot.pop(old_slot, None)
        if new_slot is not None:
            store.vehicle_of_slot[new_slot] = vs.vehicle_id
        rec.track_id = None if new_slot is None else int(store.cols.gid[new_slot])
        return rec.track_id

    def vehicle_track_id(self, vehicle_id: str) -> int | None:
        rec = self.vehicles.get(vehicle_id)
        return None if rec is None else rec.track_id

    # ------------------------------------------------------------------ maintenance
    def maintain(self, now: float) -> None:
        """Delete tracks not updated for ``track_timeout_s``, merge duplicates, forget old alerts, drop
        hazard sources not refreshed for ``HazardConfig.source_timeout_s``."""
        cfg = self.config
        c = self.store.cols
        dead = np.nonzero(c.alive & (now - c.seen_s > cfg.track_timeout_s))[0]
        for s in dead.tolist():
            self._delete(s)
        self.stats.deleted += len(dead)
        self._merge_duplicates(now)
        for aid in [a for a, r in self.alerts.items() if now - r.last_seen_s > cfg.ev_alert_timeout_s]:
            del self.alerts[aid]
        self.hazards.maintain(now)

    def _delete(self, slot: int) -> None:
        vehicle = self.store.delete(slot)
        if vehicle is not None and vehicle in self.vehicles:
            self.vehicles[vehicle].track_id = None

    def _merge_duplicates(self, now: float) -> None:
        """Close tracks that are one car (``fusion.duplicates``): the older id keeps them."""
        for keep, drop in fusion.duplicates(self.store, now, self.config):
            aid = self.store.absorb(keep, drop)
            if aid is not None and aid in self.alerts:
                self.alerts[aid].track_id = int(self.store.cols.gid[keep])
            self._delete(drop)
            self.stats.merged += 1

    def stale_rsus(self, now: float) -> list[str]:
        """RSUs whose object stream (or health) has stopped; expected RSUs never heard count after the
        first ``rsu_stale_s`` of listening."""
        cfg = self.config
        out = []
        for name in self.store.rsu_names:
            last = self.rsu_last_objects.get(name)
            h = self.rsu_last_health.get(name)
            if last is None:
                ref = h if h is not None else self.started_s
                if ref is not None and now - ref > cfg.rsu_stale_s:
                    out.append(name)
                continue
            if now - last > cfg.rsu_stale_s or (h is not None and now - h > cfg.rsu_health_stale_s):
                out.append(name)
        return out

    # ------------------------------------------------------------------ reading
    def is_ev_mask(self, slots: np.ndarray, now: float) -> np.ndarray:
        c = self.store.cols
        by_objects = (c.ev_obj_until_s[slots] > now) & ~c.ev_suppressed[slots]
        if not self.config.ev_from_objects_alone:
            by_objects &= c.ev_named[slots]
        return (c.ev_alert_until_s[slots] > now) | by_objects

    def _tracks(self, slots: np.ndarray, now: float) -> list[Track]:
        return self.store.records(slots, now, self.is_ev_mask(slots, now))

    def tracks(self, now: float) -> list[Track]:
        """Every live track, predicted to ``now``, ordered by id."""
        return sorted(self._tracks(self.store.live_slots(), now), key=lambda t: t.track_id)

    def snapshot(self, now: float) -> Picture:
        """The immutable picture at ``now``: every live track predicted to it (store order), the hazards, and
        the vehicles (in the order first heard, each where its last state puts it at ``now``:
        ``ego_position_now``) with the track bound to each."""
        live = self.store.live_slots()
        table = self.store.table(live, now, self.is_ev_mask(live, now))
        vehicles = tuple(Ego(vid, *ego_position_now(s, now), s.heading_rad, s.speed_mps, s.length_m, s.width_m,
                             s.mode, s.active_command_id, rec.track_id, rec.received_s)
                         for vid, rec in self.vehicles.items() for s in (rec.state,))
        return Picture(now, table, self.hazards.records(), vehicles)
