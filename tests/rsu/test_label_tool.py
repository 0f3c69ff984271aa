"""bench/label_tool.py: choices on the proposals turn into a valid label file (pure part, no video)."""

from __future__ import annotations

import pytest

from bench.label_tool import build_labels, parse_ranges, parse_vehicle

PROPOSALS = dict(clip="c.mp4", folder="ev_videos", width=640, height=360, fps=25.0, duration_s=2.0, boxes={
    "0.000": {"3": [10, 10, 60, 50], "4": [200, 10, 260, 50]},
    "0.500": {"3": [20, 10, 70, 50]},
    "1.000": {"7": [30, 10, 80, 50]},   # the detector gave the EV a new track id
    "1.500": {},                         # and missed it
    "2.000": {"7": [50, 10, 100, 50]},
})


def test_tracks_boxes_and_lit_ranges_become_frames():
    ev = parse_vehicle("amb kind=ambulance tracks=3,7 lit=0-0.75", "ev", 2.0)
    labels = build_labels(PROPOSALS, "elevated", [ev], ["amb 1.5 40 10 90 50"], [], "note")
    (v,) = labels.vehicles
    assert [f[0] for f in v.frames] == [0.0, 0.5, 1.0, 1.5, 2.0]
    assert v.frames[3][1:5] == (40.0, 10.0, 90.0, 50.0)           # the box read off the grid
    assert [f[5] for f in v.frames] == [True, True, False, False, False]
    assert labels.has_ev and labels.viewpoint == "elevated" and labels.note == "note"


def test_gone_ranges_and_flashers():
    ev = parse_vehicle("amb tracks=3,7", "ev", 2.0)
    hz = parse_vehicle("hz kind=hazard tracks=4 lit=all", "flasher", 2.0)
    labels = build_labels(PROPOSALS, "roadside", [ev, hz], [], ["amb 0.9-1.1"], "")
    amb, flasher = labels.vehicles
    assert 1.0 not in [f[0] for f in amb.frames]
    assert flasher.role == "flasher" and len(flasher.frames) == 1 and labels.evs == [amb]


def test_bad_choices_say_what_is_wrong():
    with pytest.raises(ValueError, match="A-B"):
        parse_ranges("1to2", 5.0)
    with pytest.raises(ValueError, match="unknown field"):
        parse_vehicle("amb colour=red", "ev", 5.0)
    ev = parse_vehicle("amb tracks=99", "ev", 2.0)
    with pytest.raises(ValueError, match="no box"):
        build_labels(PROPOSALS, "elevated", [ev], [], [], "")
    with pytest.raises(ValueError, match="NAME T X1"):
        build_labels(PROPOSALS, "elevated", [parse_vehicle("amb tracks=3", "ev", 2.0)], ["amb 1.0 1 2"], [], "")


def test_sheet_frames_are_the_frames_the_scan_stamps_at_those_times():
    """A clip that skips 0.3 s at 8 s: the sheet's frame for 9.5 s is the one the scan stamps 9.5 s, not frame
    9.5 x fps (which the scan stamps 9.8 s)."""
    import numpy as np

    from bench.label_tool import frames_at
    from rsu.frames import VideoSource
    from tests.conftest import require_shared

    clip = require_shared("data", "real", "ev_videos", "roadside_night_ambulance_india_redblue.mp4")
    ((t, sheet),) = frames_at(clip, [9.5])
    with VideoSource(clip, read_timeout_s=30.0) as source:
        stamped = min((f for f in source if 9.3 < f.timestamp_s < 9.7), key=lambda f: abs(f.timestamp_s - 9.5))
        assert abs(stamped.timestamp_s - 9.5) < 0.011
    assert t == 9.5 and np.array_equal(sheet, stamped.image)
