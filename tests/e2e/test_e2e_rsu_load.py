"""bench/e2e_rsu_load.py: per-RSU processed fps, drops, frame age and CPU per stage from a run's
recording, and the first frame with the lamps lit that the alerting RSU published."""

from __future__ import annotations

import pytest

from bench.e2e_rsu_load import first_lit_frame_s, load_figures, rsu_load
from deploy.record import McapRecorder
from protocol.codec import encode
from protocol.enums import Lighting, Role
from protocol.keys import rsu_key, sim_world_key
from protocol.messages import Health, ObjectList, WorldSnapshot

C = "tload"


def _record(path, messages):
    with McapRecorder(path) as rec:
        for key, msg in messages:
            rec.on_bytes(key, encode(msg))


def _health(rsu, t, fps, age_ms, dropped):
    return Health(src=rsu, seq=int(t), stamp=t, role=Role.RSU, uptime_s=t - 98.9,
                  rates_hz={"frames": fps, "camera": 15.0},
                  latency_ms={"detect": 9.0, "detect_cpu": 6.0, "render_cpu": 4.0, "hazard_cpu": 1.5,
                              "frame_age": age_ms, "frame_age_max": age_ms + 20.0},
                  drops={"source": dropped})


def test_load_per_rsu_from_health_while_the_simulator_ran(tmp_path):
    path = tmp_path / "run.mcap"
    msgs = [(rsu_key(C, "rsu1", "health"), _health("rsu1", 99.0, 0.0, 0.0, 0))]  # before the simulator: not counted
    msgs += [(sim_world_key(C), WorldSnapshot(src="sim", stamp=100.0 + 0.05 * k, scenario="s", sim_time_s=0.05 * k,
                                             lighting=Lighting.DAY, actors=[])) for k in range(101)]
    # every period ending inside the simulator's run counts (of the camera's frames, those processed), not the one
    # that runs past the last snapshot (105.9); the raw count of the first (partial: the RSU started in it) does not
    for k, (fps, dropped) in enumerate([(3.0, 0), (15.0, 5), (14.0, 5), (15.0, 6), (13.0, 8), (7.0, 8)]):
        msgs.append((rsu_key(C, "rsu1", "health"), _health("rsu1", 100.9 + k, fps, 60.0 + k, dropped)))
        msgs.append((rsu_key(C, "rsu2", "health"), _health("rsu2", 100.9 + k, 14.0 if k % 2 else 15.0, 40.0, 0)))
    msgs += [(rsu_key(C, "rsu2", "objects"), ObjectList(src="rsu2", seq=k, stamp=102.0 + 0.07 * k, rsu_id="rsu2",
                                                        frame=k, measurement_time=101.95 + 0.0667 * k, objects=[]))
             for k in range(5)]
    _record(path, msgs)
    load = rsu_load(path)
    assert set(load) == {"rsu1", "rsu2"}
    one = load["rsu1"]
    # of the camera's 15 fps, those processed: 3 of 3, 15 of 20, 14 of 14, 15 of 16, 13 of 15
    assert one["fps_min"] == pytest.approx(15 * 15 / 20) and one["fps_median"] == pytest.approx(15 * 15 / 16, abs=0.01)
    assert one["rate_min_hz"] == 13.0 and one["camera_fps"] == 15.0
    assert one["frames_dropped"] == 8 and one["frames_dropped_running"] == 8 and one["periods"] == 5
    assert one["frame_age_ms_median"] == pytest.approx(62.0) and one["frame_age_ms_max"] == pytest.approx(84.0)
    assert one["cpu_ms_per_frame"] == {"render": 4.0, "detect": 6.0, "hazard": 1.5}
    fig = load_figures([{"rsu_load": load}])
    assert fig["rsu_fps_min"] == pytest.approx(11.25) and fig["rsu_rate_min_hz"] == 13.0
    # a raw count of 14 in a period where no camera frame was passed over is all of the camera's frames
    assert fig["rsu_load"]["rsu2"]["fps_min"] == 15.0 and fig["rsu_load"]["rsu2"]["rate_min_hz"] == 14.0
    # lights on at 102.0: rsu2's first frame captured at or after it (102.0167) went out at 102.07
    assert first_lit_frame_s(path, "rsu2", 102.0) == pytest.approx(102.07)
    assert first_lit_frame_s(path, "rsu1", 102.0) is None and first_lit_frame_s(path, None, 102.0) is None
    assert rsu_load(tmp_path / "absent.mcap") == {}


def test_processed_fps_by_how_fast_the_machine_ran_the_detector():
    """Periods are banded by their detector CPU per frame over the RSU's own reference (its detector alone)."""
    from bench.e2e_rsu_load import fps_by_machine_speed

    runs = [{"rsu_load": {"rsu1": {"fps_detect_cpu_ms": [(15.0, 7.0), (14.5, 7.9), (12.0, 9.5), (9.0, 14.0)]},
                          "rsu2": {"fps_detect_cpu_ms": [(13.0, 11.0)]}}}]
    bands = fps_by_machine_speed(runs, {"rsu1": 7.0, "rsu2": 10.0})
    assert [b["periods"] for b in bands] == [3, 0, 1, 1]  # ratios 1.0, 1.13, 1.1 (rsu2) | - | 1.36 | 2.0
    assert bands[0] == {"slowdown_from": 0.0, "slowdown_to": 1.15, "periods": 3, "periods_under_14": 1,
                        "fps_min": 13.0}
    assert bands[1]["fps_min"] is None and bands[2]["fps_min"] == 12.0
    assert bands[3]["slowdown_to"] is None and bands[3]["periods_under_14"] == 1
    assert fps_by_machine_speed(runs, {}) == []  # no reference, no bands


@pytest.mark.slow
def test_detector_reference_times_every_rsus_own_window():
    """bench/e2e_rsu_load.detector_reference_ms: CPU ms per frame of each RSU's detector on its own renders."""
    from bench.e2e_rsu_load import detector_reference_ms
    from protocol.corridor import load_corridor

    ref = detector_reference_ms(frames=2, repeats=1)
    assert set(ref) == {r.rsu_id for r in load_corridor().rsus}
    assert all(0.5 < ms < 500.0 for ms in ref.values()), ref
