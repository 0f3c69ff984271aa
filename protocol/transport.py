"""Swappable transports (docs/architecture.md §Transports).

One small interface, ``publish(key, message)`` / ``subscribe(key_expr, callback) -> handle`` /
``close()``, and three implementations:

- ``ZenohTransport`` (``protocol.zenoh_transport``, the only module that imports zenoh): eclipse-zenoh 1.x;
  peer mode on loopback by default (multicast scouting on ``lo``, no router needed), client mode against
  routers with ``connect``.
- ``LocalBus`` (``protocol.local_bus``): in-process and synchronous (a publish delivers before it returns), with
  the same key-expression matching as Zenoh; for tests and the lockstep runner.
- ``DsrcLink`` (``protocol.radio``): wraps any transport with a seeded radio channel model: latency + jitter,
  independent and bursty loss, range, bandwidth, scheduled outages.

Beyond publish/subscribe, the same interface carries Zenoh's other primitives, so the
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

import logging
import threading
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field

from protocol import metrics
from protocol.codec import ProtocolError, decode, encode
from protocol.keys import KeyError_, message_type_for_key
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
