"""The COCO YOLOX model and SORT on real traffic video track real cars (skips without ../shared)."""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import pytest

from rsu.detect import OnnxDetector
from rsu.frames import VideoSource
from rsu.track import SortTracker

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
            tracks = tracker.update(det.boxes, det.scores, det.classes)
            ids = tracks.track_ids.tolist()
            assert len(ids) == len(set(ids))
            frames_per_id.update(ids)
    long_lived = [tid for tid, n in frames_per_id.items() if n >= n_frames // 2]
    assert len(long_lived) >= 3, f"expected several cars tracked for >= {n_frames // 2} frames, got {frames_per_id}"
