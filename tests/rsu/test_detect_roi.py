"""An RSU's detector searches only where its zone of responsibility lies in the frame (rsu.detect_roi):
the window holds the road within range from the ground to a truck's roof, keeps the detector's pixel scale, and
finds the vehicles in it where the whole frame finds them."""

import numpy as np
import pytest

from protocol.corridor import load_corridor
from rsu.build import PipelineConfig, build_detector
from rsu.calibration.camera_geometry import project
from rsu.detect_roi import PROJECT_SCALE, ROI_MARGIN_M, VEHICLE_TOP_M, detection_roi, zone_box_px

CORRIDOR = load_corridor()


@pytest.mark.parametrize("rsu_id", [r.rsu_id for r in CORRIDOR.rsus])
def test_zone_box_holds_the_road_within_range_up_to_a_trucks_roof_and_leaves_the_sky_out(rsu_id):
    rsu, road = CORRIDOR.rsu(rsu_id), CORRIDOR.road
    box = zone_box_px(rsu.camera, road, rsu.position, rsu.max_range_m)
    assert box is not None and box[1] > 100  # the sky and the far road are out
    s = np.arange(0.0, road.length_m, 2.0)
    for d in (0.5 * road.lane_width_m, 1.5 * road.lane_width_m):
        x, y, _ = road.pose_at(s, np.full_like(s, d))
        near = np.hypot(x - rsu.position[0], y - rsu.position[1]) <= rsu.max_range_m
        for z in (0.0, VEHICLE_TOP_M):
            uv, depth = project(rsu.camera, np.column_stack([x[near], y[near], np.full(near.sum(), z)]))
            uv = uv[(depth > 0.5) & (uv[:, 0] >= 0) & (uv[:, 0] < 1280) & (uv[:, 1] >= 0) & (uv[:, 1] < 720)]
            assert len(uv)
            assert (uv[:, 0] >= box[0]).all() and (uv[:, 0] <= box[2]).all()
            assert (uv[:, 1] >= box[1]).all() and (uv[:, 1] <= box[3]).all()
    farther = zone_box_px(rsu.camera, road, rsu.position, rsu.max_range_m + 40.0)
    assert farther[1] < box[1]  # a longer range reaches higher in the image
    with pytest.raises(ValueError):
        zone_box_px(rsu.camera, road, rsu.position, 0.0)


def test_detection_window_keeps_the_scale_holds_the_box_and_stays_in_the_frame():
    roi, hw = detection_roi((0, 173, 833, 720), (1280, 720), 0.4)
    assert hw == (224, 352) and roi == (0, 160, 880, 720)
    assert (roi[2] - roi[0]) * 0.4 == hw[1] and (roi[3] - roi[1]) * 0.4 == hw[0]  # the letterbox keeps 0.4
    roi, hw = detection_roi((500, 300, 700, 400), (1280, 720), 0.4)
    assert roi[0] <= 500 and roi[2] >= 700 and roi[1] <= 300 and roi[3] >= 400
    assert hw == (64, 96) and roi == (480, 270, 720, 430)  # centred on the box
    assert detection_roi(None, (1280, 720), 0.4) == ((0, 0, 1280, 720), (288, 512))  # no zone: the whole frame
    assert detection_roi((0, 0, 1279, 719), (1280, 720), 0.4) == ((0, 0, 1280, 720), (288, 512))


def test_the_rsu_detector_finds_in_its_window_what_the_whole_frame_finds_there():
    from bench.rsu_sim_clips import render_sim_clip

    clip = render_sim_clip("rellis_ev_yield", "rsu1", seed=900_004, duration_s=3.0)
    windowed = build_detector(PipelineConfig(), CORRIDOR, "rsu1")
    whole = build_detector(PipelineConfig(detect_roi=False), CORRIDOR, "rsu1")
    rsu = CORRIDOR.rsu("rsu1")
    box = zone_box_px(rsu.camera, CORRIDOR.road, rsu.position, rsu.max_range_m + ROI_MARGIN_M)
    assert windowed.roi == detection_roi(box, (1280, 720), PROJECT_SCALE)[0] and windowed.input_hw == (288, 448)
    assert whole.roi is None and whole.input_hw == (384, 640)
    x1, y1, x2, y2 = windowed.roi
    found = matched = 0
    for frame in clip.frames[::5]:
        a, b = whole.detect(frame.image), windowed.detect(frame.image)
        # away from the window's edges (40 px): there the network sees the window's border padding, not the road
        # beyond it, and at scale 0.5 the window's grid is not the whole frame's (144 px down: 72 input px, not a
        # multiple of the 32-px stride), so boxes near an edge may differ
        inside = (a.boxes[:, 0] >= x1 + 40) & (a.boxes[:, 1] >= y1 + 40) & (a.boxes[:, 2] <= x2 - 40)
        for box_a in a.boxes[inside]:
            found += 1
            ious = _iou(box_a, b.boxes)
            matched += int(len(ious) and ious.max() >= 0.8)
    assert found >= 10 and matched / found >= 0.95, (matched, found)


def _iou(box, boxes):
    if len(boxes) == 0:
        return np.zeros(0)
    x1, y1 = np.maximum(box[0], boxes[:, 0]), np.maximum(box[1], boxes[:, 1])
    x2, y2 = np.minimum(box[2], boxes[:, 2]), np.minimum(box[3], boxes[:, 3])
    inter = np.clip(x2 - x1, 0, None) * np.clip(y2 - y1, 0, None)
    area = lambda b: (b[..., 2] - b[..., 0]) * (b[..., 3] - b[..., 1])  # noqa: E731
    return inter / (area(box) + area(boxes) - inter)


def test_the_rsu_cli_searches_its_zone_unless_told_the_whole_frame():
    from rsu.cli import build_parser, pipeline_config

    base = ["--rsu", "rsu1", "--source", "sim"]
    assert pipeline_config(build_parser().parse_args(base)).detect_roi
    assert not pipeline_config(build_parser().parse_args([*base, "--whole-frame"])).detect_roi
