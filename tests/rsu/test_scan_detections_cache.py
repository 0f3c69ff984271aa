"""The kept detections of a scanned clip: replayed in frame order, and keyed so that a changed video, model or
setting never reads them back."""

from __future__ import annotations

import numpy as np
import pytest

from rsu.build import PipelineConfig
from rsu.perception import Detections
from rsu.scan import DetectionsReplay, detections_key


class _Counting:
    name = "fake"

    def __init__(self) -> None:
        self.calls = 0

    def detect(self, image):
        self.calls += 1
        return Detections(np.array([[self.calls, 0, 10, 10]], float), np.array([0.9]), np.array([0]))


def test_recorded_detections_replay_in_order_without_the_detector():
    inner = _Counting()
    rec = DetectionsReplay(inner)
    for _ in range(3):
        rec.detect(np.zeros((4, 4, 3), np.uint8))
    replay = DetectionsReplay(rows=rec.rows)
    assert [float(replay.detect(None).boxes[0, 0]) for _ in range(3)] == [1.0, 2.0, 3.0]
    assert inner.calls == 3
    with pytest.raises(ValueError, match="end before the video"):
        replay.detect(None)


def test_the_key_changes_with_the_video_the_model_and_the_settings(tmp_path):
    video, model = tmp_path / "clip.mp4", tmp_path / "det.onnx"
    video.write_bytes(b"frames")
    model.write_bytes(b"weights")
    cfg = PipelineConfig(detector=str(model))
    key = detections_key(video, model, cfg, None)
    assert detections_key(video, model, cfg, None) == key
    assert detections_key(video, model, cfg, 5.0) != key
    assert detections_key(video, model, PipelineConfig(detector=str(model), score_threshold=0.4), None) != key
    model.write_bytes(b"other weights")
    assert detections_key(video, model, cfg, None) != key
    model.write_bytes(b"weights")
    video.write_bytes(b"other frames")
    assert detections_key(video, model, cfg, None) != key
