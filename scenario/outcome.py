"""Pass/fail of a run: the one yield judge of every runner and the scenario verdict. Pure.

**Yield judge** (``judge_yield``), fed with ground-truth samples of the AV and the EV in the road frame
(s along the road, d to the left; lane k spans ``[k w, (k + 1) w]``) by the rig (``scenario/faults.py``),
the lockstep corridor, the process runs (``deploy/up.py``) and the demo (``RunMonitor``):

- **the EV's lane** comes from the EV's own path: every lane its body touches in the ``EV_LANE_WINDOW_S``
  before it reaches the AV (an EV that drives round the AV afterwards does not move the lane to where it
  went, and a lane it was leaving at lights-on does not count); never recomputed per sample afterwards;
- the EV **reaches** the AV at the first sample after lights-on where, behind it, its front is within its
  following distance of the AV's rear: ``reach_gap_m + reach_headway_s * v_EV`` (2 m + 1 s x speed);
- **yielded** (the only pass): at that moment the AV's whole body (its width turned by its heading
  error) is out of the EV's lane, it stays out until the EV has passed it (or the run ends), and there
  was no collision. The margin is reach time - the time the AV's body left the lane for good;
- **stopped in the EV's lane**, **blocked** (in the lane when reached: the margin, negative, says how
  late it got out, None if never), **collision**: failures;
- **not reached**: the EV never came within its following distance, so the run tested nothing: a fault
  runner re-times or re-seeds such a case; it is never a pass;
- the **EV's delay**: the time the EV lost from lights-on until it passed the AV against driving on at
  ``v_ref``, the highest speed it had from lights-on to the reach: the integral of ``(1 - v / v_ref)+ dt``.

**Scenario verdict** (``judge_run``), from ``RunMonitor.metrics`` (which carries the yield verdict):

- an EV that switches its lights on: the yield verdict;
- an EV that never switches its lights on: no yield command at all (a false alarm stops traffic), no
  collision;
- anything else (e.g. hazards): no collision and, where measured, at least ``MIN_HAZARD_CLEARANCE_M`` of
  lateral clearance to a hazard it passed (or a stop before it).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Any

MIN_HAZARD_CLEARANCE_M = 1.0
STOPPED_MPS = 0.05
EV_LANE_WINDOW_S = 1.0
"""The EV's lane is the lanes its body touched in this long before it reached the AV (its approach)."""


@dataclass(frozen=True)
class Body:
    """One vehicle at one instant, road frame."""

    s_m: float
    d_m: float
    length_m: float
    width_m: float
    speed_mps: float
    heading_error_rad: float = 0.0
    """Heading minus the road's: a car turned across the lane covers more of it."""

    def half_width_m(self) -> float:
        h = self.heading_error_rad
        return (self.width_m * abs(math.cos(h)) + self.length_m * abs(math.sin(h))) / 2


@dataclass(frozen=True)
class YieldSample:
    t_s: float
    av: Body
    ev: Body | None
    ev_lights_on: bool


@dataclass(frozen=True)
class YieldParams:
    lane_width_m: float = 3.7
    reach_gap_m: float = 2.0
    reach_headway_s: float = 1.0

    def following_distance_m(self, ev_speed_mps: float) -> float:
        return self.reach_gap_m + self.reach_headway_s * max(0.0, ev_speed_mps)


@dataclass(frozen=True)
class YieldVerdict:
    status: str
    """``yielded`` (the only pass), ``blocked``, ``stopped_in_ev_lane``, ``collision``, ``not_reached``,
    ``no_lights`` (the EV never switched its lights on while the AV was there)."""
    passed: bool
    reason: str
    margin_s: float | None
    """Reach time - the time the AV's body left the EV's lane for good (negative: how late)."""
    lights_on_s: float | None = None
    reach_s: float | None = None
    lane_clear_s: float | None = None
    ev_passed_s: float | None = None
    ev_lane_d_m: tuple[float, float] | None = None
    """The strip of road the EV's lane(s) cover, (right edge, left edge) in d."""
    ev_delay_s: float | None = None

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        for k in ("margin_s", "lights_on_s", "reach_s", "lane_clear_s", "ev_passed_s", "ev_delay_s"):
            if d[k] is not None:
                d[k] = round(d[k], 3)
        return d


