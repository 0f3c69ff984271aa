"""RSU service: in-process on a LocalBus with a stepped clock, and as a process over Zenoh."""

from __future__ import annotations

import time
import uuid
from collections import Counter, defaultdict
from pathlib import Path

import cv2
import numpy as np
import pytest

from protocol.clock import SimClock
from protocol.corridor import load_corridor
from protocol.enums import HealthStatus, ObjectType
from protocol.keys import all_rsus_expr, rsu_key
from protocol.local_bus import LocalBus
from protocol.messages import Health, ObjectList
from protocol.zenoh_transport import ZenohTransport
from rsu.build import MOTION, PipelineConfig, build_detector, build_pipeline, build_tracker
from rsu.frames import ArraySource, Frame, SourceStalled
from rsu.localize import Localizer
from rsu.pipeline import RsuPipeline
from rsu.service import RsuService

pytestmark = pytest.mark.serial  # processes, Zenoh or its own timing: make test runs it alone


ROOT = Path(__file__).resolve().parents[2]
CORRIDOR = load_corridor()
FPS = 15.0
MOTION_RSU = PipelineConfig(detector=MOTION, motion_min_area_px=1500, max_age=3, ev_classifier=False)


def _scene(n_frames=60, empty_frames=15, size=(1280, 720)):
    """Two textured boxes ('vehicles') driving across a road image after a few empty frames."""
    rng = np.random.default_rng(0)
    background = cv2.GaussianBlur(rng.integers(70, 110, (size[1], size[0], 3), dtype=np.uint8), (5, 5), 0)
    car_a = rng.integers(0, 255, (60, 100, 3), dtype=np.uint8)
    car_b = rng.integers(0, 255, (50, 90, 3), dtype=np.uint8)
    frames = []
    for k in range(n_frames):
        image = background.copy()
        if k >= empty_frames:
            j = k - empty_frames
            xa, xb = 250 + 10 * j, 950 - 8 * j
            image[500:560, xa:xa + 100] = car_a
            image[420:470, xb:xb + 90] = car_b
        frames.append(image)
    return frames


class _ClockedSource(ArraySource):
    """An ArraySource whose reads advance a SimClock by one frame period (lockstep)."""

    def __init__(self, images, clock: SimClock, stall_after: int | None = None) -> None:
        super().__init__(images, FPS, "cam")
        self.clock, self.stall_after, self.reads = clock, stall_after, 0
        self.drops = 0

    def read(self, timeout_s=None) -> Frame | None:
        self.clock.advance(1.0 / FPS)
        self.reads += 1
        if self.stall_after is not None and self.reads > self.stall_after:
            self.clock.advance(timeout_s or 1.0)
            raise SourceStalled("no frame")
        return super().read(timeout_s)


def _service(bus, clock, source, **kw):
    pipeline = build_pipeline(MOTION_RSU, CORRIDOR, "rsu1")
    return RsuService(CORRIDOR, "rsu1", source, pipeline, bus, clock, corridor_id="tlocal", **kw)


def test_service_publishes_objects_every_frame_and_health_at_1hz(tmp_path):
    bus, clock = LocalBus(), SimClock(100.0)
    lists: list[ObjectList] = []
    health: list[Health] = []
    bus.subscribe(rsu_key("tlocal", "rsu1", "objects"), lambda k, m: lists.append(m))
    bus.subscribe(rsu_key("tlocal", "rsu1", "health"), lambda k, m: health.append(m))
    out = tmp_path / "annotated.mp4"
    svc = _service(bus, clock, _ClockedSource(_scene(60), clock), annotate_path=str(out))
    assert svc.run() == 0
    assert [m.frame for m in lists] == list(range(60))
    assert [m.seq for m in lists] == list(range(60))
    assert lists[5].measurement_time == pytest.approx(5 / FPS)
    ids_per_frame = [sorted(o.object_id for o in m.objects) for m in lists[30:]]
    assert all(ids == ids_per_frame[0] for ids in ids_per_frame) and len(ids_per_frame[0]) == 2
    obj = lists[-1].objects[0]
    assert obj.obj_type == ObjectType.VEHICLE and obj.hits > 10 and obj.speed_mps > 1.0
    assert abs(obj.lat_deg - CORRIDOR.origin_lat_deg) < 0.01 and abs(obj.lon_deg - CORRIDOR.origin_lon_deg) < 0.01
    # 60 frames at 15 fps = 4 s: health at start, 1 Hz, and a final one
    assert 4 <= len(health) <= 7, [round(h.stamp, 3) for h in health]
    assert all(h.status == HealthStatus.OK for h in health)
    assert set(health[2].latency_ms) >= {"detect", "track", "localize", "publish"}
    assert health[2].rates_hz["frames"] == pytest.approx(FPS, rel=0.1)
    cap = cv2.VideoCapture(str(out))
    assert int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) == 60
    cap.release()


