"""An RSU's V2X gateway: the RSU's messages as standard V2X for outside ITS stations, and its radio's CAMs for the DDM.

It works from the RSU's published keys, beside the RSU service (no change to it):

- ``iea/{c}/rsu/{rsu}/objects`` -> a CPM (TS 103 324) on ``iea/{c}/v2x/rsu/{rsu}/cpm``, at most every
  ``cpm_period_s`` (TS 103 324 6.1.2: 1-10 Hz; 2 Hz by default: a CPM of 30 objects costs about 10 ms to
  encode with asn1tools);
- ``iea/{c}/rsu/{rsu}/ev`` -> a DENM (TS 103 831, cause 95 ``emergencyVehicleApproaching``) on
  ``iea/{c}/v2x/rsu/{rsu}/denm`` for each active alert, and its cancellation when the alert is cleared;
- the RSU's radio: the CAMs broadcast on ``iea/{c}/v2x/obu/*/cam`` that reach it (its transport is a ``DsrcLink``
  receiving with the radio model's loss; a CAM whose position is beyond ``radio_range_m`` of the mast is not
  heard) are passed on, as received, in an envelope signed by the RSU on ``iea/{c}/v2x/rsu/{rsu}/rx``.

Everything published is UPER bytes or a V2X envelope (``protocol.v2x.secure``); a message that does not build or
decode is counted in ``errors`` and dropped.
"""

from __future__ import annotations

import argparse
import logging
import math
import sys
import threading
from collections import Counter
from collections.abc import Callable

from protocol.corridor import Corridor
from protocol.enums import AlertState
from protocol.keys import rsu_key
from protocol.messages import EvAlert, ObjectList
from protocol.security import Signer
from protocol.transport import Subscription, Transport
from protocol.v2x.build import cam_info, ev_denm, rsu_cpm, station_id
from protocol.v2x.codec import V2xError, decode, encode
from protocol.v2x.keys import v2x_obu_cam_expr, v2x_rsu_key
from protocol.v2x.secure import CAM_VALID_FOR_S, open_envelope, seal

log = logging.getLogger(__name__)


class V2xGateway:
    def __init__(self, transport: Transport, corridor: Corridor, corridor_id: str, rsu_id: str, *,
                 clock: Callable[[], float], signer: Signer | None = None, radio: Transport | None = None,
                 cpm_period_s: float = 0.5, radio_range_m: float | None = None) -> None:
        self.transport = transport
        self.radio = radio or transport
        self.corridor = corridor
        self.c = corridor_id
        self.rsu_id = rsu_id
        self.rsu = corridor.rsu(rsu_id)
        self.clock = clock
        self.signer = signer
        self.cpm_period_s = cpm_period_s
        self.radio_range_m = radio_range_m if radio_range_m is not None else corridor.transport.dsrc_range_m
        self.station = station_id(f"{corridor_id}/{rsu_id}")
        self.lat_deg, self.lon_deg = corridor.to_latlon(*self.rsu.position)
        self.counts: Counter = Counter()
        self._next_cpm_s = float("-inf")
        self._lock = threading.Lock()
        self._subs: list[Subscription] = []

    def start(self) -> V2xGateway:
        self._subs = [
            self.transport.subscribe(rsu_key(self.c, self.rsu_id, "objects"), self._on_objects),
            self.transport.subscribe(rsu_key(self.c, self.rsu_id, "ev"), self._on_alert),
            self.radio.subscribe_bytes(v2x_obu_cam_expr(self.c), self._on_air),
        ]
        return self

    def close(self) -> None:
        for s in self._subs:
            s.close()
        self._subs = []

    # -- pure parts, callable without a transport
    def cpm_bytes(self, objects: ObjectList) -> bytes:
        return encode("CPM", rsu_cpm(objects, self.station, self.lat_deg, self.lon_deg, *self.rsu.position))

    def denm_bytes(self, alert: EvAlert, now_s: float) -> bytes:
        return encode("DENM", ev_denm(alert, self.station, now_s))

    def in_range(self, cam: bytes) -> bool:
        """Whether a CAM's position lies within the radio's range of the mast (unknown position: heard)."""
        info = cam_info(decode(cam, expected="CAM"))
        if info.lat_deg is None or info.lon_deg is None:
            return True
        x, y = self.corridor.from_latlon(info.lat_deg, info.lon_deg)
        return math.hypot(x - self.rsu.position[0], y - self.rsu.position[1]) <= self.radio_range_m

    # -- handlers
    def _publish(self, topic: str, payload: bytes) -> None:
        self.transport.publish_bytes(v2x_rsu_key(self.c, self.rsu_id, topic), payload)
        self.counts[topic] += 1

    def _on_objects(self, _key: str, msg: ObjectList) -> None:
        now = self.clock()
        with self._lock:
            if now < self._next_cpm_s:
                return
            self._next_cpm_s = now + self.cpm_period_s
        try:
            self._publish("cpm", self.cpm_bytes(msg))
        except V2xError as e:
            self.counts["errors"] += 1
            log.warning("%s: CPM not built: %s", self.rsu_id, e)

    def _on_alert(self, _key: str, msg: EvAlert) -> None:
        try:
            self._publish("denm", self.denm_bytes(msg, self.clock()))
        except V2xError as e:
            self.counts["errors"] += 1
            log.warning("%s: DENM not built: %s", self.rsu_id, e)
        if msg.state == AlertState.CLEARED:
            self.counts["denm_cancelled"] += 1

    def _on_air(self, key: str, payload: bytes) -> None:
        """A broadcast CAM that reached this radio: passed on to the DDM, signed by this RSU."""
        now = self.clock()
        try:
            cam = open_envelope(payload).payload
            if not self.in_range(cam):
                self.counts["out_of_range"] += 1
                return
        except V2xError:
            self.counts["errors"] += 1
            return
        if self.signer is None:
            self.counts["unsigned_not_relayed"] += 1
            return
        relay_key = v2x_rsu_key(self.c, self.rsu_id, "rx")
        self.transport.publish_bytes(relay_key, seal(self.signer, relay_key, payload, now, CAM_VALID_FOR_S,
                                                     rsu_id=self.rsu_id, heard_on=key, rx_time_s=now))
        self.counts["rx"] += 1


