"""Fault scenarios of the corridor (issue 8 "Fault tests"), each with a pass/fail outcome and a margin.

Two runners:

- ``run_command_link`` (in process, lockstep): the real ``DdmService`` and ``VehicleService`` on one
  ``SimClock`` over a ``LocalBus``; every message to and from the vehicle goes through a ``DsrcLink``
  with the channel under test (latency + jitter, independent loss, scheduled outages). Scripted RSUs
  stand in for perception: each publishes at 15 Hz the object list of what its camera sees (the AV's
  true pose, the EV) and, from ``lights_on_s + alert_delay_s``, the EvAlert at 2 Hz. The EV drives in
  the AV's lane at constant speed. Fast (a few seconds of CPU per run) and deterministic per seed.
- the process-level faults (an RSU killed, the DDM killed and restarted, the router restarted) run
  the corridor's real processes over Zenoh on loopback: see ``deploy/process_faults.py``.

Outcome of an EV-yield run, measured from ground truth by ``YieldJudge``: the EV *reaches* the AV when
it comes within its following distance of the AV's rear (2 m + 1 s x its speed). If the AV has left
the EV's lane by then the pull-over worked (margin = reach time - time the lane was clear); if it is
stopped in the lane it stopped safely in lane (margin = reach time - stop time); otherwise it blocked
the EV (margin negative: how late).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any

from protocol.channel import ChannelModel
from protocol.clock import SimClock
from protocol.corridor import Corridor, load_corridor
from protocol.keys import all_vehicles_expr, rsu_key
from protocol.messages import (
    AlertState,
    DetectedObject,
    EvAlert,
    EvState,
    ObjectList,
    ObjectType,
    PathSwitchCommand,
    VehicleMode,
)
from protocol.transport import DsrcLink, LocalBus

CAMERA_VIEW_M = (18.0, 120.0)
"""What each RELLIS camera sees along x, relative to its own x (deploy/corridors/rellis.toml)."""


@dataclass(frozen=True)
class FaultOutcome:
    """One row of the fault table."""

    name: str
    kind: str
    passed: bool
    outcome: str
    margin_s: float | None
    """How much earlier than needed the AV was safe (negative: how late); None where not applicable."""
    runner: str
    details: dict[str, Any] = field(default_factory=dict)

    def row(self) -> str:
        m = "-" if self.margin_s is None else f"{self.margin_s:+.2f} s"
        return f"{self.name:<34} {'PASS' if self.passed else 'FAIL':<5} {m:>9}  {self.outcome}"


@dataclass(frozen=True)
class YieldScenario:
    """The scripted EV approach (the RELLIS field test: EV behind the AV in lane 1, faster)."""

    ev_gap_m: float = 50.0
    """EV centre this far behind the AV's at t = 0."""
    ev_speed_mps: float = 17.0
    lights_on_s: float = 4.0
    alert_delay_s: float = 0.4
    """Lights on -> first EvAlert (the RSU's detection latency, measured by iea demo at ~0.4 s)."""
    frame_rate_hz: float = 15.0
    duration_s: float = 20.0
    reach_gap_m: float = 2.0
    lane_clear_m: float = 0.2
    """The AV is out of the EV's lane when the lateral gap between their sides exceeds this (YieldJudge)."""


def _detected(corridor: Corridor, oid: int, x: float, y: float, vx: float, vy: float, *, ev: bool,
              length_m: float, width_m: float) -> DetectedObject:
    lat, lon = corridor.to_latlon(x, y)
    return DetectedObject(
        object_id=oid, pos_x_m=x, pos_y_m=y, lat_deg=lat, lon_deg=lon, bbox_px=(0.0, 0.0, 10.0, 10.0),
        obj_type=ObjectType.EV if ev else ObjectType.VEHICLE, ev_state=EvState.CONFIRMED if ev else EvState.NONE,
        ev_score=0.9 if ev else 0.0, vel_x_mps=vx, vel_y_mps=vy, speed_mps=math.hypot(vx, vy),
        heading_rad=math.atan2(vy, vx) if (vx or vy) else 0.0, length_m=length_m, width_m=width_m,
        pos_cov_m2=(0.09, 0.0, 0.09), lane=None)


