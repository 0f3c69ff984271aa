"""`iea foxglove [--port 8765]`: the corridor live in Foxglove or Lichtblick over the Foxglove WebSocket protocol.

The process joins the corridor over Zenoh (peer on loopback, or ``--connect`` a router), subscribes to
every key of the corridor and serves, with Foxglove's own server (the ``foxglove-sdk`` package, extra
``foxglove``), the same channels a recording holds (``deploy.record``):

- every key as its record view (``protocol.record_view``: the JSON Schema of ``protocol/schema/<Kind>.json``
  with every record's fields named, in the form Foxglove reads; topic: the key);
- each RSU's camera frames (``iea/<c>/rsu/<rsu>/camera/jpeg``, ``foxglove.CompressedImage``);
- the derived scene, transforms, map fixes and log (``deploy.foxglove_scene``) at ``--scene-hz``, with
  the DDM's fused tracks (its state queryable, polled at 2 Hz).

Connect Foxglove or Lichtblick to ``ws://<host>:<port>`` ("Foxglove WebSocket") and open
``deploy/foxglove/corridor_layout.json``. Every channel of the corridor's layout is advertised at
start, so a client can subscribe before the first message. The bridge only displays: it decodes
strictly, verifies nothing and publishes nothing on the corridor. Messages are converted only for
channels a client subscribes to; the scene is kept whatever is subscribed.
"""

from __future__ import annotations

import argparse
import json
import logging
import signal
import sys
import threading
import time
from typing import Any

from deploy.foxglove_scene import (
    ALIASES,
    SCENE_KINDS,
    SCHEMA_FIX,
    SCHEMA_LOG,
    SCHEMA_SCENE,
    SCHEMA_TF,
    TOPIC_EV_FIX,
    TOPIC_LOG,
    TOPIC_OBJECTS,
    TOPIC_ROAD,
    TOPIC_TF,
    CorridorScene,
    DdmStatePoll,
    alias,
)
from deploy.record import CAMERA_KIND, SCHEMA_ENCODING, WIRE_KIND, WIRE_SCHEMA, foxglove_schema, json_record
from protocol import keys
from protocol.codec import ProtocolError, decode
from protocol.json_view import JsonViewError
from protocol.record_view import record_view_schema, to_json
from protocol.runtime import stop_on_ctrl_c

log = logging.getLogger("deploy.foxglove")
NEEDS = "the Foxglove bridge needs the foxglove-sdk package: pip install 'iea-corridor[foxglove]'"


def schema_bytes(kind: str) -> bytes:
    """The JSON Schema of a channel's kind: a message kind's, Foxglove's, or the raw-bytes wrapper's."""
    if kind == WIRE_KIND:
        return json.dumps(WIRE_SCHEMA).encode()
    if kind.startswith("foxglove."):
        return foxglove_schema(kind)
    return json.dumps(record_view_schema(kind)).encode()


def corridor_channels(corridor: Any, corridor_id: str) -> list[tuple[str, str]]:
    """``(topic, kind)`` of every channel the bridge advertises at start: each key of the layout, each RSU's
    camera and the derived channels."""
    c = corridor_id
    out = []
    for r in corridor.rsus:
        out += [(keys.rsu_key(c, r.rsu_id, t), m.KIND) for t, m in keys.RSU_TOPICS.items()]
        out.append((keys.rsu_camera_key(c, r.rsu_id), CAMERA_KIND))
    for v in corridor.vehicles:
        out += [(keys.vehicle_key(c, v.vehicle_id, t), m.KIND) for t, m in keys.VEHICLE_TOPICS.items()]
    out += [(keys.ddm_health_key(c), "Health"), (keys.sim_world_key(c), "WorldSnapshot"),
            (keys.sim_health_key(c), "Health")]
    out += [(TOPIC_ROAD, SCHEMA_SCENE), (TOPIC_OBJECTS, SCHEMA_SCENE), (TOPIC_TF, SCHEMA_TF), (TOPIC_LOG, SCHEMA_LOG),
            (TOPIC_EV_FIX, SCHEMA_FIX)]
    out += [(f"/map/{v.vehicle_id}", SCHEMA_FIX) for v in corridor.vehicles]
    for kind, pattern in ALIASES.items():
        out += sorted({(pattern.format(id=v.vehicle_id), kind) for v in corridor.vehicles})
    return out


