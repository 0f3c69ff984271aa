"""The emulated radio: a seeded channel model (pure: no threads, no clocks) and ``DsrcLink``, the transport that
puts it in front of any other transport (the DSRC / SmartConnect stand-in).

A message offered at time ``now`` is, in this order: dropped during a scheduled outage; dropped when
the node is beyond ``range_m`` of every peer radio; dropped by the bursty Gilbert-Elliott chain
(two states, good and bad, each with its own loss probability; Gilbert 1960, Elliott 1963); dropped
by independent Bernoulli loss; queued behind earlier messages at ``bandwidth_bps`` (dropped if the
queue would hold it longer than ``max_queue_s``); then delivered after ``latency_s`` plus a
half-normal jitter of scale ``jitter_s``, never before an earlier message (radios do not reorder).

Defaults stand for DSRC (docs/architecture.md §Radio model): a few ms latency, 300 m range, 6 Mb/s.
"""

from __future__ import annotations

import heapq
import itertools
import math
import random
import threading
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

from protocol.clock import Clock, WallClock
from protocol.transport import BytesCallback, Subscription, Transport


@dataclass(frozen=True)
class GilbertElliott:
    """Two-state Markov loss: per message, good->bad with ``p_good_to_bad``, bad->good with ``p_bad_to_good``."""

    p_good_to_bad: float
    p_bad_to_good: float
    loss_good: float = 0.0
    loss_bad: float = 1.0

    def __post_init__(self) -> None:
        for name in ("p_good_to_bad", "p_bad_to_good", "loss_good", "loss_bad"):
            v = getattr(self, name)
            if not 0.0 <= v <= 1.0:
                raise ValueError(f"GilbertElliott.{name} must be a probability in [0, 1], got {v}")
        if self.p_good_to_bad + self.p_bad_to_good == 0:
            raise ValueError("GilbertElliott needs p_good_to_bad + p_bad_to_good > 0")

    @property
    def bad_fraction(self) -> float:
        return self.p_good_to_bad / (self.p_good_to_bad + self.p_bad_to_good)

    @property
    def mean_loss(self) -> float:
        """Stationary loss probability."""
        pb = self.bad_fraction
        return pb * self.loss_bad + (1 - pb) * self.loss_good

    @property
    def mean_burst_length(self) -> float:
        """Mean number of consecutive messages spent in the bad state."""
        return 1.0 / self.p_bad_to_good if self.p_bad_to_good > 0 else math.inf

    @classmethod
    def from_mean(cls, mean_loss: float, mean_burst_length: float) -> GilbertElliott:
        """Bursts of total loss (loss_bad = 1) with the given stationary loss and mean burst length."""
        if not 0.0 < mean_loss < 1.0:
            raise ValueError(f"mean_loss must be in (0, 1), got {mean_loss}")
        if mean_burst_length < 1.0:
            raise ValueError(f"mean_burst_length must be >= 1 message, got {mean_burst_length}")
        r = 1.0 / mean_burst_length
        p = r * mean_loss / (1.0 - mean_loss)
        return cls(p_good_to_bad=min(p, 1.0), p_bad_to_good=r)


@dataclass(frozen=True)
class ChannelModel:
    latency_s: float = 0.0
    jitter_s: float = 0.0
    loss: float = 0.0
    """Independent per-message loss probability."""
    burst: GilbertElliott | None = None
    range_m: float | None = None
    bandwidth_bps: float | None = None
    max_queue_s: float = 1.0
    outages: tuple[tuple[float, float], ...] = ()
    """Windows (start_s, end_s) of total loss, on the link's clock."""

    def __post_init__(self) -> None:
        for name in ("latency_s", "jitter_s", "max_queue_s"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise ValueError(f"ChannelModel.{name} must be a finite number >= 0, got {v}")
        if not 0.0 <= self.loss <= 1.0:
            raise ValueError(f"ChannelModel.loss must be a probability in [0, 1], got {self.loss}")
        if self.range_m is not None and not self.range_m > 0:
            raise ValueError(f"ChannelModel.range_m must be > 0, got {self.range_m}")
        if self.bandwidth_bps is not None and not self.bandwidth_bps > 0:
            raise ValueError(f"ChannelModel.bandwidth_bps must be > 0, got {self.bandwidth_bps}")
        for start, end in self.outages:
            if not end > start:
                raise ValueError(f"outage ({start}, {end}) must end after it starts")

    @classmethod
    def dsrc(cls, **overrides: object) -> ChannelModel:
        """Typical DSRC: 3 ms +- 1 ms, 300 m range, 6 Mb/s, 1% loss."""
        base: dict[str, object] = dict(latency_s=0.003, jitter_s=0.001, loss=0.01, range_m=300.0, bandwidth_bps=6e6)
        base.update(overrides)
        return cls(**base)  # type: ignore[arg-type]

    @property
    def expected_loss(self) -> float:
        """Loss from the random parts of the model (not range, outages or bandwidth)."""
        keep = 1.0 - self.loss
        if self.burst is not None:
            keep *= 1.0 - self.burst.mean_loss
        return 1.0 - keep


@dataclass
class ChannelState:
    """The running state of one direction of one link."""

    model: ChannelModel
    seed: int = 0
    counts: Counter = field(default_factory=Counter)
    _bad: bool = False
    _busy_until: float = -math.inf
    _last_at: float = -math.inf

    def __post_init__(self) -> None:
        self._rng = random.Random(self.seed)

    def admit(self, now: float, size_bytes: int, distance_m: float | None = None) -> float | None:
        """Delivery time for a message offered now, or None if the channel drops it."""
        m, rng = self.model, self._rng
        self.counts["offered"] += 1
        if any(start <= now < end for start, end in m.outages):
            self.counts["dropped_outage"] += 1
            return None
        if m.range_m is not None and distance_m is not None and distance_m > m.range_m:
            self.counts["dropped_range"] += 1
            return None
        if m.burst is not None:
            ge = m.burst
            if self._bad:
                self._bad = rng.random() >= ge.p_bad_to_good
            else:
                self._bad = rng.random() < ge.p_good_to_bad
            if rng.random() < (ge.loss_bad if self._bad else ge.loss_good):
                self.counts["dropped_burst"] += 1
                return None
        if m.loss > 0 and rng.random() < m.loss:
            self.counts["dropped_loss"] += 1
            return None
        start = now
        if m.bandwidth_bps is not None:
            start = max(now, self._busy_until)
            if start - now > m.max_queue_s:
                self.counts["dropped_bandwidth"] += 1
                return None
            self._busy_until = start + size_bytes * 8.0 / m.bandwidth_bps
            start = self._busy_until
        at = start + m.latency_s + (abs(rng.gauss(0.0, m.jitter_s)) if m.jitter_s > 0 else 0.0)
        at = max(at, self._last_at)
        self._last_at = at
        self.counts["delivered"] += 1
        return at

    @property
    def dropped(self) -> int:
        return sum(v for k, v in self.counts.items() if k.startswith("dropped_"))


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
