"""Command builder shared by the vehicle tests (a uniquely named module: other packages have conftests too)."""

from __future__ import annotations

import numpy as np

from protocol.enums import Manoeuvre
from protocol.messages import PathSwitchCommand
from protocol.road import Road
from vehicle.reference import lane_centre_waypoints, lane_change_waypoints


def make_command(road: Road, s_car: float, *, command_id: str = "c1", seq: int = 1, vehicle_id: str = "av1",
                 now: float = 0.0, valid_s: float = 5.0, manoeuvre: Manoeuvre = Manoeuvre.PULL_OVER,
                 stop_ahead_m: float | None = 100.0, waypoints=None, speed_mps: float = 13.4,
                 from_lane: int = 1, to_lane: int = 0) -> PathSwitchCommand:
    if waypoints is None:
        if from_lane == to_lane:
            waypoints = lane_centre_waypoints(road, to_lane, s_car - 3.0, s_car + 150.0)
        else:
            waypoints = lane_change_waypoints(road, s_car + 5.0, from_lane, to_lane, 40.0, 150.0, lead_m=8.0)
    stop = None
    if stop_ahead_m is not None:
        sx, sy, _ = road.pose_at(s_car + stop_ahead_m, road.lane_centre_offset_m(to_lane))
        stop = (float(sx), float(sy))
    return PathSwitchCommand(
        src="ddm", stamp=now, command_id=command_id, command_seq=seq, vehicle_id=vehicle_id, manoeuvre=manoeuvre,
        reason="test", target_lane=to_lane, waypoints=[(float(x), float(y)) for x, y in np.asarray(waypoints)],
        target_speed_mps=speed_mps, stop_point=stop, issued_at=now, valid_until=now + valid_s)