class _Listener:
    """``foxglove.websocket.ServerListener``: counts the clients subscribed to each topic."""

    def __init__(self, subscribed: dict[str, int]) -> None:
        self.subscribed = subscribed

    def on_subscribe(self, client: Any, channel: Any) -> None:
        self.subscribed[channel.topic] = self.subscribed.get(channel.topic, 0) + 1

    def on_unsubscribe(self, client: Any, channel: Any) -> None:
        self.subscribed[channel.topic] = max(0, self.subscribed.get(channel.topic, 0) - 1)


class FoxgloveBridge:
    """The Foxglove WebSocket server fed from a transport's ``subscribe_bytes`` (Zenoh, or a ``LocalBus``)."""

    def __init__(self, corridor: Any, corridor_id: str | None = None, *, host: str = "127.0.0.1", port: int = 8765,
                 scene_hz: float = 10.0, camera: bool = True, clock: Any = time.time) -> None:
        try:
            import foxglove
        except ImportError as exc:
            raise RuntimeError(NEEDS) from exc
        self._fx = foxglove
        self.corridor = corridor
        self.corridor_id = corridor_id or corridor.corridor_id
        self.scene = CorridorScene(corridor, scene_hz=scene_hz)
        self.scene_period_s = 1.0 / scene_hz
        self.camera = camera
        self.clock = clock
        self.context = foxglove.Context()
        self._lock = threading.Lock()
        self._channels: dict[str, Any] = {}
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self.transport: Any = None
        self._ddm_poll: DdmStatePoll | None = None
        self.received = 0
        self.sent = 0
        self.bytes_sent = 0
        self.subscribed: dict[str, int] = {}
        """Clients subscribed, by topic (the server's listener keeps it)."""
        self.server = foxglove.start_server(name=f"iea-corridor {self.corridor_id}", host=host, port=port,
                                            context=self.context, server_listener=_Listener(self.subscribed))
        self.port = self.server.port
        self.host = host
        for topic, kind in corridor_channels(corridor, self.corridor_id):
            self._channel(topic, kind)

    @property
    def url(self) -> str:
        return f"ws://{self.host}:{self.port}"

    def _channel(self, topic: str, kind: str) -> Any:
        ch = self._channels.get(topic)
        if ch is None:
            with self._lock:
                ch = self._channels.get(topic)
                if ch is None:
                    schema = self._fx.Schema(name=kind, encoding=SCHEMA_ENCODING, data=schema_bytes(kind))
                    ch = self._channels[topic] = self._fx.Channel(topic, schema=schema, message_encoding="json",
                                                                  context=self.context, metadata={"kind": kind})
        return ch

    def _send(self, topic: str, kind: str, data: bytes, t_s: float) -> None:
        self._channel(topic, kind).log(data, log_time=max(0, int(t_s * 1e9)))
        self.sent += 1
        self.bytes_sent += len(data)

    # ------------------------------------------------------------------ inputs
    def on_bytes(self, key: str, payload: bytes) -> None:
        """One message of the corridor: forwarded as its record view (when subscribed) and into the scene."""
        now = self.clock()
        self.received += 1
        if not self.camera and keys.is_camera_key(key):
            return
        ch = self._channels.get(key)
        if ch is None or ch.has_sinks():
            try:
                kind = "" if keys.is_camera_key(key) else keys.message_type_for_key(key).KIND
                topic, data = key, (bytes(payload) if not kind else to_json(payload))
                kind = kind or CAMERA_KIND
            except (JsonViewError, keys.KeyError_):
                topic, kind, data = json_record(key, payload)
            self._send(topic, kind, data, now)
        for topic, kind, data, t in self._scene_inputs(key, payload, now):
            self._send(topic, kind, data, t)

    def _scene_inputs(self, key: str, payload: bytes, now: float) -> list:
        """The log lines a message makes (the scene itself goes out on the timer)."""
        try:
            mtype = keys.message_type_for_key(key)
            if mtype.KIND not in SCENE_KINDS:
                return []
            msg = decode(payload, mtype)
        except (ProtocolError, keys.KeyError_):
            return []
        return self.scene.on_message(key, msg, now) + alias(msg, payload, now)

    def tick(self, now: float | None = None) -> int:
        """Send the derived messages due now; returns how many."""
        now = self.clock() if now is None else now
        out = self.scene.tick(now)
        for topic, kind, data, t in out:
            self._send(topic, kind, data, t)
        return len(out)

    # ------------------------------------------------------------------ wiring
    def attach(self, transport: Any, *, poll_ddm: bool = True) -> None:
        """Subscribe to the corridor on ``transport`` and start the scene timer and (``poll_ddm``) the poll of
        the DDM's state for its fused tracks."""
        self.transport = transport
        transport.subscribe_bytes(keys.corridor_expr(self.corridor_id), self.on_bytes)
        self._spawn(self._scene_loop, "foxglove scene")
        if poll_ddm:
            self._ddm_poll = DdmStatePoll(transport, self.corridor_id, self.scene, clock=self.clock).start()

    def _spawn(self, fn: Any, name: str) -> None:
        th = threading.Thread(target=fn, name=name, daemon=True)
        th.start()
        self._threads.append(th)

    def _scene_loop(self) -> None:
        while not self._stop.wait(self.scene_period_s / 2.0):
            try:
                self.tick()
            except Exception:  # a bad input must not stop the scene
                log.exception("scene tick failed")

    def wait(self, duration_s: float | None = None) -> None:
        self._stop.wait(duration_s)

    def close(self) -> None:
        self._stop.set()
        if self._ddm_poll is not None:
            self._ddm_poll.close()
        for th in self._threads:
            th.join(timeout=2.0)
        self.server.stop()


