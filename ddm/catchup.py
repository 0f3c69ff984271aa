"""What a starting DDM asks the corridor, and what it tells an operator.

- ``catch_up_queries``: a DDM that starts or restarts queries the RSUs' latest object lists, their
  active EV and hazard alerts and health, and the vehicles' latest states, instead of waiting for the
  next 2 Hz alert repeat; ``catch_up_order`` feeds the replies in the order the fusion needs them
  (tracks before the vehicles bound to them, both before the alerts that name a track).
- ``state_document``: the DDM's picture as the JSON answer of ``iea/{c}/ddm/state``.
- ``CorridorPresence``: the DDM service's presence, state and catch-up methods (a mixin of
  ``ddm.service.DdmService``, which owns the state they use: ``presence``, ``world``, ``_lock``...).
"""

from __future__ import annotations

import json
import logging
import math
from typing import Any

from protocol.codec import encode
from protocol.keys import KeyError_, all_vehicles_expr, ddm_state_key, parse_key
from protocol.messages import Envelope, ObjectList
from protocol.ranges import MAX_COUNT

log = logging.getLogger("ddm")

MAX_STATE_TRACKS = 256
"""Tracks listed in a state answer (the rest are counted): an operator's table, not a data feed."""
_ORDER = {"objects": 0, "health": 1, "state": 2, "hazard": 3, "ev": 4}


def catch_up_queries(corridor_id: str) -> list[str]:
    """Key expressions a starting DDM queries: every RSU topic (its ``state`` JSON is skipped by
    ``catch_up_order``) and every vehicle's state."""
    return [f"iea/{corridor_id}/rsu/*/*", all_vehicles_expr(corridor_id, "state")]


def catch_up_order(replies: list[tuple[str, Envelope]]) -> list[tuple[str, Envelope]]:
    """Replies in ingest order: object lists, health, vehicle states, hazards, EV alerts; others dropped."""
    keep = []
    for key, msg in replies:
        try:
            topic = parse_key(key).topic
        except KeyError_:
            continue
        if topic in _ORDER:
            keep.append((_ORDER[topic], getattr(msg, "stamp", 0.0), key, msg))
    keep.sort(key=lambda r: (r[0], r[1]))
    return [(k, m) for _, _, k, m in keep]


def _r(v: float, nd: int = 2) -> float | None:
    return round(v, nd) if math.isfinite(v) else None


def state_document(ddm: Any, now: float) -> dict[str, Any]:
    """The DDM's picture (``ddm`` a ``DdmService``; call with its lock held): fused tracks, vehicles,
    outstanding commands, active EVs and hazards, stale and lost services."""
    tracks = ddm.world.tracks(now)
    evs = [t for t in tracks if t.is_ev]
    vehicles = {}
    for vid, rec in ddm.world.vehicles.items():
        s = rec.state
        cmd = ddm.commands.state_of(vid)
        vehicles[vid] = {"mode": s.mode.value, "x_m": _r(s.pos_x_m), "y_m": _r(s.pos_y_m),
                         "speed_mps": _r(s.speed_mps), "age_s": _r(now - rec.received_s, 3),
                         "active_command_id": s.active_command_id,
                         "command": None if cmd is None else {"id": cmd.command_id, "state": str(cmd.state)},
                         "present": not ddm.presence.lost("vehicle").get(vid)}
    alerts = [{"alert_id": aid, "track_id": a.track_id} for aid, a in sorted(ddm.world.alerts.items())]
    hazards = [{"hazard_id": str(h), **{k: (_r(v) if isinstance(v, float) else v)
                                        for k, v in _hazard_fields(rec).items()}}
               for h, rec in sorted(ddm.world.hazards.hazards.items(), key=lambda kv: str(kv[0]))]
    return {
        "ddm_id": ddm.ddm_id, "corridor_id": ddm.corridor_id, "stamp": now,
        "uptime_s": _r(now - ddm.started_s), "listening": now < ddm.listen_until_s,
        "tracks_total": len(tracks),
        "tracks": [{"id": t.track_id, "x_m": _r(t.x_m), "y_m": _r(t.y_m), "speed_mps": _r(math.hypot(t.vx_mps, t.vy_mps)),
                    "type": str(getattr(t.obj_type, "value", t.obj_type)), "ev": t.is_ev, "lane": t.lane, "rsus": list(t.rsus)}
                   for t in tracks[:MAX_STATE_TRACKS]],
        "active_evs": [{"track_id": t.track_id, "alert_id": t.ev_alert_id} for t in evs],
        "alerts": alerts, "hazards": hazards, "vehicles": vehicles,
        "outstanding_commands": ddm.commands.outstanding(),
        "stale_rsus": sorted(ddm.stale_now), "lost": {r: sorted(ddm.presence.lost(r)) for r in ("rsu", "vehicle")},
        "alive": {r: sorted(ids) for r, ids in ddm.presence.alive.items()},
    }


