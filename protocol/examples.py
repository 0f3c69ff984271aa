"""One valid example of every message kind, on its key: for self-tests, benchmarks and fuzzing seeds."""

from __future__ import annotations

from protocol import keys
from protocol.messages import (
    Actor,
    CommandAck,
    DetectedObject,
    Envelope,
    EvAlert,
    EvEvidence,
    HazardAlert,
    Health,
    LightBar,
    ObjectList,
    PathSwitchCommand,
    VehicleState,
    WorldSnapshot,
)


def object_list(n_objects: int = 30, stamp: float = 1.0, seq: int = 0, rsu_id: str = "rsu1") -> ObjectList:
    objects = [
        DetectedObject(
            object_id=i + 1, pos_x_m=20.0 + 3.0 * i, pos_y_m=1.85 + 3.7 * (i % 2), lat_deg=30.6331 + 1e-5 * i,
            lon_deg=-96.4789, bbox_px=(100.0 + 10 * i, 300.0, 180.0 + 10 * i, 360.0), obj_type="vehicle",
            obj_type_cfd=0.93, ev_score=0.02, ev_state="none", light_state="off", vel_x_mps=13.2, vel_y_mps=0.1,
            speed_mps=13.2, heading_rad=0.01, length_m=4.6, width_m=1.9, height_m=1.5, pos_cov_m2=(0.04, 0.0, 0.02),
            lane=i % 2, age_s=1.5, hits=22,
        )
        for i in range(n_objects)
    ]
    return ObjectList(src=rsu_id, seq=seq, stamp=stamp, rsu_id=rsu_id, frame=seq, measurement_time=stamp,
                      objects=objects)


def example_messages(corridor: str = "rellis", stamp: float = 1.0, seq: int = 0) -> list[tuple[str, Envelope]]:
    """(key, message) for each of the eight message kinds. The world's ``sim_time_s`` counts from the
    start of the example scenario, at 00:00 UTC of the stamp's day (``stamp`` for stamps under a day)."""
    c = corridor
    return [
        (keys.rsu_key(c, "rsu1", "objects"), object_list(30, stamp, seq)),
        (keys.rsu_key(c, "rsu1", "ev"), EvAlert(
            src="rsu1", seq=seq, stamp=stamp, alert_id="rsu1-ev-7", state="active", rsu_id="rsu1", object_id=7,
            pos_x_m=40.0, pos_y_m=5.5, lat_deg=30.6335, lon_deg=-96.4785, vel_x_mps=19.0, speed_mps=19.0,
            lane=1, confidence=0.97, first_seen=max(0.0, stamp - 0.4), evidence=EvEvidence(frames=6, flash_hz=2.0, mean_score=0.9))),
        (keys.rsu_key(c, "rsu2", "hazard"), HazardAlert(
            src="rsu2", seq=seq, stamp=stamp, hazard_id="rsu2-hz-1", state="appear", rsu_id="rsu2", pos_x_m=120.0,
            pos_y_m=1.8, lat_deg=30.6332, lon_deg=-96.4777, lane=0, length_m=0.8, width_m=0.6, confidence=0.8,
            first_seen=stamp)),
        (keys.vehicle_key(c, "av1", "cmd"), PathSwitchCommand(
            src="ddm", seq=seq, stamp=stamp, command_id="ddm-av1-1", command_seq=1, vehicle_id="av1",
            manoeuvre="pull_over", reason="EV approaching from behind in lane 1, passes in 6.2 s", target_lane=0,
            waypoints=[(100.0 + 2.0 * i, 5.55 - 3.7 * min(i, 20) / 20) for i in range(40)],
            speed_profile_mps=[max(0.0, 13.4 - 0.34 * i) for i in range(40)], target_speed_mps=0.0,
            stop_point=(178.0, 1.85), issued_at=stamp, valid_until=stamp + 30.0)),
        (keys.vehicle_key(c, "av1", "ack"), CommandAck(
            src="av1", seq=seq, stamp=stamp, command_id="ddm-av1-1", vehicle_id="av1", status="accepted")),
        (keys.vehicle_key(c, "av1", "state"), VehicleState(
            src="av1", seq=seq, stamp=stamp, vehicle_id="av1", pos_x_m=100.0, pos_y_m=5.55, lat_deg=30.6335,
            lon_deg=-96.4780, heading_rad=0.0, speed_mps=13.4, mode="driving", lane=1)),
        (keys.ddm_health_key(c), Health(
            src="ddm", seq=seq, stamp=stamp, role="ddm", uptime_s=12.0, rates_hz={"loop": 20.0},
            latency_ms={"decision": 0.8}, drops={}, rejected={"invalid": 1}, stale=["rsu3"])),
        (keys.sim_world_key(c), WorldSnapshot(
            src="sim", seq=seq, stamp=stamp, scenario="rellis_ev_yield", sim_time_s=stamp % 86400.0, seed=1, actors=[
                Actor(actor_id="av1", kind="av", pos_x_m=100.0, pos_y_m=5.55, heading_rad=0.0, length_m=4.9,
                      width_m=1.9, height_m=1.5, speed_mps=13.4, lane=1),
                Actor(actor_id="ev1", kind="ev", pos_x_m=50.0, pos_y_m=5.55, heading_rad=0.0, length_m=5.5,
                      width_m=2.0, height_m=2.2, speed_mps=19.0, lane=1, colour_bgr=(255, 255, 255),
                      light_bar=LightBar(on=True, pattern="alternating", frequency_hz=2.0)),
            ])),
    ]
