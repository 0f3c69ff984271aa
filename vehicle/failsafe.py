"""Fail-safe watchdog (pure): when to cap the speed and when to give up on the plan and stop at the curb.

Triggers, checked every control step, in every mode:
- ``degraded`` (not latched): no valid, authenticated DDM heartbeat (its Health, or a command that passed
  the command gate) for ``link_degraded_s``: the car keeps driving but caps its speed at
  ``degraded_speed_mps`` and says so in its VehicleState (``detail``) and Health (status degraded);
  it ends as soon as the DDM is heard again;
- ``link_lost``: silent for ``link_lost_s`` while cruising, or for ``link_degraded_s`` during a commanded
  manoeuvre (the DDM that steers the car may be gone): minimal-risk stop;
- ``localisation_stale``: the newest position fix was measured more than ``localisation_stale_s``
  ago (dead reckoning drifts; the car should not keep driving on it).
The silence is counted from the last heartbeat, or from the first check when none was ever heard.
The minimal-risk stop (``vehicle.core``) steers to the right edge of the road (the shoulder, or the curb
side of the rightmost lane) unless the car's last picture shows that side occupied. Once triggered the
watchdog latches: the car stays stopped until the cause has cleared and a new command is accepted
(``clear``).
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class FailsafeConfig:
    link_timeout_s: float = 3.5
    """No valid DDM heartbeat (Health at 1 Hz, or a command) for this long: degraded while cruising, a
    minimal-risk stop during a manoeuvre. Three missed heartbeats and a half: a single lost Health on a
    lossy radio must not stop the car."""
    link_lost_s: float = 10.0
    """... and for this long while cruising: minimal-risk stop."""
    degraded_speed_mps: float = 8.0
    """Speed cap while degraded (29 km/h: room to stop within 13 m at the comfort deceleration)."""
    localisation_stale_s: float = 1.0
    mrm_decel_mps2: float = 2.5
    """Deceleration of the minimal-risk stop (comfortable, below the 3 m/s^2 cap)."""
    curb_margin_m: float = 0.3
    """The minimal-risk stop leaves this much between the car's right side and the road's right edge."""

    def __post_init__(self) -> None:
        if not (self.link_timeout_s > 0 and self.localisation_stale_s > 0 and self.mrm_decel_mps2 > 0
                and self.link_lost_s >= self.link_timeout_s and self.degraded_speed_mps > 0
                and self.curb_margin_m >= 0):
            raise ValueError(f"fail-safe timeouts, speeds and deceleration must be > 0 and link_lost_s >= "
                             f"link_timeout_s: {self}")

    @property
    def link_degraded_s(self) -> float:
        return self.link_timeout_s


class Watchdog:
    def __init__(self, config: FailsafeConfig = FailsafeConfig()) -> None:
        self.config = config
        self.last_link_s: float | None = None
        self.first_check_s: float | None = None
        self.reason: str | None = None
        """Why the minimal-risk manoeuvre is active (None: not active)."""
        self.triggered_at_s: float | None = None
        self.degraded: str | None = None
        """Why the car is degraded (speed capped) now (None: it is not)."""

    def link_seen(self, now_s: float) -> None:
        """A valid, authenticated DDM heartbeat (Health) or command arrived."""
        self.last_link_s = now_s if self.last_link_s is None else max(self.last_link_s, now_s)

    def silent_s(self, now_s: float) -> float:
        """Seconds since the last heartbeat (since the first check when none was heard)."""
        if self.first_check_s is None:
            self.first_check_s = now_s
        ref = self.last_link_s if self.last_link_s is not None else self.first_check_s
        return max(0.0, now_s - ref)

    def check(self, now_s: float, in_manoeuvre: bool, localisation_age_s: float) -> str | None:
        """Return the active fail-safe reason (latched), triggering it when a condition holds; updates
        ``degraded``."""
        c = self.config
        silent = self.silent_s(now_s)
        heard = "never" if self.last_link_s is None else f"{silent:.2f} s ago"
        self.degraded = None
        if silent > c.link_degraded_s:
            self.degraded = (f"degraded: no DDM heartbeat for {silent:.1f} s (limit {c.link_degraded_s} s), speed "
                             f"capped at {c.degraded_speed_mps} m/s")
        if self.reason is None:
            if localisation_age_s > c.localisation_stale_s:
                self._trigger(now_s, f"localisation stale: newest fix {localisation_age_s:.2f} s old "
                                     f"(limit {c.localisation_stale_s} s)")
            elif in_manoeuvre and silent > c.link_degraded_s:
                self._trigger(now_s, f"link lost: no command or DDM heartbeat, last {heard} "
                                     f"(limit {c.link_degraded_s} s) during a manoeuvre")
            elif silent > c.link_lost_s:
                self._trigger(now_s, f"link lost: no command or DDM heartbeat, last {heard} "
                                     f"(limit {c.link_lost_s} s) while cruising")
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
