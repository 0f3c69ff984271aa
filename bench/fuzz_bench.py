"""Fuzz every decoder and every service message handler (issue 9, "Robustness").

Inputs are built from valid encodings of each message kind (seeds made for the target: commands that
start at the car, alerts next to the AV, acks naming the DDM's outstanding command ...) by

- structure-aware mutations of the msgpack tree: a field replaced by NaN/inf/huge/negative/zero
  numbers, wrong types, over-long strings, deep nesting, a list grown past its cap or to thousands of
  items, a field deleted or an unknown one added, the kind or version changed; valid-looking numeric
  perturbations (1e300 metres, 2**53 ids) that pass the codec and reach the handler's logic;
- byte-level mutations: bit flips, truncation, insertion, splicing, random bytes, an oversized payload;
- wrong keys: a valid payload on a key carrying another kind, keys outside the schema.

Targets: ``protocol.codec.decode`` for each of the 8 kinds; the LocalBus/transport rejection path; the
DDM's ``_on_rsu``, ``_on_vehicle_state``, ``_on_ack`` (with ``step`` between inputs); the vehicle's
``_on_cmd`` (with signature checking on; half the mutated commands re-signed with the trusted key so
they reach the command book), ``_on_rsu`` (RSU localisation) and DDM-health watchdog; the simulator's
``_on_state``; the RSU side's ``SimCamera._on_snapshot`` + render. Handlers are fed through a real
``LocalBus`` (bytes -> decode -> callback), so their input is exactly what a peer can produce.

A crash is any exception other than the expected refusal (``ProtocolError`` from ``decode``,
``KeyError_`` for an unpublishable key), including one the transport caught and counted in
``stats.handler_errors`` and one raised by the service's ``step``. Memory: resident set size growth
from 10 % of the run to its end, the size of every peer-growable collection at the end, and with
``--tracemalloc`` the traced peak and the traced growth (Python/numpy memory still held at the end
minus at 10 %: what the target kept; RSS also moves with the allocator's free lists). The LRU caches
of ``protocol.keys`` (4,096 parsed keys, 16,384 key matches) fill up to their caps when a target
invents keys. Per-input cost: mean and max microseconds (the max includes scheduler stalls).

    python bench/fuzz_bench.py                 # 100,000 inputs per target (about 15 min on one core)
    python bench/fuzz_bench.py --quick         # 2,000 per target
    python bench/fuzz_bench.py --n 5000 --targets decode_PathSwitchCommand,vehicle_cmd --json
"""

from __future__ import annotations

import argparse
import dataclasses
import gc
import json
import math
import os
import random
import sys
import time
import traceback
import tracemalloc
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import msgpack

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from protocol import keys  # noqa: E402
from protocol.clock import SimClock  # noqa: E402
from protocol.codec import MAX_PAYLOAD_BYTES, ProtocolError, decode, encode  # noqa: E402
from protocol.examples import example_messages, object_list  # noqa: E402
from protocol.keys import KeyError_  # noqa: E402
from protocol.messages import (  # noqa: E402
    MAX_ACTORS,
    MAX_OBJECTS,
    MAX_WAYPOINTS,
    MESSAGE_TYPES,
    AckStatus,
    AlertState,
    CommandAck,
    EvAlert,
    Health,
    Manoeuvre,
    PathSwitchCommand,
    Role,
    VehicleMode,
    VehicleState,
)
from protocol.transport import LocalBus  # noqa: E402

C = "fuzz"

# ----------------------------------------------------------------------------- mutation engine
_NUMBERS: tuple[Any, ...] = (
    0, -0.0, 1, -1, 0.5, -0.5, 5e-324, 1e-308, 1e308, -1e308, 1.7976931348623157e308, math.nan, math.inf, -math.inf,
    2**31, -(2**31), 2**53, 2**53 + 1, 2**63 - 1, -(2**63), 2**64 - 1, 1e16, -1e16, 4 * math.pi + 1e-9, 90.0000001,
    -180.0000001, 15, 16, 255, 256, 65535, 1e6, -1e6, 1e9, 3.0, 100.0)
