"""The corridor as Foxglove's well-known messages: 3D scene, frames, map fixes and the event log.

Beside the raw channels (every key as its record view, ``protocol.record_view``), recordings and `iea foxglove` carry derived
channels in Foxglove's own schemas (JSON encoding), which its 3D, Map and Log panels draw:

| topic              | schema                    | what                                                        |
|--------------------|---------------------------|-------------------------------------------------------------|
| ``/scene/road``    | ``foxglove.SceneUpdate``  | lane edges and centres; each RSU's camera, label and field   |
|                    |                           | of view (``2 atan(w / 2 fx)`` out to its range); every       |
|                    |                           | ``static_period_s``                                          |
| ``/scene/objects`` | ``foxglove.SceneUpdate``  | every fused track as a box coloured by kind (the EV red while |
|                    |                           | its alert is active), each AV with its commanded path and    |
|                    |                           | stop point; replaces the previous update; ``scene_hz``       |
| ``/tf``            | ``foxglove.FrameTransforms`` | ``corridor`` -> each RSU camera and each AV               |
| ``/map/<vehicle>`` | ``foxglove.LocationFix``  | each AV in WGS84 (``Corridor.to_latlon``)                    |
| ``/map/ev``        | ``foxglove.LocationFix``  | the EV of the newest active alert, in WGS84                  |
| ``/log``           | ``foxglove.Log``          | alerts, hazards, commands and acks as they happen            |
| ``/vehicle/<id>/state``, ``/vehicle/<id>/cmd``, ``/alerts/ev`` | the kind's | each AV's state and commands and  |
|                    |                           | every RSU's EV alerts under names that do not hold the       |
|                    |                           | corridor id (a layout's plots and logs work on any corridor) |

Every pose is in the corridor frame (``frame_id`` ``corridor``: east/north metres from the corridor's
origin). The fused tracks are the DDM's (its state document, ``on_ddm_state``) while one is fresh,
else every RSU's tracks (its ``ObjectList``). ``CorridorScene`` holds the latest of each input; its
builders are pure (no clock, no I/O): the caller passes the time.
"""

from __future__ import annotations

import json
import logging
import math
import threading
import time
from typing import Any

import numpy as np

from deploy.view_model import DEFAULT_RANGE_M, corridor_plan
from protocol import foxglove_msgs as fx
from protocol import keys
from protocol.codec import ProtocolError, decode
from protocol.keys import KeyError_, message_type_for_key

FRAME = "corridor"
SCENE_HZ = 10.0
STATIC_PERIOD_S = 2.0
OBJECTS_STALE_S = 2.0
"""An RSU object list or a DDM state older than this (receive time) is not drawn."""
ALERT_STALE_S = 3.0
"""An active EV alert not repeated for this long (RSUs repeat them at 2 Hz) no longer colours its EV."""

TOPIC_ROAD, TOPIC_OBJECTS, TOPIC_TF, TOPIC_LOG, TOPIC_EV_FIX = "/scene/road", "/scene/objects", "/tf", "/log", "/map/ev"
SCHEMA_SCENE, SCHEMA_TF, SCHEMA_FIX, SCHEMA_LOG = ("foxglove.SceneUpdate", "foxglove.FrameTransforms",
                                                   "foxglove.LocationFix", "foxglove.Log")

COLOURS: dict[str, fx.RGBA] = {
    "ev_alerted": (0.95, 0.10, 0.10, 0.95),
    "ev": (1.0, 0.55, 0.0, 0.9),
    "vehicle": (0.35, 0.55, 0.85, 0.85),
    "pedestrian": (0.2, 0.8, 0.3, 0.9),
    "cyclist": (0.6, 0.85, 0.2, 0.9),
    "other": (0.6, 0.6, 0.6, 0.8),
    "av": (0.0, 0.85, 0.85, 0.95),
    "path": (0.85, 0.2, 0.85, 1.0),
    "lane": (0.9, 0.9, 0.9, 0.6),
    "edge": (1.0, 1.0, 1.0, 0.95),
    "shoulder": (0.9, 0.8, 0.2, 0.8),
    "centre": (0.5, 0.5, 0.5, 0.3),
    "rsu": (1.0, 0.85, 0.1, 0.9),
    "fov": (1.0, 0.85, 0.1, 0.45),
}
SIZE_M = {"vehicle": (4.6, 1.9, 1.6), "pedestrian": (0.6, 0.6, 1.8), "cyclist": (1.8, 0.6, 1.7),
          "other": (2.0, 1.5, 1.5)}
