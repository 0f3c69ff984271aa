"""What an RSU sends fits its uplink: bulk (object lists, camera frames) is thinned, alerts never are.

An RSU on a thin backhaul (a cellular or radio link of tens of kbit/s) that publishes object lists at the
camera's rate fills every buffer between it and its router: Zenoh's batches, the socket's send buffer, the link's
queue. An EvAlert published then waits behind all of it, whatever its priority: a priority orders Zenoh's own
queues, not the bytes already handed to the kernel (the network lab's 16 kbit/s row, with RSUs not told their
uplink: no EvAlert gets through in 20 s).

``UplinkBudget`` is a token bucket over the bytes the RSU sends (a leaky-bucket shaper, RFC 2697's single-rate
form): it fills at ``share`` of the uplink's rate up to ``burst_s`` of it. Bulk goes out only when the bucket
is not in debt (``allow``; its bytes may take it there) and the message fits the bucket's depth (a camera frame
of 30 kB never goes on a 16 kbit/s link), else the RSU skips it (the next object list replaces it); alerts and
health always go out and take their bytes from the bucket (``spend``), so bulk waits after them.
Kept under ``share`` of the rate the link's queues stay empty and an alert crosses it in its own transmission
time. Every message is counted with ``PER_MESSAGE_OVERHEAD_B`` for Zenoh's framing and the TCP/IP headers.
"""

from __future__ import annotations

import math
import threading
from typing import Any

from protocol.clock import Clock
from protocol.qos import BULK, OBJECTS, qos_for_key
from protocol.transport import Subscription, Transport

DEFAULT_SHARE = 0.5
"""The fraction of the uplink's rate bulk may use on average (the rest is headroom for alerts, retransmissions,
Zenoh's own traffic)."""
DEFAULT_BURST_S = 2.0
"""The bucket's depth in seconds of its fill (an object list of 2 kB still fits at 16 kbit/s)."""
PER_MESSAGE_OVERHEAD_B = 80
"""Zenoh framing plus IPv4 and TCP headers (with timestamps) per message, bytes."""


def validate_uplink_bit_s(rate_bit_s: float | None) -> float | None:
    """``rate_bit_s`` as a positive finite bit rate (None: no budget); ValueError naming the problem."""
    if rate_bit_s is None:
        return None
    rate = float(rate_bit_s)
    if not math.isfinite(rate) or rate < 1000.0:
        raise ValueError(f"uplink rate {rate_bit_s} bit/s: expected a rate of at least 1000 bit/s (e.g. 16000 for "
                         "a 16 kbit/s backhaul), or no budget at all")
    return rate


class UplinkBudget:
    """Token bucket of ``share`` x ``rate_bit_s`` / 8 bytes per second, ``burst_s`` of it deep (starts full)."""

    def __init__(self, rate_bit_s: float, share: float = DEFAULT_SHARE, burst_s: float = DEFAULT_BURST_S) -> None:
        rate = validate_uplink_bit_s(rate_bit_s)
        if not 0.0 < share <= 1.0:
            raise ValueError(f"uplink share must be in (0, 1], got {share}")
        if burst_s <= 0.0:
            raise ValueError(f"burst must be positive, got {burst_s} s")
        self.rate_bit_s = rate
        self.fill_b_per_s = share * rate / 8.0
        self.depth_b = self.fill_b_per_s * burst_s
        self.tokens_b = self.depth_b
        self._t_s: float | None = None
        self.skipped = 0
        """Bulk messages left out."""
        self.skipped_b = 0

    def _refill(self, now_s: float) -> None:
        if self._t_s is not None and now_s > self._t_s:
            self.tokens_b = min(self.depth_b, self.tokens_b + (now_s - self._t_s) * self.fill_b_per_s)
        if self._t_s is None or now_s > self._t_s:
            self._t_s = now_s

    def spend(self, payload_b: int, now_s: float) -> None:
        """A message that goes out whatever the budget (an alert, health): its bytes are taken, debt allowed."""
        self._refill(now_s)
        self.tokens_b -= payload_b + PER_MESSAGE_OVERHEAD_B

    def allow(self, payload_b: int, now_s: float) -> bool:
        """Whether a bulk message of ``payload_b`` bytes may go out now: the bucket is not in debt and the message
        fits its depth (its bytes are then taken); a refusal is counted in ``skipped``."""
        self._refill(now_s)
        need = payload_b + PER_MESSAGE_OVERHEAD_B
        if self.tokens_b > 0.0 and need <= self.depth_b:
            self.tokens_b -= need
            return True
        self.skipped += 1
        self.skipped_b += payload_b
        return False


def is_bulk_key(key: str) -> bool:
    """Whether a message on ``key`` is bulk the RSU may leave out (object lists, camera frames, anything that
    Zenoh itself may drop under congestion: ``protocol.qos`` kinds ``OBJECTS`` and ``BULK``)."""
    return qos_for_key(key) in (OBJECTS, BULK)


class ShapedTransport(Transport):
    """``inner`` with an ``UplinkBudget`` on what is published: bulk beyond the budget is left out (counted in
    ``budget.skipped``), everything else goes out and is counted against it. Bulk on a key nobody subscribes to
    is not counted (Zenoh sends a publication only where a subscriber matches). Closing it closes ``inner``."""

    def __init__(self, inner: Transport, budget: UplinkBudget, clock: Clock) -> None:
        self.inner = inner
        self.stats = inner.stats
        self._stats_lock = getattr(inner, "_stats_lock", threading.Lock())
        self.budget = budget
        self.clock = clock

    def publish_bytes(self, key: str, payload: bytes) -> None:
        now = self.clock.now()
        if is_bulk_key(key):
            if not self.inner.wait_for_subscribers(key, 0.0):  # nobody listens: nothing goes on the link
                self.inner.publish_bytes(key, payload)
                return
            if not self.budget.allow(len(payload), now):
                return
        else:
            self.budget.spend(len(payload), now)
        self.inner.publish_bytes(key, payload)

    def subscribe_bytes(self, key_expr: str, callback: Any) -> Subscription:
        return self.inner.subscribe_bytes(key_expr, callback)

    def close(self) -> None:
        self.inner.close()
