"""Road hazards from a fixed camera: static objects that appear in a lane and stay. Pure core.

Dual background (Porikli, Ivanov, Haga 2008, "Robust abandoned object detection using dual
foregrounds"), per pixel at a reduced working scale, on frames at most ``rate_hz`` (3) a second (debris
is static; every rate and duration is in seconds, so the behaviour does not depend on the frame rate):

- long-term background ``B_L``: the per-pixel median of ``init_frames`` frames spread over the first
  seconds (moving traffic drops out of a median), then a running average with the slow time constant
  ``long_tau_s`` (rate 1 - exp(-dt / tau) for an update dt after the last), learnt only where the pixel matches
  it (and frozen under static candidates, so a hazard is never absorbed). Where no frame has shown the
  median's value (not one of its own looks, nor any since: a blend of the cars of a platoon far from the camera,
  that cover the same pixels in most of its looks), the road standing still there, no track over it, replaces
  it before any evidence counts, whenever that comes; a primed empty road is shown;
- short-term background ``B_S``: a running average with the fast time constant ``short_tau_s``.

A pixel is *static foreground* when the frame differs from ``B_L`` (``> diff_threshold``, largest
channel difference) but matches ``B_S`` (``< stable_threshold``): something new that has stopped
moving. Moving traffic differs from both. An evidence image ``E`` counts seconds of static foreground:
+dt per static update, -``decay`` dt where the pixel shows the long-term background again, held
(unchanged) while something moves over it or a tracked vehicle covers it; clipped to ``[0, evidence_max_s]``.

Tracked vehicles are not hazards: a track whose box centre has *moved* (more than ``moved_px`` and
``moved_fraction`` of its box since it began), or whose localised speed stayed above
``moving_speed_mps`` for ``moving_s``, is a vehicle, and its region, the union of its boxes over
the last ``stop_window_s`` grown by ``vehicle_grow`` (a slow car's uniform body looks static while a
background detector's box of it shrinks), is held. A slow or stopped vehicle's region catches new tracks
born inside it (fragments of it), and when its track ends while stopped (a queue: a background-subtraction
detector loses a car that stands still) the region is *parked*: held while its static foreground stays,
at most ``parked_hold_s``. A track that never moved (the motion detector tracks a new box of debris too)
is not a vehicle and masks nothing. A new hazard must lie mostly outside held regions.

Hazards: connected components of ``E >= off_s`` (hysteresis) inside the watched road
(:func:`road_mask`: the carriageway and shoulder up to ``max_range_m``, projected with the camera
model); a new hazard needs ``on_pixels_min`` pixels with ``E >= on_s`` (static that long)
and must not be a *ghost* (an object that was in the background and left: more edge on its outline in
the background than in the frame; ghosts are absorbed into the background). Each component is
localised on the road plane: the lowest pixel of each of its image columns (the object's ground contact
seen from above) is back-projected with the RSU's camera model (``to_ground``, e.g.
``Localizer.mapper.to_ground``); the position is the mean of those ground points, width and length
their extent across and along the road. Only components that overlap a lane (``0 < d < lanes * lane
width`` in the road frame, after the half width) and are ``min_width_m`` to ``max_width_m`` wide are
hazards. Life cycle per hazard: ``appear`` (first confirmed), ``persist`` every ``persist_period_s``,
``clear`` once no component has matched it for ``clear_after_s``.

An RSU started with debris already on the road learns it as background (the initial median); give it a
frame of the empty road (:meth:`HazardDetector.prime`, ``iea-rsu --hazard-background``) to find it.

No ground truth is read: the detector sees pixels, track boxes, the camera model and the road map.
"""

from rsu.hazard.background import StaticForeground, road_mask
from rsu.hazard.config import HazardConfig, HazardEvent, ToGround
from rsu.hazard.detector import HazardDetector, HazardStats

__all__ = ["HazardConfig", "HazardDetector", "HazardEvent", "HazardStats", "StaticForeground", "ToGround",
           "road_mask"]
