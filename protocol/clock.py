"""Time sources behind one interface: the wall clock for deployment, a stepped clock for lockstep runs.

Services never call ``time`` directly: they take a ``Clock`` so the same code runs in real time over
Zenoh and faster than real time in one process.
"""

from __future__ import annotations

import threading
import time
from typing import Protocol, runtime_checkable


@runtime_checkable
class Clock(Protocol):
    def now(self) -> float:
        """Seconds; message stamps use this."""
        ...

    def sleep(self, duration_s: float) -> None: ...


class WallClock:
    """Real time: UNIX epoch seconds, so stamps compare across processes on synchronised hosts."""

    def now(self) -> float:
        return time.time()

    def sleep(self, duration_s: float) -> None:
        if duration_s > 0:
            time.sleep(duration_s)


class SimClock:
    """A stepped clock: time moves only when the lockstep runner advances it."""

    def __init__(self, start_s: float = 0.0) -> None:
        if start_s < 0:
            raise ValueError(f"start_s must be >= 0, got {start_s}")
        self._t = float(start_s)
        self._lock = threading.Lock()

    def now(self) -> float:
        return self._t

    def advance(self, dt_s: float) -> float:
        if not dt_s >= 0:
            raise ValueError(f"a clock only moves forward; got dt_s={dt_s}")
        with self._lock:
            self._t += dt_s
            return self._t

    def sleep(self, duration_s: float) -> None:
        """Sleeping on a simulated clock advances it (single-threaded lockstep use)."""
        if duration_s > 0:
            self.advance(duration_s)


class RateTimer:
    """Fires at a fixed period on any clock: ``if timer.due(clock.now()): ...``."""

    def __init__(self, period_s: float, start_s: float | None = None) -> None:
        if not period_s > 0:
            raise ValueError(f"period_s must be > 0, got {period_s}")
        self.period_s = period_s
        self._next = start_s

    def due(self, now_s: float) -> bool:
        if self._next is None:
            self._next = now_s + self.period_s
            return True
        if now_s + 1e-9 >= self._next:
            # skip missed periods instead of bursting to catch up
            missed = max(0, int((now_s - self._next) // self.period_s))
            self._next += (missed + 1) * self.period_s
            return True
        return False
