"""Fault scenarios of the corridor (docs/faults.md), each with a pass/fail outcome and a margin.

Two runners:

- ``run_command_link`` (in process, lockstep): the real ``DdmService`` and ``VehicleService`` on one
  ``SimClock`` over a ``LocalBus``, on a signed corridor (a DDM key and one per RSU, ``rig_keys``, as ``iea
  up`` runs); every message to and from the vehicle goes through its radio (``VehicleRadio``: the command
  link to the DDM and the RSUs' broadcasts, each a ``DsrcLink``) with the channel under test (latency +
  jitter, independent loss, scheduled outages of the command link or of the whole radio). Scripted RSUs
  stand in for perception: each publishes at 15 Hz the object list of what its camera sees (the AV's
  true pose, the EV) and, from ``lights_on_s + alert_delay_s``, the EvAlert at 2 Hz. The EV drives in
  the AV's lane at constant speed. Fast (a few seconds of CPU per run) and deterministic per seed.
- the process-level faults (an RSU killed, the DDM killed and restarted, the router restarted) run
  the corridor's real processes over Zenoh on loopback: see ``deploy/process_faults.py``.

Each row is judged by its kind's judge (``scenario/fault_judges.py``: ``latency``, ``dropout``).
Outcome of an EV-yield run: the one yield judge, ``scenario.outcome.judge_yield``, on ground truth:
pass only when the AV's body is out of the EV's lane before the EV is within its following distance of
it (2 m + 1 s x its speed), with no collision; stopped in the lane, blocked and "the EV never reached the
AV" are failures. Every row passes only on its own criterion AND that outcome.

Physical bound (``rig_bound``): the latest first EvAlert after lights-on from which the AV, on a perfect
link, still clears the EV's lane in time (found by bisection on the rig itself, so it is that EV speed
and that vehicle's lane change). A row whose fault cannot let the command reach the vehicle before the
bound (alert delay + the fault's own delay: an outage's length, a latency's p99) is *beyond the bound*:
listed with the bound, never counted as passed.

The rig's alert delay is the measured process-mode distribution of lights-on -> first EvAlert
(``MEASURED_ALERT_DELAY_S``; ``bench/e2e_bench.py`` passes the one it measured): rows run at its p99.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from dataclasses import dataclass
from typing import Any

from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

from protocol.clock import SimClock
from protocol.corridor import Corridor, load_corridor
from protocol.enums import AlertState, EvState, ObjectType, VehicleMode
from protocol.keys import all_vehicles_expr, rsu_key
from protocol.local_bus import LocalBus
from protocol.messages import DetectedObject, EvAlert, ObjectList, PathSwitchCommand
from protocol.radio import ChannelModel, DsrcLink
from protocol.security import Signer, public_key_b64
from protocol.transport import Subscription, Transport
from scenario.fault_judges import DeliverySeen, FaultOutcome, judge_dropout, judge_latency, lost_commands
from scenario.outcome import Body, YieldTrace, out_of_strip

CAMERA_VIEW_M = (18.0, 120.0)
"""What each RELLIS camera sees along x, relative to its own x (deploy/corridors/rellis.toml)."""


MEASURED_ALERT_DELAY_S = {"median": 0.86, "p99": 1.42}
"""Lights on -> first EvAlert over Zenoh (process mode, ``bench/e2e_bench.py``); the
bench replaces it with the distribution it measures in the same run."""


@dataclass(frozen=True)
class YieldScenario:
    """The scripted EV approach (the RELLIS field test: EV behind the AV in lane 1, faster)."""

    ev_gap_m: float = 50.0
    """EV centre this far behind the AV's at t = 0."""
    ev_speed_mps: float = 17.0
    lights_on_s: float = 4.0
    alert_delay_s: float = MEASURED_ALERT_DELAY_S["p99"]
    """Lights on -> first EvAlert (the RSU's detection latency over Zenoh: the measured p99)."""
    frame_rate_hz: float = 15.0
    duration_s: float = 20.0
    reach_gap_m: float = 2.0
    """The EV stops this far behind the AV's rear while the AV blocks its lane."""


