"""Acting on an EvAlert the car hears itself when its command is late. Pure.

The DDM decides; the car only follows its commands. But when the command path to the car is cut (a
command-link outage: the RSUs' broadcasts still reach it) the DDM's pull-over arrives after the EV. The
car then acts on its own, on evidence it can trust, and only when it must:

- the alert is **signed** by an RSU key of the corridor's trust list (the service verifies it: an
  unsigned corridor never moves a car this way, nor does an unsigned or forged alert);
- the EV is **behind the car in the car's own lane** (Frenet s, d on the corridor's road), driving on at
  the alert's speed since the alert's stamp;
- **nothing from the DDM** since the first such alert of this approach, for ``command_deadline_s``: no
  command and no signed heartbeat (the DDM answers an alert within about 0.13 s over Zenoh, median:
  a command later than the deadline is late; a DDM heard alive after the alert that sends nothing is waiting
  on purpose, for a gap in lane 0); and the car is cruising (a DDM manoeuvre is never overridden);
- the EV will come within its **following distance** of the car (2 m + 1 s x its speed, the yield
  judge's reach, ``scenario/outcome.py``) within ``reach_horizon_s``: an EV far behind or not closing
  leaves the DDM time; the DDM may be holding the car at speed on purpose (a car beside it in lane 0).

The manoeuvre is the fail-safe's stop at the curb (``VehicleCore.direct_pull_over``), holding the speed
over the lane change (braking while an EV closes in the car's lane brings it on sooner) and only when the
car's picture shows the curb side free from ``curb_check_behind_m`` behind it (unsigned object lists
may keep a car where it is, never move it). A car that cannot move over keeps driving.
"""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class DirectAlertConfig:
    enabled: bool = True
    command_deadline_s: float = 0.3
    """No command accepted this long after the first signed alert of an approach: the command is late."""
    reach_horizon_s: float = 5.0
    """Act only when the EV would reach the car's following distance within this (at the speeds now)."""
    following_gap_m: float = 2.0
    following_time_s: float = 1.0
    ev_length_m: float = 6.5
    """The EV's body length (an EvAlert gives its centre only): a fire engine's, the longest assumed."""
    alert_max_age_s: float = 1.5
    """An alert older than this (three missed 2 Hz repeats) no longer counts."""
    episode_gap_s: float = 3.0
    """No signed alert for this long ends an approach: the next one starts a new deadline."""
    lat_accel_mps2: float = 3.0
    """Lateral acceleration of the pull-over's lane change (the DDM's urgent_lat_accel_mps2)."""
    curb_check_behind_m: float = 25.0
    """The curb side must be free from this far behind the car (a car in lane 0 closing at 5 m/s moves 15 m
    during a 3 s lane change; the fail-safe's own check looks 10 m back)."""

    def __post_init__(self) -> None:
        if not (self.command_deadline_s >= 0 and self.reach_horizon_s > 0 and self.alert_max_age_s > 0
                and self.episode_gap_s > 0 and self.lat_accel_mps2 > 0 and self.curb_check_behind_m >= 0):
            raise ValueError(f"direct-alert deadlines, horizon, ages and lateral acceleration must be > 0: {self}")


@dataclass(frozen=True, slots=True)
class HeardAlert:
    """A verified EvAlert as the car keeps it: where the EV was, when, how fast, and who said so."""

    stamp_s: float
    x_m: float
    y_m: float
    vel_x_mps: float
    vel_y_mps: float
    rsu_id: str


def time_to_reach_s(gap_m: float, ev_speed_mps: float, car_speed_mps: float, cfg: DirectAlertConfig) -> float:
    """Seconds until an EV ``gap_m`` behind (bumper to bumper) is within its following distance of the car
    at constant speeds: (gap - (following_gap + following_time x v_ev)) / (v_ev - v_car); 0 when it is
    already within it, inf when it is not closing."""
    room = gap_m - (cfg.following_gap_m + cfg.following_time_s * max(ev_speed_mps, 0.0))
    if room <= 0:
        return 0.0
    closing = ev_speed_mps - car_speed_mps
    return room / closing if closing > 1e-6 else math.inf


def act_on_alert(alert: HeardAlert, now_s: float, road, car_pose: tuple[float, float, float], car_speed_mps: float,
                 car_length_m: float, first_alert_s: float, last_ddm_heard_s: float | None, cruising: bool,
                 cfg: DirectAlertConfig = DirectAlertConfig()) -> str | None:
    """Why the car should pull over on its own now (see the module docstring), or None.

    ``first_alert_s``: when this approach's first signed alert was heard; ``last_ddm_heard_s``: when the car
    last heard the DDM (a command that passed its gate or a signed heartbeat; None: never); ``cruising``: the
    car is in DRIVING mode."""
    if not cfg.enabled or not cruising:
        return None
    if now_s - first_alert_s < cfg.command_deadline_s:
        return None
    if last_ddm_heard_s is not None and last_ddm_heard_s > first_alert_s:
        return None  # the DDM was heard during this approach: it is in charge
    age = now_s - alert.stamp_s
    if age > cfg.alert_max_age_s:
        return None
    x, y, _ = car_pose
    s_car, d_car = (float(v) for v in road.to_frenet(x, y))
    ex, ey = alert.x_m + alert.vel_x_mps * max(age, 0.0), alert.y_m + alert.vel_y_mps * max(age, 0.0)
    s_ev, d_ev = (float(v) for v in road.to_frenet(ex, ey))
    lane_car, lane_ev = road.lane_of_offset(d_car), road.lane_of_offset(d_ev)
    if lane_car is None or lane_ev != lane_car or s_ev >= s_car:
        return None  # not in the car's lane, or not behind it
    gap = s_car - s_ev - (car_length_m + cfg.ev_length_m) / 2.0
    v_ev = math.hypot(alert.vel_x_mps, alert.vel_y_mps)
    t_reach = time_to_reach_s(gap, v_ev, car_speed_mps, cfg)
    if t_reach > cfg.reach_horizon_s:
        return None
    return (f"signed EvAlert from {alert.rsu_id}: EV {gap:.0f} m behind in lane {lane_car}, {v_ev:.1f} m/s, "
            f"within its following distance in {t_reach:.1f} s; nothing from the DDM {now_s - first_alert_s:.2f} s "
            f"after the first alert (deadline {cfg.command_deadline_s:.2f} s)")
