"""Fuzz targets of ``bench/fuzz_bench.py``, protocol and DDM side: each decoder, the
LocalBus/transport rejection path, the DDM's ``_on_rsu``, ``_on_vehicle_state`` and ``_on_ack``.

Seeds are made for the target (alerts next to the AV, acks naming the DDM's outstanding command ...)
and mutated by ``bench/fuzz_mutator.py``; wrong keys too (a valid payload on a key carrying another
kind, keys outside the schema). Handlers are fed through a real ``LocalBus`` (bytes -> decode ->
callback), so their input is exactly what a peer can produce. ``Target.feed`` delivers one input;
``Target.after`` is the scene's own work between inputs (a service step, a render, a fresh car).
"""


from __future__ import annotations

import dataclasses
import random
from typing import Any

import msgpack

from bench.fuzz_mutator import Mutator
from protocol import keys
from protocol.clock import SimClock
from protocol.codec import MAX_PAYLOAD_BYTES, ProtocolError, decode, encode
from protocol.enums import AckStatus, AlertState, Role, VehicleMode
from protocol.examples import example_messages, object_list
from protocol.keys import KeyError_
from protocol.local_bus import LocalBus
from protocol.messages import CommandAck, EvAlert, Health, PathSwitchCommand, VehicleState

C = "fuzz"


# ----------------------------------------------------------------------------- targets
class Target:
    """One thing to fuzz. ``feed(payload)`` returns True when the input reached the decoder's output /
    the handler, False when refused; it raises on a crash."""

    name = "target"

    def __init__(self, rng: random.Random) -> None:
        self.rng = rng
        self.mutator = Mutator(rng, self.seeds())

    def seeds(self) -> list[bytes]:
        raise NotImplementedError

    def payload(self) -> bytes:
        return self.mutator()

    def feed(self, payload: bytes) -> bool:
        raise NotImplementedError

    def after(self) -> None:
        """The scene's own work between inputs (a service step, a render, a fresh car), timed apart from
        the input: it runs on the service's clock, not per peer message."""

    def sizes(self) -> dict[str, int]:
        return {}


def claimed_kind(payload: bytes) -> str | None:
    """The ``kind`` a payload's top-level map claims, read without unpacking the rest (unpacking a whole
    1 MB input of 1 M nested lists takes seconds and 100+ MB, which would be charged to the bus)."""
    if len(payload) > MAX_PAYLOAD_BYTES:
        return None
    unpacker = msgpack.Unpacker(raw=False, max_buffer_size=max(1, len(payload)), max_str_len=64,
                                max_bin_len=0, max_array_len=0, max_map_len=64, max_ext_len=0)
    unpacker.feed(payload)
    try:
        for _ in range(unpacker.read_map_header()):
            if unpacker.unpack() == "kind":
                kind = unpacker.unpack()
                return kind if isinstance(kind, str) else None
            unpacker.skip()
    except Exception:  # noqa: BLE001 - not a map, truncated, a container as a key ...: no kind
        return None
    return None


def _kind_seeds(kind: type) -> list[bytes]:
    out = [encode(m) for _, m in example_messages(C, stamp=10.0) if type(m) is kind]
    if kind.KIND == "ObjectList":
        out += [encode(object_list(n, 10.0)) for n in (0, 1, 5)]
    return out


class DecodeTarget(Target):
    def __init__(self, rng: random.Random, kind: type) -> None:
        self.kind = kind
        self.name = f"decode_{kind.KIND}"
        super().__init__(rng)

    def seeds(self) -> list[bytes]:
        return _kind_seeds(self.kind)

    def feed(self, payload: bytes) -> bool:
        try:
            decode(payload, self.kind if self.rng.random() < 0.9 else None)
        except ProtocolError:
            return False
        return True


def mutated_payload(mutator: Mutator, rng: random.Random, msg, probability: float) -> bytes:
    """``msg`` encoded, its msgpack tree mutated first with ``probability``; its plain encoding when the mutant
    does not pack."""
    tree = msgpack.unpackb(encode(msg), raw=False)
    if rng.random() < probability:
        tree = mutator.mutate_tree(tree)
    try:
        return msgpack.packb(tree, use_bin_type=True)
    except (OverflowError, ValueError, TypeError):
        return encode(msg)


class _BusTarget(Target):
    """Feeds bytes through a LocalBus: a handler exception is caught and counted by the transport."""

    bus: LocalBus

    def _keys(self) -> list[str]:
        raise NotImplementedError

    def _odd_keys(self) -> list[str]:
        """Keys the subscription matches but whose kind is wrong or unknown."""
        return []

    def feed(self, payload: bytes) -> bool:
        before_err = self.bus.stats.handler_errors
        before_rx = self.bus.stats.received
        odd = self._odd_keys()
        key = self.rng.choice(odd) if odd and self.rng.random() < 0.08 else self.rng.choice(self._keys())
        self.bus.publish_bytes(key, payload)
        if self.bus.stats.handler_errors != before_err:
            raise RuntimeError(f"handler raised on {key} (see the log above)")
        return self.bus.stats.received != before_rx


