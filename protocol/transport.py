"""Swappable transports (DESIGN.md "Transports").

One small interface, ``publish(key, message)`` / ``subscribe(key_expr, callback) -> handle`` /
``close()``, and three implementations:

- ``ZenohTransport`` (``protocol.zenoh_transport``, the only module that imports zenoh): eclipse-zenoh 1.x;
  peer mode on loopback by default (multicast scouting on ``lo``, no router needed), client mode against
  routers with ``connect``.
- ``LocalBus``: in-process and synchronous (a publish delivers before it returns), with the same
  key-expression matching as Zenoh; for tests and the lockstep runner.
- ``DsrcLink``: wraps any transport with a seeded radio channel model (``protocol/channel.py``):
  latency + jitter, independent and bursty loss, range, bandwidth, scheduled outages.

Beyond publish/subscribe (issue 21), the same interface carries Zenoh's other primitives, so the
services use them without knowing the transport:

- presence: ``declare_token(key)`` (a liveliness token, gone when the session is) and
  ``subscribe_presence(key_expr, callback(key, alive), history=True)``;
- state: ``declare_queryable(key_expr, handler(query_expr) -> [(key, payload)])`` and
  ``query_bytes(key_expr, timeout_s)`` / ``query(key_expr, timeout_s)`` (decoded replies);
- QoS: every publication gets the priority / congestion control / express of its kind
  (``protocol.qos.qos_for_key``; ``ZenohTransport(qos=...)`` overrides it). On the receiving side a
  subscription to a bulk kind only (``.../objects``, ``.../world``) is delivered by a worker thread
  from a bounded ring (newest kept, ``bulk_queue`` samples): the network thread never decodes bulk, so
  a command queued behind a flood of snapshots is delivered at once.

Wrappers with an ``inner`` transport (``DsrcLink``, ``protocol.security.SecureTransport``) pass presence
and queries to it unchanged: the radio model applies to the data streams only.

Every transport decodes strictly (``protocol.codec``) before a callback sees a message: bad input is
counted in ``stats.rejected`` by reason and dropped; an exception raised by a callback is counted
and logged, never propagated into the transport's thread.
"""

from __future__ import annotations

import heapq
import itertools
import logging
import threading
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

from protocol import metrics
from protocol.channel import ChannelModel, ChannelState
from protocol.clock import Clock, WallClock
from protocol.codec import ProtocolError, decode, encode
from protocol.keys import KeyError_, key_matches, message_type_for_key
from protocol.messages import Envelope

log = logging.getLogger(__name__)