ALIASES = {"VehicleState": "/vehicle/{id}/state", "PathSwitchCommand": "/vehicle/{id}/cmd", "EvAlert": "/alerts/ev"}
"""Kinds also sent under a topic without the corridor id (their record view, their schema)."""


def alias(msg: Any, payload: bytes, now_s: float) -> list[Derived]:
    """A message's record view (``protocol.record_view``) under its alias topic (``ALIASES``), if its kind has one."""
    from protocol.json_view import JsonViewError
    from protocol.record_view import to_json

    pattern = ALIASES.get(msg.KIND)
    if pattern is None:
        return []
    try:
        view = to_json(payload)
    except JsonViewError:
        return []
    return [(pattern.format(id=getattr(msg, "vehicle_id", "")), msg.KIND, view, now_s)]


SCENE_KINDS = frozenset({"ObjectList", "EvAlert", "HazardAlert", "VehicleState", "PathSwitchCommand", "CommandAck"})
"""What the scene draws from (world snapshots and health are not decoded for it)."""
Derived = tuple[str, str, bytes, float]
"""``(topic, schema, JSON bytes, time_s)``, as ``deploy.record.Derived``."""


def _dump(obj: dict[str, Any]) -> bytes:
    return json.dumps(obj, separators=(",", ":"), allow_nan=False).encode()


def track_colour(obj_type: str, is_ev: bool, alerted: bool) -> fx.RGBA:
    """A track's colour: the EV red while its alert is active, orange otherwise; others by kind."""
    if is_ev:
        return COLOURS["ev_alerted" if alerted else "ev"]
    return COLOURS.get(obj_type, COLOURS["other"])


# ------------------------------------------------------------------ static scene
def road_scene(corridor: Any, t_s: float) -> dict[str, Any]:
    """``/scene/road``: lane edges and centres, and each RSU's camera with its field of view."""
    plan = corridor_plan(corridor)
    lines = [fx.line(pts, COLOURS.get(kind, COLOURS["lane"]), thickness_m=0.15 if kind != "lane" else 0.1)
             for pts, kind in zip(plan["edges"], plan["edge_kinds"], strict=True)]
    lines += [fx.line(pts, COLOURS["centre"], thickness_m=0.05) for pts in plan["lane_centres"]]
    entities = [fx.entity("road", FRAME, t_s, lines=lines, metadata={"lanes": plan["lanes"],
                                                                     "lane_width_m": plan["lane_width_m"]})]
    for r in plan["rsus"]:
        entities.append(rsu_entity(r, t_s))
    return fx.scene_update(entities)


def fov_polygon(x_m: float, y_m: float, yaw_rad: float, hfov_rad: float, range_m: float,
                arc_points: int = 8) -> list[tuple[float, float]]:
    """A camera's horizontal field of view on the ground: its position and an arc at ``range_m``."""
    pts = [(x_m, y_m)]
    for k in range(arc_points + 1):
        a = yaw_rad - hfov_rad / 2.0 + hfov_rad * k / arc_points
        pts.append((x_m + range_m * math.cos(a), y_m + range_m * math.sin(a)))
    return pts


