"""The V2X unit of an equipped emergency vehicle (a role of the simulator): CAMs at 10 Hz over the air.

It follows the simulator's world snapshots (``iea/{c}/sim/world``): the EV knows its own pose as a GNSS receiver
would (the true position plus Gaussian noise of ``gnss_sigma_m``), its speed and heading, and whether its light
bar is on (the siren is taken to run with it). Every ``period_s`` (TS 103 900 6.1.3: at most 10 Hz) it builds the
CAM (``protocol.v2x.build.ev_cam``), signs it in a V2X envelope (``protocol.v2x.secure``) when given a key, and
publishes it on ``iea/{c}/v2x/obu/{ev}/cam`` through the transport it is given: a ``DsrcLink`` whose position is
the EV's and whose peers are the RSU masts applies the radio model (loss, range, latency) to every broadcast.
"""

from __future__ import annotations

import random
from collections.abc import Callable

from protocol.codec import ProtocolError
from protocol.corridor import Corridor
from protocol.enums import ActorKind
from protocol.keys import sim_world_key
from protocol.messages import Actor, WorldSnapshot
from protocol.security import Signer
from protocol.transport import Subscription, Transport
from protocol.v2x.build import ev_cam, station_id
from protocol.v2x.codec import encode
from protocol.v2x.keys import v2x_obu_cam_key
from protocol.v2x.secure import seal

CAM_PERIOD_S = 0.1
DUE_TOLERANCE_S = 1e-3
"""A snapshot this close before a CAM's due time is on time (stamps are sums of float steps)."""


class EvRadio:
    """Broadcasts the CAMs of the snapshot's EVs (all of them, or ``ev_ids``) on their own keys."""

    def __init__(self, transport: Transport, corridor: Corridor, corridor_id: str, *, signer: Signer | None = None,
                 period_s: float = CAM_PERIOD_S, gnss_sigma_m: float = 0.7, seed: int = 0,
                 ev_ids: tuple[str, ...] | None = None, clock: Callable[[], float] | None = None) -> None:
        self.transport = transport
        self.corridor = corridor
        self.corridor_id = corridor_id
        self.signer = signer
        self.period_s = period_s
        self.gnss_sigma_m = gnss_sigma_m
        self.ev_ids = ev_ids
        self.clock = clock
        self.rng = random.Random(f"ev-radio-{seed}")
        self._next_s: dict[str, float] = {}
        self.sent = 0
        self.position: tuple[float, float] | None = None
        """The last EV position broadcast (true, for the radio model's range)."""
        self._sub: Subscription | None = None

    def start(self) -> EvRadio:
        self._sub = self.transport.subscribe(sim_world_key(self.corridor_id), self._on_world)
        return self

    def close(self) -> None:
        if self._sub is not None:
            self._sub.close()
            self._sub = None

    def _on_world(self, _key: str, snap: WorldSnapshot) -> None:
        if isinstance(snap, WorldSnapshot):
            self.on_snapshot(snap)

    def on_snapshot(self, snap: WorldSnapshot) -> int:
        """Broadcast what is due at this snapshot; returns the number of CAMs sent."""
        now = self.clock() if self.clock is not None else snap.stamp
        n = 0
        for actor in snap.actors:
            if actor.kind != ActorKind.EV or (self.ev_ids is not None and actor.actor_id not in self.ev_ids):
                continue
            due = self._next_s.get(actor.actor_id)
            if due is not None and now + DUE_TOLERANCE_S < due:
                continue
            # on the period's grid (snapshots at 20 Hz meet a 10 Hz period exactly), restarted after a gap
            self._next_s[actor.actor_id] = (now if due is None or now - due >= self.period_s else due) + self.period_s
            self.broadcast(actor, now)
            n += 1
        return n

    def cam_bytes(self, actor: Actor, now_s: float) -> bytes:
        """The UPER CAM of ``actor`` as its own GNSS and CAN bus see it at ``now_s``."""
        x = actor.pos_x_m + self.rng.gauss(0.0, self.gnss_sigma_m)
        y = actor.pos_y_m + self.rng.gauss(0.0, self.gnss_sigma_m)
        lat, lon = self.corridor.to_latlon(x, y)
        on = bool(actor.light_bar is not None and actor.light_bar.on)
        return encode("CAM", ev_cam(station_id(actor.actor_id), now_s, lat, lon, actor.heading_rad, actor.speed_mps,
                                    light_bar=on, siren=on, length_m=actor.length_m, width_m=actor.width_m,
                                    position_sigma_m=self.gnss_sigma_m))

    def broadcast(self, actor: Actor, now_s: float) -> None:
        key = v2x_obu_cam_key(self.corridor_id, actor.actor_id)
        payload = self.cam_bytes(actor, now_s)
        if self.signer is not None:
            payload = seal(self.signer, key, payload, now_s)
        self.position = (actor.pos_x_m, actor.pos_y_m)
        try:
            self.transport.publish_bytes(key, payload)
        except ProtocolError:
            return
        self.sent += 1


def start_radio(transport: Transport, corridor: Corridor, corridor_id: str, key_path: str | None = None, *,
                seed: int = 0, loss: float | None = None) -> EvRadio:
    """The EV's radio on ``transport`` behind the corridor's DSRC model (a ``DsrcLink`` from the EV to the RSU
    masts: latency, jitter, ``dsrc_loss`` or ``loss``, ``dsrc_range_m``), signing with ``key_path`` when given."""
    from protocol.radio import ChannelModel, DsrcLink
    from protocol.security import TrustList, load_signer

    t = corridor.transport
    model = ChannelModel(latency_s=t.dsrc_latency_s, jitter_s=t.dsrc_jitter_s,
                         loss=t.dsrc_loss if loss is None else loss, range_m=t.dsrc_range_m)
    holder: list[EvRadio] = []
    link = DsrcLink(transport, model, seed=seed, directions=("tx",), position=lambda: holder[0].position,
                    peers=[r.position for r in corridor.rsus])
    signer = load_signer(key_path, None, TrustList.from_corridor(corridor)) if key_path else None
    radio = EvRadio(link, corridor, corridor_id, signer=signer, seed=seed)
    holder.append(radio)
    return radio.start()