MessageCallback = Callable[[str, Envelope], None]
BytesCallback = Callable[[str, bytes], None]
RejectCallback = Callable[[str, Exception], None]
PresenceCallback = Callable[[str, bool], None]
"""``callback(token_key, alive)``: a liveliness token appeared (True) or was lost (False)."""
QueryHandler = Callable[[str], list[tuple[str, bytes]]]
"""``handler(query_key_expr) -> [(concrete_key, payload)]``: the replies to one query."""


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

    # -- presence and queries (wrappers pass them to ``inner``)
    def _inner(self, what: str) -> Transport:
        inner = getattr(self, "inner", None)
        if not isinstance(inner, Transport):
            raise NotImplementedError(f"{type(self).__name__} does not implement {what}")
        return inner

    def declare_token(self, key: str) -> Subscription:
        """Declare a liveliness token on concrete ``key``; ``close()`` withdraws it."""
        return self._inner("declare_token").declare_token(key)

    def subscribe_presence(self, key_expr: str, callback: PresenceCallback, *, history: bool = True) -> Subscription:
        """``callback(key, alive)`` for every token under ``key_expr`` that appears or is lost; with
        ``history`` the tokens alive now are reported first."""
        return self._inner("subscribe_presence").subscribe_presence(key_expr, callback, history=history)

    def query_presence(self, key_expr: str, timeout_s: float = 1.0) -> list[str]:
        """The liveliness tokens alive now under ``key_expr`` (a liveliness query)."""
        return self._inner("query_presence").query_presence(key_expr, timeout_s)

    def wait_for_subscribers(self, key: str, timeout_s: float) -> bool:
        """Block until a subscriber matching concrete ``key`` is known to this transport, or ``timeout_s``;
        True when one is. A transport that delivers to whoever subscribed at publish time (LocalBus) has
        nothing to wait for; wrappers ask ``inner``."""
        inner = getattr(self, "inner", None)
        return inner.wait_for_subscribers(key, timeout_s) if isinstance(inner, Transport) else True

    def declare_queryable(self, key_expr: str, handler: QueryHandler) -> Subscription:
        """Answer queries intersecting ``key_expr`` with ``handler(query_expr)``'s (key, payload) pairs."""
        return self._inner("declare_queryable").declare_queryable(key_expr, handler)

    def query_bytes(self, key_expr: str, timeout_s: float = 1.0) -> list[tuple[str, bytes]]:
        """Every reply to a query on ``key_expr``; returns when all queryables answered or at ``timeout_s``."""
        return self._inner("query_bytes").query_bytes(key_expr, timeout_s)

    def query(self, key_expr: str, timeout_s: float = 1.0) -> list[tuple[str, Envelope]]:
        """``query_bytes`` decoded strictly by key (as ``subscribe`` does); bad replies are counted in
        ``stats.rejected`` and left out."""
        out = []
        for key, payload in self.query_bytes(key_expr, timeout_s):
            try:
                out.append((key, decode(payload, message_type_for_key(key))))
            except (ProtocolError, KeyError_) as exc:
                with self._stats_lock:
                    self.stats.rejected[exc.reason if isinstance(exc, ProtocolError) else "key"] += 1
                log.debug("rejected reply on %s: %s", key, exc)
        return out

    def answer_latest(self, key_expr: str, latest: Callable[[], list[tuple[str, Envelope]]]) -> Subscription:
        """A queryable answering with the encoded messages ``latest()`` returns (latest Health, objects...)."""
        return self.declare_queryable(key_expr, lambda _q: [(k, encode(m)) for k, m in latest()])

    # -- message level
    def publish(self, key: str, message: Envelope) -> None:
        """Encode and publish; the key must carry this message's kind."""
        expected = message_type_for_key(key)
        if type(message) is not expected:
            raise ProtocolError(f"key {key!r} carries {expected.KIND}, not {type(message).__name__}", "kind")
        self.publish_bytes(key, encode(message))
        with self._stats_lock:
            self.stats.published += 1
        metrics.on_published(key, message)  # a no-op unless the process serves metrics (--metrics-port)

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
                metrics.on_rejected(key, reason)
                log.debug("rejected input on %s: %s", key, exc)
                if on_reject is not None:
                    on_reject(key, exc)
                return
            with self._stats_lock:
                self.stats.received += 1
            metrics.on_received(key, message)
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
        self._tokens: dict[int, str] = {}
        self._presence: dict[int, tuple[str, PresenceCallback]] = {}
        self._queryables: dict[int, tuple[str, QueryHandler]] = {}
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

    def _register(self, table: dict, entry: tuple) -> Subscription:
        """``entry`` in ``table`` under a fresh id until the returned subscription is closed."""
        with self._lock:
            rid = next(self._ids)
            table[rid] = entry

        def close() -> None:
            with self._lock:
                table.pop(rid, None)

        return Subscription(close)

    def subscribe_bytes(self, key_expr: str, callback: BytesCallback) -> Subscription:
        return self._register(self._subs, (key_expr, callback))

    def declare_token(self, key: str) -> Subscription:
        if "*" in key or "$" in key:
            raise KeyError_(f"a liveliness token needs a concrete key, got {key!r}")
        with self._lock:
            tid = next(self._ids)
            self._tokens[tid] = key
        self._notify_presence(key, True)

        def close() -> None:
            with self._lock:
                gone = self._tokens.pop(tid, None)
            if gone is not None:
                self._notify_presence(gone, False)

        return Subscription(close)

    def _notify_presence(self, key: str, alive: bool) -> None:
        with self._lock:
            targets = [cb for expr, cb in self._presence.values() if key_matches(expr, key)]
        for cb in targets:
            cb(key, alive)

    def subscribe_presence(self, key_expr: str, callback: PresenceCallback, *, history: bool = True) -> Subscription:
        with self._lock:
            sid = next(self._ids)
            self._presence[sid] = (key_expr, callback)
            alive = sorted({k for k in self._tokens.values() if key_matches(key_expr, k)}) if history else []
        for k in alive:
            callback(k, True)

        def close() -> None:
            with self._lock:
                self._presence.pop(sid, None)

        return Subscription(close)

    def query_presence(self, key_expr: str, timeout_s: float = 1.0) -> list[str]:
        with self._lock:
            return sorted({k for k in self._tokens.values() if key_matches(key_expr, k)})

    def declare_queryable(self, key_expr: str, handler: QueryHandler) -> Subscription:
        return self._register(self._queryables, (key_expr, handler))

    def query_bytes(self, key_expr: str, timeout_s: float = 1.0) -> list[tuple[str, bytes]]:
        with self._lock:
            handlers = [h for _, h in self._queryables.values()]
        out = []
        for h in handlers:  # every queryable sees the query and answers the keys it has that match it
            out.extend((k, bytes(p)) for k, p in h(key_expr) if key_matches(key_expr, k))
        return out

    def close(self) -> None:
        with self._lock:
            self._subs.clear()
            self._presence.clear()
            self._queryables.clear()
            self._tokens.clear()
        self._closed = True


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