def ev_lane_strip(samples: Sequence[YieldSample], lane_width_m: float) -> tuple[float, float] | None:
    """(lo, hi) in d of the lanes the EV's body touched over ``samples`` (its approach path)."""
    lo, hi = math.inf, -math.inf
    for smp in samples:
        if smp.ev is None:
            continue
        half = smp.ev.half_width_m()
        lo, hi = min(lo, smp.ev.d_m - half), max(hi, smp.ev.d_m + half)
    if math.isinf(lo):
        return None
    eps = 1e-6  # an EV exactly on its lane's centre touches only that lane
    return math.floor((lo + eps) / lane_width_m) * lane_width_m, math.ceil((hi - eps) / lane_width_m) * lane_width_m


def out_of_strip(av: Body, strip: tuple[float, float]) -> bool:
    half = av.half_width_m()
    return av.d_m + half <= strip[0] or av.d_m - half >= strip[1]


def _reached(smp: YieldSample, p: YieldParams) -> bool:
    av, ev = smp.av, smp.ev
    if ev is None or ev.s_m >= av.s_m:
        return False
    gap = (av.s_m - av.length_m / 2) - (ev.s_m + ev.length_m / 2)
    return gap <= p.following_distance_m(ev.speed_mps)


def _passed(smp: YieldSample) -> bool:
    return smp.ev is not None and smp.ev.s_m - smp.ev.length_m / 2 > smp.av.s_m + smp.av.length_m / 2


def ev_delay_s(samples: Sequence[YieldSample], v_ref_mps: float) -> float:
    """Time the EV lost against ``v_ref_mps``: the integral of (1 - v / v_ref)+ dt over ``samples``."""
    lost = 0.0
    for a, b in zip(samples, samples[1:], strict=False):
        if a.ev is None or v_ref_mps <= 0:
            continue
        lost += max(0.0, 1.0 - a.ev.speed_mps / v_ref_mps) * (b.t_s - a.t_s)
    return lost


def judge_yield(samples: Sequence[YieldSample], params: YieldParams = YieldParams(), *,
                collision: bool = False) -> YieldVerdict:
    """The verdict of one EV approach (module docstring); ``samples`` in time order."""
    lit = next((i for i, smp in enumerate(samples) if smp.ev_lights_on and smp.ev is not None), None)
    if lit is None:
        return YieldVerdict("no_lights", False, "the EV never switched its lights on", None)
    t_on = samples[lit].t_s
    reach = next((i for i in range(lit, len(samples)) if _reached(samples[i], params)), None)
    passed_i = next((i for i in range(lit, len(samples)) if _passed(samples[i])), None)
    end = reach if reach is not None else (passed_i if passed_i is not None else len(samples) - 1)
    start = end
    while start > lit and samples[end].t_s - samples[start - 1].t_s <= EV_LANE_WINDOW_S + 1e-9:
        start -= 1
    strip = ev_lane_strip(samples[start:end + 1], params.lane_width_m)
    approach = [smp.ev.speed_mps for smp in samples[lit:end + 1] if smp.ev is not None]
    v_ref = max(approach) if approach else 0.0
    delay_end = passed_i if passed_i is not None else len(samples) - 1
    delay = ev_delay_s(samples[lit:delay_end + 1], v_ref)
    t_passed = None if passed_i is None else samples[passed_i].t_s
    common = dict(lights_on_s=t_on, ev_lane_d_m=strip, ev_delay_s=delay, ev_passed_s=t_passed)
    if collision:
        return YieldVerdict("collision", False, "collision", None, **common)
    if reach is None:
        why = "the EV passed without coming within its following distance" if passed_i is not None else \
            "the EV never came within its following distance of the AV"
        return YieldVerdict("not_reached", False, why + ": the run tested nothing (re-time it)", None, **common)
    t_reach = samples[reach].t_s
    common["reach_s"] = t_reach
    # when the AV's body left the strip for good (up to the EV passing it or the run's end)
    stay_end = passed_i if passed_i is not None and passed_i > reach else len(samples) - 1
    clear_since = None
    for i in range(lit, stay_end + 1):
        if out_of_strip(samples[i].av, strip):
            if clear_since is None:
                clear_since = samples[i].t_s
        else:
            clear_since = None
    out_at_reach = out_of_strip(samples[reach].av, strip)
    if out_at_reach and clear_since is not None and clear_since <= t_reach:
        return YieldVerdict("yielded", True, f"out of the EV's lane {t_reach - clear_since:.2f} s before the EV "
                            f"reached it; EV delay {delay:.2f} s", t_reach - clear_since,
                            lane_clear_s=clear_since, **common)
    av = samples[reach].av
    if not out_at_reach and av.speed_mps < STOPPED_MPS:
        return YieldVerdict("stopped_in_ev_lane", False, f"stopped in the EV's lane when the EV reached it; EV delay "
                            f"{delay:.2f} s", None if clear_since is None else t_reach - clear_since,
                            lane_clear_s=clear_since, **common)
    if out_at_reach:
        why = "out of the EV's lane when reached but moved back in before the EV passed"
        margin = None
    else:
        margin = None if clear_since is None else t_reach - clear_since
        why = ("in the EV's lane when the EV reached it" + ("" if margin is None else f" (out {-margin:.2f} s late)"))
    return YieldVerdict("blocked", False, f"blocked the EV: {why}; EV delay {delay:.2f} s", margin,
                        lane_clear_s=clear_since, **common)