@dataclass
class YieldJudge:
    """Scores an EV approach from ground truth (the scripted rig's poses or the simulator's snapshots).

    Road frame (s along the road, d to the left). The EV's lane is where the EV drives when the AV
    starts to respond (its light bar on / the manoeuvre starting). The EV *reaches* the AV when, still
    behind it, its front comes within its following distance of the AV's rear (``reach_gap_m`` +
    ``reach_headway_s`` x its speed: from there an EV still in the AV's lane has to brake for it). The AV
    is *out of the EV's lane* when the lateral gap between its side and an EV in that lane exceeds
    ``lane_clear_m``. ``outcome()``: out of the EV's lane in time (margin = reach - out of lane),
    stopped safely in lane (margin = reach - stop), or blocked the EV (margin = reach - out of lane,
    negative: how late; None if it never left the lane).
    """

    reach_gap_m: float = 2.0
    reach_headway_s: float = 1.0
    lane_clear_m: float = 0.2
    events: dict[str, float] = field(default_factory=dict)
    _reach_overlap: bool = False
    _clear_since: float | None = None
    _ev_lane_d: float | None = None

    def following_distance_m(self, ev_speed_mps: float) -> float:
        return self.reach_gap_m + self.reach_headway_s * max(0.0, ev_speed_mps)

    def update(self, t: float, av: tuple[float, float, float, float, float],
               ev: tuple[float, float, float, float, float] | None, manoeuvring: bool = True) -> None:
        """``av`` = (s, d, length, width, speed), ``ev`` = (s, d, length, width, speed) or None."""
        s, d, length, width, speed = av
        if speed < 0.05:
            self.events.setdefault("av_stopped", t)
        if ev is None:
            return
        es, ed, elen, ewid, espeed = ev
        if self._ev_lane_d is None or not manoeuvring:
            self._ev_lane_d = ed  # fixed once the response has started
        overlap = abs(d - self._ev_lane_d) < (width + ewid) / 2 + self.lane_clear_m
        if overlap:
            self._clear_since = None
        elif manoeuvring and self._clear_since is None:
            self._clear_since = t
        reached = "ev_reaches_av" in self.events
        if reached and self._reach_overlap and not overlap:
            self.events.setdefault("lane_clear_late", t)
        gap = (s - length / 2) - (es + elen / 2)
        if not reached and es < s and gap <= self.following_distance_m(espeed):
            self.events["ev_reaches_av"] = t
            self._reach_overlap = overlap
            if self._clear_since is not None:
                self.events["lane_clear"] = self._clear_since
        if es - elen / 2 > s + length / 2:
            self.events.setdefault("ev_passed_av", t)

    def on_snapshot(self, snap, road) -> None:
        """Feed a ``WorldSnapshot`` (the simulator's ground truth)."""
        av = next((a for a in snap.actors if a.kind.value == "av"), None)
        ev = next((a for a in snap.actors if a.kind.value == "ev"), None)
        if av is None:
            return
        if ev is not None and ev.light_bar is not None and ev.light_bar.on:
            self.events.setdefault("lights_on", snap.sim_time_s)
        sa, da = road.to_frenet(av.pos_x_m, av.pos_y_m)
        e = None
        if ev is not None:
            se, de = road.to_frenet(ev.pos_x_m, ev.pos_y_m)
            e = (se, de, ev.length_m, ev.width_m, ev.speed_mps)
        self.update(snap.sim_time_s, (sa, da, av.length_m, av.width_m, av.speed_mps), e,
                    manoeuvring="lights_on" in self.events)

    def outcome(self) -> tuple[bool, str, float | None]:
        ev = self.events
        reach = ev.get("ev_reaches_av")
        if reach is None:
            if "ev_passed_av" in ev:
                return True, "EV passed without reaching the AV", None
            return True, "EV never reached the AV", None
        if not self._reach_overlap and "lane_clear" in ev:
            return True, "out of the EV's lane in time", reach - ev["lane_clear"]
        if "av_stopped" in ev and ev["av_stopped"] <= reach:
            return True, "stopped safely in lane", reach - ev["av_stopped"]
        late = ev.get("lane_clear_late")
        return False, "blocked the EV", None if late is None else reach - late


