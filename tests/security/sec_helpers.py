"""Throwaway key pairs and trust entries for the security tests (a uniquely named module)."""

from __future__ import annotations

import dataclasses

from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

from protocol.corridor import Corridor, load_corridor
from protocol.security import Signer, public_key_b64


def key(key_id: str) -> tuple[Signer, str]:
    """(signer, base64 public key) of a fresh Ed25519 key."""
    private = Ed25519PrivateKey.generate()
    return Signer(key_id, private), public_key_b64(private.public_key())


def ddm_entry(key_id: str, public: str, vehicles=("*",)) -> dict:
    return {"key_id": key_id, "role": "ddm", "public_key": public, "vehicles": list(vehicles)}


def rsu_entry(key_id: str, public: str, rsu_id: str) -> dict:
    return {"key_id": key_id, "role": "rsu", "public_key": public, "rsu_id": rsu_id}


def corridor_with(trust: list[dict], corridor_id: str | None = None) -> Corridor:
    c = load_corridor()
    return dataclasses.replace(c, trust=tuple(trust), corridor_id=corridor_id or c.corridor_id)


def pull_over(road, s_car: float, now: float, *, command_id: str = "c1", seq: int = 1, vehicle_id: str = "av1",
              valid_s: float = 5.0):
    """A pull-over from lane 1 to lane 0 starting just ahead of the car (as the DDM would plan it)."""
    import numpy as np

    from protocol.enums import Manoeuvre
    from protocol.messages import PathSwitchCommand
    from vehicle.reference import lane_change_waypoints

    wp = np.asarray(lane_change_waypoints(road, s_car + 5.0, 1, 0, 40.0, 150.0, lead_m=8.0))
    sx, sy, _ = road.pose_at(s_car + 100.0, road.lane_centre_offset_m(0))
    return PathSwitchCommand(
        src="ddm", stamp=now, command_id=command_id, command_seq=seq, vehicle_id=vehicle_id,
        manoeuvre=Manoeuvre.PULL_OVER, reason="test", target_lane=0,
        waypoints=[(float(x), float(y)) for x, y in wp], target_speed_mps=13.4, stop_point=(float(sx), float(sy)),
        issued_at=now, valid_until=now + valid_s)


def resume(now: float, *, command_id: str, seq: int, vehicle_id: str = "av1", valid_s: float = 5.0):
    from protocol.enums import Manoeuvre
    from protocol.messages import PathSwitchCommand

    return PathSwitchCommand(src="ddm", stamp=now, command_id=command_id, command_seq=seq, vehicle_id=vehicle_id,
                             manoeuvre=Manoeuvre.RESUME, reason="test", target_lane=1, waypoints=[],
                             target_speed_mps=13.4, issued_at=now, valid_until=now + valid_s)