def _hazard_fields(rec: Any) -> dict[str, Any]:
    out = {}
    for name in ("state", "lane", "x_m", "y_m", "pos_x_m", "pos_y_m", "confidence"):
        v = getattr(rec, name, None)
        if isinstance(v, (int, float, str)) and not isinstance(v, bool):
            out[name] = v
    return out


def encode_state(doc: dict[str, Any]) -> bytes:
    return json.dumps(doc, separators=(",", ":"), default=str).encode()


class CorridorPresence:
    """Liveliness, queryables and the start-up catch-up of the DDM; see ``ddm.service``."""

    def _on_presence(self, key: str, alive: bool) -> None:
        now = self.clock.now()
        with self._lock:
            change = self.presence.update(key, alive, now)
            if change is None:
                return
            role, node, up = change
            if role == "rsu":
                log.log(logging.INFO if up else logging.WARNING, "RSU %s %s (liveliness token)", node,
                        "is up" if up else "is gone")
                self._refresh_stale(now)
            elif role == "vehicle" and not up:
                log.warning("vehicle %s is gone (liveliness token lost): no decisions for it", node)

    def _refresh_stale(self, now: float, publish: bool = True) -> bool:
        """Stale RSUs: silent streams (``world.stale_rsus``) and lost tokens; log and publish changes."""
        stale = set(self.world.stale_rsus(now)) | set(self.presence.lost("rsu"))
        for r in sorted(stale - self.stale_now):
            log.warning("RSU %s is stale (%s)", r, "token lost" if r in self.presence.lost("rsu")
                        else f"no objects for > {self.config.rsu_stale_s:.2f} s")
        for r in sorted(self.stale_now - stale):
            log.info("RSU %s is alive again", r)
        changed = stale != self.stale_now
        self.stale_now = stale
        self._stale_reported = stale
        if changed and publish and self.last_health is not None:
            self.publish_health(now)  # at once, not at the next 1 Hz beat
        return changed

    def _count_missed(self, key: str, seq: int) -> None:
        """Sample-miss detection on the alert and ack streams: a gap in a publisher's ``seq``. The sum
        saturates at ``MAX_COUNT``: a peer's seq jumps (each up to 2**53) must not make Health unpublishable."""
        last = self._last_seq.get(key)
        self._last_seq[key] = seq
        if last is not None and seq > last + 1:
            name = "missed_alert_samples" if "/rsu/" in key else "missed_ack_samples"
            self.counters[name] = min(MAX_COUNT, self.counters[name] + seq - last - 1)

    def _answer_state(self, _query: str) -> list[tuple[str, bytes]]:
        with self._lock:
            doc = state_document(self, self.clock.now())
        return [(ddm_state_key(self.corridor_id), encode_state(doc))]

    def _answer_health(self, _query: str) -> list[tuple[str, bytes]]:
        h = self.last_health
        return [] if h is None else [(self._health_key, encode(h))]

    def catch_up(self, timeout_s: float = 0.5) -> int:
        """Query what the corridor knows now (object lists, active alerts, vehicle states) and ingest it;
        when every RSU of the corridor answered with objects, stop listening and decide at once."""
        replies = []
        try:
            for expr in catch_up_queries(self.corridor_id):
                replies += self.transport.query(expr, timeout_s)
        except NotImplementedError:
            return 0
        ordered = catch_up_order(replies)
        for key, msg in ordered:
            topic = parse_key(key).topic
            self.catch_up_replies[topic] = self.catch_up_replies.get(topic, 0) + 1
            if parse_key(key).domain == "vehicle":
                self._on_vehicle_state(key, msg)
            else:
                self._on_rsu(key, msg)
        heard = {parse_key(k).node for k, m in ordered if isinstance(m, ObjectList)}
        expected = {r.rsu_id for r in self.corridor.rsus}
        if expected and expected <= heard:
            now = self.clock.now()
            with self._lock:
                self.listen_until_s = min(self.listen_until_s, now)
                self._decide_all(now)
            log.info("caught up from %d replies (%s): deciding at once", len(ordered),
                     ", ".join(f"{k}={v}" for k, v in sorted(self.catch_up_replies.items())))
        elif ordered:
            log.info("caught up from %d replies; RSUs not heard yet: %s", len(ordered),
                     ", ".join(sorted(expected - heard)) or "-")
        return len(ordered)
