"""Settings of the hazard detector (``HazardConfig``) and what it reports (``HazardEvent``); see ``rsu.hazard``."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from protocol.enums import HazardState

ToGround = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]
"""(N, 2) pixels (u, v) -> ((N, 2) ground x, y; (N,) valid)."""


@dataclass(frozen=True)
class HazardConfig:
    scale: float = 0.5
    """Working scale of the background models (1280x720 -> 640x360)."""
    rate_hz: float = 2.0
    """The detector looks at a frame at most this often (debris is static, a camera's 15 fps are not
    needed; 0 = every frame). Every duration below is in seconds, so the behaviour does not depend on it. At 2 Hz
    and at 3 Hz ``bench/hazard_bench.py`` reads the same recall, false alarms and clearance, detection 1.18 s instead of 1.35 s (median), for a third less of the detector's CPU."""
    phase_s: float = 0.0
    """The first look waits this long after the first frame, and the looks keep that phase: a corridor's RSUs that
    share one machine look in turn, not on the same frames (``rsu.build.build_hazards`` gives RSU k of the corridor
    k / 4 of a period; in step, four looks of ~10 ms of CPU each landed on the same frame every half second;
    what that did to dropped frames was not measured apart from the machine's run-to-run spread)."""
    warmup_fps: float = 15.0
    """Frame rate assumed for untimed warm-up frames (``HazardDetector.learn_background`` without a time)."""
    init_frames: int = 9
    init_interval_s: float = 0.5
    """Long-term background: median of ``init_frames`` frames at least ``init_interval_s`` apart (every look at
    2 Hz: 9 frames over 4 s; a car at 10 m/s moves 40 m meanwhile)."""
    long_tau_s: float = 33.3
    """Long-term background's time constant (a rate of 0.002 per frame at 15 fps)."""
    short_tau_s: float = 0.232
    """Short-term background's time constant (a rate of 0.25 per frame at 15 fps): the learning rate of an
    update dt after the last is 1 - exp(-dt / tau)."""
    diff_threshold: float = 28.0
    """Largest channel difference (0-255) from the long-term background that makes a pixel foreground
    (sensor noise in the renders is ~3 levels; asphalt texture under blur ~8)."""
    stable_threshold: float = 10.0
    """Largest channel difference from the short-term background of a still pixel."""
    on_s: float = 1.0
    """A new hazard needs pixels static for this long (evidence: seconds of static foreground)."""
    off_s: float = 1 / 3
    """... and stays while its pixels keep at least this much evidence (hysteresis)."""
    evidence_max_s: float = 4.0
    """Evidence saturates here: a removed object's pixels decay back below ``off_s`` in
    (evidence_max_s - off_s) / decay seconds."""
    decay: float = 3.0
    """Evidence lost per second where the pixel shows the long-term background again."""
    max_update_gap_s: float = 1.0
    """Longest time one update counts (a stalled camera does not turn one frame into seconds of evidence)."""
    on_pixels_min: int = 12
    """Pixels (working scale) with E >= on_s that a new hazard needs (a 0.5 m object at 80 m is
    about 4 x 3 working pixels; at 20 m about 15 x 10)."""
    min_area_px: int = 10
    """Smallest component (working-scale pixels) considered at all."""
    moved_px: float = 12.0
    moved_fraction: float = 0.25
    moving_speed_mps: float = 2.0
    moving_s: float = 4 / 15
    """... or whose localised speed (when the caller gives speeds) stayed at least ``moving_speed_mps`` for
    ``moving_s`` (a slow car far away moves a few pixels a second)."""
    """A track whose box centre moved more than ``moved_px`` (full-scale pixels) and this fraction of its
    smaller box side since it began is a vehicle (a car entering at the image edge grows from the edge:
    its centre moves though its bottom stays on the border)."""
    min_parked_width_m: float = 1.2
    """A stopped track's region is parked only if its box's bottom edge spans at least this on the road
    (vehicle-sized), so a box of debris that a detector tracked is never masked for long."""
    max_vehicle_overlap: float = 0.5
    """A new hazard must have less than this fraction of its pixels inside held vehicle regions."""
    vehicle_margin_px: float = 4.0
    stop_window_s: float = 1.5
    stop_px: float = 4.0
    stop_check_s: float = 0.5
    slow_fraction: float = 0.5
    """A moved track whose bottom-centre moved less than ``stop_px`` or this fraction of its box height
    over the last ``stop_check_s`` is slow or stopped: new tracks born inside its region are fragments
    of it, and when the track ends its region is parked."""
    vehicle_grow: float = 0.2
    """A vehicle's held region is the union of its boxes over ``stop_window_s`` grown by this fraction
    of its box size on every side."""
    parked_hold_s: float = 120.0
    """A stopped vehicle's region is held at most this long after its track ended."""
    parked_release_fraction: float = 0.25
    """... and released once less than this fraction of it is static foreground (it drove off)."""
    min_width_m: float = 0.2
    """Narrower static components (a sliver along a lane line, a shadow edge) are not reported."""
    max_width_m: float = 3.0
    """Wider static components are not debris (and not a lane-blocking object one lane can pass)."""
    max_length_m: float = 6.0
    """Longer static components are not debris (a slow car far away smears to ~7 m)."""
    match_m: float = 2.0
    """A component within this distance of a known hazard (or overlapping its box) is that hazard."""
    clear_after_s: float = 1.0
    persist_period_s: float = 1.0
    position_smoothing: float = 0.2
    """Exponential smoothing weight of a new measurement of a known hazard's position and size."""
    max_range_m: float = 120.0
    """Road farther than this from the camera is not watched (a 0.5 m object there is ~3 pixels)."""
    ghost_edge_ratio: float = 1.2
    """A new static component whose outline has more edge (Sobel) in the long-term background than in
    the frame is a ghost (something that was there when the background was learnt has left): it is
    absorbed into the background instead of reported."""
    max_foreground_fraction: float = 0.4
    """A frame whose long-term foreground exceeds this (exposure jump, camera moved) is skipped."""

    def __post_init__(self) -> None:
        if not 0.05 <= self.scale <= 1.0:
            raise ValueError(f"scale must be in [0.05, 1], got {self.scale}")
        if not 0 < self.off_s <= self.on_s <= self.evidence_max_s:
            raise ValueError(f"need 0 < off_s <= on_s <= evidence_max_s, got {self.off_s}, {self.on_s}, "
                             f"{self.evidence_max_s}")
        if self.long_tau_s <= 0 or self.short_tau_s <= 0:
            raise ValueError("long_tau_s and short_tau_s must be > 0 s")
        if self.init_frames < 1 or self.init_interval_s < 0 or self.decay <= 0:
            raise ValueError("need init_frames >= 1, init_interval_s >= 0 s and decay > 0")
        if self.rate_hz < 0 or self.warmup_fps <= 0 or self.max_update_gap_s <= 0:
            raise ValueError("need rate_hz >= 0 (0: every frame), warmup_fps > 0 and max_update_gap_s > 0")
        if not 0.0 <= self.phase_s <= 10.0:
            raise ValueError(f"need 0 <= phase_s <= 10 s, got {self.phase_s}")

    @property
    def period_s(self) -> float:
        """Shortest time between two frames the detector looks at (0: every frame)."""
        return 1.0 / self.rate_hz if self.rate_hz > 0 else 0.0


@dataclass(frozen=True)
class HazardEvent:
    """One life-cycle event of a hazard seen by this camera (corridor frame, metres)."""

    hazard_id: int
    state: HazardState
    x_m: float
    y_m: float
    lane: int | None
    length_m: float
    width_m: float
    confidence: float
    first_seen_s: float
    bbox_px: tuple[float, float, float, float]
    lat_deg: float | None = None
    lon_deg: float | None = None
    """Set by the pipeline (``rsu.pipeline.RsuPipeline``), from the corridor's origin."""

