"""Pass/fail of a scenario run, from its metrics (``RunMonitor.metrics``). Pure.

- a scenario whose EV switches its lights on: the AV must have left the EV's lane before the EV passes it
  and come to a stop at the right-hand edge (lane 0 or the shoulder), with no collision. Whether it was
  already stopped when the EV passed is reported too (``stopped_before_ev_passed``): with a 19 m/s EV
  closing from 50 m on a 13.4 m/s AV, a lane change and stop (>= 5.4 s at 3 m/s^2 braking) cannot always
  finish first, so it is a figure, not the pass condition;
- an EV that never switches its lights on (``ev_lights_never_on``): no yield command at all (a false
  alarm stops traffic), and no collision;
- anything else (e.g. hazards): no collision, and where the run measured it, at least
  ``MIN_HAZARD_CLEARANCE_M`` of lateral clearance to a hazard it passed (or a stop before it).
"""

from __future__ import annotations

from typing import Any

MIN_HAZARD_CLEARANCE_M = 1.0


def judge_run(metrics: dict[str, Any], *, ev_lights_on: bool | None) -> tuple[bool, str]:
    """(passed, one-line reason). ``ev_lights_on``: does the scenario's EV switch its lights on (None: no EV)."""
    if metrics.get("collision"):
        return False, f"collision (min gap {metrics.get('min_gap_to_any_vehicle_m')} m)"
    yields = [c for c in metrics.get("commands", []) if c.get("manoeuvre") not in ("resume",)]
    if ev_lights_on:
        lane = metrics.get("stop_lane")
        where = "on the shoulder" if lane is None else f"in lane {lane}"
        stop_s = metrics["latency_s"].get("lights_on_to_stop_s")
        if metrics.get("stop_position_m") is None:
            return False, "the AV never stopped for the EV"
        if lane not in (None, 0):
            return False, f"the AV stopped in lane {lane}, not at the right-hand edge"
        if metrics.get("stopped_before_ev_passed"):
            return True, f"moved over and stopped {where} {stop_s} s after lights-on, before the EV passed; no collision"
        if metrics.get("moved_over_before_ev_passed"):
            return True, (f"moved out of the EV's lane {metrics.get('out_of_ev_lane_s')} s after lights-on, before "
                          f"the EV passed ({metrics.get('ev_passed_av_s')} s), stopped {where} at {stop_s} s; "
                          "no collision")
        return False, (f"the AV was still in the EV's lane when it passed ({metrics.get('ev_passed_av_s')} s after "
                       "lights-on)")
    if ev_lights_on is False:
        if yields:
            return False, f"false alarm: {len(yields)} yield command(s) for an EV with its lights off"
        return True, "no command for an EV with its lights off; no collision"
    clearance = metrics.get("min_hazard_clearance_m")
    if clearance is not None and clearance < MIN_HAZARD_CLEARANCE_M and not metrics.get("stopped_before_hazard"):
        return False, f"passed a hazard with {clearance:.2f} m < {MIN_HAZARD_CLEARANCE_M} m lateral clearance"
    return True, "no collision" + (f"; hazard clearance {clearance:.2f} m" if clearance is not None else "")