def test_stalled_source_is_reported_then_given_up():
    bus, clock = LocalBus(), SimClock(0.0)
    health: list[Health] = []
    bus.subscribe(rsu_key("tlocal", "rsu1", "health"), lambda k, m: health.append(m))
    svc = _service(bus, clock, _ClockedSource(_scene(30), clock, stall_after=10), read_timeout_s=1.0,
                   max_stall_s=3.0)
    assert svc.run() == 3
    assert svc.frames == 10 and svc.stalls >= 3
    assert any(h.status == HealthStatus.DEGRADED and h.rejected["stalls"] >= 1 for h in health)
    assert health[-1].status == HealthStatus.ERROR


def _write_video(path: Path, frames) -> Path:
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), FPS, (frames[0].shape[1], frames[0].shape[0]))
    for f in frames:
        writer.write(f)
    writer.release()
    return path


@pytest.mark.slow
def test_iea_rsu_process_publishes_stable_ids_over_zenoh(tmp_path, spawn):
    video = _write_video(tmp_path / "scene.avi", _scene(70))
    cid = f"t{uuid.uuid4().hex[:8]}"
    received: list[ObjectList] = []
    health: list[Health] = []
    transport = ZenohTransport()
    transport.subscribe(all_rsus_expr(cid), lambda k, m: (received if isinstance(m, ObjectList) else health).append(m))
    proc = spawn("-m", "rsu", "--rsu", "rsu1", "--corridor-id", cid, "--source", str(video), "--detector", "motion",
                 "--realtime", "--max-age", "3", "--log-level", "WARNING")
    try:
        rc = proc.wait(timeout=60)
        time.sleep(0.5)
        _, err = proc.communicate(timeout=5)
    finally:
        transport.close()
    assert rc == 0, err
    assert len(received) >= 50, f"received {len(received)} ObjectLists"
    assert health and all(h.src == "rsu1" for h in health)
    frames_per_id: dict[int, int] = Counter()
    boxes_by_id: dict[int, list] = defaultdict(list)
    for m in received:
        for o in m.objects:
            frames_per_id[o.object_id] += 1
            boxes_by_id[o.object_id].append(o.bbox_px)
    steady = [tid for tid, n in frames_per_id.items() if n >= 35]
    assert len(steady) == 2, frames_per_id  # both vehicles, each under one id the whole time
    xs = [np.mean([b[0] for b in boxes_by_id[tid]][:3]) for tid in steady]
    assert min(xs) < 640 < max(xs)  # one is the left car, the other the right one


def test_classifier_hook_marks_ev_tracks():
    bus, clock = LocalBus(), SimClock(0.0)
    lists: list[ObjectList] = []
    bus.subscribe(rsu_key("tlocal", "rsu1", "objects"), lambda k, m: lists.append(m))
    calls = []

    def classifier(frame, tracks):
        calls.append(frame.frame_number)
        # the left car (smaller x) is the EV with flashing lights
        return tracks.with_columns(ev_scores=np.where(tracks.boxes[:, 0] < 640, 0.9, 0.1))

    pipeline = RsuPipeline(build_detector(MOTION_RSU), build_tracker(MOTION_RSU), Localizer(CORRIDOR, "rsu1"),
                           classifier=classifier)
    svc = RsuService(CORRIDOR, "rsu1", _ClockedSource(_scene(45), clock), pipeline, bus, clock, corridor_id="tlocal")
    assert svc.run() == 0
    assert calls == list(range(45))
    last = {o.object_id: o for o in lists[-1].objects}
    kinds = sorted((o.bbox_px[0] < 640, o.obj_type, o.ev_score) for o in last.values())
    assert kinds == [(False, ObjectType.VEHICLE, 0.1), (True, ObjectType.EV, 0.9)]


def test_cli_rejects_a_thread_count_below_one(capsys):
    from rsu.cli import main

    assert main(["--rsu", "rsu1", "--source", "sim", "--threads", "0"]) == 2
    assert "--threads must be >= 1" in capsys.readouterr().err