def _detected(corridor: Corridor, oid: int, x: float, y: float, vx: float, vy: float, *, ev: bool,
              length_m: float, width_m: float) -> DetectedObject:
    lat, lon = corridor.to_latlon(x, y)
    return DetectedObject(
        object_id=oid, pos_x_m=x, pos_y_m=y, lat_deg=lat, lon_deg=lon, bbox_px=(0.0, 0.0, 10.0, 10.0),
        obj_type=ObjectType.EV if ev else ObjectType.VEHICLE, ev_state=EvState.CONFIRMED if ev else EvState.NONE,
        ev_score=0.9 if ev else 0.0, vel_x_mps=vx, vel_y_mps=vy, speed_mps=math.hypot(vx, vy),
        heading_rad=math.atan2(vy, vx) if (vx or vy) else 0.0, length_m=length_m, width_m=width_m,
        pos_cov_m2=(0.09, 0.0, 0.09), lane=None)


class VehicleRadio(Transport):
    """The vehicle's radio as two links: the RSUs' broadcasts (``rsu``: their object lists and EvAlerts)
    and the command link to the DDM (``cmd``: commands, acks, the DDM's Health, the vehicle's own state).
    A command-link outage cuts ``cmd`` only; a radio outage both."""

    def __init__(self, cmd: DsrcLink, rsu: DsrcLink) -> None:
        super().__init__()
        self.inner, self.cmd, self.rsu = cmd, cmd, rsu  # presence and queries go over the command link
        self.stats = cmd.stats

    def _link(self, key: str) -> DsrcLink:
        return self.rsu if "/rsu/" in key else self.cmd

    def publish_bytes(self, key: str, payload: bytes) -> None:
        self._link(key).publish_bytes(key, payload)

    def subscribe_bytes(self, key_expr: str, callback: Any) -> Subscription:
        return self._link(key_expr).subscribe_bytes(key_expr, callback)


@functools.lru_cache(maxsize=4)
def rig_keys(corridor_id: str, rsu_ids: tuple[str, ...]) -> tuple[Signer, dict[str, Signer], tuple[dict, ...]]:
    """The rig's signing keys (a DDM key, one per RSU) and the trust entries naming them: the rig runs a
    signed corridor, as ``iea up`` does (only signed evidence moves a car)."""
    def key(kid: str) -> tuple[Signer, str]:
        private = Ed25519PrivateKey.generate()
        return Signer(kid, private), public_key_b64(private.public_key())

    ddm, ddm_pub = key(f"{corridor_id}-rig-ddm")
    trust = [{"key_id": ddm.key_id, "role": "ddm", "public_key": ddm_pub, "vehicles": ["*"]}]
    rsus = {}
    for rsu in rsu_ids:
        rsus[rsu], pub = key(f"{corridor_id}-rig-{rsu}")
        trust.append({"key_id": rsus[rsu].key_id, "role": "rsu", "public_key": pub, "rsu_id": rsu})
    return ddm, rsus, tuple(trust)


@dataclass
class LinkRunResult:
    outcome: FaultOutcome
    events: dict[str, float]
    counts: dict[str, Any]


