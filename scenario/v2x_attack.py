"""A V2X attacker: lights-on CAMs for an EV's StationId that the corridor must not act on.

Three kinds, at 10 Hz on the EV's own CAM key (``iea/{c}/v2x/obu/{ev}/cam``) from ``start_s`` of scenario time:

- ``forged``: the EV's place, signed with a fresh key that claims the EV's key id but is not the trusted one;
- ``replayed``: the EV's place, signed with the EV's real key ``replay_delay_s`` (2 s) in the past: its own
  lights-on CAMs recorded and played back late;
- ``contradicted``: the EV's real key (a stolen one), for an EV driving at 18 m/s along a lane through the
  cameras' clear views, from the start whose path stays clear of the traffic longest as it drives on (the
  attacker sees the road), so that its CAMs agree with each other kinematically but no camera sees a car there. It falls
  silent while the claim is within 10 m of an actor, and for good once it would leave the last camera's view
  (``view_end_x_m``): a claim on a car the cameras see, or out of their view, is not contradicted by them (the
  DDM's known limit of a stolen key), not this attack.

``Attacker`` is the logic (no transport, no clock): where the claimed EV is, what time the CAM is signed at,
which key signs, and the sealed CAM. The lockstep runner (``scenario.v2x_lockstep``) and the process below both
use it.

    python -m scenario.v2x_attack --kind forged --corridor keys/corridor-v2x.toml --corridor-id ID \\
        --ev-key keys/ev1.pem --connect tcp/127.0.0.1:PORT [--duration-s 20]

The process follows the simulator's ``iea/{c}/sim/world`` snapshots and broadcasts through a ``DsrcLink``, as the
EV's radio does (``sim.ev_radio.start_radio``): the corridor's DSRC latency, jitter, loss (``--radio-loss``) and
range, with the transmitter at the claimed place (a forger stands near the EV it imitates; a stolen-key sender
near the place it claims) and the RSU masts as peers. The RSUs' gateways then hear it as they hear the EV.
"""

from __future__ import annotations

import argparse
import logging
import math
import sys
import threading
import time
from collections.abc import Callable

from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

from protocol.corridor import Corridor
from protocol.messages import WorldSnapshot
from protocol.security import Signer
from protocol.v2x.build import ev_cam, station_id
from protocol.v2x.codec import encode
from protocol.v2x.keys import v2x_obu_cam_key
from protocol.v2x.secure import seal

log = logging.getLogger("iea.v2x_attack")

ATTACKS = ("forged", "replayed", "contradicted")
CLAIMED_SPEED_MPS = 18.0
PERIOD_S = 0.1
REPLAY_DELAY_S = 2.0
START_S = 0.5
"""Scenario time of the first CAM."""
CLEAR_OF_ACTORS_M = 15.0
"""The contradicted EV's start is at least this far from every actor."""
NEAR_ACTOR_M = 10.0
"""A claim closer than this to an actor is counted in ``sent_near_actor``: there the cameras see a car."""
VIEW_MARGIN_M = 10.0
DEFAULT_VIEW_RANGE_M = 120.0
"""Reach of a camera whose RSU has no ``max_range_m`` (as the DDM takes it)."""


def view_end_x_m(corridor: Corridor) -> float:
    """Where the cameras' views end along the road (the farthest mast plus its reach), less ``VIEW_MARGIN_M``."""
    return max(r.position[0] + (r.max_range_m or DEFAULT_VIEW_RANGE_M) for r in corridor.rsus) - VIEW_MARGIN_M


def forged_signer(key_id: str) -> Signer:
    """A fresh key under ``key_id``: the trust list holds another public key for that id."""
    return Signer(key_id, Ed25519PrivateKey.generate())


