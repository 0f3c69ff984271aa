"""``SimCamera``: the RSU's frame source in simulation.

It subscribes to ``WorldSnapshot`` (``iea/{c}/sim/world``) through any ``Transport`` and renders that
RSU's view locally, so the RSU works on pixels exactly as on a real camera's frames. It is the only
consumer of ground truth besides evaluation code: it hands out images, a timestamp and a frame number,
never the snapshot. ``render(snapshot)`` is the plain path for lockstep runs (no transport, no threads).
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass

import numpy as np

from protocol.corridor import Corridor
from protocol.enums import Lighting
from protocol.keys import sim_world_key
from protocol.messages import WorldSnapshot
from protocol.transport import Subscription, Transport
from sim.render.renderer import Renderer


def camera_phase_s(index: int, fps: float, snapshot_hz: float = 20.0) -> float:
    """How much earlier than t = k / fps the corridor's ``index``-th camera exposes frame k.

    Real cameras run free, not in step. In step, a 15 fps camera fed 20 Hz snapshots starts a frame on 3 of every 4
    snapshots, every camera on the same 3: all four RSUs' work arrived at once, and none on the fourth. Cameras
    0, 1, 2, 3 take (k + 1/2) / 4 of a frame period, which puts the snapshot each passes over on a different slot:
    three RSUs start a frame on every snapshot."""
    slots = max(1, round(snapshot_hz / (snapshot_hz - fps))) if snapshot_hz > fps else 1
    return ((index % slots) + 0.5) / (slots * fps)


@dataclass(frozen=True)
class Frame:
    """One camera frame: BGR image (h, w, 3) uint8, capture time (s, sim clock) and frame number."""

    image: np.ndarray
    timestamp_s: float
    frame_number: int
    camera_id: str
    stamp_s: float
    """When the simulator published the snapshot, on its clock (UNIX seconds in a real-time run): the
    capture time a live camera would stamp the frame with. ``timestamp_s`` is the scenario time."""


class SimCamera:
    """Frame source of one RSU camera rendered from world snapshots."""

    def __init__(self, corridor: Corridor, rsu_id: str, transport: Transport | None = None, *, seed: int = 0,
                 noise: bool = True, motion_blur: bool = True, exposure: bool = True, queue_frames: int = 2,
                 prerender: bool = False, phase_s: float | None = None) -> None:
        if not 1 <= queue_frames <= 64:
            raise ValueError(f"queue_frames must be in [1, 64], got {queue_frames}")
        self.corridor = corridor
        self.rsu = corridor.rsu(rsu_id)
        self.phase_s = camera_phase_s(corridor.rsu_index(rsu_id), self.rsu.camera.fps) if phase_s is None \
            else float(phase_s)
        """How much earlier than the scenario clock's whole frame periods this camera exposes (``camera_phase_s``)."""
        if not 0.0 <= self.phase_s < 1.0 / self.rsu.camera.fps:
            raise ValueError(f"phase_s must be in [0, 1/fps), got {self.phase_s}")
        self.renderer = Renderer(self.rsu.camera, corridor.road, seed=seed, noise=noise, motion_blur=motion_blur,
                                 exposure=exposure)
        self.fps = self.rsu.camera.fps
        self.queue_frames = queue_frames
        """Camera frames held for a late reader, newest kept (a live camera's ``--queue-size``, default 2)."""
        self._pending: dict[int, WorldSnapshot] = {}  # frame index -> its first snapshot, oldest first
        self._latest_seen: int | None = None
        self._cond = threading.Condition()
        self._sub: Subscription | None = None
        self.snapshots_received = 0
        self.prerender = prerender
        """The static scene (sky, terrain, road) and sensor noise of every lighting were made at construction, so the
        first frame costs what any frame does (an RSU would otherwise pass over the camera frames of its first
        0.3-0.4 s)."""
        self.frames_skipped = 0
        """Camera frames never delivered because ``read`` came later than the next frame (the reader fell behind:
        it gets the newest frame, not the ones it missed)."""
        self.last_render_times_s = (0.0, 0.0)
        """(wall-clock, CPU of this thread) seconds of the last ``render``: the camera's share of an RSU's work
        when it renders in the RSU's process (``rsu.service.RsuService`` reports it as the ``render`` stage)."""
        if prerender:  # the static scene and noise texture of every lighting, before the first frame is due
            self.renderer.prepare(*(lighting.value for lighting in Lighting))
        if transport is not None:
            self._sub = transport.subscribe(sim_world_key(corridor.corridor_id), self._on_snapshot)

    @property
    def width_px(self) -> int:
        return self.rsu.camera.width_px

    @property
    def height_px(self) -> int:
        return self.rsu.camera.height_px

    def _on_snapshot(self, _key: str, snap: WorldSnapshot) -> None:
        n = self.frame_index(snap.sim_time_s)
        with self._cond:
            self.snapshots_received += 1
            newest = max(self._pending, default=self._latest_seen)
            if newest is not None and n <= newest:
                return  # a second snapshot within a frame already captured (snapshots 20 Hz, camera 15 fps)
            self._pending[n] = snap
            while len(self._pending) > self.queue_frames:  # the buffer keeps the newest frames
                del self._pending[min(self._pending)]
            self._cond.notify_all()

    @property
    def newest_held(self) -> WorldSnapshot | None:
        """The snapshot of the newest camera frame held and not delivered yet (None: none held)."""
        with self._cond:
            return self._pending[max(self._pending)] if self._pending else None

    @property
    def frames_held(self) -> int:
        """Camera frames held for the reader (at most ``queue_frames``)."""
        with self._cond:
            return len(self._pending)

    def frame_index(self, sim_time_s: float) -> int:
        """The camera's frame counter at a sim time (it exposes a frame every 1/fps s from t = -phase_s)."""
        return int((sim_time_s + self.phase_s) * self.fps + 1e-6)

    def render(self, snapshot: WorldSnapshot) -> Frame:
        """Render one frame of the snapshot (lockstep path); the frame number is the camera's counter."""
        n = self.frame_index(snapshot.sim_time_s)
        t0, c0 = time.perf_counter(), time.thread_time()
        img = self.renderer.render(snapshot, frame_index=n)
        self.last_render_times_s = (time.perf_counter() - t0, time.thread_time() - c0)
        return Frame(img, float(snapshot.sim_time_s), n, self.rsu.rsu_id, float(snapshot.stamp))

    def read(self, timeout_s: float = 1.0) -> Frame | None:
        """The oldest camera frame still held, not a queue: the camera captures frame k from the first snapshot
        at or after k / fps (snapshots come at 20 Hz, so a 15 fps camera skips one in four) and holds the newest
        ``queue_frames`` frames, as a live camera's driver does; frames pushed out of that buffer because the
        reader came late are counted in ``frames_skipped``. None on timeout."""
        with self._cond:
            if not self._cond.wait_for(lambda: bool(self._pending), timeout_s):
                return None
            n = min(self._pending)
            snap = self._pending.pop(n)
            if self._latest_seen is not None:
                self.frames_skipped += max(0, n - self._latest_seen - 1)
            self._latest_seen = n
        return self.render(snap)

    def frames(self, timeout_s: float = 1.0):
        """Iterate frames until no snapshot arrives within timeout_s."""
        while True:
            f = self.read(timeout_s)
            if f is None:
                return
            yield f

    def close(self) -> None:
        if self._sub is not None:
            self._sub.close()
            self._sub = None
