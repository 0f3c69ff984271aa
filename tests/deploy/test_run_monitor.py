"""RunMonitor (scenario/monitor.py): the figures of a run, from the messages of the corridor; and judge_run."""

from __future__ import annotations

from protocol import keys
from protocol.corridor import load_corridor
from protocol.messages import Actor, LightBar, ObjectList, WorldSnapshot
from scenario.monitor import RunMonitor
from scenario.outcome import judge_run


def snap(t: float, av_xy: tuple[float, float], ev_xy: tuple[float, float], ev_speed: float, seq: int) -> WorldSnapshot:
    return WorldSnapshot(src="sim", seq=seq, stamp=t, scenario="x", sim_time_s=t, seed=1, actors=[
        Actor(actor_id="av1", kind="av", pos_x_m=av_xy[0], pos_y_m=av_xy[1], heading_rad=0.0, length_m=4.9,
              width_m=1.9, height_m=1.5, speed_mps=10.0, lane=1),
        Actor(actor_id="ev1", kind="ev", pos_x_m=ev_xy[0], pos_y_m=ev_xy[1], heading_rad=0.0, length_m=5.5,
              width_m=2.0, height_m=2.2, speed_mps=ev_speed, lane=1,
              light_bar=LightBar(on=True, pattern="alternating", frequency_hz=2.0)),
    ])


def test_moved_over_ev_delay_and_lost_messages():
    road = load_corridor().road
    m = RunMonitor("c", road=road)
    wk = keys.sim_world_key("c")
    # t=0: both in lane 1; t=1: the AV is in lane 0 (centre 1.85 m); t=2: the EV is ahead of the AV
    m.on_message(wk, snap(0.0, (100.0, 5.55), (60.0, 5.55), 18.0, 0))
    m.on_message(wk, snap(1.0, (110.0, 1.85), (95.0, 5.55), 9.0, 1))  # within its following distance: AV out
    m.on_message(wk, snap(2.0, (112.0, 1.85), (120.0, 5.55), 18.0, 3))  # seq 2 was lost
    out = m.metrics()
    assert out["out_of_ev_lane_s"] == 1.0 and out["ev_passed_av_s"] == 2.0
    assert out["moved_over_before_ev_passed"] is True and out["stopped_before_ev_passed"] is False
    assert out["yield"]["status"] == "yielded" and out["yield"]["margin_s"] == 0.0
    assert out["messages_lost_per_link"] == {"world": 1}
    assert out["ev_min_speed_lights_on_mps"] == 9.0
    assert abs(out["ev_delay_s"] - 0.5) < 1e-9  # (1 - 18/18) * 1 s + (1 - 9/18) * 1 s
    # object lists of one RSU: seq gaps per key
    ok = keys.rsu_key("c", "rsu1", "objects")
    for seq in (0, 1, 4):
        m.on_message(ok, ObjectList(src="rsu1", seq=seq, stamp=float(seq), rsu_id="rsu1", frame=seq,
                                    measurement_time=float(seq), objects=[]))
    assert m.metrics()["messages_lost_per_link"] == {"world": 1, "objects": 2}


def test_judge_run_verdicts():
    base = {"collision": False, "commands": [{"manoeuvre": "pull_over"}], "latency_s": {"lights_on_to_stop_s": 7.0},
            "stop_position_m": (120.0, 1.25), "stop_lane": 0, "stopped_before_ev_passed": False,
            "moved_over_before_ev_passed": True, "out_of_ev_lane_s": 2.1, "ev_passed_av_s": 5.6,
            "yield": {"passed": True, "status": "yielded", "reason": "out of the EV's lane 1.2 s before"}}
    ok, why = judge_run(base, ev_lights_on=True)
    assert ok and "out of the EV's lane" in why
    blocked = {"passed": False, "status": "blocked", "reason": "in the EV's lane"}
    assert not judge_run({**base, "yield": blocked}, ev_lights_on=True)[0]
    assert not judge_run({**base, "collision": True, "min_gap_to_any_vehicle_m": -0.5}, ev_lights_on=True)[0]
    ok, why = judge_run({**base, "commands": [{"manoeuvre": "pull_over"}]}, ev_lights_on=False)
    assert not ok and "false alarm" in why
    assert judge_run({**base, "commands": []}, ev_lights_on=False)[0]
    assert not judge_run({**base, "min_hazard_clearance_m": 0.4}, ev_lights_on=None)[0]