class Attacker:
    """Lights-on CAMs for ``ev_id``'s StationId, one per ``period_s`` (the module docstring says the three kinds).

    ``ev_signer``: the EV's real key (replayed, contradicted; a forger makes its own under the same key id).
    ``step(now, snap)`` returns the (key, sealed CAM) due at ``now`` (the attacker's clock: what the CAM is signed
    at) given the latest world snapshot, or None.
    """

    def __init__(self, kind: str, corridor: Corridor, corridor_id: str, ev_signer: Signer, *, ev_id: str = "ev1",
                 replay_delay_s: float = REPLAY_DELAY_S, start_s: float = START_S, period_s: float = PERIOD_S) -> None:
        if kind not in ATTACKS:
            raise ValueError(f"attack {kind!r}: expected one of {', '.join(ATTACKS)}")
        self.kind = kind
        self.corridor = corridor
        self.ev_id = ev_id
        self.station = station_id(ev_id)
        self.signer = forged_signer(ev_signer.key_id) if kind == "forged" else ev_signer
        self.replay_delay_s = replay_delay_s
        self.start_s = start_s
        self.period_s = period_s
        self.key = v2x_obu_cam_key(corridor_id, ev_id)
        self.next_s = float("-inf")
        self.sent = 0
        self.sent_near_actor = 0
        """CAMs that put the EV within ``NEAR_ACTOR_M`` of an actor: there a camera sees a car (contradicted: the
        claim caught up with the traffic)."""
        self.position: tuple[float, float] | None = None
        """The last claimed place (the transmitter's, for a radio model's range)."""
        self._start: tuple[float, float, float] | None = None
        self.view_end_x_m = view_end_x_m(corridor)

    def signed_at(self, now: float) -> float:
        """The time the CAM carries and is signed at."""
        return now - self.replay_delay_s if self.kind == "replayed" else now

    def claim(self, snap: WorldSnapshot, now: float) -> tuple[float, float]:
        """Where the CAM puts the EV (corridor frame): its true place (forged, replayed; while the snapshot holds
        it) or, contradicted, an EV at ``CLAIMED_SPEED_MPS`` along a lane from a point clear of every actor."""
        ev = next((a for a in snap.actors if a.actor_id == self.ev_id), None)
        if self.kind != "contradicted" and ev is not None:
            return ev.pos_x_m, ev.pos_y_m
        if self._start is None:
            self._start = (now, *self.clear_start(snap))
        t0, x0, y0 = self._start
        return x0 + CLAIMED_SPEED_MPS * (now - t0), y0

    def clear_start(self, snap: WorldSnapshot) -> tuple[float, float]:
        """The start (x every 10 m from 30 m, each lane's centre) whose drive at ``CLAIMED_SPEED_MPS`` stays longest
        ``CLEAR_OF_ACTORS_M`` or more from every actor, each driving on at its speed and heading (the attacker sees
        the road; at 18 m/s a claim catches up with the traffic ahead of it), the first of the best."""
        road = self.corridor.road
        best: tuple[float, float, float] | None = None
        x = 30.0
        while x < self.view_end_x_m - 60.0:
            for lane in range(road.lanes):
                y = road.lane_centre_offset_m(lane)
                clear_s = self._clear_for_s(snap, x, y)
                if best is None or clear_s > best[0]:
                    best = (clear_s, x, y)
            x += 10.0
        return (best[1], best[2]) if best is not None else (40.0, road.lane_centre_offset_m(0))

    def _clear_for_s(self, snap: WorldSnapshot, x0: float, y0: float, step_s: float = 0.25) -> float:
        """How long a claim driven from (x0, y0) stays ``CLEAR_OF_ACTORS_M`` from every actor (at most until the
        views' end)."""
        horizon_s = max(0.0, (self.view_end_x_m - x0) / CLAIMED_SPEED_MPS)
        moving = [(a.pos_x_m, a.pos_y_m, a.speed_mps * math.cos(a.heading_rad), a.speed_mps * math.sin(a.heading_rad))
                  for a in snap.actors]
        t = 0.0
        while t <= horizon_s:
            x = x0 + CLAIMED_SPEED_MPS * t
            if any(math.hypot(x - ax - vx * t, y0 - ay - vy * t) < CLEAR_OF_ACTORS_M for ax, ay, vx, vy in moving):
                return t
            t += step_s
        return horizon_s

    def near_an_actor(self, snap: WorldSnapshot, x: float, y: float) -> bool:
        """Whether a claim at (x, y) is on or beside a car the cameras see (within ``NEAR_ACTOR_M``)."""
        return any(math.hypot(a.pos_x_m - x, a.pos_y_m - y) < NEAR_ACTOR_M for a in snap.actors)

    def cam(self, snap: WorldSnapshot, now: float) -> bytes:
        """The sealed lights-on CAM at ``now``."""
        x, y = self.claim(snap, now)
        self.position = (x, y)
        lat, lon = self.corridor.to_latlon(x, y)
        t_signed = self.signed_at(now)
        cam = encode("CAM", ev_cam(self.station, t_signed, lat, lon, 0.0, CLAIMED_SPEED_MPS, True, True))
        return seal(self.signer, self.key, cam, t_signed)

    def step(self, now: float, snap: WorldSnapshot) -> tuple[str, bytes] | None:
        if snap.sim_time_s < self.start_s or now < self.next_s - 1e-6:  # 1 us: float sums of the period
            return None
        if self.kind == "contradicted" and self.claim(snap, now)[0] > self.view_end_x_m:
            return None  # out of every camera's view: nothing would contradict it
        # the next one a period after this one's slot (not after now): a caller a little late keeps 10 Hz
        slot = now if self.next_s == float("-inf") else self.next_s
        self.next_s = slot + self.period_s if slot + self.period_s > now else now + self.period_s
        payload = self.cam(snap, now)
        self.sent += 1
        if self.position is not None and self.near_an_actor(snap, *self.position):
            self.sent_near_actor += 1
        return self.key, payload


