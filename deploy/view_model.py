"""What `iea view` shows, as plain data: the corridor plan and the live picture, no I/O here.

- ``corridor_plan(corridor)``: the road in the corridor frame (its centre line and every lane edge as
  polylines, sampled along the road with ``Road.pose_at``), and each RSU with its camera's position,
  heading and horizontal field of view (``2 atan(w / 2 fx)``) out to its range.
- ``CorridorPicture``: fed every message of the corridor (``on_message``), liveliness changes
  (``on_presence``) and the DDM's state document (``on_ddm_state``, the fused tracks); ``snapshot()`` is
  the JSON the page draws: each RSU's tracked objects (ids, speeds, EV state), the active EV alerts
  with their cues, each AV with its mode and commanded path, the active hazards, a health row per
  service (rates, per-stage latency, drops, rejected inputs by reason, link state) and a timeline of
  alerts, commands and acks.
"""

from __future__ import annotations

import math
import threading
from collections import deque
from typing import Any

from protocol.keys import KeyError_, parse_alive_key, parse_key

PLAN_STEP_M = 5.0
DEFAULT_RANGE_M = 120.0
OBJECTS_STALE_S = 2.0
"""An RSU's object list older than this (receive time) is not drawn."""
ALERT_STALE_S = 3.0
"""An active EV alert not repeated for this long (RSUs repeat them at 2 Hz) is not drawn."""
LINK_STALE_S = 3.0
"""A service whose Health is older than this (1 Hz beats) shows as silent."""
TIMELINE_LEN = 200


def _r(v: float, nd: int = 2) -> float | None:
    return round(float(v), nd) if math.isfinite(v) else None


def corridor_plan(corridor: Any) -> dict[str, Any]:
    """The static drawing of the corridor: road polylines, lanes and RSUs with their fields of view."""
    import numpy as np

    road = corridor.road
    n = max(2, int(math.ceil(road.length_m / PLAN_STEP_M)) + 1)
    s = np.linspace(0.0, road.length_m, n)

    def line(d_m: float) -> list[list[float]]:
        x, y, _ = road.pose_at(s, d_m)
        return [[_r(a), _r(b)] for a, b in zip(x, y, strict=True)]

    edges = [-road.shoulder_width_m] + [i * road.lane_width_m for i in range(road.lanes + 1)]
    rsus = []
    for r in corridor.rsus:
        cam = r.camera
        hfov = 2.0 * math.atan(cam.width_px / (2.0 * cam.fx_px))
        rsus.append({"id": r.rsu_id, "x_m": _r(cam.x_m), "y_m": _r(cam.y_m), "yaw_rad": _r(cam.yaw_rad, 4),
                     "hfov_rad": _r(hfov, 4), "range_m": _r(r.max_range_m or DEFAULT_RANGE_M), "fps": cam.fps})
    return {"corridor_id": corridor.corridor_id, "name": corridor.name, "lanes": road.lanes,
            "lane_width_m": road.lane_width_m, "length_m": _r(road.length_m),
            "edges": [line(d) for d in edges], "edge_kinds": ["shoulder", "edge"] + ["lane"] * (road.lanes - 1) + ["edge"],
            "lane_centres": [line((i + 0.5) * road.lane_width_m) for i in range(road.lanes)],
            "rsus": rsus, "vehicles": [v.vehicle_id for v in corridor.vehicles]}


def _obj(o: Any) -> dict[str, Any]:
    return {"id": o.object_id, "x": _r(o.pos_x_m), "y": _r(o.pos_y_m), "v": _r(o.speed_mps, 1),
            "h": _r(o.heading_rad, 3), "l": _r(o.length_m or 4.5, 1), "w": _r(o.width_m or 1.8, 1),
            "type": o.obj_type.value, "ev": o.ev_state.value, "lane": o.lane}