class TransportTarget(_BusTarget):
    """The rejection path itself: any key (valid or not), any bytes; only valid messages get through."""

    name = "transport_localbus"

    def __init__(self, rng: random.Random) -> None:
        super().__init__(rng)
        self.bus = LocalBus()
        self.delivered = 0
        self.bus.subscribe(keys.corridor_expr(C), self._on)
        self._keys_by_kind: dict[str, list[str]] = {}
        for k, _ in example_messages(C):
            self._keys_by_kind.setdefault(keys.message_type_for_key(k).__name__, []).append(k)

    def _on(self, key: str, msg: Any) -> None:
        if type(msg) is not keys.message_type_for_key(key):
            raise AssertionError(f"{type(msg).__name__} delivered on {key}")
        self.delivered += 1

    def seeds(self) -> list[bytes]:
        return [encode(m) for _, m in example_messages(C, stamp=10.0)]

    def _keys(self) -> list[str]:
        if not hasattr(self, "_key_pool"):
            self._key_pool = self._make_keys()
        return self._key_pool

    def _make_keys(self) -> list[str]:
        return [k for k, _ in example_messages(C)] + [
            f"iea/{C}/rsu/rsu1/nope", f"iea/{C}/vehicle/av1", f"iea/{C}", f"iea/{C}/x/y/z/w", f"iea/{C}/rsu//objects",
            f"iea/{C}/rsu/{'r' * 300}/objects", f"iea/{C}/vehicle/av 1/cmd", f"iea/{C}/sim/world/extra"]

    def _key_for_kind(self, payload: bytes) -> str | None:
        """A key whose message type is the one the payload claims to be, so well-formed inputs reach the
        subscriber (a random key would pair them with the wrong kind nearly always)."""
        kind = claimed_kind(payload)
        matching = self._keys_by_kind.get(kind) if kind is not None else None
        return self.rng.choice(matching) if matching else None

    def feed(self, payload: bytes) -> bool:
        key = self.rng.choice(self._keys())
        if self.rng.random() < 0.5:
            key = self._key_for_kind(payload) or key
        if self.rng.random() < 0.02:
            key = f"iea/{C}/rsu/*/objects"  # unpublishable: refused with KeyError_
        before = self.bus.stats.received
        try:
            self.bus.publish_bytes(key, payload)
        except KeyError_:
            return False
        if self.bus.stats.handler_errors:
            raise RuntimeError(f"a {key} message reached the subscriber with the wrong kind")
        return self.bus.stats.received != before


# -- DDM
def _corridor():
    from protocol.corridor import load_corridor
    return dataclasses.replace(load_corridor(), corridor_id=C)


