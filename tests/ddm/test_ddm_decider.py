"""The decider alone (no service, no bus, no clock): an EvAlert in the world's picture reaches a command
through it; rollback, EV over hazard and adoption after a restart."""

from __future__ import annotations

from ddm_rig import lane_y

from ddm.commands import CommandState
from ddm.config import DdmConfig, HazardConfig
from ddm.decider import Decider
from ddm.geometry import RoadFrame
from ddm.world import CorridorWorld
from protocol.corridor import load_corridor
from protocol.enums import AckStatus, AlertState, Manoeuvre, VehicleMode
from protocol.messages import CommandAck, EvAlert, HazardAlert, PathSwitchCommand, VehicleState

CORRIDOR = load_corridor()
T0 = 100.0


def setup(cfg: DdmConfig | None = None) -> tuple[Decider, CorridorWorld]:
    cfg = cfg or DdmConfig()
    frame = RoadFrame(CORRIDOR.road)
    world = CorridorWorld(cfg, rsu_ids=tuple(r.rsu_id for r in CORRIDOR.rsus), frame=frame,
                          hazard_config=HazardConfig())
    return Decider(CORRIDOR, frame, cfg, HazardConfig(), ddm_id="ddm", started_s=T0), world


def av_state(t: float, x: float = 20.0, *, mode: VehicleMode = VehicleMode.DRIVING, active: str | None = None,
             speed: float = 13.4) -> VehicleState:
    return VehicleState(src="av1", stamp=t, vehicle_id="av1", pos_x_m=x, pos_y_m=lane_y(1), lat_deg=30.6,
                        lon_deg=-96.4, heading_rad=0.0, speed_mps=speed, mode=mode, active_command_id=active)


def ev_alert(t: float, x: float = -30.0, state: AlertState = AlertState.ACTIVE) -> EvAlert:
    return EvAlert(src="rsu1", stamp=t, alert_id="rsu1-ev-7", state=state, rsu_id="rsu1", object_id=7, pos_x_m=x,
                   pos_y_m=lane_y(1), lat_deg=30.6, lon_deg=-96.4, vel_x_mps=20.0, speed_mps=20.0, lane=1,
                   confidence=0.9, first_seen=t - 1.0)


def hazard_alert(t: float, x: float) -> HazardAlert:
    return HazardAlert(src="rsu1", stamp=t, hazard_id="rsu1-hz-1", state="persist", rsu_id="rsu1", pos_x_m=x,
                       pos_y_m=lane_y(1), lat_deg=30.6, lon_deg=-96.4, length_m=1.2, width_m=0.9, confidence=0.8,
                       first_seen=t)


def pull_over_sent(cfg: DdmConfig) -> tuple[Decider, CorridorWorld, PathSwitchCommand]:
    """The decider after it sent the AV at x = 20 m its pull-over for an EV 50 m behind, at T0."""
    decider, world = setup(cfg)
    world.ingest_vehicle_state(av_state(T0), T0)
    world.ingest_ev_alert(ev_alert(T0), T0)
    decider.decide(world.snapshot(T0))
    (cmd,) = decider.due_commands(T0)
    return decider, world, cmd


def test_an_ev_alert_in_the_world_becomes_a_pull_over_command_through_the_decider():
    decider, world = setup()
    world.ingest_vehicle_state(av_state(T0), T0)
    assert decider.decide(world.snapshot(T0)) == 0 and decider.due_commands(T0) == []  # nothing to yield to
    world.ingest_ev_alert(ev_alert(T0), T0)  # 50 m behind in the AV's lane, closing at 6.6 m/s
    assert decider.decide(world.snapshot(T0), near=(-30.0, lane_y(1))) == 1
    (cmd,) = decider.due_commands(T0)
    assert cmd.vehicle_id == "av1" and cmd.manoeuvre == Manoeuvre.PULL_OVER and cmd.target_lane == 0
    mem = decider.memory["av1"].ev
    assert mem.phase == "yielding" and mem.manoeuvre == Manoeuvre.PULL_OVER and mem.cause_ids
    assert mem.stop_s_m is not None  # the pull-over's planned room, noted after planning
    assert decider.counters["decisions"] == 1 and decider.counters["cmd_issued"] == 1
    assert decider.ev_aware_s == T0


def test_an_alert_far_from_the_vehicle_is_left_to_the_next_step():
    decider, world = setup()
    world.ingest_vehicle_state(av_state(T0, x=400.0), T0)
    world.ingest_ev_alert(ev_alert(T0), T0)
    assert decider.decide(world.snapshot(T0), near=(-30.0, lane_y(1))) == 0 and "av1" not in decider.memory


def test_a_rejected_command_rolls_the_memory_back_and_waits_before_planning_again():
    cfg = DdmConfig()
    decider, world, cmd = pull_over_sent(cfg)
    decider.on_ack(CommandAck(src="av1", stamp=T0 + 0.05, command_id=cmd.command_id, vehicle_id="av1",
                              status=AckStatus.REJECTED, reason="path starts behind the car"), T0 + 0.05)
    mem = decider.memory["av1"]
    assert mem.ev.phase == "normal" and mem.ev.manoeuvre is None and not mem.ev.cause_ids  # as before it
    assert mem.replan_after_s == T0 + 0.05 + cfg.replan_backoff_s and decider.counters["cmd_rejected"] == 1
    t = T0 + 0.1
    world.ingest_vehicle_state(av_state(t, x=21.3), t)
    world.ingest_ev_alert(ev_alert(t, x=-28.0), t)
    assert decider.decide(world.snapshot(t)) == 0  # inside the backoff
    t = T0 + 0.6
    world.ingest_vehicle_state(av_state(t, x=28.0), t)
    world.ingest_ev_alert(ev_alert(t, x=-18.0), t)
    assert decider.decide(world.snapshot(t)) == 1  # planned anew
    assert decider.commands.state_of("av1").state == CommandState.SENT
    assert decider.commands.state_of("av1").command_id != cmd.command_id


