"""Policies: pure functions from the DDM's picture (:class:`ddm.picture.Picture`) to intents.

- :mod:`ddm.policy.ev`: yield to emergency vehicles (Texas Transportation Code 545.156; CARMA's
  approaching-emergency-vehicle plugin; docs/architecture.md §DDM).
- :mod:`ddm.policy.hazard`: steer around or stop before road hazards (Clemson hazard navigation report,
  eq. 2-3; docs/architecture.md §DDM).

Both read the picture, the vehicle's :class:`ddm.intent.Response` (what was commanded before) and a
:class:`PolicyContext`; neither writes anything. The manoeuvre rules they share are in
:mod:`ddm.manoeuvre`; the decider (:mod:`ddm.decider`) puts EV before hazard.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

from ddm.config import DdmConfig, HazardConfig
from ddm.geometry import RoadFrame

NEIGHBOUR_RADIUS_M = 150.0
"""Tracks within this distance of an AV are considered for its gap checks."""


@dataclass(frozen=True)
class PolicyContext:
    """What the policies need besides the picture: the road, the thresholds, and each autonomous vehicle's
    configured cruise speed and width (the corridor file's; the speed limit for a vehicle it does not
    list, and a 1.9 m wide car)."""

    frame: RoadFrame
    config: DdmConfig
    hazard_config: HazardConfig
    speed_limit_mps: float
    cruise_mps: Mapping[str, float] = field(default_factory=dict)
    width_m: Mapping[str, float] = field(default_factory=dict)

    def cruise_of(self, vehicle_id: str) -> float:
        return self.cruise_mps.get(vehicle_id, self.speed_limit_mps)

    def width_of(self, vehicle_id: str) -> float:
        return self.width_m.get(vehicle_id, 1.9)
