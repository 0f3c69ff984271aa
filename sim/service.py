"""Simulator service (imperative shell): runs a scenario's world in (scaled) real time, publishes
``WorldSnapshot`` at 20 Hz on ``iea/{c}/sim/world`` and ``Health`` at 1 Hz on ``iea/{c}/sim/health``,
takes the AV pose from ``iea/{c}/vehicle/{veh}/state`` when a vehicle process publishes it, and can
record any RSU camera's rendered view to a video file.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import Counter
from dataclasses import dataclass

import cv2

from protocol import metrics, presence
from protocol.clock import Clock, RateTimer, WallClock
from protocol.codec import encode
from protocol.enums import HealthStatus, Role
from protocol.keys import all_vehicles_expr, sim_health_key, sim_world_key
from protocol.messages import Health, VehicleState, WorldSnapshot
from protocol.runtime import freeze_startup_heap
from protocol.transport import Transport
from sim.render.renderer import Renderer
from sim.scenario import Scenario
from sim.world import World

log = logging.getLogger("iea.sim")
WORLD_RATE_HZ = 20.0
HEALTH_PERIOD_S = 1.0
AV_STATE_TIMEOUT_S = 3.0
"""Without vehicle state for this long, the AV goes back to its script (from its last pose). Until then the
world carries its last state forward (``World.set_av_pose``): a car whose radio is lossy still moves, and its
states arrive in bursts seconds apart (the DDM carries them forward as long, ``ddm.world.EGO_PREDICTION_MAX_S``)."""


@dataclass
class Recording:
    rsu_id: str
    path: str


class SimService:
    def __init__(self, scenario: Scenario, transport: Transport, clock: Clock | None = None, *,
                 corridor_id: str | None = None, speed: float = 1.0, duration_s: float | None = None,
                 recordings: list[Recording] | None = None, src: str = "sim", seed: int | None = None) -> None:
        if not speed > 0:
            raise ValueError(f"speed must be > 0, got {speed}")
        self.scenario = scenario
        scenario.corridor.road.prepare()  # its first road query would cost 0.4 s at the scenario's start
        self.transport = transport
        self.clock = clock or WallClock()
        self.corridor_id = corridor_id or scenario.corridor.corridor_id
        self.speed = speed
        self.duration_s = scenario.duration_s if duration_s is None else duration_s
        self.world = World(scenario, seed=seed)
        self.src = src
        self.dt_s = 1.0 / WORLD_RATE_HZ
        self.rejected: Counter = Counter()
        self.published = 0
        self.av_updates = 0
        self._pending_states: dict[str, VehicleState] = {}
        self._last_state: dict[str, tuple[VehicleState, float]] = {}
        """Per AV, the newest state applied and the time it describes (its stamp, at most when it was applied)."""
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._step_ms = 0.0
        self.last_snapshot: WorldSnapshot | None = None
        """The snapshot the last ``step_once`` published."""
        self._recorders = []
        for rec in recordings or []:
            rsu = scenario.corridor.rsu(rec.rsu_id)
            r = Renderer(rsu.camera, scenario.corridor.road, seed=self.world.seed)
            writer = cv2.VideoWriter(rec.path, cv2.VideoWriter_fourcc(*"mp4v"), rsu.camera.fps,
                                     (rsu.camera.width_px, rsu.camera.height_px))
            if not writer.isOpened():
                raise ValueError(f"cannot open video file {rec.path!r} for writing")
            self._recorders.append([rsu, r, writer, -1])
        self._vehicle_ids = {v.vehicle_id for v in self.world.vehicles() if v.kind == "av"}
        self._sub = transport.subscribe(all_vehicles_expr(self.corridor_id, "state"), self._on_state,
                                        on_reject=lambda _k, _e: None)
        self._last_health: Health | None = None
        self._handles = [  # presence token, latest Health on query
            presence.serve(transport, sim_health_key(self.corridor_id),
                           lambda _q: [] if self._last_health is None
                           else [(sim_health_key(self.corridor_id), encode(self._last_health))]),
            presence.announce(transport, self.corridor_id, "sim", "sim"),
        ]

    def _on_state(self, _key: str, msg: VehicleState) -> None:
        if msg.vehicle_id not in self._vehicle_ids:
            self.rejected["unknown_vehicle"] += 1
            return
        with self._lock:
            self._pending_states[msg.vehicle_id] = msg

    def set_av_state(self, msg: VehicleState) -> None:
        """Take an AV state directly (lockstep: the plant's true pose, not a radio message)."""
        self._on_state("", msg)

    def close_subscription(self) -> None:
        """Stop listening to vehicle state on the transport (the lockstep runner feeds ``set_av_state``)."""
        self._sub.close()

    def stop(self) -> None:
        self._stop.set()

    def step_once(self) -> None:
        """One world step: apply the latest AV states, step, publish the snapshot, record frames."""
        with self._lock:
            states, self._pending_states = self._pending_states, {}
        now = self.clock.now()
        for st in list(states.values()):
            last = self._last_state.get(st.vehicle_id)
            age_s = max(now - st.stamp, 0.0)
            if (last is not None and st.stamp < last[0].stamp) or age_s > AV_STATE_TIMEOUT_S:
                del states[st.vehicle_id]  # older than one applied already, or too old to carry forward
                continue
            # a state is where the car was at its stamp: one that a lossy link delivers seconds late (TCP hands
            # a stall's states over in a burst) is carried forward to now, not taken as where the car is now
            self.world.set_av_pose(st, age_s)
            self.av_updates += 1
            self._last_state[st.vehicle_id] = (st, now - age_s)
        for vid, (last, t_last) in list(self._last_state.items()):
            if vid in states:
                continue
            if now - t_last > AV_STATE_TIMEOUT_S:
                self.world.release_av(vid)
                del self._last_state[vid]
                log.info("no state from %s for %.1f s: AV scripted again", vid, now - t_last)
            else:
                self.world.set_av_pose(last, now - t_last)
        t0 = time.perf_counter()
        self.world.step(self.dt_s)
        self._step_ms = (time.perf_counter() - t0) * 1e3
        metrics.observe_stages({"step": self._step_ms / 1e3})
        snap = self.world.snapshot(stamp=self.clock.now(), src=self.src, seq=self.published)
        self.last_snapshot = snap
        self.transport.publish(sim_world_key(self.corridor_id), snap)
        self.published += 1
        for rec in self._recorders:
            rsu, r, writer, last = rec
            idx = int(snap.sim_time_s * rsu.camera.fps)
            if idx != last:
                writer.write(r.render(snap, frame_index=idx))
                rec[3] = idx

    def health(self, uptime_s: float) -> Health:
        rej = dict(self.rejected)
        for reason, n in self.transport.stats.rejected.items():
            rej[f"decode_{reason}"] = n
        return Health(src=self.src, stamp=self.clock.now(), role=Role.SIM, status=HealthStatus.OK,
                      uptime_s=max(0.0, uptime_s), rates_hz={"world": WORLD_RATE_HZ * self.speed},
                      latency_ms={"world_step": self._step_ms}, rejected=rej,
                      detail=f"scenario {self.scenario.name} t={self.world.t_s:.2f}s av_updates={self.av_updates}")

    def wait_to_start(self, timeout_s: float, *, avs: bool = True, rsu_ids: tuple[str, ...] | list[str] = (),
                      poll_s: float = 0.02) -> bool:
        """Hold the world at t = 0 until the corridor is up (or ``timeout_s``): every AV of the scenario has sent
        its state (``avs``) and every RSU of ``rsu_ids`` has declared its liveliness token.

        A vehicle process starts driving its own plant as soon as it is up. Started beside the simulator
        it may be up seconds later (imports, Zenoh discovery on a loaded host); a world that ran from the
        scenario's script meanwhile would see its AV jump back to the start pose, and the traffic behind
        it (the EV) close up. An RSU declares its token once its pipeline is built; on a slow two-core host
        four RSUs loading their models at once took 7-9 s, and a world started before them lit the EV's lamps
        with no camera watching (the scenario then measured the RSUs' start-up, not the pipeline).
        A vehicle process drives from the moment it is up, so a world held for RSUs after its AV reported
        would see the AV far ahead: start the vehicle once the RSUs are up (``iea up`` and ``iea demo`` do).
        Returns True when everything reported; False: the world starts anyway, and the log names who is missing.
        """
        alive = presence.AliveSet(self.transport, self.corridor_id, "rsu") if rsu_ids else None
        if alive is not None and not alive.watching:
            log.warning("this transport has no liveliness tokens: the world does not wait for the RSUs")
            rsu_ids = ()
        deadline = self.clock.now() + timeout_s
        t0 = self.clock.now()
        try:
            while not self._stop.is_set():
                with self._lock:
                    missing = sorted(self._vehicle_ids - set(self._pending_states)) if avs else []
                if rsu_ids:
                    missing += alive.missing(rsu_ids)
                if not missing:
                    waited = [*sorted(self._vehicle_ids if avs else ()), *sorted(rsu_ids)]
                    if waited:
                        log.info("every service reported (%s) after %.1f s: the world starts", ", ".join(waited),
                                 self.clock.now() - t0)
                    return True
                if self.clock.now() >= deadline:
                    log.warning("nothing from %s within %.1f s: the world starts without them",
                                ", ".join(missing), timeout_s)
                    return False
                self.clock.sleep(poll_s)
            return False
        finally:
            if alive is not None:
                alive.close()

    def run(self, wait_for_av_s: float | None = None, wait_for_rsus: tuple[str, ...] | list[str] = (),
            wait_timeout_s: float = 60.0) -> int:
        """Run until the scenario's duration or stop(); returns the number of snapshots published.
        ``wait_for_av_s``: first hold the world until the AVs report; ``wait_for_rsus``: and until these RSUs
        are up, at most ``wait_timeout_s`` for them (:meth:`wait_to_start`)."""
        freeze_startup_heap()  # full GC passes scan only what the service makes from now on
        avs = wait_for_av_s is not None and bool(self._vehicle_ids)
        if wait_for_rsus:
            self.wait_to_start(max(wait_timeout_s, wait_for_av_s or 0.0), avs=avs, rsu_ids=tuple(wait_for_rsus))
        elif avs:
            self.wait_to_start(wait_for_av_s)
        start = self.clock.now()
        health_timer = RateTimer(HEALTH_PERIOD_S)
        next_t = start
        try:
            while not self._stop.is_set() and self.world.t_s < self.duration_s - 1e-9:
                self.step_once()
                now = self.clock.now()
                if health_timer.due(now):
                    self._last_health = self.health(now - start)
                    self.transport.publish(sim_health_key(self.corridor_id), self._last_health)
                next_t += self.dt_s / self.speed
                delay = next_t - self.clock.now()
                if delay > 0:
                    self.clock.sleep(delay)
                elif delay < -1.0:
                    next_t = self.clock.now()  # fell behind (slow recorder): do not burst
        finally:
            self.close()
        return self.published

    def close(self) -> None:
        self.world.close()
        presence.close_all(self._handles)
        self._sub.close()
        for _rsu, _r, writer, _last in self._recorders:
            writer.release()
        self._recorders = []


def run_scenario(scenario: str, zenoh, *, corridor_file: str | None = None, corridor_id: str | None = None,
                 record: list[str] = (), speed: float = 1.0, duration_s: float | None = None, seed: int | None = None,
                 lighting: str | None = None, wait_for_av_s: float | None = None, wait_for_rsus: str | None = None,
                 wait_timeout_s: float = 60.0, ev_key: str | None = None, traffic: str | None = None,
                 ev_radio_loss: float | None = None) -> int:
    """``iea-sim run``: scenario ``scenario`` (a name or a .toml path) in real time over Zenoh (``zenoh``:
    ``ZenohSettings``) until its end or SIGTERM/SIGINT. ``record``: ``RSU:FILE.mp4`` items. An equipped EV
    broadcasts its CAMs (``sim.ev_radio``), signed with ``ev_key`` (PEM) when given, its radio losing each with
    probability ``ev_radio_loss`` (None: the corridor's ``dsrc_loss``). Raises ValueError
    (ScenarioError, CorridorError) and KeyError (an unknown RSU) before anything is published."""
    import signal

    from protocol.corridor import load_corridor
    from protocol.zenoh_transport import ZenohTransport
    from sim.scenario import load_scenario

    if wait_for_av_s is not None and not wait_for_av_s >= 0:
        raise ValueError(f"--wait-for-av wants seconds >= 0, got {wait_for_av_s}")
    if not wait_timeout_s >= 0:
        raise ValueError(f"--wait-timeout wants seconds >= 0, got {wait_timeout_s}")
    if ev_radio_loss is not None and not 0.0 <= ev_radio_loss <= 1.0:
        raise ValueError(f"--ev-radio-loss wants a probability in [0, 1], got {ev_radio_loss}")
    corridor = load_corridor(corridor_file) if corridor_file else None
    sc = load_scenario(scenario, corridor).with_overrides(seed=seed, lighting=lighting, traffic=traffic)
    recs = []
    for item in record:
        rsu, sep, path = item.partition(":")
        if not sep or not path:
            raise ValueError(f"--record wants RSU:FILE.mp4, got {item!r}")
        sc.corridor.rsu(rsu)
        recs.append(Recording(rsu, path))
    rsu_ids = rsus_to_wait_for(wait_for_rsus, sc.corridor)
    transport = ZenohTransport(zenoh)
    try:
        svc = SimService(sc, transport, corridor_id=corridor_id, speed=speed, duration_s=duration_s, recordings=recs)
        radio = None
        if sc.ev is not None and sc.ev.equipped:
            from sim.ev_radio import start_radio

            radio = start_radio(transport, sc.corridor, corridor_id or sc.corridor.corridor_id, ev_key, seed=sc.seed,
                                loss=ev_radio_loss)
        signal.signal(signal.SIGTERM, lambda *_: svc.stop())
        signal.signal(signal.SIGINT, lambda *_: svc.stop())
        n = svc.run(wait_for_av_s=wait_for_av_s, wait_for_rsus=rsu_ids, wait_timeout_s=wait_timeout_s)
        log.info("published %d snapshots", n)
        if radio is not None:
            log.info("the EV's radio sent %d CAMs (radio %s)", radio.sent, dict(radio.transport.counts["tx"]))
            radio.close()
    finally:
        transport.close()
    return 0


def rsus_to_wait_for(spec: str | None, corridor) -> list[str]:
    """``--wait-for-rsus``: ``None``/``""`` -> none, ``all`` -> every RSU of the corridor, else comma-separated ids
    (each checked against the corridor: an unknown id raises KeyError naming the corridor's RSUs)."""
    if not spec:
        return []
    if spec.strip() == "all":
        return [r.rsu_id for r in corridor.rsus]
    ids = [i.strip() for i in spec.split(",") if i.strip()]
    for i in ids:
        corridor.rsu(i)
    return ids
