"""DDM configuration: every threshold of fusion, EV response, planning and command delivery, with defaults.

Defaults are chosen for the RELLIS scenario (the thesis's test, ch. 4: AV at 13.4 m/s, EV 50 m behind,
closing at 5-10 m/s) and justified next to each field. CARMA's approaching-emergency-vehicle plugin
(docs/architecture.md §DDM, comparable systems) is the reference; its thresholds are for highway speeds
and are scaled down here where noted.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

from ddm.threat import LX_MAX_M


@dataclass(frozen=True)
class DdmConfig:
    # ------------------------------------------------------------------ fusion (ddm/world.py)
    gate_chi2: float = 9.21
    """Position gate on the normalised innovation (chi-square, 2 dof, 99 %). With the default noise
    a lateral offset of one lane (3.7 m) is outside the gate, so cars in adjacent lanes never merge."""
    gate_speed_mps: float = 4.0
    """Largest velocity difference between a measurement and a track it may join (an opposite-direction
    car passing at the same spot differs by ~2 v and never matches)."""
    velocity_settle_s: float = 1.0
    """An RSU object younger than this (its ``age_s``) is gated on position only: its velocity is still
    converging (the RSU's filter starts at zero speed)."""
    min_pos_var_m2: float = 0.25
    """Floor of the position variance used in gating (RSU-to-RSU calibration bias of ~0.5 m)."""
    vel_meas_var_m2ps2: float = 1.0
    """Variance of an RSU velocity measurement ((m/s)^2): RSU SORT velocities are differenced positions."""
    young_vel_meas_var_m2ps2: float = 100.0
    """... of an object younger than ``velocity_settle_s`` (its filter started at zero speed)."""
    accel_noise_m2ps4: float = 4.0
    """Process noise of the constant-velocity filter (white acceleration, (m/s^2)^2): covers 2 m/s^2 braking."""
    map_gate_m: float = 8.0
    """A known (rsu, object) -> track binding is dropped when the measurement lands farther than this
    from the prediction (an RSU reused an id for another car)."""
    track_timeout_s: float = 1.5
    """A track not updated for this long is deleted (Autoware V2X drops measurements older than 1.5 s);
    it also bounds how long a track coasts across a gap between two RSUs' fields of view."""
    max_measurement_age_s: float = 1.5
    """Object lists whose capture time is older than this on arrival are dropped (Autoware: 1.5 s)."""
    max_future_s: float = 0.5
    """Object lists stamped further ahead than this (clock skew) are rejected."""
    merge_distance_m: float = 2.5
    """Two tracks closer than this with similar velocity and no RSU in common are merged (older id kept)."""
    rsu_stale_s: float = 0.3
    """An RSU whose object stream is silent this long is stale (RSUs publish at 10-15 Hz: 3-4 frames
    missed). With the 20 Hz loop it is marked within 0.35 s (a stale RSU is to be marked within 0.5 s)."""
    rsu_health_stale_s: float = 2.5
    """An RSU whose 1 Hz health is silent this long is stale too (2 missed beats + jitter)."""
    vehicle_gate_m: float = 3.0
    """An autonomous vehicle's reported pose is bound to the nearest track within this distance."""
    vehicle_state_timeout_s: float = 1.0
    """A vehicle whose 20 Hz state is silent this long gets no new decisions (its pose is unknown)."""
    ev_object_hold_s: float = 2.0
    """An object reported ``ev_state=confirmed`` keeps its EV mark this long (RSUs confirm at
    different times; avoids flicker in the overlap)."""
    ev_from_objects_alone: bool = False
    """True: an object list's unsigned EV state marks a track as EV on its own (a forged object list could
    then move a car; kept to measure what the rule costs). False: only on a track an EvAlert has named."""
    ev_alert_timeout_s: float = 5.0
    """An active EvAlert not refreshed for this long is forgotten (alerts repeat at 2 Hz: 10 missed;
    CARMA forgets after 15 s at highway speeds, our corridor is ~10 s of driving)."""

    # ------------------------------------------------------------------ EV response (ddm/policy/ev.py)
    ev_lookbehind_m: float = 200.0
    """Only EVs at most this far behind are considered (2 RSU spans; CARMA's 152.4 m pass margin
    is of the same order)."""
    act_time_to_pass_s: float = 25.0
    """Respond when the EV will reach the AV within this time (CARMA starts at 75 s on highways; at
    50 m and 5-10 m/s closing our EV passes in 5-10 s, so 25 s covers the whole approach)."""
    act_gap_m: float = 80.0
    """... or when it is this close behind whatever its closing speed (Texas 545.156: yield on the
    immediate approach, also to an EV that is not gaining yet: one that just switched its lights on
    is still accelerating, so its time to pass says little)."""
    min_closing_mps: float = 0.5
    """Closing speeds below this count as not closing (time to pass = infinity)."""
    too_late_s: float = 4.0
    """Below this time to pass, no lane change: slow in lane (CARMA: 13 s at highway speed, where a
    change takes longer; ours takes ``lane_change_min_s`` = 3 s at 13.4 m/s, + 1 s margin)."""
    ev_closing_assumed_mps: float = 6.0
    """For timing the stop, an EV closes at least this fast (one that just switched its lights on is
    still accelerating: RELLIS EV 19 m/s vs AV 13.4 m/s)."""
    let_faster_pass: bool = True
    """No safe gap in lane 0 because a faster car is coming by there: keep speed and let it pass, then pull
    over; False: slow in lane for the gap."""
    pull_over_hold_speed: bool = True
    """A pull-over keeps its speed until its lane change is done, then brakes to the stop (an AV that
    brakes while still in the lane of an EV closing from behind brings the EV onto it sooner); False: brake
    from the start."""
    urgent_within_s: float = 8.0
    """With the EV's time to pass below this, a held-speed pull-over steers at ``urgent_lat_accel_mps2``
    without the ``lane_change_min_s`` floor."""
    stop_margin_s: float = 1.0
    """A pull-over aims to be stopped this long before the EV's time to pass (braking harder than
    comfort, up to ``max_decel_mps2``, when the EV is close)."""
    slow_speed_mps: float = 4.47
    """Speed to slow to in lane (CARMA: 4.47 m/s = 10 mph)."""
    pass_margin_m: float = 30.0
    """The pass is done once the EV is this far ahead of the AV (CARMA: 152.4 m at highway speeds;
    30 m is > 1.5 s of EV travel at 20 m/s and two car lengths beyond the AV's own length)."""
    ev_predict_s: float = 10.0
    """An EV lost from view is predicted (at its last speed) for this long before the AV may resume."""
    resume_hold_s: float = 1.5
    """A yielding AV resumes only once no EV has been behind or passing it for this long (RSU tracks
    of two cars side by side can merge or switch for a moment while the EV passes)."""
    min_ev_speed_mps: float = 1.0
    """A slower 'EV' is parked, not approaching (a hazard, not this policy)."""
    same_direction_cos: float = 0.5
    """EV velocity within 60 deg of the road direction counts as the same direction."""
    gap_time_s: float = 1.0
    """Required time headway to the leader and from the follower in the target lane."""
    gap_min_m: float = 6.0
    """Required bumper-to-bumper clearance whatever the speeds (about one car length)."""
    replan_backoff_s: float = 0.5
    """After a rejected or expired command, wait this long before planning anew."""
    relink_gap_s: float = 0.5
    """A vehicle silent this long (20 Hz state) was out of radio reach: heard again with its command still
    unacknowledged, that command is planned again from the car's fresh state."""
    replan_shorter_m: float = 3.0
    """A pull-over is planned anew (a shorter stop) when a vehicle ahead in lane 0 leaves at least this
    much less room than the commanded stop needs (a car the RSUs saw only after the command)."""
    replan_min_speed_mps: float = 1.0
    """... while the AV still moves faster than this (a nearly stopped car has nothing to re-plan)."""

    # ------------------------------------------------------------------ planning (ddm/paths.py)
    comfort_decel_mps2: float = 2.0
    """Deceleration to the stop (<= 3 m/s^2 for comfort; Apollo's pull-over allows 4.5)."""
    max_decel_mps2: float = 3.0
    creep_speed_mps: float = 2.0
    """A pull-over with less room ahead than its lane change needs brakes hard to this speed and creeps on."""
    urgent_lat_accel_mps2: float = 3.0
    """An urgent pull-over (the EV is close) may steer up to this lateral acceleration (the vehicle
    accepts paths up to 4 m/s^2)."""
    max_lat_accel_mps2: float = 2.0
    """Largest lateral acceleration of a commanded path (comfort; curvature limit = a / v^2)."""
    max_curvature_1pm: float = 0.19
    """Vehicle limit: tan(max road-wheel steer 0.5 rad) / wheelbase 2.84 m (the mid-size car of docs/architecture.md §Vehicle controller)."""
    lane_change_min_s: float = 3.0
    """A lane change takes at least this long (its length is at least v * 3 s)."""
    lane_change_min_m: float = 15.0
    curb_clearance_m: float = 0.3
    """Gap kept between the car's side and the curb / lane edge when stopped."""
    stop_on_shoulder: bool = False
    """True: stop on the shoulder when it is at least car width + 2 clearances wide (clears lane 0 too).
    Default: stop at the curb side of lane 0, one lane to the right of the EV's lane (Texas 545.156:
    'as close as possible to the right-hand edge or curb'; the thesis, ch. 4: the car changes one lane
    to the right and stops)."""
    waypoint_step_m: float = 1.0
    path_tail_m: float = 10.0
    """Waypoints continue this far past the stop point (the controller's look-ahead needs them)."""
    resume_length_m: float = 120.0
    resume_accel_mps2: float = 1.5

    # ------------------------------------------------------------------ delivery (ddm/commands.py)
    retransmit_initial_s: float = 0.1
    """First retransmission after 100 ms (one DSRC latency budget), doubling each time ..."""
    retransmit_max_s: float = 0.8
    """... up to this interval."""
    max_attempts: int = 20
    """... and at most this many sends (about 12 s), then the command expires explicitly."""
    command_validity_s: float = 60.0
    """valid_until = issued_at + this (an EV pass takes ~10-30 s)."""
    in_flight_replan_behind_m: float = 10.0
    """An unacknowledged command the car does not report executing, whose path starts this far behind where the
    car is now, is planned again from the car's position (two thirds of the 15 m behind the car that
    ``vehicle.commands.CommandLimits`` still accepts): on a stalled link the retransmissions would arrive with a
    path the car has driven past. A command merely late (its ack on the way) is left alone: the car's state names
    it as active first, or the car is still short of this distance."""

    # ------------------------------------------------------------------ service (ddm/service.py)
    rate_hz: float = 20.0
    health_period_s: float = 1.0
    startup_listen_s: float = 1.0
    """After a (re)start, listen this long before commanding anything (rebuild the picture)."""

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if isinstance(v, bool):
                continue
            if not isinstance(v, int | float) or v != v or v < 0:
                raise ValueError(f"DdmConfig.{f.name} must be a number >= 0, got {v!r}")
        if self.comfort_decel_mps2 <= 0 or self.comfort_decel_mps2 > self.max_decel_mps2:
            raise ValueError("comfort_decel_mps2 must be in (0, max_decel_mps2]")
        if self.rate_hz <= 0 or self.max_attempts < 1:
            raise ValueError("rate_hz must be > 0 and max_attempts >= 1")


@dataclass(frozen=True)
class HazardConfig:
    """Hazard fusion (:mod:`ddm.hazard_fusion`) and hazard response (:mod:`ddm.policy.hazard`) thresholds."""

    fuse_m: float = 3.0
    """Alerts of different RSUs within this distance are one hazard (RSU localisation differs by ~1 m)."""
    source_timeout_s: float = 3.5
    """A source not refreshed for this long is dropped (persist comes at 1 Hz: 3 missed + jitter)."""
    lx_max_m: float = LX_MAX_M
    ly_max_m: float | None = None
    """Report eq. 2-3 limits; None: the corridor's lane width."""
    threat_threshold: float = 0.3
    """Respond once T_f exceeds this (a hazard dead ahead has T_f = 0.71 at lx = 60 m; one 1.5 m off the
    centre line 0.42; one that barely blocks, 2.5 m off, reaches 0.3 at 43 m)."""
    min_clearance_m: float = 1.0
    """Lateral clearance the AV keeps between its side and a hazard's side (at least 1 m)."""
    position_margin_m: float = 0.3
    """Added to the clearance for the RSU localisation error of the hazard (~0.2-0.3 m laterally)."""
    stop_gap_m: float = 10.0
    """Front bumper to the hazard's near edge when stopped before it (room to steer around it later)."""
    pass_margin_m: float = 5.0
    """A hazard is passed once the AV's rear bumper is this far beyond its far edge."""
    max_stop_decel_mps2: float = 4.5
    """Hardest deceleration a stop before a hazard may ask (Apollo's emergency stop: 4.5 m/s^2)."""

    def __post_init__(self) -> None:
        for name in ("fuse_m", "source_timeout_s", "lx_max_m", "min_clearance_m", "stop_gap_m",
                     "max_stop_decel_mps2"):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and math.isfinite(v) and v > 0):
                raise ValueError(f"HazardConfig.{name} must be > 0, got {v!r}")
        if not 0.0 <= self.threat_threshold < 1.0:
            raise ValueError("threat_threshold must be in [0, 1)")
