"""``SimSource``: the simulator's rendered camera as an RSU frame source (``iea-rsu --source sim``).

A thin adapter from :class:`sim.camera_source.SimCamera` (which subscribes to ``iea/{c}/sim/world`` and
renders this RSU's view) to the RSU's :class:`rsu.frames.FrameSource` contract, so simulated frames go
through exactly the code path of a live camera. The RSU only ever sees the rendered pixels, a capture
time and the frame number: the snapshot (ground truth) never leaves ``SimCamera``.

The capture time is the snapshot's publication stamp on the simulator's clock (UNIX seconds in a
real-time run), as a live camera stamps its frames with the wall clock: the RSU's ``ObjectList``
``measurement_time`` must be on the clock the DDM runs on, or the DDM drops every list as too old
(it did, before: the scenario time of a few seconds looked decades old next to UNIX time).
"""

from __future__ import annotations

import dataclasses

from protocol.corridor import Corridor
from protocol.transport import Transport
from rsu.frames import Frame, FrameSource, SourceStalled


class SimSource(FrameSource):
    """Frames of one RSU's simulated camera; ``read`` raises :class:`SourceStalled` when no snapshot comes."""

    def __init__(self, corridor: Corridor, rsu_id: str, transport: Transport, *, corridor_id: str | None = None,
                 seed: int = 0, queue_size: int = 2) -> None:
        from sim.camera_source import SimCamera  # the simulator is only needed for --source sim

        if corridor_id and corridor_id != corridor.corridor_id:
            # SimCamera subscribes on its corridor's id: give it the overriding id (key expressions only).
            corridor = dataclasses.replace(corridor, corridor_id=corridor_id)
        # the static scenes are rendered before subscribing: the RSU's first frame is not 0.4 s late
        self.camera = SimCamera(corridor, rsu_id, transport, seed=seed, queue_frames=queue_size, prerender=True)
        self.fps = float(self.camera.fps)
        self.source_id = f"sim:{rsu_id}"
        self.stamps_capture_time = True
        """Frames carry the snapshot's publication stamp on the simulator's clock (the RSU reports their age)."""

    @classmethod
    def from_camera(cls, camera, source_id: str | None = None) -> SimSource:
        """The source of a camera the caller steps itself (the lockstep runner renders each frame and pushes it to
        ``RsuService.process_frame``): frames stamped with the scenario time, on the one simulated clock."""
        self = cls.__new__(cls)
        self.camera = camera
        self.fps = float(camera.fps)
        self.source_id = source_id or f"sim:{camera.rsu.rsu_id}"
        self.stamps_capture_time = False
        return self

    @property
    def drops(self) -> int:
        """Camera frames passed over because the RSU came late for them (the camera holds the newest
        ``queue_size`` frames, as a live source does)."""
        return self.camera.frames_skipped

    @property
    def last_render_times_s(self) -> tuple[float, float]:
        """(wall-clock, CPU) seconds of the last frame's rendering: the simulated camera's share of the RSU's work."""
        return self.camera.last_render_times_s

    def read(self, timeout_s: float | None = None) -> Frame | None:
        timeout = 5.0 if timeout_s is None else float(timeout_s)
        f = self.camera.read(timeout)
        if f is None:
            raise SourceStalled(f"{self.source_id}: no world snapshot for {timeout:.1f} s")
        return Frame(f.image, f.stamp_s, f.frame_number, self.source_id)

    def close(self) -> None:
        self.camera.close()
