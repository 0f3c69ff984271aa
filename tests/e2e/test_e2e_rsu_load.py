"""bench/e2e_rsu_load.py (issue 19): per-RSU processed fps, drops, frame age and CPU per stage from a run's
recording, and the first frame with the lamps lit that the alerting RSU published."""

from __future__ import annotations

import pytest

from bench.e2e_rsu_load import first_lit_frame_s, load_figures, rsu_load
from deploy.record import McapRecorder
from protocol.codec import encode
from protocol.keys import rsu_key, sim_world_key
from protocol.messages import Health, Lighting, ObjectList, Role, WorldSnapshot

C = "tload"


def _record(path, messages):
    with McapRecorder(path) as rec:
        for key, msg in messages:
            rec.on_bytes(key, encode(msg))


def _health(rsu, t, fps, age_ms, dropped):
    return Health(src=rsu, seq=int(t), stamp=t, role=Role.RSU, rates_hz={"frames": fps, "camera": 15.0},
                  latency_ms={"detect": 9.0, "detect_cpu": 6.0, "render_cpu": 4.0, "hazard_cpu": 1.5,
                              "frame_age": age_ms, "frame_age_max": age_ms + 20.0},
                  drops={"source": dropped})


def test_load_per_rsu_from_health_while_the_simulator_ran(tmp_path):
    path = tmp_path / "run.mcap"
    msgs = [(rsu_key(C, "rsu1", "health"), _health("rsu1", 99.0, 0.0, 0.0, 0))]  # before the simulator: not counted
    msgs += [(sim_world_key(C), WorldSnapshot(src="sim", stamp=100.0 + 0.05 * k, scenario="s", sim_time_s=0.05 * k,
                                             lighting=Lighting.DAY, actors=[])) for k in range(101)]
    for k, fps in enumerate([3.0, 15.0, 14.0, 15.0, 13.0]):  # the first period (caches, models) is not counted
        msgs.append((rsu_key(C, "rsu1", "health"), _health("rsu1", 100.9 + k, fps, 60.0 + k, k)))
        msgs.append((rsu_key(C, "rsu2", "health"), _health("rsu2", 100.9 + k, 15.0, 40.0, 0)))
    msgs += [(rsu_key(C, "rsu2", "objects"), ObjectList(src="rsu2", seq=k, stamp=102.0 + 0.07 * k, rsu_id="rsu2",
                                                        frame=k, measurement_time=101.95 + 0.0667 * k, objects=[]))
             for k in range(5)]
    _record(path, msgs)
    load = rsu_load(path)
    assert set(load) == {"rsu1", "rsu2"}
    one = load["rsu1"]
    assert one["fps_min"] == 13.0 and one["fps_median"] == 14.5 and one["camera_fps"] == 15.0
    assert one["frames_dropped"] == 4 and one["periods"] == 4
    assert one["frame_age_ms_median"] == pytest.approx(62.5) and one["frame_age_ms_max"] == pytest.approx(84.0)
    assert one["cpu_ms_per_frame"] == {"render": 4.0, "detect": 6.0, "hazard": 1.5}
    fig = load_figures([{"rsu_load": load}])
    assert fig["rsu_fps_min"] == 13.0 and fig["rsu_load"]["rsu2"]["fps_min"] == 15.0
    # lights on at 102.0: rsu2's first frame captured at or after it (102.0167) went out at 102.07
    assert first_lit_frame_s(path, "rsu2", 102.0) == pytest.approx(102.07)
    assert first_lit_frame_s(path, "rsu1", 102.0) is None and first_lit_frame_s(path, None, 102.0) is None
    assert rsu_load(tmp_path / "absent.mcap") == {}