class DdmTarget(_BusTarget):
    """One DdmService on LocalBus + SimClock; ``step`` every 10 inputs, 50 ms of clock each."""

    topics: tuple[str, ...] = ()

    def __init__(self, rng: random.Random) -> None:
        from ddm.config import DdmConfig
        from ddm.service import DdmService

        self.corridor = _corridor()
        self.bus, self.clock = LocalBus(), SimClock(100.0)
        self.svc = DdmService(self.bus, self.clock, self.corridor, DdmConfig(startup_listen_s=0.0))
        self.commands: list[PathSwitchCommand] = []
        self.bus.subscribe(keys.all_vehicles_expr(C, "cmd"), lambda k, m: self.commands.append(m) or
                           self.commands.__delitem__(slice(0, -8)))
        self.n = 0
        self.av_x = 60.0
        super().__init__(rng)

    # the scene the fuzzed inputs land in: av1 driving in lane 1, an EV behind it
    def av_state(self) -> VehicleState:
        lat, lon = self.corridor.to_latlon(self.av_x, 5.55)
        return VehicleState(src="av1", stamp=self.clock.now(), vehicle_id="av1", pos_x_m=self.av_x, pos_y_m=5.55,
                            lat_deg=lat, lon_deg=lon, heading_rad=0.0, speed_mps=13.4, mode=VehicleMode.DRIVING)

    def ev_alert(self, state: AlertState = AlertState.ACTIVE) -> EvAlert:
        x = self.av_x - 40.0
        lat, lon = self.corridor.to_latlon(x, 5.55)
        return EvAlert(src="rsu1", stamp=self.clock.now(), alert_id="rsu1-ev-1", state=state, rsu_id="rsu1",
                       object_id=1, pos_x_m=x, pos_y_m=5.55, lat_deg=lat, lon_deg=lon, vel_x_mps=20.0, speed_mps=20.0,
                       lane=1, confidence=0.9, first_seen=self.clock.now())

    def after(self) -> None:
        self.n += 1
        if self.n % 10 == 0:
            self.clock.advance(0.05)
            self.av_x = 60.0 + (self.n // 10 % 200) * 0.67  # 13.4 m/s, back to the start every 10 s
            if "state" not in self.topics:
                self.bus.publish(keys.vehicle_key(C, "av1", "state"), self.av_state())
            if "ev" not in self.topics and self.n % 200 == 0:
                self.bus.publish(keys.rsu_key(C, "rsu1", "ev"), self.ev_alert(
                    AlertState.ACTIVE if self.n % 4000 < 2000 else AlertState.CLEARED))
            self.svc.step()
            if self.bus.stats.handler_errors:
                raise RuntimeError("a handler raised during the scene's own messages")

    def sizes(self) -> dict[str, int]:
        w, s = self.svc.world, self.svc
        return {**w.sizes(), **s.decider.sizes(),
                "decision_latencies": len(s.decision_latency_ms),
                "period_latencies": len(s._period_latency)}


class DdmRsuTarget(DdmTarget):
    name = "ddm_on_rsu"
    topics = ("objects", "ev", "hazard", "health")

    def seeds(self) -> list[bytes]:
        from protocol.examples import object_list as ol

        out = [encode(m) for _, m in example_messages(C, stamp=100.0)[:3]]
        out.append(encode(self.ev_alert()))
        out.append(encode(ol(8, 100.0, rsu_id="rsu1")))
        out.append(encode(Health(src="rsu1", stamp=100.0, role=Role.RSU)))
        return out

    def payload(self) -> bytes:
        p = super().payload()
        if self.rng.random() < 0.3 and len(p) <= 64 * 1024:  # stamps near the DDM's clock: lists not simply too old
            try:
                tree = msgpack.unpackb(p, raw=False)
                if isinstance(tree, dict):
                    for k in ("stamp", "measurement_time", "first_seen"):
                        if isinstance(tree.get(k), int | float):
                            tree[k] = self.clock.now() - self.rng.uniform(-1.0, 2.0)
                    p = msgpack.packb(tree, use_bin_type=True)
            except (ValueError, TypeError, OverflowError, msgpack.UnpackException):
                pass
        return p

    def _keys(self) -> list[str]:
        return [keys.rsu_key(C, r, t) for r in ("rsu1", "rsu2") for t in self.topics]

    def _odd_keys(self) -> list[str]:
        return [f"iea/{C}/rsu/rsu1/state", f"iea/{C}/rsu/rsu9/objects", f"iea/{C}/rsu/{'x' * 64}/ev"]


class DdmStateTarget(DdmTarget):
    name = "ddm_on_vehicle_state"
    topics = ("state",)

    def seeds(self) -> list[bytes]:
        st = self.av_state()
        return [encode(st), encode(st.model_copy(update={"mode": VehicleMode.MANOEUVRE, "active_command_id": "x-1"})),
                encode(st.model_copy(update={"vehicle_id": "av2", "src": "av2"}))]

    def _keys(self) -> list[str]:
        return [keys.vehicle_key(C, "av1", "state"), keys.vehicle_key(C, "av2", "state")]

    def _odd_keys(self) -> list[str]:
        return [keys.vehicle_key(C, f"v{self.rng.randrange(10**6)}", "state")]


class DdmAckTarget(DdmTarget):
    name = "ddm_on_ack"
    topics = ("ack",)

    def seeds(self) -> list[bytes]:
        return [encode(CommandAck(src="av1", stamp=100.0, command_id="ddm-av1-1", vehicle_id="av1", status=s))
                for s in AckStatus]

    def payload(self) -> bytes:
        cur = self.svc.commands.state_of("av1")
        if cur is not None and self.rng.random() < 0.5:  # an ack naming the command the DDM waits on
            ack = CommandAck(src="av1", stamp=self.clock.now(), command_id=cur.command_id, vehicle_id="av1",
                             status=self.rng.choice(list(AckStatus)), reason=self.rng.choice(("", "x" * 200)))
            return mutated_payload(self.mutator, self.rng, ack, 0.5)
        return super().payload()

    def _keys(self) -> list[str]:
        return [keys.vehicle_key(C, "av1", "ack")]

    def _odd_keys(self) -> list[str]:
        return [keys.vehicle_key(C, "av2", "ack")]


# -- vehicle
