"""A scripted corridor in one process, for bench/zenoh_bench.py and the Zenoh tests.

It plays the RSUs of the corridor file and one autonomous vehicle as the real services do on the wire:
each declares its liveliness token, publishes (RSU object lists at 15 Hz, an active EvAlert refreshed
at 2 Hz, vehicle state at 20 Hz, Health at 1 Hz) and answers queries on its keys with the latest
messages (``protocol.presence.serve``). Scripted, not simulated: an EV approaches the AV from behind in
the AV's lane, so a DDM that knows the EV decides to yield.

    python bench/zenoh_corridor_stub.py --corridor-id ID --connect tcp/127.0.0.1:PORT [--duration-s S]

With ``--credentials-dir DIR`` (a folder from ``iea deploy acl|mesh``) every RSU and the vehicle open
their own session with their own credentials (``DIR/<id>.json5``), as separate services would behind
an ACL router.

Prints ``ready`` once its tokens and queryables are declared; stops at ``--duration-s`` or SIGTERM
(SIGKILL it to test presence: its tokens go with its session).
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from protocol import presence  # noqa: E402
from protocol.codec import encode  # noqa: E402
from protocol.corridor import load_corridor  # noqa: E402
from protocol.enums import AlertState, EvState, HealthStatus, ObjectType, Role, VehicleMode
from protocol.keys import rsu_key, vehicle_key  # noqa: E402
from protocol.messages import DetectedObject, EvAlert, Health, ObjectList, VehicleState
from protocol.transport import Transport  # noqa: E402
from protocol.zenoh_transport import ZenohSettings, ZenohTransport  # noqa: E402

LANE_W_M = 3.7
AV_X_M, AV_LANE, AV_SPEED_MPS = 120.0, 1, 10.0
EV_GAP_M, EV_SPEED_MPS = 70.0, 20.0


def _obj(corridor, oid: int, x: float, lane: int, v: float, ev: bool) -> DetectedObject:
    y = (lane + 0.5) * LANE_W_M
    lat, lon = corridor.to_latlon(x, y)
    return DetectedObject(object_id=oid, pos_x_m=x, pos_y_m=y, lat_deg=lat, lon_deg=lon,
                          bbox_px=(0.0, 0.0, 10.0, 10.0), obj_type=ObjectType.EV if ev else ObjectType.VEHICLE,
                          ev_state=EvState.CONFIRMED if ev else EvState.NONE, ev_score=0.9 if ev else 0.0,
                          vel_x_mps=v, vel_y_mps=0.0, speed_mps=v, heading_rad=0.0, length_m=4.8, width_m=1.9,
                          pos_cov_m2=(0.25, 0.0, 0.25), lane=lane)


class CorridorStub:
    """RSUs + one AV on ``transport`` (or each on its own: ``by_node``); ``tick(t)`` publishes what is due
    at wall time ``t``."""

    def __init__(self, transport: Transport, corridor, corridor_id: str, vehicle_id: str = "av1",
                 by_node: dict[str, Transport] | None = None) -> None:
        self.t, self.corridor, self.c, self.vid = transport, corridor, corridor_id, vehicle_id
        self.by_node = by_node or {}
        self.rsus = [r.rsu_id for r in corridor.rsus]
        self.start = time.time()
        self.seq = 0
        self.latest: dict[str, object] = {}
        self._lock = threading.Lock()
        self.handles = []
        for r in self.rsus:
            t = self.by_node.get(r, transport)
            self.handles.append(presence.serve(t, f"iea/{corridor_id}/rsu/{r}/*",
                                               self._answer(f"iea/{corridor_id}/rsu/{r}/")))
            self.handles.append(presence.announce(t, corridor_id, "rsu", r))
        prefix = f"iea/{corridor_id}/vehicle/{vehicle_id}/"
        t = self.by_node.get(vehicle_id, transport)
        for topic in ("state", "health"):  # concrete keys, as the vehicle service (and its ACL grant) has them
            self.handles.append(presence.serve(t, prefix + topic, self._answer(prefix + topic)))
        self.handles.append(presence.announce(t, corridor_id, "vehicle", vehicle_id))

    def _answer(self, prefix: str):
        """Each service answers with its own latest messages."""
        def answer(_q: str) -> list[tuple[str, bytes]]:
            with self._lock:
                return [(k, encode(m)) for k, m in self.latest.items() if k.startswith(prefix)]
        return answer

    def _put(self, key: str, msg) -> None:
        self.by_node.get(key.split("/")[3], self.t).publish(key, msg)
        with self._lock:
            self.latest[key] = msg

    def tick(self, now: float) -> None:
        dt = (now - self.start) % 20.0  # the script loops every 20 s (the corridor is a few hundred metres)
        av_x = AV_X_M + AV_SPEED_MPS * dt
        ev_x = av_x - EV_GAP_M + (EV_SPEED_MPS - AV_SPEED_MPS) * min(dt, 3.0)
        self.seq += 1
        cars = [(1, av_x, AV_LANE, AV_SPEED_MPS, False), (2, ev_x, AV_LANE, EV_SPEED_MPS, True),
                (3, av_x + 30.0, 0, AV_SPEED_MPS, False)]
        for i, r in enumerate(self.rsus):
            objs = [_obj(self.corridor, 100 * (i + 1) + oid, x, ln, v, ev) for oid, x, ln, v, ev in cars]
            self._put(rsu_key(self.c, r, "objects"), ObjectList(src=r, seq=self.seq, stamp=now, rsu_id=r,
                                                                 frame=self.seq, measurement_time=now, objects=objs))
        r0 = self.rsus[0]
        if self.seq % 7 == 1:  # 2 Hz at the 15 Hz frame rate
            y = (AV_LANE + 0.5) * LANE_W_M
            lat, lon = self.corridor.to_latlon(ev_x, y)
            self._put(rsu_key(self.c, r0, "ev"), EvAlert(
                src=r0, seq=self.seq // 7, stamp=now, alert_id=f"{r0}-ev-102", state=AlertState.ACTIVE, rsu_id=r0,
                object_id=102, pos_x_m=ev_x, pos_y_m=y, lat_deg=lat, lon_deg=lon, vel_x_mps=EV_SPEED_MPS,
                vel_y_mps=0.0, speed_mps=EV_SPEED_MPS, lane=AV_LANE, confidence=0.9, first_seen=self.start))
        lat, lon = self.corridor.to_latlon(av_x, (AV_LANE + 0.5) * LANE_W_M)
        self._put(vehicle_key(self.c, self.vid, "state"), VehicleState(
            src=self.vid, seq=self.seq, stamp=now, vehicle_id=self.vid, pos_x_m=av_x,
            pos_y_m=(AV_LANE + 0.5) * LANE_W_M, lat_deg=lat, lon_deg=lon, heading_rad=0.0, speed_mps=AV_SPEED_MPS,
            mode=VehicleMode.DRIVING, active_command_id=None))
        if self.seq % 15 == 1:
            for src, key, role in [(r, rsu_key(self.c, r, "health"), Role.RSU) for r in self.rsus] + \
                                  [(self.vid, vehicle_key(self.c, self.vid, "health"), Role.VEHICLE)]:
                self._put(key, Health(src=src, seq=self.seq // 15, stamp=now, role=role, status=HealthStatus.OK,
                                      uptime_s=dt, detail="corridor stub"))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--corridor", default=None, help="corridor file (default: deploy/corridors/rellis.toml)")
    ap.add_argument("--corridor-id", required=True)
    ap.add_argument("--duration-s", type=float, default=60.0)
    ap.add_argument("--rate-hz", type=float, default=15.0)
    ap.add_argument("--credentials-dir", default=None, help="each RSU and the vehicle joins with DIR/<id>.json5")
    ZenohSettings.add_arguments(ap)
    args = ap.parse_args(argv)
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    corridor = load_corridor(args.corridor)
    settings = ZenohSettings.from_args(args)
    by_node: dict[str, Transport] = {}
    if args.credentials_dir:
        for node in [*(r.rsu_id for r in corridor.rsus), "av1"]:
            by_node[node] = ZenohTransport(ZenohSettings(mode=settings.mode, connect=settings.connect,
                                                         config_file=f"{args.credentials_dir}/{node}.json5"))
        transport = by_node["av1"]
    else:
        transport = ZenohTransport(settings)
    stub = CorridorStub(transport, corridor, args.corridor_id, by_node=by_node)
    stub.tick(time.time())
    print("ready", flush=True)
    end = time.monotonic() + args.duration_s
    period = 1.0 / args.rate_hz
    while not stop.is_set() and time.monotonic() < end:
        stop.wait(period)
        stub.tick(time.time())
    for t in {id(t): t for t in [transport, *by_node.values()]}.values():
        t.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