_OTHERS: tuple[Any, ...] = (
    None, True, False, "", "x" * 65, "y" * 300, "\x00", "../../etc", "é", "av1", "rsu1", "ddm", "*", "a/b",
    b"", b"\x00" * 63, b"\x00" * 64, b"\xff" * 65, [], {}, [1, 2], [1.0, 2.0, 3.0], {"a": 1}, {"kind": "Health"},
    [[0.0, 0.0]], [[1e308, -1e308]] * 3)
_KINDS = tuple(m.KIND for m in MESSAGE_TYPES) + ("", "kind", "Nope")


def _deep(depth: int) -> Any:
    v: Any = 0
    for _ in range(depth):
        v = [v]
    return v


class Mutator:
    """Produces fuzz payloads from seed messages (see the module docstring for the operators)."""

    def __init__(self, rng: random.Random, seeds: list[bytes]) -> None:
        self.rng = rng
        self.seeds = seeds
        self.oversize = b"\x91" + b"\xc0" * (MAX_PAYLOAD_BYTES + 1)

    # -- tree level
    def _paths(self, tree: Any) -> list[tuple]:
        out: list[tuple] = []

        def walk(node: Any, path: tuple, depth: int) -> None:
            out.append(path)
            if depth > 4:
                return
            if isinstance(node, dict):
                for k, v in node.items():
                    walk(v, (*path, k), depth + 1)
            elif isinstance(node, list):
                idx = range(len(node)) if len(node) <= 4 else self.rng.sample(range(len(node)), 4)
                for i in idx:
                    walk(node[i], (*path, i), depth + 1)

        walk(tree, (), 0)
        return out

    @staticmethod
    def _get(tree: Any, path: tuple) -> Any:
        for p in path:
            tree = tree[p]
        return tree

    def _set(self, tree: Any, path: tuple, value: Any) -> Any:
        if not path:
            return value
        try:  # an earlier mutation of this round may have replaced the parent
            self._get(tree, path[:-1])[path[-1]] = value
        except (KeyError, IndexError, TypeError):
            pass
        return tree

    def _value_like(self, old: Any) -> Any:
        r = self.rng
        if isinstance(old, bool):
            return r.choice((not old, 0, 1, None))
        if isinstance(old, int):
            return r.choice((old + r.randint(-3, 3), old * r.choice((-1, 2, 1000)), r.getrandbits(r.choice((8, 32, 53))),
                             r.choice(_NUMBERS)))
        if isinstance(old, float):
            return r.choice((old * r.choice((-1.0, 0.0, 1e3, 1e-3, 1e6, 1e300)), old + r.gauss(0.0, 50.0),
                             r.uniform(-1e4, 1e4), r.choice(_NUMBERS)))
        if isinstance(old, str):
            return r.choice((old + "x", old[:-1], old * r.randint(2, 40), "".join(r.choice("abc-_.é/* \x00")
                                                                                  for _ in range(r.randint(0, 80)))))
        if isinstance(old, bytes):
            return bytes(r.getrandbits(8) for _ in range(r.choice((0, 63, 64, 65, 200))))
        return r.choice(_OTHERS + _NUMBERS)

    def mutate_tree(self, tree: Any) -> Any:
        r = self.rng
        paths = self._paths(tree)
        for _ in range(r.choice((1, 1, 1, 2, 3, 4))):
            path = r.choice(paths)
            try:
                old = self._get(tree, path)
            except (KeyError, IndexError, TypeError):
                continue
            op = r.random()
            if op < 0.35:
                tree = self._set(tree, path, self._value_like(old))
            elif op < 0.55:
                tree = self._set(tree, path, r.choice(_NUMBERS + _OTHERS))
            elif op < 0.65 and isinstance(old, list) and old:
                cap = r.choice((len(old) * 2, MAX_OBJECTS + 1, MAX_WAYPOINTS + 1, MAX_ACTORS + 1, 5000))
                tree = self._set(tree, path, [r.choice(old)] * cap)  # shared items: packed as copies
            elif op < 0.72 and path:
                try:
                    parent = self._get(tree, path[:-1])
                except (KeyError, IndexError, TypeError):
                    continue
                if isinstance(parent, dict):
                    parent.pop(path[-1], None)
                elif isinstance(parent, list) and parent:
                    parent.pop(path[-1] if path[-1] < len(parent) else -1)
            elif op < 0.78 and isinstance(old, dict):
                old[r.choice(("extra", "auth", "kind", "v", "x" * 70, "seq"))] = r.choice(_NUMBERS + _OTHERS)
            elif op < 0.84 and isinstance(tree, dict):
                tree[r.choice(("kind", "v"))] = r.choice(_KINDS + (0, 2, -1, None, 1))
            elif op < 0.88:
                tree = self._set(tree, path, _deep(r.choice((20, 200, 2000))))
            elif op < 0.94 and isinstance(old, list) and old:
                tree = self._set(tree, path, old[: r.randint(0, len(old))])
            else:
                tree = self._set(tree, path, self._value_like(old))
        return tree

    def tree_payload(self, mutate: bool = True) -> bytes:
        seed = self.rng.choice(self.seeds)
        if not mutate:
            return seed
        tree = msgpack.unpackb(seed, raw=False)  # a fresh tree (faster than deepcopy)
        if mutate:
            tree = self.mutate_tree(tree)
        try:
            return msgpack.packb(tree, use_bin_type=True)
        except (OverflowError, ValueError, TypeError):
            return self.rng.choice(self.seeds)

    # -- byte level
    def byte_payload(self) -> bytes:
        r = self.rng
        data = bytearray(r.choice(self.seeds))
        op = r.random()
        if op < 0.3:
            for _ in range(r.randint(1, 8)):
                if data:
                    i = r.randrange(len(data))
                    data[i] ^= 1 << r.randrange(8)
        elif op < 0.45:
            del data[r.randrange(len(data) + 1):]
        elif op < 0.6:
            i = r.randrange(len(data) + 1)
            data[i:i] = bytes(r.getrandbits(8) for _ in range(r.randint(1, 16)))
        elif op < 0.7:
            other = r.choice(self.seeds)
            data = data[: r.randrange(len(data) + 1)] + other[r.randrange(len(other) + 1):]
        elif op < 0.8:
            data = bytearray(r.getrandbits(8) for _ in range(r.choice((0, 1, 2, 5, 17, 100, 1000))))
        elif op < 0.83:
            return self.oversize
        elif op < 0.9:
            data += bytes(r.getrandbits(8) for _ in range(r.randint(1, 8)))  # trailing bytes
        else:
            i = r.randrange(len(data) + 1)
            data[i:i] = bytes([r.choice((0xDC, 0xDD, 0xDE, 0xDF, 0xC9, 0xC6, 0xDB))]) + b"\xff\xff\xff\xff"
        return bytes(data)

    def __call__(self) -> bytes:
        p = self.rng.random()
        if p < 0.12:
            return self.tree_payload(mutate=False)  # valid: keeps the handler's state realistic
        if p < 0.72:
            return self.tree_payload()
        return self.byte_payload()


