"""EV alerts on real footage with the COCO YOLOX detector (skips without ../shared/data/real).

The four traffic videos contain no emergency vehicle: any EvAlert there is a false alarm. The two EV
videos are documented as known misses of the lamp rule (xfail, not strict): the rule is tuned on the
simulator (lamp pixels V >= 240, S >= 120) and these clips' light bars are washed out by compression
(S ~ 100-115) and thin against a near-camera box (the escort ambulance is in view with lit lamps for
about 1 s). The roadside clip is hopeless for a lamp rule: handheld, a yellow body, and the one alert the
rule raises there (at 4.2 s) is on a dark car's red tail light shaken by the camera, not on the
ambulance, so it is left out (a false alert a red-only lamp rule cannot tell from a blink). No
clip-specific tuning is done.

Measured on the escort clip (per-track lamp series, YOLOX + SORT as below, every frame of its 5.4 s):
the police escort (track 1, 0-1.24 s) carries its red/blue bar *above* the COCO box; measured in a band
extended 20 % above the box with relaxed thresholds (S >= 80, V >= 150) its red half is lit on every
frame from 0 to 0.92 s (brighter from 0.32 s; not one dark frame, where at 25 fps a 1-4 Hz flasher
would show several) and then leaves the image on the left; the blue half is lit from 0.52 to 1.04 s,
dark only once it leaves too. In view the bar reads as a steady lamp, which the rule must not alert
on (brake lights). The ambulance
(track 24, bar visible 2.08-3.12 s) has a blue bar whose halves strobe fast under heavy motion blur
from the panning camera: the blue signal dips for single frames (duty ~80 %, ~5 Hz), i.e. a steady
lamp dropping out for a frame, which the rule rejects on purpose (``min_dark_ratio``). Only extreme
relaxations confirm anything (S >= 80, V >= 150 and a lamp fraction of 0.5 % of the band: track 24 at
2.2 s; S >= 100, V >= 200, 0.5 %, band 20 % above the box: track 1 at 1.0 s), each on a different
setting, which is tuning to this clip and would admit red/blue paint and jitter elsewhere: not done.
A sound fix needs a different cue (a per-crop classifier trained on real light bars, fused as the
issue's crop score, or a spatial left/right alternation measure inside the bar), not a threshold.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from protocol.corridor import load_corridor
from protocol.messages import AlertState
from rsu.classify.ev import EvAlertManager, TrackEvClassifier
from rsu.detect import OnnxDetector
from rsu.frames import VideoSource
from rsu.localize import Localizer
from rsu.service import RsuPipeline
from rsu.track import FrameworkTracker

REAL = Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "real"
YOLOX = REAL / "yolox_nano" / "yolox_nano.onnx"
MAX_S = 12.0  # bounded test time: the first 12 s of each clip


def alerts_on(path: Path) -> list[tuple[float, int]]:
    if not (path.is_file() and YOLOX.is_file()):
        pytest.skip(f"{path} or {YOLOX} absent (../shared/data/real not beside the repository)")
    clf, manager = TrackEvClassifier(), EvAlertManager()
    pipe = RsuPipeline(OnnxDetector(YOLOX, intra_op_threads=1), FrameworkTracker("B", 3, 3, 0.3),
                       Localizer(load_corridor(), "rsu1"), clf)
    out = []
    with VideoSource(path) as src:
        for frame in src:
            if frame.timestamp_s > MAX_S:
                break
            result = pipe.process(frame)
            out += [(frame.timestamp_s, e.track_id) for e in manager.update(frame.timestamp_s, result.objects,
                                                                            clf.evidence)
                    if e.state == AlertState.ACTIVE]
    return out


@pytest.mark.shared
@pytest.mark.slow
@pytest.mark.parametrize("video", ["ambdet_video_3.mp4", "ambdet_video_4.mp4", "haarcascades_video1.avi",
                                   "haarcascades_video2.avi"])
def test_no_ev_alert_on_traffic_videos(video):
    alerts = alerts_on(REAL / "traffic_videos" / video)
    assert not alerts, f"false EV alerts on {video}: {alerts[:5]}"


@pytest.mark.shared
@pytest.mark.slow
@pytest.mark.xfail(reason="known miss: no flash pattern the lamp rule may accept (steady-looking bar, 1-frame dips under "
                          "motion blur; see module docstring)",
                   strict=False)
@pytest.mark.parametrize("video", ["india_ambulance_police_escort.mp4"])
def test_ev_videos_raise_an_alert(video):
    alerts = alerts_on(REAL / "ev_videos" / video)
    assert alerts, f"no EV alert on {video}"