@dataclass
class LinkRunResult:
    outcome: FaultOutcome
    events: dict[str, float]
    counts: dict[str, Any]


def run_command_link(channel: ChannelModel, *, name: str = "", kind: str = "latency", seed: int = 0,
                     scenario: YieldScenario = YieldScenario(), outage_after_alert: tuple[float, float] | None = None,
                     corridor: Corridor | None = None) -> LinkRunResult:
    """One lockstep run of the EV approach with the vehicle behind ``channel``.

    ``outage_after_alert`` = (start, length): a window of total loss on the vehicle link starting that
    long after the first EvAlert (the worst moment: the command is in flight).
    """
    from ddm.config import DdmConfig
    from ddm.service import DdmService
    from vehicle.service import VehicleService

    corridor = corridor or load_corridor()
    sc = scenario
    c = corridor.corridor_id
    bus = LocalBus()
    t0 = 1000.0
    clock = SimClock(t0)
    t_alert = t0 + sc.lights_on_s + sc.alert_delay_s
    if outage_after_alert is not None:
        start, length = outage_after_alert
        start += t_alert - 0.005  # half a step early: the alert goes out on the step nearest t_alert
        channel = dataclasses.replace(channel, outages=((start, start + length),))
    ddm = DdmService(bus, clock, corridor, DdmConfig())
    link = DsrcLink(bus, channel, seed=seed, clock=clock, threaded=False)
    veh = VehicleService(link, clock, corridor, "av1", seed=seed)
    vc = corridor.vehicle("av1")
    road = corridor.road
    ev_y = road.lane_centre_offset_m(1)
    ev_len, ev_w = 6.5, 2.4

    # what the DDM sends and hears, on its side of the radio
    sent: list[PathSwitchCommand] = []
    acks_at_ddm: list[tuple[float, str, str]] = []
    bus.subscribe(all_vehicles_expr(c, "cmd"), lambda k, m: sent.append(m))
    bus.subscribe(all_vehicles_expr(c, "ack"), lambda k, m: acks_at_ddm.append((clock.now(), m.command_id,
                                                                                 m.status.value)))
    cams = [(r.rsu_id, r.camera.x_m) for r in corridor.rsus]
    ev_x = veh.sim.truth.x_m - sc.ev_gap_m
    events: dict[str, float] = {}
    activations: dict[str, int] = {}
    last_active: str | None = None
    frame, dt = 0, 0.01
    next_frame, next_alert, next_ddm = t0, t_alert, t0
    judge = YieldJudge(sc.reach_gap_m, lane_clear_m=sc.lane_clear_m)
    modes_seen: set[str] = set()
    n_steps = int(round(sc.duration_s / dt))
    for _ in range(n_steps):
        now = clock.advance(dt)
        t = now - t0
        st = veh.sim.truth
        if t >= sc.lights_on_s:
            events.setdefault("lights_on", now)
        # the EV: constant speed, but it cannot drive through the AV (it brakes behind it)
        av_rear = st.x_m - vc.length_m / 2
        overlap = abs(st.y_m - ev_y) < (vc.width_m + ev_w) / 2 + sc.lane_clear_m
        ev_x += sc.ev_speed_mps * dt
        if overlap and ev_x < st.x_m and ev_x + ev_len / 2 > av_rear - sc.reach_gap_m:
            ev_x = av_rear - sc.reach_gap_m - ev_len / 2  # it may not drive through the AV
        # RELLIS is straight along +x from y = 0, so (x, y) serve as the road frame's (s, d)
        judge.update(now, (st.x_m, st.y_m, vc.length_m, vc.width_m, st.vx_mps), (ev_x, ev_y, ev_len, ev_w,
                                                                                  sc.ev_speed_mps),
                     manoeuvring="manoeuvre" in events)
        link.deliver_due(now)
        if now + 1e-9 >= next_frame:  # scripted RSUs: object lists at the camera rate
            next_frame += 1.0 / sc.frame_rate_hz
            frame += 1
            for rsu, cx in cams:
                lo, hi = cx + CAMERA_VIEW_M[0], cx + CAMERA_VIEW_M[1]
                objs = []
                if lo <= st.x_m <= hi:
                    objs.append(_detected(corridor, 1, st.x_m, st.y_m, st.vx_mps * math.cos(st.yaw_rad),
                                          st.vx_mps * math.sin(st.yaw_rad), ev=False, length_m=vc.length_m,
                                          width_m=vc.width_m))
                if lo <= ev_x <= hi:
                    objs.append(_detected(corridor, 2, ev_x, ev_y, sc.ev_speed_mps, 0.0, ev=now >= t_alert,
                                          length_m=ev_len, width_m=ev_w))
                bus.publish(rsu_key(c, rsu, "objects"), ObjectList(src=rsu, seq=frame, stamp=now, rsu_id=rsu,
                                                                   frame=frame, measurement_time=now, objects=objs))
        if now + 1e-9 >= next_alert:  # the EvAlert of the first RSU that sees the EV, at 2 Hz
            next_alert += 0.5
            rsu = next((r for r, cx in cams if cx + CAMERA_VIEW_M[0] <= ev_x <= cx + CAMERA_VIEW_M[1]), None)
            if rsu is not None:
                lat, lon = corridor.to_latlon(ev_x, ev_y)
                events.setdefault("first_alert", now)
                bus.publish(rsu_key(c, rsu, "ev"), EvAlert(
                    src=rsu, stamp=now, alert_id=f"{rsu}-ev", state=AlertState.ACTIVE, rsu_id=rsu, object_id=2,
                    pos_x_m=ev_x, pos_y_m=ev_y, lat_deg=lat, lon_deg=lon, vel_x_mps=sc.ev_speed_mps,
                    speed_mps=sc.ev_speed_mps, confidence=0.9, first_seen=t_alert))
        if sent:
            events.setdefault("command_sent", sent[0].stamp)
        veh.step(now)
        core = veh.sim.core
        modes_seen.add(core.mode.value)
        active = None if core.book.active is None else core.book.active.command_id
        if active is not None and active != last_active:
            activations[active] = activations.get(active, 0) + 1
        last_active = active
        if core.mode == VehicleMode.MANOEUVRE:
            events.setdefault("manoeuvre", now)
        if core.mode == VehicleMode.MINIMAL_RISK:
            events.setdefault("failsafe", now)
        if core.mode in (VehicleMode.STOPPED, VehicleMode.MINIMAL_RISK) and st.vx_mps < 0.05:
            events.setdefault("stopped", now)
        if now + 1e-9 >= next_ddm:
            next_ddm += 1.0 / ddm.config.rate_hz
            ddm.step(now)
        if "ev_passed_av" in judge.events and now - judge.events["ev_passed_av"] > 3.0 \
                and ddm.commands.outstanding() == 0 and (not sent or now - sent[-1].stamp > 1.0):
            break  # the EV is well past and no command is in flight: the outcome is known
    link.close()
    ddm.close()
    veh.close()
    bus.close()

    # -- the outcome
    for k, v in judge.events.items():
        events.setdefault(k, v)
    rel = {k: round(v - events.get("lights_on", t0), 3) for k, v in events.items()}
    issued = list(dict.fromkeys(c.command_id for c in sent))
    manoeuvre_of = {c.command_id: c.manoeuvre.value for c in sent}
    acked = {cid for _, cid, _ in acks_at_ddm}
    lost = [cid for i, cid in enumerate(issued) if cid not in acked and not any(x in acked for x in issued[i + 1:])]
    duplicates = {cid: n for cid, n in activations.items() if n > 1}
    first_sent = {}
    for cmd in sent:
        first_sent.setdefault(cmd.command_id, cmd.stamp)
    lon = events.get("lights_on", t0)
    counts = {
        "commands_issued": len(issued),
        "manoeuvres": [f"{manoeuvre_of[i]}@{first_sent[i] - lon:.2f}s" for i in issued],
        "transmissions": len(sent), "acks_at_ddm": len(acks_at_ddm), "lost_commands": lost,
        "duplicate_activations": duplicates, "ddm_expired": int(ddm.counters["cmd_expired"]),
        "link": {d: dict(v) for d, v in link.counts.items()}, "modes": sorted(modes_seen),
    }
    ok, outcome, margin = judge.outcome()
    if "manoeuvre" in events and "lights_on" in events:
        outcome += f", starts +{events['manoeuvre'] - events['lights_on']:.2f} s"
    if "failsafe" in events:
        outcome += ", fail-safe stop"
    details_yield = {"passed": ok, "outcome": outcome}
    if kind == "dropout":  # pass/fail on delivery (issue 8); the yield outcome and margin show the cost
        ok = not lost and not duplicates and counts["ddm_expired"] == 0
        if lost:
            outcome = f"{len(lost)} command(s) lost; {outcome}"
        elif duplicates:
            outcome = f"duplicate manoeuvre {sorted(duplicates)}; {outcome}"
        else:
            outcome = f"every command acked, none executed twice; {outcome}"
    details = {"events_since_lights_on_s": rel, **counts, "yield": details_yield,
               "lights_on_to_command_at_vehicle_s": _diff(events, "lights_on", "manoeuvre")}
    out = FaultOutcome(name or kind, kind, ok, outcome, None if margin is None else round(margin, 3),
                       "lockstep ddm+vehicle, scripted RSUs", details)
    return LinkRunResult(out, events, counts)