def run_command_link(channel: ChannelModel, *, name: str = "", kind: str = "latency", seed: int = 0,
                     scenario: YieldScenario = YieldScenario(), outage_after_alert: tuple[float, float] | None = None,
                     command_outage_after_alert: tuple[float, float] | None = None,
                     corridor: Corridor | None = None, direct_alerts: Any = None) -> LinkRunResult:
    """One lockstep run of the EV approach with the vehicle behind ``channel`` (its radio: the command link
    to the DDM and the RSUs' broadcasts, ``VehicleRadio``, each through ``channel``), on a signed corridor.

    ``outage_after_alert`` = (start, length): a window of total loss on the whole vehicle radio starting
    that long after the first EvAlert (the worst moment: the command is in flight);
    ``command_outage_after_alert``: the same on the command link only (the RSUs are still heard).
    ``direct_alerts``: the vehicle's ``DirectAlertConfig`` (default: on).
    """
    if kind not in ("latency", "dropout"):
        raise ValueError(f"run_command_link: kind {kind!r} is not a fault of the rig: use 'latency' or 'dropout' "
                         "(the process and corridor runners run the rsu_kill and ddm_restart kinds)")
    from ddm.config import DdmConfig
    from ddm.service import DdmService
    from vehicle.ev_direct import DirectAlertConfig
    from vehicle.service import VehicleService

    corridor = corridor or load_corridor()
    ddm_signer, rsu_signers, trust = rig_keys(corridor.corridor_id, tuple(r.rsu_id for r in corridor.rsus))
    corridor = dataclasses.replace(corridor, trust=trust)
    sc = scenario
    c = corridor.corridor_id
    bus = LocalBus()
    t0 = 1000.0
    clock = SimClock(t0)
    t_alert = t0 + sc.lights_on_s + sc.alert_delay_s

    def cut(ch: ChannelModel, window: tuple[float, float] | None) -> ChannelModel:
        if window is None:
            return ch
        start = window[0] + t_alert - 0.005  # half a step early: the alert goes out on the step nearest t_alert
        return dataclasses.replace(ch, outages=ch.outages + ((start, start + window[1]),))

    cmd_channel = cut(cut(channel, outage_after_alert), command_outage_after_alert)
    ddm = DdmService(bus, clock, corridor, DdmConfig(), signer=ddm_signer)
    link = DsrcLink(bus, cmd_channel, seed=seed, clock=clock, threaded=False)
    rsu_link = DsrcLink(bus, cut(channel, outage_after_alert), seed=seed + 7919, clock=clock, threaded=False)
    veh = VehicleService(VehicleRadio(link, rsu_link), clock, corridor, "av1", seed=seed,
                         direct_alerts=direct_alerts or DirectAlertConfig())
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
    trace = YieldTrace(road=road)
    ev_strip = (road.lane_width_m, 2 * road.lane_width_m)  # the EV drives in lane 1
    modes_seen: set[str] = set()
    n_steps = int(round(sc.duration_s / dt))
    for _ in range(n_steps):
        now = clock.advance(dt)
        t = now - t0
        st = veh.sim.truth
        if t >= sc.lights_on_s:
            events.setdefault("lights_on", now)
        # the EV: constant speed, but it cannot drive through an AV in its lane (it brakes behind it).
        # RELLIS is straight along +x from y = 0, so (x, y) serve as the road frame's (s, d)
        av_rear = st.x_m - vc.length_m / 2
        av_body = Body(st.x_m, st.y_m, vc.length_m, vc.width_m, st.vx_mps, math.remainder(st.yaw_rad, 2 * math.pi))
        ev_x0 = ev_x
        ev_x += sc.ev_speed_mps * dt
        if not out_of_strip(av_body, ev_strip) and ev_x < st.x_m and ev_x + ev_len / 2 > av_rear - sc.reach_gap_m:
            ev_x = max(ev_x0, av_rear - sc.reach_gap_m - ev_len / 2)  # it may not drive through the AV
        trace.add(now, av_body, Body(ev_x, ev_y, ev_len, ev_w, (ev_x - ev_x0) / dt), t >= sc.lights_on_s)
        if ev_x - ev_len / 2 > st.x_m + vc.length_m / 2:
            events.setdefault("ev_passed_av", now)
        link.deliver_due(now)
        rsu_link.deliver_due(now)
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
                k = rsu_key(c, rsu, "ev")
                bus.publish(k, rsu_signers[rsu].sign_message(k, EvAlert(
                    src=rsu, stamp=now, alert_id=f"{rsu}-ev", state=AlertState.ACTIVE, rsu_id=rsu, object_id=2,
                    pos_x_m=ev_x, pos_y_m=ev_y, lat_deg=lat, lon_deg=lon, vel_x_mps=sc.ev_speed_mps,
                    speed_mps=sc.ev_speed_mps, confidence=0.9, first_seen=t_alert)))
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
            if veh.direct_pull_overs:
                events.setdefault("direct_pull_over", now)
        if core.mode in (VehicleMode.STOPPED, VehicleMode.MINIMAL_RISK) and st.vx_mps < 0.05:
            events.setdefault("stopped", now)
        if now + 1e-9 >= next_ddm:
            next_ddm += 1.0 / ddm.config.rate_hz
            ddm.step(now)
        if "ev_passed_av" in events and now - events["ev_passed_av"] > 3.0 \
                and ddm.commands.outstanding() == 0 and (not sent or now - sent[-1].stamp > 1.0):
            break  # the EV is well past and no command is in flight: the outcome is known
    link.close()
    rsu_link.close()
    ddm.close()
    veh.close()
    bus.close()

    # -- the outcome
    verdict = trace.verdict()
    for k in ("reach", "lane_clear"):
        if getattr(verdict, f"{k}_s") is not None:
            events[{"reach": "ev_reaches_av"}.get(k, k)] = getattr(verdict, f"{k}_s")
    rel = {k: round(v - events.get("lights_on", t0), 3) for k, v in events.items()}
    issued = list(dict.fromkeys(c.command_id for c in sent))
    manoeuvre_of = {c.command_id: c.manoeuvre.value for c in sent}
    delivery = DeliverySeen(tuple(issued), frozenset(cid for _, cid, _ in acks_at_ddm), dict(activations),
                            int(ddm.counters["cmd_expired"]))
    first_sent = {}
    for cmd in sent:
        first_sent.setdefault(cmd.command_id, cmd.stamp)
    lon = events.get("lights_on", t0)
    counts = {
        "commands_issued": len(issued),
        "manoeuvres": [f"{manoeuvre_of[i]}@{first_sent[i] - lon:.2f}s" for i in issued],
        "transmissions": len(sent), "acks_at_ddm": len(acks_at_ddm),
        "lost_commands": lost_commands(delivery.issued, delivery.acked),
        "duplicate_activations": {cid: n for cid, n in activations.items() if n > 1},
        "ddm_expired": delivery.expired_at_ddm,
        "link": {d: dict(v) for d, v in link.counts.items()}, "modes": sorted(modes_seen),
        "rsu_link": {d: dict(v) for d, v in rsu_link.counts.items()}, "direct_pull_overs": veh.direct_pull_overs,
    }
    note = ""
    if "manoeuvre" in events and "lights_on" in events:
        note += f", starts +{events['manoeuvre'] - events['lights_on']:.2f} s"
    if "direct_pull_over" in events:
        note += f", pulled over on its own on the signed EvAlert +{events['direct_pull_over'] - events['lights_on']:.2f} s"
    elif "failsafe" in events:
        note += ", fail-safe stop"
    judged = judge_dropout(delivery, verdict.to_dict()) if kind == "dropout" else judge_latency(verdict.to_dict())
    details = {"events_since_lights_on_s": rel, **counts, "yield": verdict.to_dict(),
               "alert_delay_s": sc.alert_delay_s,
               "lights_on_to_command_at_vehicle_s": _diff(events, "lights_on", "manoeuvre")}
    out = judged.row(name or kind, kind, "lockstep ddm+vehicle, scripted RSUs", details, yield_note=note)
    return LinkRunResult(out, events, counts)


