"""Presence by liveliness tokens: who is up in the corridor, learned from Zenoh itself.

Every service declares the token ``iea/{c}/alive/{role}/{id}`` for as long as it runs (``announce``);
Zenoh withdraws it when the service's session ends, cleanly or not (a killed process closes its TCP
link and the router or peer drops its declarations at once; a silent link after the session lease).
A watcher (``watch``) hears each appearance and loss, and ``PresenceBook`` (pure) keeps the picture.
Health messages stay for rates and counters; presence does not wait for their timeout.

The helpers accept any ``Transport``; one without presence support (a test double) yields ``None``
and the service falls back to its Health and stream timeouts.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

from protocol.keys import KeyError_, alive_expr, alive_key, parse_alive_key
from protocol.transport import QueryHandler, Subscription, Transport

log = logging.getLogger(__name__)


@dataclass
class PresenceBook:
    """Alive services by role, and when each lost one went (pure; times are the caller's clock)."""

    alive: dict[str, set[str]] = field(default_factory=dict)
    lost_s: dict[tuple[str, str], float] = field(default_factory=dict)
    """(role, id) -> when its token was lost; removed when it comes back."""

    def update(self, key: str, is_alive: bool, now_s: float) -> tuple[str, str, bool] | None:
        """Apply one token event; returns ``(role, id, alive)`` when it changed something, else None."""
        try:
            _, role, node = parse_alive_key(key)
        except KeyError_:
            return None
        ids = self.alive.setdefault(role, set())
        if is_alive:
            if node in ids:
                return None
            ids.add(node)
            self.lost_s.pop((role, node), None)
        else:
            if node not in ids:
                return None
            ids.discard(node)
            self.lost_s[(role, node)] = now_s
        return role, node, is_alive

    def is_alive(self, role: str, node: str) -> bool:
        return node in self.alive.get(role, ())

    def lost(self, role: str) -> dict[str, float]:
        """Services of ``role`` seen alive and then lost (id -> when), and not back since."""
        return {n: t for (r, n), t in self.lost_s.items() if r == role}


def announce(transport: Transport, corridor_id: str, role: str, node_id: str) -> Subscription | None:
    """Declare this service's liveliness token (None when the transport has no presence)."""
    try:
        return transport.declare_token(alive_key(corridor_id, role, node_id))
    except NotImplementedError:
        log.debug("%s has no liveliness tokens: %s/%s not announced", type(transport).__name__, role, node_id)
        return None


def watch(transport: Transport, corridor_id: str, callback: Callable[[str, bool], None],
          role: str = "*") -> Subscription | None:
    """Subscribe to the tokens of ``role`` (history included: the ones alive now come first)."""
    try:
        return transport.subscribe_presence(alive_expr(corridor_id, role), callback, history=True)
    except NotImplementedError:
        log.debug("%s has no liveliness subscribers", type(transport).__name__)
        return None


class AliveSet:
    """The ids of ``role`` whose tokens are alive now in ``corridor_id``, kept by a watch (history included).
    ``watching`` is False when the transport has no presence; ``close()`` ends the watch."""

    def __init__(self, transport: Transport, corridor_id: str, role: str) -> None:
        self.role = role
        self._ids: set[str] = set()
        self._lock = threading.Lock()
        self._sub = watch(transport, corridor_id, self._on_token, role=role)
        self.watching = self._sub is not None

    def _on_token(self, key: str, is_alive: bool) -> None:
        try:
            _, role, node = parse_alive_key(key)
        except KeyError_:
            return
        if role == self.role:
            with self._lock:
                (self._ids.add if is_alive else self._ids.discard)(node)

    def missing(self, ids: Iterable[str]) -> list[str]:
        """Those of ``ids`` without a live token, sorted."""
        with self._lock:
            return sorted(set(ids) - self._ids)

    def close(self) -> None:
        if self._sub is not None:
            self._sub.close()
            self._sub = None


def wait_for_tokens(transport: Transport, corridor_id: str, role: str, ids: Iterable[str], timeout_s: float,
                    poll_s: float = 0.05) -> list[str] | None:
    """Block until every id of ``ids`` (of ``role``) has a live token, or ``timeout_s``; returns the ids still
    missing ([] when all came), None when the transport has no presence (nothing to wait for)."""
    ids = list(ids)  # looked at on every poll
    alive = AliveSet(transport, corridor_id, role)
    try:
        if not alive.watching:
            return None
        deadline = time.monotonic() + timeout_s
        while (missing := alive.missing(ids)) and time.monotonic() < deadline:
            time.sleep(poll_s)
        return missing
    finally:
        alive.close()


def serve(transport: Transport, key_expr: str, handler: QueryHandler) -> Subscription | None:
    """Declare a queryable (None when the transport has none)."""
    try:
        return transport.declare_queryable(key_expr, handler)
    except NotImplementedError:
        log.debug("%s has no queryables: %s not served", type(transport).__name__, key_expr)
        return None


def close_all(handles: list[Subscription | None]) -> None:
    for h in handles:
        if h is not None:
            h.close()
    handles.clear()