def rsu_entity(r: dict[str, Any], t_s: float) -> dict[str, Any]:
    """One RSU (a ``corridor_plan`` entry): a mast, its label and its field of view."""
    fov = fov_polygon(r["x_m"], r["y_m"], r["yaw_rad"], r["hfov_rad"], r["range_m"] or DEFAULT_RANGE_M)
    return fx.entity(f"rsu/{r['id']}", FRAME, t_s,
                     lines=[fx.line(fov, COLOURS["fov"], thickness_m=0.2, kind=fx.LINE_LOOP, z_m=0.05)],
                     cubes=[fx.cube(r["x_m"], r["y_m"], r["yaw_rad"], (0.5, 0.5, 6.0), COLOURS["rsu"])],
                     texts=[fx.text(r["x_m"], r["y_m"], 7.0, r["id"], COLOURS["rsu"])],
                     metadata={"hfov_rad": r["hfov_rad"], "range_m": r["range_m"], "fps": r["fps"]})


# ------------------------------------------------------------------ dynamic scene
def track_entity(track: dict[str, Any], t_s: float, lifetime_s: float) -> dict[str, Any]:
    """One fused track (``id``, ``x_m``, ``y_m``, ``yaw_rad``, ``type``, ``ev``, ``alerted``, optional
    ``size_m``) as a box with its id and speed."""
    kind = track.get("type", "other")
    size = track.get("size_m") or SIZE_M.get(kind, SIZE_M["other"])
    rgba = track_colour(kind, bool(track.get("ev")), bool(track.get("alerted")))
    label = f"{track['id']}" + (f" {track['speed_mps']:.1f} m/s" if track.get("speed_mps") is not None else "")
    if track.get("ev"):
        label = ("EV ALERT " if track.get("alerted") else "EV ") + label
    return fx.entity(f"track/{track['id']}", FRAME, t_s, lifetime_s=lifetime_s,
                     cubes=[fx.cube(track["x_m"], track["y_m"], track.get("yaw_rad", 0.0), size, rgba)],
                     texts=[fx.text(track["x_m"], track["y_m"], size[2] + 1.0, label, rgba, 12.0)],
                     metadata={"type": kind, "ev": str(bool(track.get("ev"))).lower(),
                               "alerted": str(bool(track.get("alerted"))).lower()})


def vehicle_entity(v: dict[str, Any], command: dict[str, Any] | None, t_s: float,
                   lifetime_s: float) -> dict[str, Any]:
    """One AV (``id``, ``x_m``, ``y_m``, ``yaw_rad``, ``length_m``, ``width_m``, ``mode``) with its commanded
    path (``waypoints``) and stop point."""
    lines, cubes = [], [fx.cube(v["x_m"], v["y_m"], v["yaw_rad"], (v["length_m"], v["width_m"], 1.6), COLOURS["av"])]
    label = f"{v['id']} {v['mode']} {v['speed_mps']:.1f} m/s"
    if command is not None:
        if len(command["waypoints"]) >= 2:
            lines.append(fx.line(command["waypoints"], COLOURS["path"], thickness_m=0.3, z_m=0.1))
        if command.get("stop_point") is not None:
            sx, sy = command["stop_point"]
            cubes.append(fx.cube(sx, sy, v["yaw_rad"], (0.4, 2.5, 1.0), COLOURS["path"]))
        label += f"\n{command['manoeuvre']}"
    return fx.entity(f"av/{v['id']}", FRAME, t_s, lifetime_s=lifetime_s, lines=lines, cubes=cubes,
                     texts=[fx.text(v["x_m"], v["y_m"], 3.0, label, COLOURS["av"], 13.0)],
                     metadata={"mode": v["mode"], "command": command["command_id"] if command else ""})


def objects_scene(tracks: list[dict[str, Any]], vehicles: list[dict[str, Any]],
                  commands: dict[str, dict[str, Any]], t_s: float, lifetime_s: float = 1.0) -> dict[str, Any]:
    """``/scene/objects``: replaces the topic's entities with these tracks and AVs."""
    ents = [track_entity(t, t_s, lifetime_s) for t in tracks]
    ents += [vehicle_entity(v, commands.get(v["id"]), t_s, lifetime_s) for v in vehicles]
    return fx.scene_update(ents, t_s, replace_all=True)


