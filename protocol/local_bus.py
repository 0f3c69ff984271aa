"""``LocalBus``: an in-process transport with Zenoh's key-expression semantics (``protocol.transport``'s interface).

Delivery is synchronous and ordered (a publish delivers before it returns), which makes it the bus of the tests and
of the lockstep runner, where one clock steps every service.
"""

from __future__ import annotations

import itertools
import threading

from protocol.keys import KeyError_, key_matches
from protocol.transport import BytesCallback, PresenceCallback, QueryHandler, Subscription, Transport


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
