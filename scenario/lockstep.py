"""The whole corridor in one process on a simulated clock: ``iea scenario run NAME --inprocess``.

docs/architecture.md §Three ways to run: this is the lockstep way. The simulator (``SimService``),
one RSU per camera of the corridor (``SimCamera`` renders the snapshot to pixels, then the RSU's own
``RsuService`` runs detector -> SORT -> EV classifier -> localiser and publishes), the DDM
(``DdmService``) and the vehicle (``VehicleService``) share a ``LocalBus`` and a ``SimClock``. A
small scheduler advances the clock to the next due time of any component (world 20 Hz, cameras at
their fps, DDM at its rate, vehicle control at 100 Hz) and runs what is due, so a run is
deterministic for a given seed and runs as fast as the CPU allows (or paced to real time).

Links. The vehicle reaches the DDM through an optional ``DsrcLink`` (``vehicle_channel``: latency,
jitter, loss, bursts) in both directions; the RSU -> DDM links are wired. The physical world is not
a radio: the simulator takes the AV's true pose straight from the vehicle's plant, not over the link.

What is not modelled: processing time. A frame's objects are published at the frame's capture time
(the measured per-stage latency is in the RSU's Health and in ``bench/rsu_bench.py``).

Faults. ``schedule`` takes ``(t_s, action)`` pairs; actions are methods of the runner such as
``kill_rsu("rsu2")``, ``kill_ddm()`` and ``start_ddm()`` (a fresh DDM with no memory, as after a
crash), so the fault tests can script a run.

Scoring (``RunMonitor`` from ``scenario/monitor.py``) reads the simulator's ground truth; perception
never does.
"""

from __future__ import annotations

import heapq
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

from ddm.build import DdmOptions, build_ddm
from ddm.config import DdmConfig
from ddm.service import DdmService
from protocol import keys
from protocol.clock import SimClock
from protocol.corridor import Corridor
from protocol.local_bus import LocalBus
from protocol.messages import VehicleState
from protocol.radio import ChannelModel, DsrcLink
from protocol.transport import Transport
from rsu.build import PipelineConfig, build_pipeline
from rsu.frames import Frame
from rsu.service import RsuService
from rsu.sim_source import SimSource
from scenario.monitor import RunMonitor
from sim.camera_source import SimCamera
from sim.scenario import Scenario, load_scenario
from sim.service import SimService
from sim.warmup import WARMUP_S, warmup_frames
from vehicle.service import VehicleService

WORLD_PERIOD_S = 0.05


@dataclass
class LockstepConfig:
    scenario: str = "rellis_ev_yield"
    seed: int | None = None
    """Scenario seed (traffic, camera noise); None: the scenario file's."""
    duration_s: float | None = None
    """None: the scenario's duration."""
    detector: str = "project"
    """``project`` (models/iea_det_tiny.onnx), ``motion`` (MOG2, no model) or a path to an ONNX detector."""
    vehicle_channel: ChannelModel | None = None
    """Radio between the vehicle and the rest (both directions); None: a perfect link."""
    channel_seed: int = 0
    ddm_config: DdmConfig = field(default_factory=DdmConfig)
    vehicle_seed: int = 0
    record_vehicle: bool = False
    annotate_dir: Path | None = None
    """Write every RSU's annotated video here."""
    realtime: bool = False
    """Pace the simulated clock to the wall clock (for watching); the default runs as fast as it can."""
    hazards: bool = True
    """RSUs run the static-object hazard detector (``rsu.hazard``)."""
    warmup_s: float = WARMUP_S
    """Before scenario time 0 the motion and hazard detectors learn their background from this many seconds
    of each camera's own frames of the road with traffic (``sim.warmup``): no picture of the empty road."""
    camera_hz: float | None = None
    """Each RSU's annotated frames a second on the bus (``rsu.camera_feed``); None: 2 when the run is recorded,
    else 0."""
    traffic: str | None = None
    """Who drives the traffic: ``project`` or ``sumo`` (``sim.sumo``); None: the scenario's choice."""


class _Task:
    """A periodic job of the scheduler."""

    def __init__(self, name: str, period_s: float, fn: Callable[[float], None], start_s: float = 0.0) -> None:
        self.name, self.period_s, self.fn = name, period_s, fn
        self.next_s = start_s
        self.alive = True


class Recorder(Protocol):
    """What records a run: every message's bytes as the bus delivers them (e.g. ``deploy.record.McapRecorder``)."""

    def on_bytes(self, key: str, payload: bytes) -> None: ...

    def close(self) -> None: ...


RecorderFactory = Callable[[Callable[[], float], dict[str, str]], Recorder]
"""``factory(clock_now, metadata) -> Recorder``: the recorder of a run, given its clock and its metadata."""