def transforms(rsus: list[dict[str, Any]], vehicles: list[dict[str, Any]], t_s: float) -> dict[str, Any]:
    """``/tf``: each RSU camera (``rsu/<id>``, 6 m up, looking along its yaw) and AV (``av/<id>``) in the
    corridor frame."""
    tfs = [fx.frame_transform(FRAME, f"rsu/{r['id']}", t_s, r["x_m"], r["y_m"], 6.0, r["yaw_rad"]) for r in rsus]
    tfs += [fx.frame_transform(FRAME, f"av/{v['id']}", t_s, v["x_m"], v["y_m"], 0.0, v["yaw_rad"]) for v in vehicles]
    return fx.frame_transforms(tfs)


# ------------------------------------------------------------------ state
class CorridorScene:
    """The latest picture of one corridor and the derived messages it makes (thread-safe)."""

    def __init__(self, corridor: Any, *, scene_hz: float = SCENE_HZ, static_period_s: float = STATIC_PERIOD_S) -> None:
        if not 0.5 <= scene_hz <= 60.0:
            raise ValueError(f"scene rate {scene_hz} Hz is outside 0.5..60")
        self.corridor = corridor
        self.road = corridor.road
        self.road.prepare()
        self.plan_rsus = corridor_plan(corridor)["rsus"]
        self.scene_period_s = 1.0 / scene_hz
        self.static_period_s = static_period_s
        self._lock = threading.Lock()
        self._tick_lock = threading.Lock()
        self.objects: dict[str, tuple[float, list[Any]]] = {}
        self.fused: tuple[float, list[dict[str, Any]]] | None = None
        self.alerts: dict[str, tuple[float, Any]] = {}
        self.vehicles: dict[str, Any] = {}
        self.commands: dict[str, Any] = {}
        self._acks: dict[str, str] = {}
        self._hazards: set[str] = set()
        self._next_scene_s: float | None = None
        self._next_static_s: float | None = None

    # ------------------------------------------------------------ inputs
    def on_message(self, key: str, msg: Any, now_s: float) -> list[Derived]:
        """Take one decoded message; returns the log lines it makes (``/log``)."""
        kind = msg.KIND
        logs: list[dict[str, Any]] = []
        with self._lock:
            if kind == "ObjectList":
                self.objects[msg.rsu_id] = (now_s, list(msg.objects))
            elif kind == "EvAlert":
                known = msg.alert_id in self.alerts
                if msg.state.value == "active":
                    self.alerts[msg.alert_id] = (now_s, msg)
                    if not known:
                        logs.append(fx.log_line(now_s, "warning", msg.rsu_id,
                                                f"EV alert {msg.alert_id}: {msg.speed_mps:.1f} m/s lane {msg.lane} "
                                                f"x {msg.pos_x_m:.1f} m, cues {', '.join(c.value for c in msg.evidence.cues) or '-'}"))
                elif known:
                    self.alerts.pop(msg.alert_id, None)
                    reason = f" ({msg.clear_reason.value})" if msg.clear_reason is not None else ""
                    logs.append(fx.log_line(now_s, "info", msg.rsu_id, f"EV alert {msg.alert_id} cleared{reason}"))
            elif kind == "HazardAlert":
                if msg.state.value != "clear" and msg.hazard_id not in self._hazards:
                    self._hazards.add(msg.hazard_id)
                    logs.append(fx.log_line(now_s, "warning", msg.rsu_id,
                                            f"hazard {msg.hazard_id} in lane {msg.lane} at x {msg.pos_x_m:.1f} m"))
                elif msg.state.value == "clear" and msg.hazard_id in self._hazards:
                    self._hazards.discard(msg.hazard_id)
                    logs.append(fx.log_line(now_s, "info", msg.rsu_id, f"hazard {msg.hazard_id} clear"))
            elif kind == "VehicleState":
                self.vehicles[msg.vehicle_id] = msg
            elif kind == "PathSwitchCommand":
                old = self.commands.get(msg.vehicle_id)
                self.commands[msg.vehicle_id] = msg
                if old is None or old.command_id != msg.command_id:
                    logs.append(fx.log_line(now_s, "warning" if msg.manoeuvre.value != "resume" else "info", "ddm",
                                            f"{msg.vehicle_id} {msg.command_id}: {msg.manoeuvre.value} - {msg.reason}"))
            elif kind == "CommandAck":
                if self._acks.get(msg.command_id) != msg.status.value:
                    self._acks[msg.command_id] = msg.status.value
                    logs.append(fx.log_line(now_s, "info", msg.vehicle_id,
                                            f"{msg.vehicle_id} {msg.command_id}: {msg.status.value}"
                                            + (f" ({msg.reason})" if msg.reason else "")))
        return [(TOPIC_LOG, SCHEMA_LOG, _dump(entry), now_s) for entry in logs]

    def on_ddm_state(self, doc: dict[str, Any], now_s: float) -> None:
        """The DDM's state document (``iea/<c>/ddm/state``): its fused tracks replace the RSUs' while fresh."""
        tracks = doc.get("tracks") if isinstance(doc, dict) else None
        if isinstance(tracks, list):
            with self._lock:
                self.fused = (now_s, [t for t in tracks if isinstance(t, dict)][:256])

    # ------------------------------------------------------------ outputs
    def _yaw_along_road(self, x_m: float, y_m: float) -> float:
        s, _d = self.road.to_frenet(x_m, y_m)
        return float(self.road.pose_at(float(np.atleast_1d(s)[0]), 0.0)[2])

    def tracks(self, now_s: float) -> list[dict[str, Any]]:
        """The tracks to draw: the DDM's fused tracks while fresh, else every RSU's."""
        with self._lock:
            alerted = {(a.rsu_id, a.object_id) for t, a in self.alerts.values() if now_s - t <= ALERT_STALE_S}
            fused = self.fused if self.fused is not None and now_s - self.fused[0] <= OBJECTS_STALE_S else None
            objects = [(rid, objs) for rid, (t, objs) in self.objects.items() if now_s - t <= OBJECTS_STALE_S]
            any_alert = bool(alerted)
        out = []
        if fused is not None:
            for t in fused[1]:
                x, y = t.get("x_m"), t.get("y_m")
                if not (isinstance(x, int | float) and isinstance(y, int | float)):
                    continue
                is_ev = bool(t.get("ev"))
                out.append({"id": f"ddm/{t.get('id')}", "x_m": x, "y_m": y, "yaw_rad": self._yaw_along_road(x, y),
                            "type": str(t.get("type", "other")), "speed_mps": t.get("speed_mps"), "ev": is_ev,
                            "alerted": is_ev and any_alert})
            return out
        for rid, objs in objects:
            for o in objs:
                is_ev = o.ev_state.value in ("confirmed",) or (rid, o.object_id) in alerted
                out.append({"id": f"{rid}/{o.object_id}", "x_m": o.pos_x_m, "y_m": o.pos_y_m,
                            "yaw_rad": o.heading_rad, "type": o.obj_type.value, "speed_mps": o.speed_mps,
                            "ev": is_ev, "alerted": (rid, o.object_id) in alerted,
                            "size_m": (o.length_m or SIZE_M["vehicle"][0], o.width_m or SIZE_M["vehicle"][1],
                                       o.height_m or SIZE_M["vehicle"][2])})
        return out

    def _vehicles(self) -> tuple[list[dict[str, Any]], dict[str, dict[str, Any]]]:
        with self._lock:
            states, cmds = list(self.vehicles.values()), dict(self.commands)
        vehicles = [{"id": s.vehicle_id, "x_m": s.pos_x_m, "y_m": s.pos_y_m, "yaw_rad": s.heading_rad,
                     "length_m": s.length_m, "width_m": s.width_m, "mode": s.mode.value, "speed_mps": s.speed_mps}
                    for s in states]
        commands = {vid: {"command_id": c.command_id, "manoeuvre": c.manoeuvre.value,
                          "waypoints": [tuple(p) for p in c.waypoints], "stop_point": c.stop_point}
                    for vid, c in cmds.items() if c.manoeuvre.value != "resume"}
        return vehicles, commands

    def ev_fix(self, now_s: float) -> dict[str, Any] | None:
        """The EV of the newest active alert as a WGS84 fix (None without one)."""
        with self._lock:
            live = [(t, a) for t, a in self.alerts.values() if now_s - t <= ALERT_STALE_S]
        if not live:
            return None
        _t, a = max(live, key=lambda ta: ta[0])
        lat, lon = self.corridor.to_latlon(a.pos_x_m, a.pos_y_m)
        return fx.location_fix(now_s, FRAME, lat, lon, sigma_m=2.0, rgba=COLOURS["ev_alerted"])

    def tick(self, now_s: float, *, force: bool = False) -> list[Derived]:
        """The derived messages due at ``now_s``: the objects scene, transforms and map fixes every scene
        period, the road scene every ``static_period_s`` (both at once on the first call)."""
        with self._tick_lock:
            return self._tick(now_s, force)

    def _tick(self, now_s: float, force: bool) -> list[Derived]:
        out: list[Derived] = []
        if self._next_static_s is None or now_s + 1e-9 >= self._next_static_s or force:
            self._next_static_s = now_s + self.static_period_s
            out.append((TOPIC_ROAD, SCHEMA_SCENE, _dump(road_scene(self.corridor, now_s)), now_s))
        if not force and self._next_scene_s is not None and now_s + 1e-9 < self._next_scene_s:
            return out
        self._next_scene_s = now_s + self.scene_period_s
        vehicles, commands = self._vehicles()
        out.append((TOPIC_OBJECTS, SCHEMA_SCENE, _dump(objects_scene(self.tracks(now_s), vehicles, commands, now_s)),
                    now_s))
        out.append((TOPIC_TF, SCHEMA_TF, _dump(transforms(self.plan_rsus, vehicles, now_s)), now_s))
        for v in vehicles:
            lat, lon = self.corridor.to_latlon(v["x_m"], v["y_m"])
            out.append((f"/map/{v['id']}", SCHEMA_FIX,
                        _dump(fx.location_fix(now_s, f"av/{v['id']}", lat, lon, sigma_m=0.5, rgba=COLOURS["av"])),
                        now_s))
        ev = self.ev_fix(now_s)
        if ev is not None:
            out.append((TOPIC_EV_FIX, SCHEMA_FIX, _dump(ev), now_s))
        return out

    def feed(self, key: str, payload: bytes, now_s: float) -> list[Derived]:
        """One received payload (decoded strictly; anything else is skipped) and what is due now: the
        ``derive`` function of ``deploy.record.McapRecorder``."""
        out: list[Derived] = []
        try:
            kind = message_type_for_key(key)
            msg = decode(payload, kind) if kind.KIND in SCENE_KINDS else None
        except (ProtocolError, KeyError_):
            msg = None
        if msg is not None:
            out += self.on_message(key, msg, now_s) + alias(msg, payload, now_s)
        out += self.tick(now_s)
        return out