def _diff(ev: dict[str, float], a: str, b: str) -> float | None:
    return round(ev[b] - ev[a], 3) if a in ev and b in ev else None


LATENCIES_S = (0.0, 0.05, 0.1, 0.2, 0.3)
LOSSES = (0.1, 0.3, 0.5)
OUTAGES_S = (1.0, 2.0)


def latency_channel(latency_s: float) -> ChannelModel:
    """The latency case: ``latency_s`` each way with a half-normal jitter of a quarter of it."""
    return ChannelModel(latency_s=latency_s, jitter_s=latency_s / 4)


def latency_faults(seed: int = 0) -> list[FaultOutcome]:
    return [run_command_link(latency_channel(lat), name=f"latency {lat * 1000:.0f} ms +jitter", seed=seed).outcome
            for lat in LATENCIES_S]


def dropout_faults(seed: int = 0) -> list[FaultOutcome]:
    out = []
    for p in LOSSES:
        out.append(run_command_link(ChannelModel(latency_s=0.003, loss=p), name=f"loss {p:.0%}", kind="dropout",
                                    seed=seed).outcome)
    for length in OUTAGES_S:
        out.append(run_command_link(ChannelModel(latency_s=0.003), name=f"{length:.0f} s outage at the command",
                                    kind="dropout", seed=seed, outage_after_alert=(0.0, length)).outcome)
    return out


