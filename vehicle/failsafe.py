"""Fail-safe watchdog (pure): when to give up on the plan and stop in lane (minimal-risk manoeuvre).

Triggers, checked every control step:
- ``link_lost``: in a commanded manoeuvre and neither a command nor a DDM health message has been
  heard for ``link_timeout_s`` (the DDM that steers the car may be gone);
- ``localisation_stale``: the newest position fix was measured more than ``localisation_stale_s``
  ago (dead reckoning drifts; the car should not keep driving on it).
Once triggered the watchdog latches: the car stops in its lane and stays stopped until the cause
has cleared and a new command is accepted (``clear``).
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class FailsafeConfig:
    link_timeout_s: float = 3.5
    """No command or DDM Health (1 Hz) for this long during a manoeuvre: minimal-risk stop. Three missed
    heartbeats and a half: a single lost Health on a lossy radio must not stop the car."""
    localisation_stale_s: float = 1.0
    mrm_decel_mps2: float = 2.5
    """Deceleration of the minimal-risk stop (comfortable, below the 3 m/s^2 cap)."""

    def __post_init__(self) -> None:
        if not (self.link_timeout_s > 0 and self.localisation_stale_s > 0 and self.mrm_decel_mps2 > 0):
            raise ValueError(f"fail-safe timeouts and deceleration must be > 0: {self}")


class Watchdog:
    def __init__(self, config: FailsafeConfig = FailsafeConfig()) -> None:
        self.config = config
        self.last_link_s: float | None = None
        self.reason: str | None = None
        """Why the minimal-risk manoeuvre is active (None: not active)."""
        self.triggered_at_s: float | None = None

    def link_seen(self, now_s: float) -> None:
        """A command or a DDM health message arrived."""
        self.last_link_s = now_s if self.last_link_s is None else max(self.last_link_s, now_s)

    def check(self, now_s: float, in_manoeuvre: bool, localisation_age_s: float) -> str | None:
        """Return the active fail-safe reason (latched), triggering it when a condition holds."""
        if self.reason is None:
            c = self.config
            if localisation_age_s > c.localisation_stale_s:
                self._trigger(now_s, f"localisation stale: newest fix {localisation_age_s:.2f} s old "
                                     f"(limit {c.localisation_stale_s} s)")
            elif in_manoeuvre:
                silent = None if self.last_link_s is None else now_s - self.last_link_s
                if silent is None or silent > c.link_timeout_s:
                    heard = "never" if silent is None else f"{silent:.2f} s ago"
                    self._trigger(now_s, f"link lost: no command or DDM health for {heard} "
                                         f"(limit {c.link_timeout_s} s) during a manoeuvre")
        return self.reason

    def healthy(self, now_s: float, localisation_age_s: float) -> str | None:
        """Why the car cannot take a new command now (None when it can)."""
        if localisation_age_s > self.config.localisation_stale_s:
            return f"localisation stale: newest fix {localisation_age_s:.2f} s old"
        return None

    def _trigger(self, now_s: float, reason: str) -> None:
        self.reason, self.triggered_at_s = reason, now_s

    def clear(self) -> None:
        self.reason, self.triggered_at_s = None, None
