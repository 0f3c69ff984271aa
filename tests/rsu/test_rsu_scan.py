"""``iea-rsu scan`` (rsu.scan.scan_video): errors, --help, a synthetic flashing EV, and one real clip."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from rsu.cli import main

REAL = Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "real"
YOLOX = REAL / "yolox_nano" / "yolox_nano.onnx"


def write_ev_clip(path: Path, seconds: float = 4.5, fps: float = 15.0, size: tuple[int, int] = (640, 270)) -> None:
    """An empty road for 1 s, then a striped vehicle crossing it with a red/blue light bar whose halves
    alternate every 0.25 s (a 2 Hz flasher); the stripes let background subtraction see the whole body."""
    w, h = size
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, (w, h))
    assert writer.isOpened(), "OpenCV cannot write mp4v here"
    road = np.full((h, w, 3), 90, np.uint8)
    cv2.line(road, (0, 200), (w, 200), (200, 200, 200), 2)
    body = np.full((70, 130, 3), 225, np.uint8)
    body[:, ::12] = 150
    body[8:28, 20:110] = 40  # windows
    for k in range(int(seconds * fps)):
        img = road.copy()
        t = k / fps - 1.0
        if t >= 0:
            x, y = int(-140 + 150 * t), 120
            xa, xb = max(x, 0), min(x + 130, w)
            if xb > xa:
                img[y:y + 70, xa:xb] = body[:, xa - x:xb - x]
            cv2.rectangle(img, (x + 35, y - 12), (x + 95, y), (60, 60, 60), -1)  # the bar, dark
            if int(t * 4) % 2 == 0:
                cv2.rectangle(img, (x + 35, y - 12), (x + 64, y), (0, 0, 255), -1)
            else:
                cv2.rectangle(img, (x + 66, y - 12), (x + 95, y), (255, 0, 0), -1)
        writer.write(img)
    writer.release()


def json_rows(text: str) -> list[dict]:
    return [json.loads(line) for line in text.splitlines() if line.strip()]


def test_help_explains_what_it_is_for(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["scan", "--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    assert "Check a camera" in out and "--annotate" in out and "--ev-body" in out


def test_missing_video_exits_2_with_a_message(tmp_path, capsys):
    assert main(["scan", str(tmp_path / "nope.mp4"), "--ev-body", "none", "--model", "motion"]) == 2
    assert "nope.mp4" in capsys.readouterr().err


def test_unreadable_video_exits_2(tmp_path, capsys):
    bad = tmp_path / "bad.mp4"
    bad.write_text("not a video")
    assert main(["scan", str(bad), "--ev-body", "none", "--model", "motion"]) == 2
    assert "iea-rsu scan:" in capsys.readouterr().err


def test_missing_models_exit_2(tmp_path, capsys):
    clip = tmp_path / "ev.mp4"
    write_ev_clip(clip, seconds=1.0)
    assert main(["scan", str(clip), "--model", str(tmp_path / "det.onnx"), "--ev-body", "none"]) == 2
    assert "det.onnx" in capsys.readouterr().err
    assert main(["scan", str(clip), "--model", "motion", "--ev-body", str(tmp_path / "body.onnx")]) == 2
    assert "body.onnx" in capsys.readouterr().err


def test_score_threshold_out_of_range_exits_2_before_scanning(tmp_path, capsys):
    assert main(["scan", str(tmp_path / "nope.mp4"), "--score-threshold", "1.5"]) == 2
    err = capsys.readouterr().err
    assert "--score-threshold must lie in (0, 1), got 1.5" in err and "nope.mp4" not in err


def test_score_threshold_reaches_the_detector_settings(tmp_path):
    from rsu.scan import scan_video

    clip, kept = tmp_path / "ev.mp4", tmp_path / "kept"
    write_ev_clip(clip, seconds=1.0)
    scan_video(clip, detector_model="motion", body="none", detections_dir=kept)
    scan_video(clip, detector_model="motion", body="none", detections_dir=kept, score_threshold=0.5)
    assert len(list(kept.glob("ev-*.pkl"))) == 2  # the kept detections are keyed by the threshold
    with pytest.raises(ValueError, match="score_threshold"):
        scan_video(clip, detector_model="motion", body="none", score_threshold=0.0)


def test_synthetic_flashing_ev_is_alerted(tmp_path, capsys):
    clip, annotated = tmp_path / "ev.mp4", tmp_path / "out" / "annotated.mp4"
    write_ev_clip(clip)
    assert main(["scan", str(clip), "--json", "--model", "motion", "--ev-body", "none",
                 "--annotate", str(annotated)]) == 0
    captured = capsys.readouterr()
    rows = json_rows(captured.out)
    assert "2.0 s of video" in captured.err  # progress every 2 s of video
    assert rows[-1]["type"] == "summary" and rows[-1]["frames"] == 67 and rows[-1]["ev_tracks"] >= 1
    tracks = [r for r in rows if r["type"] == "track" and r["state"] == "confirmed"]
    alerts = [r for r in rows if r["type"] == "alert" and r["state"] == "active"]
    assert tracks and alerts
    t = tracks[0]
    assert {"flash", "alternation"} & set(t["cues"]) and t["body_score"] is None
    assert 1.0 <= t["first_seen_s"] <= t["confirmed_s"] <= 4.0  # the vehicle enters at 1 s
    assert alerts[0]["track_id"] == t["track_id"] and alerts[0]["t_s"] == t["confirmed_s"]
    cap = cv2.VideoCapture(str(annotated))
    try:
        assert cap.isOpened() and int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) == 67
    finally:
        cap.release()
    # the human-readable form: one line per EV track, then the summary
    assert main(["scan", str(clip), "--model", "motion", "--ev-body", "none", "--max-s", "3.5"]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert lines[0].startswith(f"EV track {t['track_id']}:") and "EV tracks" in lines[-1]


def test_labels_score_the_alert_per_vehicle(tmp_path, capsys):
    """With --labels, the flashing vehicle of the synthetic clip is found on its own track; a label file that
    puts the EV elsewhere turns the same alert into a wrong-vehicle alert; a bad label file exits 2."""
    from rsu.scan_labels import ClipLabels, LabelledVehicle, write_labels

    clip = tmp_path / "ev.mp4"
    write_ev_clip(clip)

    def labels(dx: float) -> Path:
        frames = []
        for k in range(2, 9):  # every 0.5 s from 1.0 s: the body at x = -140 + 150 (T - 1), the bar above it
            x = -140 + 150 * (k / 2 - 1) + dx
            if x + 130 > 0:
                frames.append((k / 2, max(x, 0.0), 108.0, min(x + 130, 640.0), 190.0, True))
        v = LabelledVehicle("ev", "ev", "ambulance", tuple(frames))
        return write_labels(ClipLabels("ev.mp4", "ev_videos", "roadside", 640, 270, 15.0, 4.4, (v,)),
                            tmp_path / f"labels_{dx:.0f}.json")

    assert main(["scan", str(clip), "--json", "--model", "motion", "--ev-body", "none",
                 "--labels", str(labels(0.0))]) == 0
    rows = json_rows(capsys.readouterr().out)
    assert rows[-1]["type"] == "summary" and rows[-2]["type"] == "score"
    score = rows[-2]
    assert score["evs_scorable"] == 1 and score["ev_recall"] == 1.0 and score["wrong_vehicle_alerts"] == 0
    assert score["evs"][0]["found_track"] in score["on_ev_tracks"] and score["alert_delay_max_s"] <= 3.0
    assert main(["scan", str(clip), "--model", "motion", "--ev-body", "none", "--labels", str(labels(300.0))]) == 0
    out = capsys.readouterr().out
    assert "ev missed" in out and "wrong-vehicle alerts 1" in out
    bad = tmp_path / "bad.json"
    bad.write_text('{"clip": "ev.mp4"}')
    assert main(["scan", str(clip), "--model", "motion", "--ev-body", "none", "--labels", str(bad)]) == 2
    assert "missing" in capsys.readouterr().err


@pytest.mark.shared
@pytest.mark.slow
def test_real_clip_scan_is_well_formed(capsys):
    clip = REAL / "ev_videos" / "india_ambulance_police_escort.mp4"
    if not (clip.is_file() and YOLOX.is_file()):
        pytest.skip(f"{clip} or {YOLOX} absent (../shared/data/real not beside the repository)")
    body = "default" if (Path(__file__).resolve().parents[2] / "models" / "ev_body.onnx").is_file() else "none"
    assert main(["scan", str(clip), "--json", "--ev-body", body, "--model", str(YOLOX)]) == 0
    rows = json_rows(capsys.readouterr().out)
    summary = rows[-1]
    assert summary["type"] == "summary" and summary["frames"] > 100 and 5.0 < summary["duration_s"] < 6.0
    assert all(r["type"] in ("track", "alert") for r in rows[:-1])
    for r in rows[:-1]:
        assert r["track_id"] >= 0 and set(r["cues"]) <= {"flash", "alternation", "steady_bar", "ev_body"}
        if r["type"] == "track":
            assert r["state"] in ("candidate", "confirmed") and len(r["last_box"]) == 4
            assert (r["confirmed_s"] is None) == (r["state"] == "candidate")
            assert r["body_score"] is None or 0.0 <= r["body_score"] <= 1.0
        else:
            assert r["state"] in ("active", "cleared") and 0.0 <= r["t_s"] <= summary["duration_s"]
    assert summary["ev_tracks"] == sum(r["type"] == "track" and r["state"] == "confirmed" for r in rows)