# ---------------------------------------------------------------------------------------------------
# The same faults on the whole corridor in lockstep (deploy/lockstep.py: the simulator, 4 RSUs rendering
# and processing pixels, the DDM and the vehicle on one SimClock). Slower (every camera frame is
# rendered: ~2-3x the scenario time on a loaded 2-core machine) but end to end.

LOCKSTEP_RUNNER = "lockstep corridor (sim + 4 RSUs + DDM + vehicle)"


def run_corridor_fault(name: str, kind: str, *, channel: ChannelModel | None = None, seed: int | None = None,
                       duration_s: float = 14.0, outage_s: tuple[float, float] | None = None,
                       kill_first_alerting_rsu: bool = False, restart_ddm_after_s: float | None = None
                       ) -> tuple[FaultOutcome, dict[str, Any]]:
    """One lockstep run of a scenario with one fault; the outcome is judged on the simulator's ground truth.

    ``outage_s`` = (start, length): total loss on the vehicle link in that window of scenario time (the
    run is deterministic: ``corridor_faults`` starts it when the same run without it sent its first command);
    ``kill_first_alerting_rsu``: the RSU that raised the first EvAlert stops at once;
    ``restart_ddm_after_s``: the DDM dies when the AV starts its first manoeuvre and a fresh one starts
    this long after.
    """
    from deploy.lockstep import CorridorLockstep, LockstepConfig
    from protocol import keys

    base = channel or ChannelModel()
    if outage_s is not None:
        base = dataclasses.replace(base, outages=((outage_s[0], outage_s[0] + outage_s[1]),))
    runner = CorridorLockstep(LockstepConfig(duration_s=duration_s, seed=seed, vehicle_channel=base))
    road = runner.corridor.road
    judge = YieldJudge()
    sent: dict[str, tuple[float, str]] = {}
    acks: list[tuple[float, str, str]] = []
    facts: dict[str, Any] = {}
    c = runner.corridor_id

    def on_world(_k: str, snap) -> None:
        judge.on_snapshot(snap, road)

    def on_alert(_k: str, msg) -> None:
        if msg.state.value != "active" or "first_alert" in facts:
            return
        now = runner.clock.now()
        facts["first_alert"], facts["first_alert_rsu"] = now, msg.rsu_id
        if kill_first_alerting_rsu:
            runner.at(now, lambda: runner.kill_rsu(msg.rsu_id))

    def on_state(_k: str, msg) -> None:
        if restart_ddm_after_s is not None and msg.mode.value == "manoeuvre" and "ddm_killed" not in facts:
            now = runner.clock.now()
            facts["ddm_killed"] = now
            facts["old_commands"] = set(sent)
            facts["active_at_kill"] = msg.active_command_id
            runner.at(now, runner.kill_ddm)
            runner.at(now + restart_ddm_after_s, runner.start_ddm)
        if "ddm_killed" in facts:
            facts.setdefault("modes_after_kill", []).append((runner.clock.now(), msg.mode.value))

    health_stale: list[tuple[float, list[str]]] = []
    runner.bus.subscribe(keys.sim_world_key(c), on_world)
    runner.bus.subscribe(keys.all_rsus_expr(c).replace("/*/*", "/*/ev"), on_alert)
    runner.bus.subscribe(keys.all_vehicles_expr(c, "state"), on_state)
    runner.bus.subscribe(keys.all_vehicles_expr(c, "cmd"),
                         lambda k, m: sent.setdefault(m.command_id, (runner.clock.now(), m.manoeuvre.value)))
    runner.bus.subscribe(keys.all_vehicles_expr(c, "ack"),
                         lambda k, m: acks.append((runner.clock.now(), m.command_id, m.status.value)))
    runner.bus.subscribe(keys.ddm_health_key(c), lambda k, m: health_stale.append((runner.clock.now(), list(m.stale))))
    m = runner.run()

    ok, outcome, margin = judge.outcome()
    lon = judge.events.get("lights_on")
    acked = {cid for _, cid, _ in acks}
    issued = sorted(sent, key=lambda i: sent[i][0])
    lost = [cid for i, cid in enumerate(issued) if cid not in acked and not any(x in acked for x in issued[i + 1:])]
    details: dict[str, Any] = {
        "events_sim_s": {k: round(v, 2) for k, v in judge.events.items()},
        "commands": [f"{sent[i][1]}@{sent[i][0] - (lon or 0):+.2f}s" for i in issued],
        "lost_commands": lost, "latency_s": m.get("latency_s"), "vehicle_link": m.get("vehicle_link"),
        "collision": m.get("collision"), "wall_s": m.get("wall_s"), "seed": m.get("seed"),
        "first_command_s": sent[issued[0]][0] if issued else None,
    }
    start = m.get("latency_s", {}).get("lights_on_to_manoeuvre_s")
    if start is not None:
        outcome += f", starts +{start:.2f} s"
    if kind in ("latency", "dropout"):
        if kind == "dropout":
            ok = not lost
            outcome = ("every command acked; " if not lost else f"{len(lost)} command(s) lost; ") + outcome
    elif kind == "rsu_kill":
        victim, t_kill = facts.get("first_alert_rsu"), facts.get("first_alert")
        stale_at = next((t for t, st in health_stale if t_kill is not None and t >= t_kill and victim in st), None)
        passed_at = judge.events.get("ev_passed_av")
        early = [i for i in issued if sent[i][1] == "resume" and t_kill is not None and sent[i][0] > t_kill
                 and (passed_at is None or sent[i][0] < passed_at)]
        details.update(killed=victim, stale_after_s=None if stale_at is None else round(stale_at - t_kill, 3),
                       resume_before_ev_passed=len(early))
        ok = stale_at is not None and not early
        outcome = (f"{victim} stale after {stale_at - t_kill:.2f} s" if stale_at is not None else
                   f"{victim} never reported stale") + (f"; {len(early)} early RESUME" if early else "") \
            + f"; yield: {outcome}"
        margin = None if stale_at is None else round(2.0 - (stale_at - t_kill), 3)
    elif kind == "ddm_restart":
        t_kill = facts.get("ddm_killed")
        old = facts.get("old_commands", set())
        new = [i for i in issued if i not in old]
        first_new_accept = min((t for t, cid, st in acks if cid in new and st == "accepted"), default=math.inf)
        modes = sorted({md for t, md in facts.get("modes_after_kill", []) if t < first_new_accept})
        passed_at = judge.events.get("ev_passed_av")
        contradicting = [i for i in new if sent[i][1] == "resume" and (passed_at is None or sent[i][0] < passed_at)]
        bad = [md for md in modes if md not in ("manoeuvre", "stopped", "minimal_risk")]
        details.update(modes_on_its_own=modes, new_ddm_commands=[f"{sent[i][1]}@{sent[i][0] - t_kill:+.2f}s" for i in new]
                       if t_kill is not None else [])
        ok = t_kill is not None and not bad and not contradicting
        outcome = ("no manoeuvre to interrupt" if t_kill is None else
                   f"vehicle {'fail-safe stop' if 'minimal_risk' in modes else 'kept its command'}"
                   + ("; restarted DDM sent RESUME before the EV passed" if contradicting else "")
                   + f"; yield: {outcome}")
        margin = None
    return FaultOutcome(name, kind, ok, outcome, None if margin is None else round(margin, 3), LOCKSTEP_RUNNER,
                        details), m