def build_parser() -> argparse.ArgumentParser:
    from protocol.zenoh_transport import ZenohSettings

    ap = argparse.ArgumentParser(prog="iea foxglove", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--port", type=int, default=8765, help="WebSocket port (default 8765; 0: any free port)")
    ap.add_argument("--host", default="127.0.0.1",
                    help="address to serve on (default 127.0.0.1: this machine only; 0.0.0.0 in a container)")
    ap.add_argument("--corridor", default=None, help="corridor file (the road, the RSUs; its id names the keys)")
    ap.add_argument("--corridor-id", default=None, help="corridor id in the keys (e.g. the one `iea up` printed)")
    ap.add_argument("--scene-hz", type=float, default=10.0, help="scene, transforms and map fixes a second (default 10)")
    ap.add_argument("--no-camera", action="store_true", help="do not forward the RSUs' camera frames")
    ap.add_argument("--duration-s", type=float, default=None, help="stop after this long (default: Ctrl-C)")
    ZenohSettings.add_arguments(ap)
    return ap


def main(argv: list[str] | None = None) -> int:
    stop_on_ctrl_c()  # SIGINT stops it even when started with SIGINT ignored (protocol.runtime)
    from protocol.corridor import CorridorError, load_corridor
    from protocol.zenoh_transport import ZenohSettings, ZenohTransport

    ap = build_parser()
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(asctime)s %(name)s %(levelname)s %(message)s")
    try:
        corridor = load_corridor(args.corridor)
        settings = ZenohSettings.from_args(args)
        bridge = FoxgloveBridge(corridor, args.corridor_id, host=args.host, port=args.port,
                                scene_hz=args.scene_hz, camera=not args.no_camera)
    except (CorridorError, ValueError, OSError, RuntimeError) as exc:
        print(f"iea foxglove: {exc}", file=sys.stderr)
        return 2
    signal.signal(signal.SIGTERM, lambda *_: bridge._stop.set())
    transport = ZenohTransport(settings, bulk_queue=0)
    bridge.attach(transport)
    print(f"[foxglove] corridor {bridge.corridor_id}: serving {bridge.url} "
          f"({len(bridge._channels)} channels; Ctrl-C to stop)", flush=True)
    end = None if args.duration_s is None else time.monotonic() + args.duration_s
    try:
        while not bridge._stop.wait(5.0 if end is None else max(0.0, min(5.0, end - time.monotonic()))):
            if end is not None and time.monotonic() >= end:
                break
            print(f"[foxglove] {bridge.received} received, {bridge.sent} sent ({bridge.bytes_sent / 1e6:.1f} MB)",
                  flush=True)
    except KeyboardInterrupt:
        pass
    finally:
        transport.close()
        bridge.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