def run_attacker(attacker: Attacker, transport, corridor_id: str, stop: threading.Event, *,
                 clock: Callable[[], float] = time.time, poll_s: float = 0.01) -> int:
    """Follow the world on ``transport`` and publish what ``attacker`` has due every ``poll_s`` until ``stop``;
    returns the CAMs sent."""
    from protocol.codec import ProtocolError
    from protocol.keys import sim_world_key

    latest: list[WorldSnapshot] = []

    def on_world(_key: str, snap: WorldSnapshot) -> None:
        if isinstance(snap, WorldSnapshot):
            latest[:] = [snap]

    sub = transport.subscribe(sim_world_key(corridor_id), on_world)
    try:
        while not stop.wait(poll_s):
            if not latest:
                continue
            out = attacker.step(clock(), latest[0])
            if out is not None:
                try:
                    transport.publish_bytes(*out)
                except ProtocolError:
                    pass
    finally:
        sub.close()
    return attacker.sent


def main(argv: list[str] | None = None) -> int:
    from protocol.clock import WallClock
    from protocol.corridor import CorridorError, load_corridor
    from protocol.radio import ChannelModel, DsrcLink
    from protocol.runtime import stop_on_ctrl_c
    from protocol.security import TrustList, load_signer
    from protocol.zenoh_transport import ZenohSettings, ZenohTransport
    from sim.cli import probability

    stop_on_ctrl_c()
    ap = argparse.ArgumentParser(prog="python -m scenario.v2x_attack", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--kind", required=True, choices=ATTACKS)
    ap.add_argument("--ev-key", required=True, metavar="PEM",
                    help="the EV's real key (replayed, contradicted sign with it; forged takes its key id only)")
    ap.add_argument("--ev-id", default="ev1", help="the EV whose StationId the CAMs claim (default ev1)")
    ap.add_argument("--corridor", default=None, help="corridor TOML file (its trust list names the EV's key)")
    ap.add_argument("--corridor-id", default=None)
    ap.add_argument("--radio-loss", type=probability, default=None,
                    help="the transmitter's radio loss (default: the corridor's dsrc_loss)")
    ap.add_argument("--start-s", type=float, default=START_S, help=f"scenario time of the first CAM (default {START_S})")
    ap.add_argument("--replay-delay-s", type=float, default=REPLAY_DELAY_S)
    ap.add_argument("--seed", type=int, default=0, help="the radio model's seed")
    ap.add_argument("--duration-s", type=float, default=None, help="stop after this many seconds (default: Ctrl-C)")
    ZenohSettings.add_arguments(ap)
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(levelname)s %(message)s")
    try:
        corridor = load_corridor(args.corridor)
        cid = args.corridor_id or corridor.corridor_id
        ev_signer = load_signer(args.ev_key, None, TrustList.from_corridor(corridor))
        attacker = Attacker(args.kind, corridor, cid, ev_signer, ev_id=args.ev_id,
                            replay_delay_s=args.replay_delay_s, start_s=args.start_s)
        settings = ZenohSettings.from_args(args)
    except (CorridorError, ValueError, OSError) as exc:
        print(f"v2x attack: {exc}", file=sys.stderr)
        return 2
    stop = threading.Event()
    if args.duration_s is not None:
        timer = threading.Timer(args.duration_s, stop.set)
        timer.daemon = True
        timer.start()
    t = corridor.transport
    model = ChannelModel(latency_s=t.dsrc_latency_s, jitter_s=t.dsrc_jitter_s,
                         loss=t.dsrc_loss if args.radio_loss is None else args.radio_loss, range_m=t.dsrc_range_m)
    with ZenohTransport(settings) as zt:
        link = DsrcLink(zt, model, seed=args.seed, clock=WallClock(), directions=("tx",),
                        position=lambda: attacker.position, peers=[r.position for r in corridor.rsus])
        log.info("%s attack on %s as %s (key id %s)", args.kind, cid, args.ev_id, attacker.signer.key_id)
        try:
            n = run_attacker(attacker, link, cid, stop)
        except KeyboardInterrupt:
            n = attacker.sent
        finally:
            stop.set()
            link.close()
        log.info("%s attack: %d CAMs sent, %d within %.0f m of an actor, radio %s", args.kind, n,
                 attacker.sent_near_actor, NEAR_ACTOR_M, {d: dict(c) for d, c in link.counts.items()})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
