"""Latest frame, not a queue: an RSU that falls behind its simulated camera processes the newest frame
and counts the ones it passed over; Health reports the processed rate beside the camera's, CPU per stage, the
dropped frames and the frames' age at publication."""

from __future__ import annotations

import numpy as np
import pytest

from protocol.clock import SimClock
from protocol.corridor import load_corridor
from protocol.enums import Lighting
from protocol.keys import rsu_key, sim_world_key
from protocol.local_bus import LocalBus
from protocol.messages import Health, WorldSnapshot
from rsu.build import MOTION, PipelineConfig, build_pipeline
from rsu.frames import Frame, FrameSource
from rsu.service import RsuService
from rsu.sim_source import SimSource

CORRIDOR = load_corridor()


def _snap(t_s: float) -> WorldSnapshot:
    return WorldSnapshot(src="sim", stamp=1000.0 + t_s, scenario="t", sim_time_s=t_s, lighting=Lighting.DAY,
                         actors=[])


def test_a_late_reader_gets_the_newest_frame_and_the_missed_ones_are_counted():
    bus = LocalBus()
    src = SimSource(CORRIDOR, "rsu1", bus, queue_size=1)
    key = sim_world_key(CORRIDOR.corridor_id)
    bus.publish(key, _snap(0.0))
    assert src.read(0.5).frame_number == 0 and src.drops == 0
    bus.publish(key, _snap(0.05))  # the next camera frame (15 fps), read in time
    bus.publish(key, _snap(0.1))
    assert src.read(0.5).frame_number == 1 and src.drops == 0
    for k in range(3, 11):  # 0.15 .. 0.5 s published while the RSU was busy
        bus.publish(key, _snap(0.05 * k))
    f = src.read(0.5)
    assert f.frame_number == 7 and f.timestamp_s == pytest.approx(1000.5)  # the newest, stamped on the sim clock
    assert src.drops == 7 - 1 - 1  # frames 2..6 were never processed
    wall_s, cpu_s = src.last_render_times_s
    assert wall_s > 0 and cpu_s > 0
    src.close()


def test_the_camera_holds_its_newest_two_frames_for_a_reader_one_frame_late():
    bus = LocalBus()
    src = SimSource(CORRIDOR, "rsu1", bus)  # queue_size 2, as a live source
    # the static scene of every lighting is there before the first frame (its first frame is not 0.4 s late)
    assert src.camera.renderer.static_scenes() == ("day", "dusk", "night")
    assert src.camera.renderer.noise_lightings() == ("day", "dusk", "night")  # and its sensor noise (0.1 s each)
    key = sim_world_key(CORRIDOR.corridor_id)
    bus.publish(key, _snap(0.0))
    assert src.read(0.5).frame_number == 0
    bus.publish(key, _snap(0.1))  # frame 1
    bus.publish(key, _snap(0.15))  # frame 2 arrives before the RSU read frame 1 (50 ms after it)
    f1, f2 = src.read(0.5), src.read(0.5)
    assert (f1.frame_number, f2.frame_number) == (1, 2) and src.drops == 0  # nothing lost for being 1 frame late
    assert f1.timestamp_s == pytest.approx(1000.1)  # frame 1 from its own snapshot, not the newest
    for k in range(4, 11):  # 0.2 .. 0.5 s (frames 3..7) published while the RSU was busy
        bus.publish(key, _snap(0.05 * k))
    f = src.read(0.5)
    assert f.frame_number == 6 and src.drops == 3  # the oldest of the two held; frames 3..5 pushed out
    assert src.read(0.5).frame_number == 7 and src.camera.read(0.01) is None
    bus.publish(key, _snap(0.5))  # a second snapshot within frame 7 is not a new frame
    assert src.camera.read(0.01) is None
    src.close()


class _LateSource(FrameSource):
    """Frames stamped 0.2 s before the clock (age at read), every other camera frame missed."""

    source_id, fps, stamps_capture_time = "late", 15.0, True

    def __init__(self, clock: SimClock, n: int) -> None:
        self.clock, self.n, self.k, self.drops = clock, n, 0, 0
        self.image = np.full((720, 1280, 3), 90, np.uint8)

    def read(self, timeout_s=None) -> Frame | None:
        if self.k >= self.n:
            return None
        self.clock.advance(2 / 15)
        self.k += 1
        self.drops += 1
        return Frame(self.image, self.clock.now() - 0.2, 2 * self.k, self.source_id)

    def close(self) -> None:
        pass


def test_health_reports_processed_rate_drops_cpu_per_stage_and_frame_age():
    bus, clock = LocalBus(), SimClock(50.0)
    health: list[Health] = []
    bus.subscribe(rsu_key("tlate", "rsu1", "health"), lambda _k, m: health.append(m))
    pipe = build_pipeline(PipelineConfig(detector=MOTION, ev_classifier=False), CORRIDOR, "rsu1")
    svc = RsuService(CORRIDOR, "rsu1", _LateSource(clock, 30), pipe, bus, clock, corridor_id="tlate")
    assert svc.run() == 0
    h = health[2]
    assert h.rates_hz["frames"] == pytest.approx(7.5, rel=0.15) and h.rates_hz["camera"] == 15.0
    assert h.drops["source"] >= 10
    assert h.latency_ms["frame_age"] == pytest.approx(200.0, abs=1.0)
    assert h.latency_ms["frame_age_max"] == pytest.approx(200.0, abs=1.0)
    assert h.latency_ms["detect_cpu"] > 0 and {"track_cpu", "hazard_cpu", "publish_cpu"} <= set(h.latency_ms)
