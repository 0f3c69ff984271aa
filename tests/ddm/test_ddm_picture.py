"""The world's picture: one immutable snapshot of tracks, EVs, hazards and vehicles per decision step, and
the command manager as the only maker of commands."""

from __future__ import annotations

import dataclasses

import pytest
from ddm_rig import det, lane_y, object_list

from ddm.commands import CommandManager
from ddm.config import DdmConfig, HazardConfig
from ddm.geometry import RoadFrame
from ddm.intent import Intent
from ddm.world import CorridorWorld
from protocol.corridor import load_corridor
from protocol.enums import AlertState, Manoeuvre, VehicleMode
from protocol.messages import EvAlert, HazardAlert, VehicleState

COR = load_corridor()
FRAME = RoadFrame(COR.road)
T0 = 100.0


def world() -> CorridorWorld:
    return CorridorWorld(DdmConfig(), rsu_ids=tuple(r.rsu_id for r in COR.rsus), frame=FRAME,
                         hazard_config=HazardConfig())


def test_the_picture_holds_tracks_evs_hazards_and_vehicles_and_does_not_change_with_the_world():
    w = world()
    w.ingest_objects(object_list("rsu1", 1, T0, [det(COR, 7, -30.0, lane_y(1), 20.0, ev=True),
                                                 det(COR, 8, 20.0, lane_y(1), 13.4)]), T0)
    w.ingest_vehicle_state(VehicleState(src="av1", stamp=T0, vehicle_id="av1", pos_x_m=20.0, pos_y_m=lane_y(1),
                                        lat_deg=30.6, lon_deg=-96.4, heading_rad=0.0, speed_mps=13.4,
                                        mode=VehicleMode.DRIVING), T0)
    w.ingest_ev_alert(EvAlert(src="rsu1", stamp=T0, alert_id="rsu1-ev-7", state=AlertState.ACTIVE, rsu_id="rsu1",
                              object_id=7, pos_x_m=-30.0, pos_y_m=lane_y(1), lat_deg=30.6, lon_deg=-96.4,
                              vel_x_mps=20.0, speed_mps=20.0, lane=1, confidence=0.9, first_seen=T0), T0)
    w.ingest_hazard_alert(HazardAlert(src="rsu1", stamp=T0, hazard_id="rsu1-hz-1", state="appear", rsu_id="rsu1",
                                      pos_x_m=60.0, pos_y_m=lane_y(1), lat_deg=30.6, lon_deg=-96.4, length_m=1.2,
                                      width_m=0.9, confidence=0.8, first_seen=T0), T0)
    p = w.snapshot(T0 + 0.5)
    assert len(p.tracks) == 2 and [t.ev_alert_id for t in p.evs] == ["rsu1-ev-7"]
    assert p.evs[0].x_m == pytest.approx(-30.0 + 20.0 * 0.5)  # predicted to the picture's time
    (hz,) = p.hazards
    assert hz.lane == 1 and hz.x_m == pytest.approx(60.0)
    (av,) = p.vehicles
    assert av.vehicle_id == "av1" and av.track_id == p.tracks[1].track_id and av.received_s == T0
    assert [t.track_id for t in p.tracks_near(20.0, lane_y(1), 10.0)] == [av.track_id]
    with pytest.raises(dataclasses.FrozenInstanceError):
        p.tracks = ()  # type: ignore[misc]
    with pytest.raises(dataclasses.FrozenInstanceError):
        hz.x_m = 0.0  # type: ignore[misc]
    w.ingest_hazard_alert(HazardAlert(src="rsu1", stamp=T0 + 1, hazard_id="rsu1-hz-1", state="clear",
                                      rsu_id="rsu1", pos_x_m=60.0, pos_y_m=lane_y(1), lat_deg=30.6, lon_deg=-96.4,
                                      length_m=1.2, width_m=0.9, confidence=0.8, first_seen=T0), T0 + 1)
    w.maintain(T0 + 10.0)  # every track timed out
    assert w.snapshot(T0 + 10.0).tracks == () and w.snapshot(T0 + 10.0).hazards == ()
    assert len(p.tracks) == 2 and len(p.hazards) == 1  # the earlier picture is unchanged


def test_the_command_manager_makes_a_command_only_of_an_intent_with_a_manoeuvre_and_a_path():
    from ddm.paths import plan_resume

    cm = CommandManager(DdmConfig(), source_id="ddm", seq_base=1000)
    with pytest.raises(ValueError, match="no command"):
        cm.issue_intent(Intent("hold", "keep pull_over", vehicle_id="av1"), T0)
    with pytest.raises(ValueError, match="no command"):
        cm.issue_intent(Intent(Manoeuvre.RESUME, "resume", vehicle_id="av1"), T0)  # no path
    path = plan_resume(FRAME, 20.0, lane_y(1), 0.0, 5.0, lane_y(1), 13.4, DdmConfig())
    cmd = cm.issue_intent(Intent(Manoeuvre.RESUME, "resume: EV passed", target_lane=1, path=path, vehicle_id="av1"),
                          T0)
    assert (cmd.command_id, cmd.manoeuvre, cmd.reason, cmd.target_lane) == ("ddm-av1-1001", Manoeuvre.RESUME,
                                                                          "resume: EV passed", 1)
    assert cmd.waypoints == path.waypoints and cmd.speed_profile_mps == path.speeds_mps