DDM_POLL_S = 0.5
"""How often the DDM's state (its fused tracks) is asked for the scene."""
log = logging.getLogger(__name__)


class DdmStatePoll:
    """Feeds a ``CorridorScene`` the DDM's fused tracks: its state queryable (``iea/<c>/ddm/state``) asked every
    ``period_s`` on a transport with ``query_bytes`` (Zenoh), on a thread of its own until ``close()``."""

    def __init__(self, transport: Any, corridor_id: str, scene: CorridorScene, *, period_s: float = DDM_POLL_S,
                 clock: Any = time.time) -> None:
        self.transport, self.scene, self.period_s, self.clock = transport, scene, period_s, clock
        self.key = keys.ddm_state_key(corridor_id)
        self.answers = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="ddm state poll", daemon=True)

    def start(self) -> DdmStatePoll:
        self._thread.start()
        return self

    def _run(self) -> None:
        while not self._stop.wait(self.period_s):
            try:
                for _k, payload in self.transport.query_bytes(self.key, min(0.4, self.period_s)):
                    self.scene.on_ddm_state(json.loads(payload), self.clock())
                    self.answers += 1
            except Exception:  # the session closed under us, no DDM yet, or a transient query error
                log.debug("ddm state query failed", exc_info=True)

    def close(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=2.0)