def judge_run(metrics: dict[str, Any], *, ev_lights_on: bool | None) -> tuple[bool, str]:
    """(passed, one-line reason). ``ev_lights_on``: does the scenario's EV switch its lights on (None: no EV).
    With an EV that switches its lights on, ``metrics["yield"]`` (a ``YieldVerdict.to_dict()``) decides."""
    if metrics.get("collision"):
        return False, f"collision (min gap {metrics.get('min_gap_to_any_vehicle_m')} m)"
    yields = [c for c in metrics.get("commands", []) if c.get("manoeuvre") not in ("resume",)]
    if ev_lights_on:
        v = metrics.get("yield")
        if not v:
            return False, "no yield verdict in the metrics (no AV/EV ground truth seen)"
        where = metrics.get("stop_lane")
        stop = "" if metrics.get("stop_position_m") is None else \
            f"; stopped {'on the shoulder' if where is None else f'in lane {where}'}"
        return bool(v["passed"]), f"{v['status']}: {v['reason']}{stop}"
    if ev_lights_on is False:
        if yields:
            return False, f"false alarm: {len(yields)} yield command(s) for an EV with its lights off"
        return True, "no command for an EV with its lights off; no collision"
    clearance = metrics.get("min_hazard_clearance_m")
    if clearance is not None and clearance < MIN_HAZARD_CLEARANCE_M and not metrics.get("stopped_before_hazard"):
        return False, f"passed a hazard with {clearance:.2f} m < {MIN_HAZARD_CLEARANCE_M} m lateral clearance"
    return True, "no collision" + (f"; hazard clearance {clearance:.2f} m" if clearance is not None else "")


class YieldTrace:
    """Collects ``YieldSample`` s (the imperative side: the runners feed it, ``verdict()`` judges)."""

    def __init__(self, params: YieldParams | None = None, *, road: Any = None) -> None:
        """``road``: take the lane width from it (else ``params``' or 3.7 m)."""
        if params is None:
            params = YieldParams() if road is None else YieldParams(lane_width_m=road.lane_width_m)
        self.params = params
        self.samples: list[YieldSample] = []

    def add(self, t_s: float, av: Body, ev: Body | None, ev_lights_on: bool) -> None:
        self.samples.append(YieldSample(t_s, av, ev, ev_lights_on))

    def on_snapshot(self, snap: Any, road: Any) -> None:
        """A ``WorldSnapshot`` (ground truth, evaluation only) on ``road`` (``protocol.corridor.Road``)."""
        av = next((a for a in snap.actors if a.kind.value == "av"), None)
        ev = next((a for a in snap.actors if a.kind.value == "ev"), None)
        if av is None:
            return
        lit = ev is not None and ev.light_bar is not None and ev.light_bar.on
        self.add(snap.sim_time_s, _body(av, road), None if ev is None else _body(ev, road), lit)

    def verdict(self, *, collision: bool = False) -> YieldVerdict:
        return judge_yield(self.samples, self.params, collision=collision)


def _body(actor: Any, road: Any) -> Body:
    s, d = (float(v) for v in road.to_frenet(actor.pos_x_m, actor.pos_y_m))
    herr = math.remainder(actor.heading_rad - float(road.pose_at(s, 0.0)[2]), 2 * math.pi)
    return Body(s, d, actor.length_m, actor.width_m, actor.speed_mps, herr)