def _diff(ev: dict[str, float], a: str, b: str) -> float | None:
    return round(ev[b] - ev[a], 3) if a in ev and b in ev else None


LATENCIES_S = (0.0, 0.05, 0.1, 0.2, 0.3)
LOSSES = (0.1, 0.3, 0.5)
OUTAGES_S = (1.0, 2.0)


def latency_channel(latency_s: float) -> ChannelModel:
    """The latency case: ``latency_s`` each way with a half-normal jitter of a quarter of it."""
    return ChannelModel(latency_s=latency_s, jitter_s=latency_s / 4)


def latency_fault_delay_s(latency_s: float) -> float:
    """p99 one-way delay of ``latency_channel``: latency + the half-normal jitter's p99 (2.576 sigma)."""
    return latency_s * (1.0 + 2.576 / 4)


@functools.lru_cache(maxsize=8)
def rig_bound(scenario: YieldScenario = YieldScenario(), resolution_s: float = 0.02) -> tuple[float, float]:
    """(latest alert delay, the manoeuvre start it gave) after lights-on: the latest first EvAlert from which
    the AV, on a perfect link, still gets out of the EV's lane before the EV reaches it. Bisection on the
    rig (that EV speed, that vehicle's lane change). (-inf, nan) when even an alert at lights-on is late."""
    def run(delay_s: float) -> LinkRunResult:
        return run_command_link(ChannelModel(), scenario=dataclasses.replace(scenario, alert_delay_s=delay_s))

    lo, hi = 0.0, scenario.duration_s - scenario.lights_on_s
    first = run(lo)
    if not first.outcome.details["yield"]["passed"]:
        return -math.inf, math.nan
    best = first
    while hi - lo > resolution_s:
        mid = (lo + hi) / 2
        r = run(mid)
        if r.outcome.details["yield"]["passed"]:
            lo, best = mid, r
        else:
            hi = mid
    start = best.outcome.details["lights_on_to_command_at_vehicle_s"]
    return lo, math.nan if start is None else start