class CorridorLockstep:
    """Builds the services of a scenario on one bus and clock; ``run()`` returns the run's metrics."""

    def __init__(self, config: LockstepConfig | None = None, *, scenario: Scenario | None = None,
                 recorder: RecorderFactory | None = None) -> None:
        self.config = cfg = config or LockstepConfig()
        sc = scenario or load_scenario(cfg.scenario)
        if cfg.seed is not None or cfg.traffic is not None:
            sc = sc.with_overrides(seed=cfg.seed, traffic=cfg.traffic)
        self.scenario = sc
        corridor: Corridor = sc.corridor
        self.vehicle_id = sc.av.vehicle_id if sc.av is not None else None
        if sc.av is not None:  # the vehicle process starts where the scenario puts the AV
            corridor = corridor.with_vehicle(sc.av.vehicle_id, start_s_m=sc.av.start_s_m, start_lane=sc.av.lane,
                                             cruise_speed_mps=sc.av.speed_mps)
        self.corridor = corridor
        self.corridor_id = corridor.corridor_id
        self.duration_s = sc.duration_s if cfg.duration_s is None else cfg.duration_s
        self.clock = SimClock(0.0)
        self.bus = LocalBus()
        self.monitor = RunMonitor(self.corridor_id, vehicle_id=self.vehicle_id or "av1", road=corridor.road)
        self._monitor_sub = self.bus.subscribe(keys.corridor_expr(self.corridor_id), self.monitor.on_message)
        self.recorder: Recorder | None = None
        if recorder is not None:  # subscribed before any service: it sees each message before they act on it
            self.recorder = recorder(self.clock.now, {"corridor_id": self.corridor_id, "scenario": sc.name,
                                                      "seed": str(sc.seed), "mode": "lockstep"})
            self.bus.subscribe_bytes(keys.corridor_expr(self.corridor_id), self.recorder.on_bytes)
        self.sim = SimService(sc, self.bus, self.clock, seed=sc.seed)
        self.sim.close_subscription()  # the AV's pose comes from its plant (below), not over the radio
        self._tasks: list[_Task] = []
        self._schedule: list[tuple[float, int, Callable[[], None]]] = []
        self._order = 0
        self.rsus: dict[str, RsuService] = {}
        self._cameras: dict[str, SimCamera] = {}
        self._snapshot = None
        for r in corridor.rsus:
            self._add_rsu(r.rsu_id)
        self._warm_up()
        self.ddm: DdmService | None = None
        self.start_ddm()
        self.link: DsrcLink | None = None
        self.vehicle: VehicleService | None = None
        if self.vehicle_id is not None:
            vt: Transport = self.bus
            if cfg.vehicle_channel is not None:
                self.link = DsrcLink(self.bus, cfg.vehicle_channel, seed=cfg.channel_seed, clock=self.clock,
                                     threaded=False)
                vt = self.link
            self.vehicle = VehicleService(vt, self.clock, corridor, self.vehicle_id, seed=cfg.vehicle_seed,
                                          record=cfg.record_vehicle)
            self._tasks.append(_Task("vehicle", self.vehicle.timing.control_period_s, self._vehicle_step))
        self._tasks.append(_Task("world", WORLD_PERIOD_S, self._world_step, start_s=WORLD_PERIOD_S))
        self.stats = {"frames": 0, "render_s": 0.0, "rsu_s": 0.0, "wall_s": 0.0}

    # ------------------------------------------------------------------ components
    def _add_rsu(self, rsu_id: str) -> None:
        cam = SimCamera(self.corridor, rsu_id, seed=self.scenario.seed)
        # as iea-rsu runs it: one thread, the EV-body classifier (--ev-body default)
        config = PipelineConfig(detector=self.config.detector, threads=1, hazards=self.config.hazards)
        pipe = build_pipeline(config, self.corridor, rsu_id)
        annotate = None
        if self.config.annotate_dir is not None:
            Path(self.config.annotate_dir).mkdir(parents=True, exist_ok=True)
            annotate = str(Path(self.config.annotate_dir) / f"{rsu_id}.mp4")
        camera_hz = self.config.camera_hz
        if camera_hz is None:
            camera_hz = 2.0 if self.recorder is not None else 0.0
        svc = RsuService(self.corridor, rsu_id, SimSource.from_camera(cam), pipe, self.bus, self.clock, annotate_path=annotate,
                         camera_rate_hz=camera_hz)
        self.rsus[rsu_id] = svc
        self._cameras[rsu_id] = cam
        self._tasks.append(_Task(f"rsu:{rsu_id}", 1.0 / cam.fps, lambda now, rid=rsu_id: self._rsu_step(rid, now),
                                 start_s=1.0 / cam.fps))

    def _warm_up(self) -> None:
        """The RSUs have been running: their background models learn from the cameras' own frames of the
        road before the scenario (``sim.warmup``), never from a render with the actors removed."""
        learners = {rid: svc.pipeline for rid, svc in self.rsus.items() if svc.pipeline.learns_the_road}
        if not learners:
            return
        cams = {rid: self._cameras[rid] for rid in learners}
        for rid, image in warmup_frames(self.scenario, cams, self.config.warmup_s):
            learners[rid].learn_road(image)

    def kill_rsu(self, rsu_id: str) -> None:
        """The RSU process dies: it stops publishing (no goodbye message)."""
        for t in self._tasks:
            if t.name == f"rsu:{rsu_id}":
                t.alive = False
        self.rsus.pop(rsu_id, None)

    def kill_ddm(self) -> None:
        """The DDM process dies: its subscriptions and state are gone."""
        if self.ddm is not None:
            self.ddm.close()
            self.ddm = None
        for t in self._tasks:
            if t.name == "ddm":
                t.alive = False

    def start_ddm(self) -> None:
        """A fresh DDM (no memory of earlier commands), as after a restart."""
        self.kill_ddm()
        self.ddm = build_ddm(DdmOptions(config=self.config.ddm_config), self.bus, self.clock, self.corridor)
        self._tasks.append(_Task("ddm", 1.0 / self.config.ddm_config.rate_hz, self._ddm_step, start_s=self.clock.now()))

    def at(self, t_s: float, action: Callable[[], None]) -> None:
        """Run ``action`` (e.g. ``lambda: runner.kill_rsu('rsu2')``) at scenario time ``t_s``."""
        heapq.heappush(self._schedule, (t_s, self._order, action))
        self._order += 1

    # ------------------------------------------------------------------ steps
    def _world_step(self, now: float) -> None:
        if self.vehicle is not None:
            self.sim.set_av_state(self._true_state(now))
        self.sim.step_once()
        self._snapshot = self.sim.last_snapshot

    def _true_state(self, now: float) -> VehicleState:
        """The plant's true pose (physics, not a radio message) for the simulator."""
        v = self.vehicle
        st = v.sim.truth
        msg = v.state_message(now, publish=False)
        return msg.model_copy(update={"pos_x_m": st.x_m, "pos_y_m": st.y_m, "speed_mps": max(0.0, st.vx_mps),
                                      "heading_rad": math.remainder(st.yaw_rad, 2 * math.pi)})

    def _rsu_step(self, rsu_id: str, now: float) -> None:
        if self._snapshot is None or rsu_id not in self.rsus:
            return
        t0 = time.perf_counter()
        f = self._cameras[rsu_id].render(self._snapshot)
        t1 = time.perf_counter()
        self.rsus[rsu_id].process_frame(Frame(f.image, now, f.frame_number, rsu_id))
        self.stats["render_s"] += t1 - t0
        self.stats["rsu_s"] += time.perf_counter() - t1
        self.stats["frames"] += 1

    def _ddm_step(self, now: float) -> None:
        if self.ddm is not None:
            self.ddm.step(now)

    def _vehicle_step(self, now: float) -> None:
        self.vehicle.step(now)

    # ------------------------------------------------------------------ run
    def run(self, progress: Callable[[str], None] | None = None, progress_period_s: float = 1.0) -> dict[str, Any]:
        wall0 = time.perf_counter()
        next_progress = 0.0
        end = self.duration_s
        while True:
            live = [t for t in self._tasks if t.alive]
            self._tasks = live
            t_next = min(t.next_s for t in live)
            if self._schedule:
                t_next = min(t_next, self._schedule[0][0])
            if self.link is not None:
                due = self.link.next_due()
                if due is not None:
                    t_next = min(t_next, due)
            if t_next > end + 1e-9:
                break
            if t_next > self.clock.now():
                self.clock.advance(t_next - self.clock.now())
            now = self.clock.now()
            if self.config.realtime:
                lag = now - (time.perf_counter() - wall0)
                if lag > 0:
                    time.sleep(lag)
            if self.link is not None:
                self.link.deliver_due()
            while self._schedule and self._schedule[0][0] <= now + 1e-9:
                heapq.heappop(self._schedule)[2]()
            for t in list(self._tasks):
                if t.alive and t.next_s <= now + 1e-9:
                    t.fn(now)
                    t.next_s += t.period_s
            if progress is not None and now >= next_progress:
                progress(self.monitor.progress_line())
                next_progress += progress_period_s
        self.stats["wall_s"] = time.perf_counter() - wall0
        return self.finish()

    def finish(self) -> dict[str, Any]:
        self.sim.world.close()
        for svc in self.rsus.values():
            svc.close_outputs()
        if self.recorder is not None:
            self.recorder.close()
        m = self.monitor.metrics()
        m["scenario"] = self.scenario.name
        m["seed"] = self.scenario.seed
        m["mode"] = "lockstep"
        m["traffic"] = self.scenario.traffic_model
        m["sim_time_s"] = round(self.clock.now(), 3)
        m["wall_s"] = round(self.stats["wall_s"], 2)
        m["frames"] = self.stats["frames"]
        if self.link is not None:
            m["vehicle_link"] = {d: dict(c) for d, c in self.link.counts.items()}
        if self.vehicle is not None:
            m["vehicle_rejected"] = dict(self.vehicle.rejected)
        return m


def ev_lights_on(scenario: Scenario, duration_s: float | None = None) -> bool | None:
    """Whether the scenario's EV switches its lights on within the run (None: the scenario has no EV)."""
    if scenario.ev is None:
        return None
    on = scenario.ev.lights_on_at_s
    end = scenario.duration_s if duration_s is None else duration_s
    return on is not None and on < end
