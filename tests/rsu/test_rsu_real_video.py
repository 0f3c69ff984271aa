"""The COCO YOLOX model and SORT on real traffic video track real cars (skips without ../shared)."""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import pytest

from rsu.detect import OnnxDetector
from rsu.frames import VideoSource
from rsu.track.sort import SortTracker

REAL = Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "real"
YOLOX = REAL / "yolox_nano" / "yolox_nano.onnx"


@pytest.mark.shared
@pytest.mark.parametrize("video", ["ambdet_video_3.mp4", "haarcascades_video1.avi"])
def test_yolox_and_sort_track_real_cars(video):
    path = REAL / "traffic_videos" / video
    if not (path.is_file() and YOLOX.is_file()):
        pytest.skip(f"{path} or {YOLOX} absent (../shared/data/real not beside the repository)")
    detector = OnnxDetector(YOLOX, intra_op_threads=1)
    tracker = SortTracker(max_age=3, min_hits=3, iou_threshold=0.3)
    frames_per_id: Counter[int] = Counter()
    n_frames = 60
    with VideoSource(path) as src:
        for k, frame in enumerate(src):
            if k >= n_frames:
                break
            det = detector.detect(frame.image)
            tracks = tracker.update(det.boxes, det.scores, det.class_ids)
            ids = tracks.track_ids.tolist()
            assert len(ids) == len(set(ids))
            frames_per_id.update(ids)
    long_lived = [tid for tid, n in frames_per_id.items() if n >= n_frames // 2]
    assert len(long_lived) >= 3, f"expected several cars tracked for >= {n_frames // 2} frames, got {frames_per_id}"


@pytest.mark.shared
def test_service_on_real_video_with_yolox_writes_annotated_video(tmp_path):
    from protocol.clock import WallClock
    from protocol.corridor import load_corridor
    from protocol.keys import rsu_key
    from protocol.local_bus import LocalBus
    from rsu.build import PipelineConfig, build_pipeline
    from rsu.service import RsuService

    path = REAL / "traffic_videos" / "ambdet_video_3.mp4"
    if not (path.is_file() and YOLOX.is_file()):
        pytest.skip(f"{path} or {YOLOX} absent")
    corridor = load_corridor()
    bus = LocalBus()
    lists = []
    bus.subscribe(rsu_key("treal", "rsu1", "objects"), lambda k, m: lists.append(m))
    out = tmp_path / "annotated.mp4"
    pipeline = build_pipeline(PipelineConfig(detector=str(YOLOX), max_age=3, ev_classifier=False), corridor, "rsu1")
    with VideoSource(path) as src:
        svc = RsuService(corridor, "rsu1", src, pipeline, bus, WallClock(), corridor_id="treal",
                         annotate_path=str(out), max_frames=40)
        assert svc.run() == 0
    assert len(lists) == 40 and [m.frame for m in lists] == list(range(40))
    assert max(len(m.objects) for m in lists) >= 3
    import cv2

    cap = cv2.VideoCapture(str(out))
    assert int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) == 40
    ok, image = cap.read()
    cap.release()
    assert ok and image.shape == (360, 640, 3)
