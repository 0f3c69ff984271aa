"""Swappable transports (DESIGN.md "Transports").

One small interface, ``publish(key, message)`` / ``subscribe(key_expr, callback) -> handle`` /
``close()``, and three implementations:

- ``ZenohTransport``: eclipse-zenoh 1.x; peer mode on loopback by default (multicast scouting on
  ``lo``, no router needed), client mode against routers with ``connect``.
- ``LocalBus``: in-process and synchronous (a publish delivers before it returns), with the same
  key-expression matching as Zenoh; for tests and the lockstep runner.
- ``DsrcLink``: wraps any transport with a seeded radio channel model (``protocol/channel.py``):
  latency + jitter, independent and bursty loss, range, bandwidth, scheduled outages.

Every transport decodes strictly (``protocol.codec``) before a callback sees a message: bad input is
counted in ``stats.rejected`` by reason and dropped; an exception raised by a callback is counted
and logged, never propagated into the transport's thread.
"""

from __future__ import annotations

import argparse
import heapq
import itertools
import json
import logging
import os
import threading
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

from protocol.channel import ChannelModel, ChannelState
from protocol.clock import Clock, WallClock
from protocol.codec import ProtocolError, decode, encode
from protocol.keys import KeyError_, key_matches, message_type_for_key
from protocol.messages import Envelope

log = logging.getLogger(__name__)

MessageCallback = Callable[[str, Envelope], None]
BytesCallback = Callable[[str, bytes], None]
RejectCallback = Callable[[str, Exception], None]


@dataclass
class TransportStats:
    published: int = 0
    received: int = 0
    rejected: Counter = field(default_factory=Counter)
    """Inputs dropped at the boundary, by reason (``format``, ``invalid``, ``kind``, ``key``...)."""
    handler_errors: int = 0


class Subscription:
    def __init__(self, close_fn: Callable[[], None]) -> None:
        self._close_fn: Callable[[], None] | None = close_fn

    def close(self) -> None:
        if self._close_fn is not None:
            fn, self._close_fn = self._close_fn, None
            fn()


class Transport:
    """Base class: subclasses move bytes (``publish_bytes`` / ``subscribe_bytes``)."""

    def __init__(self) -> None:
        self.stats = TransportStats()
        self._stats_lock = threading.Lock()

    # -- bytes level (implemented by subclasses)
    def publish_bytes(self, key: str, payload: bytes) -> None:
        raise NotImplementedError

    def subscribe_bytes(self, key_expr: str, callback: BytesCallback) -> Subscription:
        raise NotImplementedError

    def close(self) -> None:
        pass

    # -- message level
    def publish(self, key: str, message: Envelope) -> None:
        """Encode and publish; the key must carry this message's kind."""
        expected = message_type_for_key(key)
        if type(message) is not expected:
            raise ProtocolError(f"key {key!r} carries {expected.KIND}, not {type(message).__name__}", "kind")
        self.publish_bytes(key, encode(message))
        with self._stats_lock:
            self.stats.published += 1

    def subscribe(
        self, key_expr: str, callback: MessageCallback, on_reject: RejectCallback | None = None
    ) -> Subscription:
        """Deliver every valid message under ``key_expr`` as ``callback(key, message)``."""

        def on_bytes(key: str, payload: bytes) -> None:
            try:
                message = decode(payload, message_type_for_key(key))
            except (ProtocolError, KeyError_) as exc:
                reason = exc.reason if isinstance(exc, ProtocolError) else "key"
                with self._stats_lock:
                    self.stats.rejected[reason] += 1
                log.debug("rejected input on %s: %s", key, exc)
                if on_reject is not None:
                    on_reject(key, exc)
                return
            with self._stats_lock:
                self.stats.received += 1
            try:
                callback(key, message)
            except Exception:  # a handler bug must not kill the transport thread
                with self._stats_lock:
                    self.stats.handler_errors += 1
                log.exception("handler for %s failed", key)

        return self.subscribe_bytes(key_expr, on_bytes)

    def __enter__(self) -> Transport:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


# ---------------------------------------------------------------------- in-process
class LocalBus(Transport):
    """In-process bus with Zenoh key-expression semantics; delivery is synchronous and ordered."""

    def __init__(self) -> None:
        super().__init__()
        self._subs: dict[int, tuple[str, BytesCallback]] = {}
        self._ids = itertools.count()
        self._lock = threading.Lock()
        self._closed = False

    def publish_bytes(self, key: str, payload: bytes) -> None:
        if self._closed:
            raise RuntimeError("LocalBus is closed")
        if "*" in key or "$" in key:
            raise KeyError_(f"cannot publish on a key expression with wildcards: {key!r}")
        with self._lock:
            targets = [cb for expr, cb in self._subs.values() if key_matches(expr, key)]
        for cb in targets:
            cb(key, bytes(payload))

    def subscribe_bytes(self, key_expr: str, callback: BytesCallback) -> Subscription:
        with self._lock:
            sid = next(self._ids)
            self._subs[sid] = (key_expr, callback)

        def close() -> None:
            with self._lock:
                self._subs.pop(sid, None)

        return Subscription(close)

    def close(self) -> None:
        with self._lock:
            self._subs.clear()
        self._closed = True