def corridor_faults(seed: int | None = None, quick: bool = False) -> list[FaultOutcome]:
    """The fault table on the whole corridor in lockstep (``quick``: the extreme cases only)."""
    lat = (0.0, 0.3) if quick else LATENCIES_S
    out = [run_corridor_fault(f"latency {x * 1000:.0f} ms +jitter", "latency", channel=latency_channel(x),
                              seed=seed)[0] for x in lat]
    first_cmd = out[0].details["first_command_s"]  # the perfect-link run: when the first command went out
    losses = (0.5,) if quick else LOSSES
    out += [run_corridor_fault(f"loss {p:.0%}", "dropout", channel=ChannelModel(latency_s=0.003, loss=p),
                               seed=seed)[0] for p in losses]
    if first_cmd is not None:
        for length in ((2.0,) if quick else OUTAGES_S):
            out.append(run_corridor_fault(f"{length:.0f} s outage at the command", "dropout", seed=seed,
                                          channel=latency_channel(0.0), outage_s=(first_cmd - 0.005, length))[0])
    out.append(run_corridor_fault("RSU killed with the EV in view", "rsu_kill", seed=seed,
                                  kill_first_alerting_rsu=True)[0])
    out.append(run_corridor_fault("DDM killed + restarted mid-manoeuvre", "ddm_restart", seed=seed,
                                  restart_ddm_after_s=1.0)[0])
    return out