def test_an_unacknowledged_command_the_car_drives_past_is_planned_again_from_where_the_car_is():
    decider, world, first = pull_over_sent(DdmConfig())
    # the link stalls: no ack, the car's state still arrives; 0.6 s on it is 8 m past the path's start
    t = T0 + 0.6
    world.ingest_vehicle_state(av_state(t, x=20.0 + 13.4 * 0.6), t)
    world.ingest_ev_alert(ev_alert(t, x=-30.0 + 20.0 * 0.6), t)
    assert decider.decide(world.snapshot(t)) == 0 and decider.counters["cmd_replanned_in_flight"] == 0
    # a car that reports executing the command has it: only the ack is late, nothing planned again
    t = T0 + 0.9
    world.ingest_vehicle_state(av_state(t, x=20.0 + 13.4 * 0.9, mode=VehicleMode.MANOEUVRE,
                                        active=first.command_id), t)
    assert decider.decide(world.snapshot(t)) == 0 and decider.counters["cmd_replanned_in_flight"] == 0
    # 1 s on it is 13.4 m past it (the car rejects 15 m): planned again from the car's position, superseding
    t = T0 + 1.0
    world.ingest_vehicle_state(av_state(t, x=20.0 + 13.4), t)
    world.ingest_ev_alert(ev_alert(t, x=-30.0 + 20.0), t)
    assert decider.decide(world.snapshot(t)) == 1 and decider.counters["cmd_replanned_in_flight"] == 1
    (second,) = decider.due_commands(t)
    assert second.supersedes == first.command_id and second.manoeuvre == Manoeuvre.PULL_OVER
    assert abs(second.waypoints[0][0] - (20.0 + 13.4)) < 1.0 and first.waypoints[0][0] < 21.0
    assert decider.commands.state_of("av1").state == CommandState.SENT
    # acknowledged: never planned again, however far the car drives along it
    decider.on_ack(CommandAck(src="av1", stamp=t, command_id=second.command_id, vehicle_id="av1",
                              status=AckStatus.ACCEPTED), t)
    t = T0 + 3.0
    world.ingest_vehicle_state(av_state(t, x=20.0 + 13.4 * 3.0), t)
    decider.decide(world.snapshot(t))
    assert decider.counters["cmd_replanned_in_flight"] == 1


def test_an_ev_command_supersedes_a_hazard_command_and_resets_the_hazard_memory():
    decider, world = setup()
    world.ingest_vehicle_state(av_state(T0), T0)
    world.ingest_hazard_alert(hazard_alert(T0, 60.0), T0)  # 40 m ahead in the AV's lane
    assert decider.decide(world.snapshot(T0)) == 0  # a hazard command: not an EV command
    (hz_cmd,) = decider.due_commands(T0)
    assert hz_cmd.manoeuvre in (Manoeuvre.LANE_CHANGE, Manoeuvre.STOP_IN_LANE)
    assert decider.memory["av1"].hazard.phase in ("avoiding", "stopping")
    assert decider.counters["hazard_decisions"] == 1
    world.ingest_ev_alert(ev_alert(T0 + 0.05), T0 + 0.05)
    assert decider.decide(world.snapshot(T0 + 0.05)) == 1
    (ev_cmd,) = decider.due_commands(T0 + 0.05)
    assert ev_cmd.supersedes == hz_cmd.command_id
    mem = decider.memory["av1"]
    assert mem.ev.phase == "yielding" and mem.hazard.phase == "normal" and not mem.hazard.cause_ids


def test_a_command_from_a_previous_ddm_is_adopted_and_not_resumed_before_the_evs_can_be_heard():
    cfg = DdmConfig()
    decider, world = setup(cfg)
    vs = av_state(T0, mode=VehicleMode.STOPPED, active="ddm-old-1", speed=0.0)
    world.ingest_vehicle_state(vs, T0)
    decider.adopt(vs, T0)
    assert decider.commands.state_of("av1").state == CommandState.ADOPTED
    assert decider.memory["av1"].ev.phase == "yielding"
    t = T0 + cfg.ev_alert_timeout_s  # no EV heard: still holding
    world.ingest_vehicle_state(av_state(t, mode=VehicleMode.STOPPED, active="ddm-old-1", speed=0.0), t)
    decider.decide(world.snapshot(t))
    assert decider.due_commands(t) == []
    t = T0 + cfg.ev_alert_timeout_s + cfg.resume_hold_s + 0.1
    world.ingest_vehicle_state(av_state(t, mode=VehicleMode.STOPPED, active="ddm-old-1", speed=0.0), t)
    decider.decide(world.snapshot(t))
    (cmd,) = decider.due_commands(t)
    assert cmd.manoeuvre == Manoeuvre.RESUME and decider.memory["av1"].ev.phase == "normal"