# ---------------------------------------------------------------------- zenoh
ENV_MODE = "IEA_ZENOH_MODE"
ENV_CONNECT = "IEA_ZENOH_CONNECT"
ENV_LISTEN = "IEA_ZENOH_LISTEN"
ENV_CONFIG = "IEA_ZENOH_CONFIG"


@dataclass
class ZenohSettings:
    """How a service joins Zenoh. Precedence: CLI flags > environment > config file > defaults."""

    mode: str = "peer"
    connect: list[str] = field(default_factory=list)
    listen: list[str] = field(default_factory=list)
    config_file: str | None = None
    multicast_interface: str = "lo"
    """Scouting stays on loopback unless told otherwise (peer mode, no router needed)."""

    def __post_init__(self) -> None:
        if self.mode not in ("peer", "client", "router"):
            raise ValueError(f"zenoh mode must be peer, client or router, got {self.mode!r}")
        for ep in [*self.connect, *self.listen]:
            if "/" not in ep:
                raise ValueError(f"zenoh endpoint {ep!r} must look like tcp/127.0.0.1:7447")
        if self.mode == "client" and not self.connect:
            raise ValueError("zenoh client mode needs --connect tcp/HOST:PORT (a router to join)")

    @staticmethod
    def add_arguments(parser: argparse.ArgumentParser) -> None:
        g = parser.add_argument_group("transport (Zenoh)")
        g.add_argument("--connect", action="append", metavar="ENDPOINT", default=None,
                       help="join a Zenoh router, e.g. tcp/127.0.0.1:7447 (repeatable; implies --mode client "
                            f"unless --mode is given). Env: {ENV_CONNECT} (comma-separated)")
        g.add_argument("--listen", action="append", metavar="ENDPOINT", default=None,
                       help=f"also listen on this endpoint (repeatable). Env: {ENV_LISTEN}")
        g.add_argument("--mode", choices=["peer", "client"], default=None,
                       help=f"Zenoh session mode (default: peer on loopback, client with --connect). Env: {ENV_MODE}")
        g.add_argument("--zenoh-config", metavar="FILE", default=None,
                       help=f"a Zenoh JSON5 config file applied before the flags. Env: {ENV_CONFIG}")

    @classmethod
    def from_args(cls, args: argparse.Namespace, env: dict[str, str] | None = None) -> ZenohSettings:
        env = dict(os.environ) if env is None else env
        split = lambda v: [x.strip() for x in v.split(",") if x.strip()]  # noqa: E731
        connect = args.connect if args.connect else split(env.get(ENV_CONNECT, ""))
        listen = args.listen if args.listen else split(env.get(ENV_LISTEN, ""))
        mode = args.mode or env.get(ENV_MODE) or ("client" if connect else "peer")
        config_file = args.zenoh_config or env.get(ENV_CONFIG) or None
        if config_file and not os.path.isfile(config_file):
            raise ValueError(f"zenoh config file {config_file!r} does not exist")
        return cls(mode=mode, connect=connect, listen=listen, config_file=config_file)

    def to_config(self) -> Any:
        import zenoh

        conf = zenoh.Config.from_file(self.config_file) if self.config_file else zenoh.Config()
        conf.insert_json5("mode", json.dumps(self.mode))
        if self.connect:
            conf.insert_json5("connect/endpoints", json.dumps(self.connect))
        if self.listen:
            conf.insert_json5("listen/endpoints", json.dumps(self.listen))
        elif self.mode == "peer" and not self.config_file:
            conf.insert_json5("listen/endpoints", json.dumps(["tcp/127.0.0.1:0"]))
        if self.mode == "peer" and not self.config_file and self.multicast_interface:
            conf.insert_json5("scouting/multicast/interface", json.dumps(self.multicast_interface))
        return conf


class ZenohTransport(Transport):
    """eclipse-zenoh 1.x session. Publishers are declared once per key and publish in express mode."""

    def __init__(self, settings: ZenohSettings | None = None) -> None:
        super().__init__()
        import zenoh

        self._zenoh = zenoh
        self.settings = settings or ZenohSettings()
        self.session = zenoh.open(self.settings.to_config())
        self._publishers: dict[str, Any] = {}
        self._subs: list[Any] = []
        self._lock = threading.Lock()
        self._closed = False

    def publish_bytes(self, key: str, payload: bytes) -> None:
        pub = self._publishers.get(key)
        if pub is None:
            with self._lock:
                pub = self._publishers.get(key)
                if pub is None:
                    pub = self.session.declare_publisher(
                        key,
                        congestion_control=self._zenoh.CongestionControl.DROP,
                        express=True,
                    )
                    self._publishers[key] = pub
        pub.put(payload)

    def subscribe_bytes(self, key_expr: str, callback: BytesCallback) -> Subscription:
        def on_sample(sample: Any) -> None:
            try:
                callback(str(sample.key_expr), sample.payload.to_bytes())
            except Exception:  # never raise into zenoh's thread
                log.exception("subscriber callback on %s failed", key_expr)

        sub = self.session.declare_subscriber(key_expr, on_sample)
        with self._lock:
            self._subs.append(sub)

        def close() -> None:
            with self._lock:
                if sub in self._subs:
                    self._subs.remove(sub)
            try:
                sub.undeclare()
            except Exception:  # session may already be closed
                pass

        return Subscription(close)

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        for sub in list(self._subs):
            try:
                sub.undeclare()
            except Exception:
                pass
        self._subs.clear()
        for pub in self._publishers.values():
            try:
                pub.undeclare()
            except Exception:
                pass
        self._publishers.clear()
        self.session.close()


