"""Command validation and the command state machine: ack, idempotency, ordering, expiry."""

import math

import numpy as np
import pytest
from vehicle_helpers import make_command

from protocol.enums import AckStatus, Manoeuvre
from protocol.messages import PathSwitchCommand
from vehicle.commands import CommandBook, validate_command

POSE = (100.0, 5.55, 0.0)  # lane 1 centre, heading east


def seg(x0, y0, x1, y1, step=2.0):
    n = max(2, int(math.hypot(x1 - x0, y1 - y0) / step) + 1)
    return list(zip(np.linspace(x0, x1, n), np.linspace(y0, y1, n), strict=True))


def test_a_good_command_is_accepted(road):
    reason, path = validate_command(make_command(road, 100.0), "av1", 0.0, POSE, 13.4)
    assert reason is None and path is not None and path.stop_s_m is not None


@pytest.mark.parametrize("change, expected", [
    (dict(vehicle_id="av2"), "wrong vehicle"),
    (dict(valid_s=-1.0), "expired"),
    (dict(waypoints=seg(200.0, 5.55, 300.0, 5.55)), "starts 100.0 m from the car"),
    (dict(waypoints=seg(88.0, 5.55, 95.0, 5.55)), "path ends behind the car"),
    (dict(waypoints=[(80.0, 5.55), (90.0, 5.55), (300.0, 5.55)]), "waypoints 210.0 m apart"),
    (dict(waypoints=seg(95.0, 20.0, 200.0, 20.0)), "off the path"),
    (dict(waypoints=seg(98.0, 3.0, 98.0 + 60 * math.cos(1.0), 3.0 + 60 * math.sin(1.0))), "heading differs"),
    (dict(stop_ahead_m=None), "needs a stop_point"),
    (dict(speed_mps=60.0), "speed above"),
])
def test_bad_commands_are_rejected_with_a_reason(road, change, expected):
    valid_s = change.pop("valid_s", 5.0)
    cmd = make_command(road, 100.0, now=10.0, valid_s=max(valid_s, 0.5), **change)
    now = 10.0 if valid_s > 0 else 11.0
    reason, path = validate_command(cmd, "av1", now, POSE, 13.4)
    assert reason is not None and expected in reason and path is None


def test_first_waypoint_far_behind_is_unreachable(road):
    cmd = make_command(road, 100.0, waypoints=seg(75.0, 5.55, 300.0, 5.55))
    assert "behind the car" in validate_command(cmd, "av1", 0.0, POSE, 13.4)[0]


def test_curvature_too_high_for_the_speed(road):
    # a 3.7 m lane change squeezed into 10 m at 25 m/s needs ~ 9 m/s^2 of lateral acceleration
    from vehicle.reference import lane_change_waypoints
    wp = lane_change_waypoints(road, 105.0, 1, 0, 10.0, 150.0, step_m=1.0, lead_m=8.0)
    reason, _ = validate_command(make_command(road, 100.0, waypoints=wp), "av1", 0.0, POSE, 25.0)
    assert reason is not None and "lateral" in reason
    ok, _ = validate_command(make_command(road, 100.0, waypoints=wp), "av1", 0.0, POSE, 3.0)
    assert ok is None  # at walking pace the same path is fine


def test_stop_point_off_the_path(road):
    cmd = make_command(road, 100.0)
    cmd = cmd.model_copy(update={"stop_point": (200.0, 30.0)})
    assert "stop point" in validate_command(cmd, "av1", 0.0, POSE, 13.4)[0]


def test_ack_idempotency_ordering_and_supersede(road):
    book = CommandBook("av1")
    c1 = make_command(road, 100.0, command_id="c1", seq=5)
    d = book.offer(c1, 0.0, POSE, 13.4)
    assert [(x.command_id, x.status) for x in d] == [("c1", AckStatus.ACCEPTED)]
    # duplicate: same answer, nothing changes
    again = book.offer(c1, 0.5, POSE, 13.4)
    assert [(x.command_id, x.status) for x in again] == [("c1", AckStatus.ACCEPTED)] and book.active is c1
    # an older command never overrides a newer one
    old = make_command(road, 100.0, command_id="c0", seq=4)
    d = book.offer(old, 0.6, POSE, 13.4)
    assert d[0].status == AckStatus.REJECTED and "stale" in d[0].reason and book.active is c1
    # the same seq with another id is refused
    d = book.offer(make_command(road, 100.0, command_id="cx", seq=5), 0.6, POSE, 13.4)
    assert d[0].status == AckStatus.REJECTED and "already used" in d[0].reason
    # a newer command supersedes: c1 completed, c2 accepted
    c2 = make_command(road, 100.0, command_id="c2", seq=6, from_lane=1, to_lane=1, manoeuvre=Manoeuvre.STOP_IN_LANE)
    d = book.offer(c2, 1.0, POSE, 13.4)
    assert [(x.command_id, x.status) for x in d] == [("c1", AckStatus.COMPLETED), ("c2", AckStatus.ACCEPTED)]
    assert "superseded by c2" in d[0].reason and book.active is c2 and book.newest_seq == 6
    # a duplicate of c1 now reports its final state
    assert book.offer(c1, 1.1, POSE, 13.4)[0].status == AckStatus.COMPLETED
    done = book.complete("stopped")
    assert done.status == AckStatus.COMPLETED and book.active is None


def test_expired_and_rejected_do_not_move_the_sequence(road):
    book = CommandBook("av1")
    late = make_command(road, 100.0, command_id="late", seq=9, now=0.0, valid_s=1.0)
    d = book.offer(late, 2.0, POSE, 13.4)
    assert d[0].status == AckStatus.REJECTED and "expired" in d[0].reason
    assert book.newest_seq is None  # a refused command does not block later ones
    assert book.offer(make_command(road, 100.0, command_id="ok", seq=3, now=2.0), 2.0, POSE, 13.4)[0].status \
        == AckStatus.ACCEPTED


def test_wrong_vehicle_and_blocked(road):
    book = CommandBook("av1")
    d = book.offer(make_command(road, 100.0, vehicle_id="av9"), 0.0, POSE, 13.4)
    assert d[0].status == AckStatus.REJECTED and "wrong vehicle" in d[0].reason
    d = book.offer(make_command(road, 100.0, command_id="b"), 0.0, POSE, 13.4, blocked_reason="localisation stale")
    assert d[0].status == AckStatus.REJECTED and d[0].reason == "localisation stale"


def test_resume_needs_no_path(road):
    resume = PathSwitchCommand(src="ddm", stamp=0.0, command_id="r1", command_seq=2, vehicle_id="av1",
                               manoeuvre=Manoeuvre.RESUME, reason="ev passed", target_lane=1, waypoints=[],
                               target_speed_mps=13.4, issued_at=0.0, valid_until=5.0)
    assert validate_command(resume, "av1", 1.0, POSE, 0.0) == (None, None)
    assert np.isfinite(POSE[0])
