"""EV alerts on real footage, as an operator's ``iea-rsu scan`` runs it: COCO YOLOX-Nano, SORT,
per-track lamp evidence fused with the EV-body classifier (``models/ev_body.onnx``). Skips without
``../shared/data/real``.

The four traffic videos contain no emergency vehicle: any alert there is false. Each of the six EV clips
must raise an alert within 2 s of the EV being in view with its lights on: "in view" is when its box
first reaches the RSU's ``min_box_px`` (40 px; a smaller box is never measured), read off the clips by
eye (ground truth for scoring only, never seen by the pipeline). ``bench/ev_real_bench.py`` reports the
same figures with the alert times; the annotated video of ``iea-rsu scan CLIP --annotate OUT.mp4`` shows
which box each alert is on.

The escort, Japanese-ambulance and NYC-police clips were used to set the light-bar colour test
(:mod:`rsu.classify.lamps`): they are tuning clips for it. The Florence clip (a far ambulance whose blue bar flashes
regularly while the body classifier cannot judge it yet) set the strong light-bar flash rule
(``EvidenceConfig.strong_bar_flashes``): it is a tuning clip too. The night, roadside and traffic clips were not used to set anything.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from rsu.classify.body import DEFAULT_BODY_MODEL
from rsu.scan import DEFAULT_DETECTOR, scan_video

REAL = Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "real"

EV_IN_VIEW_S = {
    "elevated_police_nyc_redbars.mp4": 4.5,
    "handheld_ambulance_florence_blue.mp4": 4.5,
    "india_ambulance_police_escort.mp4": 0.0,
    "night_ambulance_india_blue.mp4": 0.0,
    "roadside_ambulance_yellow.mp4": 14.8,
    "street_ambulance_japan_red.mp4": 0.0,
}
"""When each EV is in view with its lights on, box >= 40 px (seconds of video; scoring only)."""
MAX_DELAY_S = 2.0
KNOWN_MISSES = {
    "elevated_police_nyc_redbars.mp4": "its sunlit red domes never read as lamp activity, so no track becomes a "
                                       "candidate and the body classifier never runs on the police cars "
                                       "(iea-rsu scan --json: 0 candidate tracks)",
}
"""Clips that do not meet the requirement (bench/ev_real_bench.py), with the reason: docs/models.md."""


def _scan(path: Path, max_s: float | None = None):
    if not (path.is_file() and DEFAULT_DETECTOR.is_file()):
        pytest.skip(f"{path} or {DEFAULT_DETECTOR} absent (../shared/data/real not beside the repository)")
    if not DEFAULT_BODY_MODEL.is_file():
        pytest.skip(f"{DEFAULT_BODY_MODEL} absent (train it with `make models`)")
    return scan_video(path, max_s=max_s)


@pytest.mark.shared
@pytest.mark.slow
@pytest.mark.parametrize("video", ["ambdet_video_3.mp4", "ambdet_video_4.mp4", "haarcascades_video1.avi",
                                   "haarcascades_video2.avi"])
def test_no_ev_alert_on_traffic_videos(video):
    result = _scan(REAL / "traffic_videos" / video)
    assert not result.ev_tracks, f"false EV alerts on {video}: {[d.track_id for d in result.ev_tracks]}"


@pytest.mark.shared
@pytest.mark.slow
@pytest.mark.parametrize("video", [pytest.param(v, marks=pytest.mark.xfail(reason=KNOWN_MISSES[v], strict=False))
                                   if v in KNOWN_MISSES else v for v in sorted(EV_IN_VIEW_S)])
def test_each_real_ev_clip_raises_an_alert_within_2_s(video):
    in_view = EV_IN_VIEW_S[video]
    result = _scan(REAL / "ev_videos" / video, max_s=in_view + MAX_DELAY_S + 0.5)
    first = result.first_alert_s
    assert first is not None, f"no EV alert on {video}"
    assert first <= in_view + MAX_DELAY_S, f"{video}: first alert {first:.2f} s, EV in view at {in_view} s"