# ---------------------------------------------------------------------- emulated radio
class DsrcLink(Transport):
    """A radio link in front of any transport (the DSRC / SmartConnect stand-in).

    Outgoing messages (``tx``) and incoming ones (``rx``) pass through a seeded ``ChannelModel``:
    each is dropped or delayed as the model says and delivered in order. With a ``WallClock`` a
    background thread delivers due messages; with a ``SimClock`` the lockstep runner calls
    ``deliver_due()`` after advancing the clock. ``position`` gives this node's (x, y) for the
    range check against ``peers`` (radio positions, e.g. the RSUs).
    """

    def __init__(
        self,
        inner: Transport,
        channel: ChannelModel,
        *,
        seed: int = 0,
        clock: Clock | None = None,
        directions: Sequence[str] = ("tx", "rx"),
        position: Callable[[], tuple[float, float] | None] | None = None,
        peers: Sequence[tuple[float, float]] = (),
        threaded: bool | None = None,
    ) -> None:
        super().__init__()
        bad = set(directions) - {"tx", "rx"}
        if bad:
            raise ValueError(f"directions must be 'tx' and/or 'rx', got {sorted(bad)}")
        self.inner = inner
        self.channel = channel
        self.clock = clock or WallClock()
        self.directions = frozenset(directions)
        self.state = {d: ChannelState(channel, seed=seed * 2 + (d == "rx")) for d in ("tx", "rx")}
        self._position = position
        self._peers = list(peers)
        self._queue: list[tuple[float, int, Callable[[], None]]] = []
        self._order = itertools.count()
        self._cv = threading.Condition()
        self._closed = False
        self._thread: threading.Thread | None = None
        if threaded if threaded is not None else isinstance(self.clock, WallClock):
            self._thread = threading.Thread(target=self._run, name="dsrc-link", daemon=True)
            self._thread.start()

    @property
    def counts(self) -> dict[str, Counter]:
        """Per direction: ``offered``, ``delivered`` and ``dropped_<reason>`` counts."""
        return {d: s.counts for d, s in self.state.items()}

    def _distance_m(self) -> float | None:
        if self._position is None or not self._peers:
            return None
        pos = self._position()
        if pos is None:
            return None
        return min(((pos[0] - px) ** 2 + (pos[1] - py) ** 2) ** 0.5 for px, py in self._peers)

    def _enqueue(self, direction: str, size: int, deliver: Callable[[], None]) -> None:
        if direction not in self.directions:
            deliver()
            return
        now = self.clock.now()
        with self._cv:
            at = self.state[direction].admit(now, size, self._distance_m())
            if at is None:
                return
            if at <= now and not self._queue:
                pass  # deliver inline below, outside the lock
            else:
                heapq.heappush(self._queue, (at, next(self._order), deliver))
                self._cv.notify()
                return
        deliver()

    def deliver_due(self, now: float | None = None) -> int:
        """Deliver every queued message whose time has come; returns how many."""
        now = self.clock.now() if now is None else now
        n = 0
        while True:
            with self._cv:
                if not self._queue or self._queue[0][0] > now:
                    return n
                _, _, deliver = heapq.heappop(self._queue)
            deliver()
            n += 1

    def pending(self) -> int:
        with self._cv:
            return len(self._queue)

    def next_due(self) -> float | None:
        """Delivery time of the earliest queued message (None when none is queued): a lockstep
        scheduler advances its clock to it."""
        with self._cv:
            return self._queue[0][0] if self._queue else None

    def _run(self) -> None:
        while True:
            with self._cv:
                if self._closed:
                    return
                if not self._queue:
                    self._cv.wait(0.5)
                    continue
                wait = self._queue[0][0] - self.clock.now()
                if wait > 0:
                    self._cv.wait(min(wait, 0.5))
                    continue
            self.deliver_due()

    def publish_bytes(self, key: str, payload: bytes) -> None:
        self._enqueue("tx", len(payload), lambda: self.inner.publish_bytes(key, payload))

    def subscribe_bytes(self, key_expr: str, callback: BytesCallback) -> Subscription:
        def on_bytes(key: str, payload: bytes) -> None:
            self._enqueue("rx", len(payload), lambda: callback(key, payload))

        return self.inner.subscribe_bytes(key_expr, on_bytes)

    def close(self) -> None:
        with self._cv:
            self._closed = True
            self._cv.notify_all()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
