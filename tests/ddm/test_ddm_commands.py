"""Command manager: retransmit with backoff until acked, supersede, expire, reject explicitly."""

from __future__ import annotations

from ddm.commands import CommandManager, CommandState
from ddm.config import DdmConfig
from protocol.enums import AckStatus, Manoeuvre
from protocol.messages import CommandAck

WP = [(0.0, 0.0), (1.0, 0.0)]


def issue(cm: CommandManager, now: float, m: Manoeuvre = Manoeuvre.PULL_OVER, vid: str = "av1"):
    return cm.issue(vid, now, manoeuvre=m, reason="test", target_lane=0, waypoints=WP, speed_profile_mps=[5.0, 0.0],
                    target_speed_mps=0.0)


def ack(cmd, status=AckStatus.ACCEPTED, reason=""):
    return CommandAck(src=cmd.vehicle_id, stamp=0.0, command_id=cmd.command_id, vehicle_id=cmd.vehicle_id,
                      status=status, reason=reason)


def sends(cm: CommandManager, t0: float, t1: float, dt: float = 0.01) -> list[float]:
    out, t = [], t0
    while t <= t1 + 1e-9:
        out += [t] * len(cm.on_tick(t))
        t = round(t + dt, 6)
    return out


def test_retransmits_with_backoff_until_acked():
    cm = CommandManager(DdmConfig(), seq_base=5000)
    cmd = issue(cm, 10.0)
    assert cmd.command_seq == 5001 and cmd.command_id == "ddm-av1-5001" and cmd.valid_until == 70.0
    times = sends(cm, 10.0, 11.6)
    gaps = [round(b - a, 2) for a, b in zip(times, times[1:], strict=False)]
    assert times[0] == 10.0 and gaps[:4] == [0.1, 0.1, 0.2, 0.4]  # backoff doubles ...
    assert max(gaps) <= 0.8  # ... up to the cap
    ev = cm.on_ack(ack(cmd), 11.7)
    assert ev.kind == "accepted" and cm.state_of("av1").state == CommandState.ACCEPTED
    assert sends(cm, 11.7, 20.0) == []  # acked: silence


def test_unacked_command_expires_explicitly():
    cfg = DdmConfig(max_attempts=4)
    cm = CommandManager(cfg)
    issue(cm, 0.0)
    assert len(sends(cm, 0.0, 5.0)) == 4
    assert cm.state_of("av1").state == CommandState.EXPIRED
    kinds = [e.kind for e in cm.drain_events()]
    assert kinds.count("retransmit") == 3 and kinds[-1] == "expired"


def test_new_command_supersedes_explicitly_and_old_acks_are_ignored():
    cm = CommandManager(DdmConfig())
    a = issue(cm, 0.0)
    cm.on_tick(0.0)
    b = issue(cm, 0.5, Manoeuvre.RESUME)
    assert b.supersedes == a.command_id and b.command_seq > a.command_seq
    assert cm.on_ack(ack(a), 0.6).kind == "ignored_ack"
    assert [c.command_id for c in cm.on_tick(0.5)] == [b.command_id]  # only the new one is sent
    kinds = [e.kind for e in cm.drain_events()]
    assert "superseded" in kinds


def test_rejection_is_reported_with_reason_and_stops_retransmission():
    cm = CommandManager(DdmConfig())
    a = issue(cm, 0.0)
    cm.on_tick(0.0)
    ev = cm.on_ack(ack(a, AckStatus.REJECTED, "path leaves the road"), 0.05)
    assert ev.kind == "rejected" and ev.detail == "path leaves the road"
    assert sends(cm, 0.1, 3.0) == []


def test_adopted_command_is_superseded_by_the_next():
    cm = CommandManager(DdmConfig(), seq_base=10**6)
    cm.adopt("av1", "olddm-av1-77")
    b = issue(cm, 1.0, Manoeuvre.RESUME)
    assert b.supersedes == "olddm-av1-77"
