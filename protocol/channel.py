"""Seeded radio channel model for ``DsrcLink`` (pure: no threads, no clocks).

A message offered at time ``now`` is, in this order: dropped during a scheduled outage; dropped when
the node is beyond ``range_m`` of every peer radio; dropped by the bursty Gilbert-Elliott chain
(two states, good and bad, each with its own loss probability; Gilbert 1960, Elliott 1963); dropped
by independent Bernoulli loss; queued behind earlier messages at ``bandwidth_bps`` (dropped if the
queue would hold it longer than ``max_queue_s``); then delivered after ``latency_s`` plus a
half-normal jitter of scale ``jitter_s``, never before an earlier message (radios do not reorder).

Defaults stand for DSRC (SPEC.md): a few ms latency, 300 m range, 6 Mb/s.
"""

from __future__ import annotations

import math
import random
from collections import Counter
from dataclasses import dataclass, field


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