def main(argv: list[str] | None = None) -> int:
    """``python -m rsu.v2x_gateway --rsu-id rsu1 [--key K.pem]``: one RSU's gateway over Zenoh until Ctrl-C."""
    from protocol.clock import WallClock
    from protocol.corridor import CorridorError, load_corridor
    from protocol.radio import ChannelModel, DsrcLink
    from protocol.runtime import stop_on_ctrl_c
    from protocol.security import TrustList, load_signer
    from protocol.zenoh_transport import ZenohSettings, ZenohTransport

    stop_on_ctrl_c()
    ap = argparse.ArgumentParser(prog="python -m rsu.v2x_gateway", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rsu-id", required=True)
    ap.add_argument("--corridor", default=None)
    ap.add_argument("--corridor-id", default=None)
    ap.add_argument("--key", default=None, help="the RSU's signing key (PEM): without it, no CAM is passed on")
    ap.add_argument("--key-id", default=None, help="its key id (default: the corridor's trust entry of its public key)")
    ap.add_argument("--radio-loss", type=float, default=None, help="the radio's loss (default: the corridor's)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--duration-s", type=float, default=None)
    ZenohSettings.add_arguments(ap)
    args = ap.parse_args(argv)
    try:
        corridor = load_corridor(args.corridor)
        cid = args.corridor_id or corridor.corridor_id
        corridor.rsu(args.rsu_id)
        signer = load_signer(args.key, args.key_id, TrustList.from_corridor(corridor)) if args.key else None
        settings = ZenohSettings.from_args(args)
    except (CorridorError, KeyError, ValueError, OSError) as exc:
        print(f"v2x gateway: {exc}", file=sys.stderr)
        return 2
    clock = WallClock()
    with ZenohTransport(settings) as zt:
        t = corridor.transport
        loss = t.dsrc_loss if args.radio_loss is None else args.radio_loss
        radio = DsrcLink(zt, ChannelModel(latency_s=t.dsrc_latency_s, jitter_s=t.dsrc_jitter_s, loss=loss),
                         seed=args.seed, clock=clock, directions=("rx",))
        gw = V2xGateway(zt, corridor, cid, args.rsu_id, clock=clock.now, signer=signer, radio=radio).start()
        stop = threading.Event()
        stop.wait(args.duration_s)
        gw.close()
        radio.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