class CorridorPicture:
    """The live picture of one corridor; every method is thread-safe (Zenoh calls from its threads)."""

    def __init__(self, corridor_id: str) -> None:
        self.corridor_id = corridor_id
        self._lock = threading.Lock()
        self.objects: dict[str, tuple[float, dict[str, Any]]] = {}
        self.alerts: dict[str, dict[str, Any]] = {}
        self.hazards: dict[str, dict[str, Any]] = {}
        self.vehicles: dict[str, dict[str, Any]] = {}
        self.commands: dict[str, dict[str, Any]] = {}
        self.health: dict[str, dict[str, Any]] = {}
        self.alive: dict[str, bool] = {}
        self.fused: list[dict[str, Any]] = []
        self.timeline: deque[dict[str, Any]] = deque(maxlen=TIMELINE_LEN)
        self._seen_commands: set[str] = set()
        self.messages = 0
        self.version = 0

    def _event(self, t: float, kind: str, text: str) -> None:
        self.timeline.append({"t": _r(t, 3), "kind": kind, "text": text})

    # ------------------------------------------------------------------ inputs
    def on_message(self, key: str, msg: Any, now_s: float) -> None:
        try:
            pk = parse_key(key)
        except KeyError_:
            return
        kind = msg.KIND
        with self._lock:
            self.messages += 1
            self.version += 1
            if kind == "ObjectList":
                self.objects[msg.rsu_id] = (now_s, {"stamp": msg.stamp, "objects": [_obj(o) for o in msg.objects]})
            elif kind == "EvAlert":
                self._on_ev(msg, now_s)
            elif kind == "HazardAlert":
                self._on_hazard(msg)
            elif kind == "VehicleState":
                self.vehicles[msg.vehicle_id] = {
                    "x": _r(msg.pos_x_m), "y": _r(msg.pos_y_m), "h": _r(msg.heading_rad, 3), "v": _r(msg.speed_mps, 1),
                    "l": msg.length_m, "w": msg.width_m, "lane": msg.lane, "mode": msg.mode.value,
                    "command": msg.active_command_id, "stamp": msg.stamp}
            elif kind == "PathSwitchCommand":
                self.commands[msg.vehicle_id] = {
                    "id": msg.command_id, "manoeuvre": msg.manoeuvre.value, "reason": msg.reason,
                    "lane": msg.target_lane, "speed": _r(msg.target_speed_mps, 1),
                    "path": [[_r(x), _r(y)] for x, y in msg.waypoints][:200],
                    "stop": None if msg.stop_point is None else [_r(msg.stop_point[0]), _r(msg.stop_point[1])],
                    "ack": self.commands.get(msg.vehicle_id, {}).get("ack") if self.commands.get(
                        msg.vehicle_id, {}).get("id") == msg.command_id else None}
                if msg.command_id not in self._seen_commands:
                    self._seen_commands.add(msg.command_id)
                    self._event(msg.stamp, "command",
                                f"{msg.vehicle_id} {msg.command_id}: {msg.manoeuvre.value} - {msg.reason}")
            elif kind == "CommandAck":
                cmd = self.commands.get(msg.vehicle_id)
                if cmd is not None and cmd["id"] == msg.command_id and cmd.get("ack") != msg.status.value:
                    cmd["ack"] = msg.status.value
                    self._event(msg.stamp, "ack", f"{msg.vehicle_id} {msg.command_id}: {msg.status.value}"
                                + (f" ({msg.reason})" if msg.reason else ""))
            elif kind == "Health":
                name = pk.node if pk.node is not None else pk.domain
                self.health[name] = {
                    "role": msg.role.value, "status": msg.status.value, "received": now_s,
                    "uptime_s": _r(msg.uptime_s, 0), "rates_hz": {k: _r(v, 1) for k, v in msg.rates_hz.items()},
                    "latency_ms": {k: _r(v, 1) for k, v in msg.latency_ms.items()}, "drops": dict(msg.drops),
                    "rejected": dict(msg.rejected), "stale": list(msg.stale), "counts": dict(msg.counts)}

    def _on_ev(self, msg: Any, now_s: float) -> None:
        state = msg.state.value
        known = msg.alert_id in self.alerts
        if state == "active":
            self.alerts[msg.alert_id] = {
                "id": msg.alert_id, "rsu": msg.rsu_id, "object": msg.object_id, "x": _r(msg.pos_x_m),
                "y": _r(msg.pos_y_m), "v": _r(msg.speed_mps, 1), "h": _r(msg.heading_rad, 3), "lane": msg.lane,
                "confidence": _r(msg.confidence), "cues": [c.value for c in msg.evidence.cues],
                "flash_hz": msg.evidence.flash_hz, "signed": msg.auth is not None, "stamp": msg.stamp,
                "received": now_s}
            if not known:
                self._event(msg.stamp, "alert", f"EV alert {msg.alert_id} from {msg.rsu_id}: "
                            f"{msg.speed_mps:.1f} m/s lane {msg.lane}, cues {', '.join(c.value for c in msg.evidence.cues) or '-'}")
        else:
            if known:
                self._event(msg.stamp, "alert", f"EV alert {msg.alert_id} {state}"
                            + (f" ({msg.clear_reason.value})" if msg.clear_reason is not None else ""))
            self.alerts.pop(msg.alert_id, None)

    def _on_hazard(self, msg: Any) -> None:
        state = msg.state.value
        known = msg.hazard_id in self.hazards
        if state != "clear":  # appear, persist
            self.hazards[msg.hazard_id] = {"id": msg.hazard_id, "rsu": msg.rsu_id, "x": _r(msg.pos_x_m),
                                           "y": _r(msg.pos_y_m), "l": msg.length_m, "lane": msg.lane, "state": state}
            if not known:
                self._event(msg.stamp, "hazard", f"hazard {msg.hazard_id} from {msg.rsu_id} in lane {msg.lane}")
        else:
            if known:
                self._event(msg.stamp, "hazard", f"hazard {msg.hazard_id} {state}")
            self.hazards.pop(msg.hazard_id, None)

    def on_presence(self, key: str, alive: bool) -> None:
        try:
            _c, role, node = parse_alive_key(key)
        except KeyError_:
            return
        with self._lock:
            self.alive[node if role in ("rsu", "vehicle") else role] = alive
            self.version += 1

    def on_ddm_state(self, doc: dict[str, Any]) -> None:
        """The fused tracks of the DDM's state answer (``iea/{c}/ddm/state``)."""
        tracks = doc.get("tracks") if isinstance(doc, dict) else None
        if not isinstance(tracks, list):
            return
        with self._lock:
            self.fused = [t for t in tracks if isinstance(t, dict)][:256]
            self.version += 1

    # ------------------------------------------------------------------ output
    def snapshot(self, now_s: float) -> dict[str, Any]:
        """The picture as JSON-ready data (what the page draws)."""
        with self._lock:
            objects = {rid: o["objects"] for rid, (t, o) in self.objects.items() if now_s - t <= OBJECTS_STALE_S}
            health = {}
            for name, h in self.health.items():
                age = now_s - h["received"]
                link = "up" if age <= LINK_STALE_S else "silent"
                if self.alive.get(name) is False:
                    link = "lost"
                health[name] = {**{k: v for k, v in h.items() if k != "received"}, "age_s": _r(age, 1), "link": link}
            for name, up in self.alive.items():
                health.setdefault(name, {"status": "?", "link": "up" if up else "lost"})
            return {
                "corridor_id": self.corridor_id, "version": self.version, "messages": self.messages,
                "objects": objects, "fused": list(self.fused),
                "alerts": [{k: v for k, v in a.items() if k != "received"} for a in self.alerts.values()
                           if now_s - a["received"] <= ALERT_STALE_S],
                "hazards": list(self.hazards.values()),
                "vehicles": {vid: {**v, "cmd": self.commands.get(vid)} for vid, v in self.vehicles.items()},
                "health": health, "timeline": list(self.timeline)[-60:],
            }