def _judged(r: FaultOutcome, fault_delay_s: float | None, scenario: YieldScenario) -> FaultOutcome:
    """Mark a row beyond the physical bound when alert delay + the fault's own delay exceed it (and it failed
    on the yield outcome); ``fault_delay_s``: the least delay the fault adds to the command (0: none)."""
    if fault_delay_s is None or r.passed:
        return r
    latest, _ = rig_bound(dataclasses.replace(scenario, alert_delay_s=0.0))
    earliest = scenario.alert_delay_s + fault_delay_s
    if earliest <= latest:
        return r
    late = f"no earlier than +{earliest:.2f} s (alert {scenario.alert_delay_s:.2f} s + fault {fault_delay_s:.2f} s)"
    if math.isinf(latest):
        bound = f"even a first EvAlert at lights-on is too late for this EV speed and lane change; this case alerts {late}"
    else:
        bound = f"latest first EvAlert that clears the lane in time +{latest:.2f} s after lights-on; this case: {late}"
    return dataclasses.replace(r, beyond_bound=bound, details={**r.details, "bound_latest_alert_s": latest,
                                                               "earliest_alert_with_fault_s": round(earliest, 3)})


def _retimed(channel: ChannelModel, scenario: YieldScenario, **kw: Any) -> FaultOutcome:
    """One rig row; an approach where the EV never reached the AV tested nothing: run it again for longer."""
    r = run_command_link(channel, scenario=scenario, **kw).outcome
    if r.details["yield"]["status"] == "not_reached":
        longer = dataclasses.replace(scenario, duration_s=2 * scenario.duration_s)
        r = run_command_link(channel, scenario=longer, **kw).outcome
        r.details["retimed_duration_s"] = longer.duration_s
    return r


def latency_faults(seed: int = 0, alert_delay_s: float = MEASURED_ALERT_DELAY_S["p99"]) -> list[FaultOutcome]:
    sc = YieldScenario(alert_delay_s=alert_delay_s)
    return [_judged(_retimed(latency_channel(lat), sc, name=f"latency {lat * 1000:.0f} ms +jitter", seed=seed),
                    latency_fault_delay_s(lat), sc) for lat in LATENCIES_S]


def dropout_faults(seed: int = 0, alert_delay_s: float = MEASURED_ALERT_DELAY_S["p99"]) -> list[FaultOutcome]:
    """Loss on the vehicle's radio, then 1 s / 2 s outages from the first command: of the command link only
    ("total loss on the command link": the RSUs' broadcasts still reach the car, which may act on a
    signed EvAlert once its command is ``command_deadline_s`` late: the fault's least delay is the shorter of
    the two) and of the whole radio (nothing reaches the car: the outage's length)."""
    from vehicle.ev_direct import DirectAlertConfig

    sc = YieldScenario(alert_delay_s=alert_delay_s)
    deadline = DirectAlertConfig().command_deadline_s
    out = []
    for p in LOSSES:
        out.append(_judged(_retimed(ChannelModel(latency_s=0.003, loss=p), sc, name=f"loss {p:.0%}", kind="dropout",
                                    seed=seed), 0.0, sc))  # at best the first send gets through
    for length in OUTAGES_S:
        out.append(_judged(_retimed(ChannelModel(latency_s=0.003), sc, name=f"{length:.0f} s command-link outage",
                                    kind="dropout", seed=seed, command_outage_after_alert=(0.0, length)),
                           min(length, deadline), sc))
    for length in OUTAGES_S:
        out.append(_judged(_retimed(ChannelModel(latency_s=0.003), sc, name=f"{length:.0f} s radio outage",
                                    kind="dropout", seed=seed, outage_after_alert=(0.0, length)), length, sc))
    return out