# ----------------------------------------------------------------------------- targets
@dataclass
class Result:
    name: str
    inputs: int = 0
    accepted: int = 0
    """Inputs that decoded (decoders) / reached the handler (services)."""
    rejected: int = 0
    crashes: int = 0
    crash_samples: list[str] = field(default_factory=list)
    mean_us: float = 0.0
    max_us: float = 0.0
    rss_growth_kb: float = 0.0
    traced_peak_kb: float | None = None
    traced_growth_kb: float | None = None
    """With ``--tracemalloc``: Python/numpy memory still allocated at the end minus at 10 % of the run."""
    state: dict[str, int] = field(default_factory=dict)
    seconds: float = 0.0


def _rss_kb() -> float:
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 1024.0
    except OSError:  # not Linux
        import resource
        return float(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)


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

    def sizes(self) -> dict[str, int]:
        return {}


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
        self.after()
        return self.bus.stats.received != before_rx

    def after(self) -> None:
        pass


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
        try:
            tree = msgpack.unpackb(payload, raw=False)
        except Exception:  # noqa: BLE001 - undecodable input: any key will do
            return None
        kind = tree.get("kind") if isinstance(tree, dict) else None
        matching = self._keys_by_kind.get(kind) if isinstance(kind, str) else None
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
        return {"tracks": w.track_count, "track_slots": int(len(w.alive)), "alerts": len(w.alerts),
                "vehicles": len(w.vehicles), "rsus": len(w.rsu_ids), "bindings": sum(len(m) for m in w._maps),
                "bind_seen": sum(len(m) for m in w._bind_seen), "responses": len(s.responses),
                "rollback": len(s._rollback), "commands_current": len(s.commands.current),
                "command_events": len(s.commands.events), "decision_latencies": len(s.decision_latency_ms),
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
        if self.rng.random() < 0.3:  # keep stamps near the DDM's clock so lists are not simply too old
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
            tree = msgpack.unpackb(encode(ack), raw=False)
            if self.rng.random() < 0.5:
                tree = self.mutator.mutate_tree(tree)
            try:
                return msgpack.packb(tree, use_bin_type=True)
            except (OverflowError, ValueError, TypeError):
                return encode(ack)
        return super().payload()

    def _keys(self) -> list[str]:
        return [keys.vehicle_key(C, "av1", "ack")]

    def _odd_keys(self) -> list[str]:
        return [keys.vehicle_key(C, "av2", "ack")]


# -- vehicle
class VehicleTarget(_BusTarget):
    """A VehicleService (signatures on: the corridor trusts one DDM key) stepped 10 ms (one control
    step) every second input; a fresh car every 4,000 inputs (20 s: the 500 m corridor ends)."""

    key = ""

    def __init__(self, rng: random.Random, localisation: str = "gnss") -> None:
        from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

        from protocol.security import Signer, public_key_b64

        private = Ed25519PrivateKey.generate()
        self.signer = Signer("ddm-fuzz", private)
        self.corridor = dataclasses.replace(_corridor(), trust=(
            {"key_id": "ddm-fuzz", "role": "ddm", "public_key": public_key_b64(private.public_key())},))
        self.localisation = localisation
        self.retired: dict[str, int] = {}
        self._new_car()
        super().__init__(rng)

    def _new_car(self) -> None:
        from vehicle.service import VehicleService

        self.bus, self.clock = LocalBus(), SimClock(1000.0)
        self.svc = VehicleService(self.bus, self.clock, self.corridor, "av1", localisation=self.localisation)
        self.n_car = 0

    def after(self) -> None:
        self.n_car += 1
        if self.n_car % 2:
            return
        self.svc.step(self.clock.now())
        self.clock.advance(0.01)
        if self.n_car % 200 == 0:
            self.bus.publish(keys.ddm_health_key(C), Health(src="ddm", stamp=self.clock.now(), role=Role.DDM))
        if self.n_car >= 4000:
            for k, v in self.sizes().items():
                self.retired[k] = max(self.retired.get(k, 0), v)
            self.svc.close()
            self._new_car()

    def _keys(self) -> list[str]:
        return [self.key]

    def sizes(self) -> dict[str, int]:
        s = self.svc
        return {"inbox": len(s._inbox), "acks_sent": len(s.acks_sent), "book_decisions": len(s.sim.core.book._decisions),
                "replay_seen": len(s.gate.replay._seen), "replay_seq": len(s.gate.replay._newest_seq),
                "max_over_cars_book_decisions": self.retired.get("book_decisions", 0),
                "max_over_cars_replay_seen": self.retired.get("replay_seen", 0)}


class VehicleCmdTarget(VehicleTarget):
    name = "vehicle_on_cmd"

    def __init__(self, rng: random.Random) -> None:
        self.key = keys.vehicle_key(C, "av1", "cmd")
        super().__init__(rng)

    def _command(self, manoeuvre: Manoeuvre) -> PathSwitchCommand:
        """A command for where the car is now (paths re-planned every 20 inputs: 13 cm of driving each)."""
        self.seq = getattr(self, "seq", 0) + 1
        now = self.clock.now()
        cache = getattr(self, "_cache", {})
        base = cache.get(manoeuvre)
        if base is None or self.seq - base[0] >= 20:
            base = cache[manoeuvre] = (self.seq, self._plan(manoeuvre))
            self._cache = cache
        return base[1].model_copy(update={"command_id": f"ddm-av1-{self.seq}", "command_seq": self.seq, "stamp": now,
                                          "issued_at": now, "valid_until": now + 10.0})

    def _plan(self, manoeuvre: Manoeuvre) -> PathSwitchCommand:
        from vehicle.reference import lane_change_waypoints

        road = self.corridor.road
        t = self.svc.sim.truth
        s_car = road.to_frenet(t.x_m, t.y_m)[0]
        now = self.clock.now()
        if manoeuvre == Manoeuvre.RESUME:
            wp: list = []
            stop = None
        else:
            wp = [(float(x), float(y)) for x, y in lane_change_waypoints(road, s_car + 5.0, 1, 0, 40.0, 120.0, lead_m=8.0)]
            sx, sy, _ = road.pose_at(s_car + 90.0, road.lane_centre_offset_m(0))
            stop = (float(sx), float(sy))
        return PathSwitchCommand(
            src="ddm", stamp=now, command_id="ddm-av1-0", command_seq=0, vehicle_id="av1",
            manoeuvre=manoeuvre, reason="fuzz", target_lane=0, waypoints=wp,
            speed_profile_mps=[max(0.0, 13.4 - 0.1 * i) for i in range(len(wp))], target_speed_mps=13.4,
            stop_point=stop, issued_at=now, valid_until=now + 10.0)

    def seeds(self) -> list[bytes]:
        return [encode(self._command(m)) for m in (Manoeuvre.PULL_OVER, Manoeuvre.RESUME, Manoeuvre.STOP_IN_LANE)]

    def payload(self) -> bytes:
        r = self.rng
        if r.random() < 0.75:  # from a command made for where the car is now
            cmd = self._command(r.choice((Manoeuvre.PULL_OVER, Manoeuvre.PULL_OVER, Manoeuvre.RESUME,
                                          Manoeuvre.SLOW_IN_LANE, Manoeuvre.LANE_CHANGE)))
            tree = msgpack.unpackb(encode(cmd), raw=False)
            if r.random() < 0.85:
                tree = self.mutator.mutate_tree(tree)
            try:
                p = msgpack.packb(tree, use_bin_type=True)
            except (OverflowError, ValueError, TypeError):
                return encode(cmd)
            if r.random() < 0.5:  # signed after mutation: passes the gate, the command book must cope
                try:
                    m = decode(p, PathSwitchCommand)
                    p = encode(self.signer.sign_message(self.key, m.model_copy(update={"auth": None})))
                except ProtocolError:
                    pass
            return p
        return super().payload()


class VehicleRsuTarget(VehicleTarget):
    name = "vehicle_on_rsu"

    def __init__(self, rng: random.Random) -> None:
        self.key = keys.rsu_key(C, "rsu1", "objects")
        super().__init__(rng, localisation="both")

    def seeds(self) -> list[bytes]:
        return [encode(object_list(n, 1000.0)) for n in (1, 3, 12)]

    def payload(self) -> bytes:
        if self.rng.random() < 0.5:  # an object list that holds the car itself (RSU fix)
            t = self.svc.sim.truth
            ol = object_list(2, self.clock.now())
            o = ol.objects[0]
            ol = ol.model_copy(update={"objects": [dataclasses.replace(o, pos_x_m=t.x_m + self.rng.gauss(0, 1),
                                                                       pos_y_m=t.y_m + self.rng.gauss(0, 1)),
                                                   ol.objects[1]],
                                       "measurement_time": self.clock.now() - self.rng.uniform(-0.5, 2.0)})
            tree = msgpack.unpackb(encode(ol), raw=False)
            if self.rng.random() < 0.7:
                tree = self.mutator.mutate_tree(tree)
            try:
                return msgpack.packb(tree, use_bin_type=True)
            except (OverflowError, ValueError, TypeError):
                return encode(ol)
        return super().payload()

    def _odd_keys(self) -> list[str]:
        return [keys.rsu_key(C, "rsu2", "ev"), keys.rsu_key(C, "rsu3", "health"), f"iea/{C}/rsu/rsu1/bogus"]


class VehicleDdmHealthTarget(VehicleTarget):
    name = "vehicle_on_ddm_health"

    def __init__(self, rng: random.Random) -> None:
        self.key = keys.ddm_health_key(C)
        super().__init__(rng)

    def seeds(self) -> list[bytes]:
        return [encode(m) for k, m in example_messages(C, stamp=1000.0) if k == self.key]


# -- simulator and RSU side
class SimStateTarget(_BusTarget):
    name = "sim_on_state"

    def __init__(self, rng: random.Random) -> None:
        from sim.scenario import load_scenario
        from sim.service import SimService

        self.bus, self.clock = LocalBus(), SimClock(10.0)
        self.scenario = load_scenario("rellis_ev_yield")
        self.svc = SimService(self.scenario, self.bus, self.clock, corridor_id=C, seed=1)
        self.rejections_before = 0
        self.n = 0
        super().__init__(rng)

    def seeds(self) -> list[bytes]:
        return [encode(m) for k, m in example_messages(C, stamp=10.0) if k.endswith("/state")]

    def _keys(self) -> list[str]:
        return [keys.vehicle_key(C, "av1", "state")]

    def _odd_keys(self) -> list[str]:
        return [keys.vehicle_key(C, "ghost", "state")]

    def feed(self, payload: bytes) -> bool:
        before = self.svc.rejected["unknown_vehicle"]
        got = super().feed(payload)
        return got and self.svc.rejected["unknown_vehicle"] == before

    def after(self) -> None:
        self.n += 1
        if self.n % 10 == 0:
            self.clock.advance(0.05)
            self.svc.step_once()
        if self.n % 20000 == 0:  # the scenario is finite: start it again
            from sim.world import World
            self.svc.world = World(self.scenario, seed=1)

    def sizes(self) -> dict[str, int]:
        return {"pending_states": len(self.svc._pending_states), "last_state": len(self.svc._last_state),
                "actors": len(self.svc.world.snapshot(0.0).actors)}


class RsuSnapshotTarget(_BusTarget):
    """The RSU's only peer input (``--source sim``): world snapshots, rendered every 200th input."""

    name = "rsu_sim_camera"

    def __init__(self, rng: random.Random) -> None:
        from sim.camera_source import SimCamera

        self.bus = LocalBus()
        self.camera = SimCamera(_corridor(), "rsu1", transport=self.bus, seed=0)
        self.n = 0
        super().__init__(rng)
        for seed in self.mutator.seeds:  # warm the renderer's caches before memory is measured
            self.camera.render(decode(seed))

    def seeds(self) -> list[bytes]:
        return [encode(m) for k, m in example_messages(C, stamp=1.0) if k.endswith("/world")]

    def _keys(self) -> list[str]:
        return [keys.sim_world_key(C)]

    def after(self) -> None:
        self.n += 1
        if self.n % 200 == 0 and self.camera._latest is not None:
            self.camera.render(self.camera._latest)

    def sizes(self) -> dict[str, int]:
        return {"snapshots_held": int(self.camera._latest is not None)}


def all_targets() -> dict[str, Callable[[random.Random], Target]]:
    out: dict[str, Callable[[random.Random], Target]] = {}
    for kind in MESSAGE_TYPES:
        out[f"decode_{kind.KIND}"] = lambda rng, k=kind: DecodeTarget(rng, k)
    out.update({
        "transport_localbus": TransportTarget, "ddm_on_rsu": DdmRsuTarget, "ddm_on_vehicle_state": DdmStateTarget,
        "ddm_on_ack": DdmAckTarget, "vehicle_on_cmd": VehicleCmdTarget, "vehicle_on_rsu": VehicleRsuTarget,
        "vehicle_on_ddm_health": VehicleDdmHealthTarget, "sim_on_state": SimStateTarget,
        "rsu_sim_camera": RsuSnapshotTarget,
    })
    return out


# ----------------------------------------------------------------------------- runner
def run_target(name: str, factory: Callable[[random.Random], Target], n: int, seed: int = 0,
               trace: bool = False, max_samples: int = 5) -> Result:
    import logging

    logging.getLogger().setLevel(logging.CRITICAL)  # handler errors are counted, not printed
    rng = random.Random(f"{seed}-{name}")
    target = factory(rng)
    res = Result(name)
    gc.collect()
    if trace:
        tracemalloc.start()
    rss_mark = None
    traced_mark = 0
    total_ns = 0
    t_start = time.perf_counter()
    for i in range(n):
        if i == n // 10:
            gc.collect()
            rss_mark = _rss_kb()
            if trace:
                traced_mark = tracemalloc.get_traced_memory()[0]
        payload = target.payload()
        t0 = time.perf_counter_ns()
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # numpy overflow warnings on 1e308 inputs are not crashes
                ok = target.feed(payload)
        except Exception as exc:  # noqa: BLE001 - a crash: record it and go on
            ok = False
            res.crashes += 1
            if len(res.crash_samples) < max_samples:
                tb = traceback.format_exception(exc)[-3:]
                res.crash_samples.append(f"{type(exc).__name__}: {exc} | payload {payload[:80]!r} | {''.join(tb)[-600:]}")
            if isinstance(target, _BusTarget):  # keep counting per input
                target.bus.stats.handler_errors = 0
        dt = time.perf_counter_ns() - t0
        total_ns += dt
        res.max_us = max(res.max_us, dt / 1000.0)
        res.inputs += 1
        res.accepted += bool(ok)
    res.rejected = res.inputs - res.accepted
    res.seconds = time.perf_counter() - t_start
    res.mean_us = total_ns / max(1, n) / 1000.0
    payload = b""  # the last input (up to 512 kB) is not state the target kept
    gc.collect()
    res.rss_growth_kb = _rss_kb() - (rss_mark if rss_mark is not None else _rss_kb())
    if trace:
        current, peak = tracemalloc.get_traced_memory()
        res.traced_peak_kb, res.traced_growth_kb = peak / 1024.0, (current - traced_mark) / 1024.0
        tracemalloc.stop()
    res.state = target.sizes()
    return res


def run(n: int, names: list[str] | None = None, seed: int = 0, trace: bool = False,
        say: Callable[[str], None] = print) -> dict[str, Any]:
    targets = all_targets()
    names = names or list(targets)
    unknown = [x for x in names if x not in targets]
    if unknown:
        raise SystemExit(f"unknown targets {unknown}; known: {', '.join(targets)}")
    results = []
    say(f"{'target':<24}{'inputs':>9}{'reached':>9}{'crashes':>8}{'mean_us':>9}{'max_us':>10}{'rss_kb':>9}  "
        "state sizes at the end")
    for name in names:
        r = run_target(name, targets[name], n, seed, trace)
        results.append(r)
        state = " ".join(f"{k}={v}" for k, v in r.state.items())
        say(f"{name:<24}{r.inputs:>9}{r.accepted:>9}{r.crashes:>8}{r.mean_us:>9.1f}{r.max_us:>10.0f}"
            f"{r.rss_growth_kb:>9.0f}  {state}" + (f" traced_peak_kb={r.traced_peak_kb:.0f} "
                                                      f"traced_growth_kb={r.traced_growth_kb:.0f}" if trace else ""))
        for s in r.crash_samples:
            say(f"    crash: {s}")
    return {
        "fuzz_inputs": sum(r.inputs for r in results),
        "fuzz_crashes": sum(r.crashes for r in results),
        "fuzz_inputs_per_target": n,
        "fuzz_targets": len(results),
        "fuzz_max_rss_growth_kb": max((r.rss_growth_kb for r in results), default=0.0),
        "fuzz_max_traced_growth_kb": max((r.traced_growth_kb for r in results if r.traced_growth_kb is not None),
                                         default=None),
        "fuzz_seconds": round(sum(r.seconds for r in results), 1),
        "targets": {r.name: dataclasses.asdict(r) for r in results},
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=100_000, help="inputs per target (default 100,000)")
    ap.add_argument("--quick", action="store_true", help="2,000 inputs per target")
    ap.add_argument("--targets", default=None, help="comma-separated subset (default: all)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--tracemalloc", action="store_true", help="also trace Python allocations (slower)")
    ap.add_argument("--json", action="store_true", help="last line: one JSON object of the figures")
    args = ap.parse_args(argv)
    n = 2000 if args.quick else args.n
    out = run(n, args.targets.split(",") if args.targets else None, args.seed, args.tracemalloc)
    print(f"fuzz: {out['fuzz_inputs']} inputs over {out['fuzz_targets']} targets, {out['fuzz_crashes']} crashes, "
          f"max RSS growth {out['fuzz_max_rss_growth_kb']:.0f} kB, {out['fuzz_seconds']:.0f} s")
    if args.json:
        print(json.dumps(out))
    return 1 if out["fuzz_crashes"] else 0


if __name__ == "__main__":
    raise SystemExit(main())
