"""Only authenticated evidence moves a car, over real Zenoh: a DDM process on a signed
corridor hears an unsigned ObjectList that marks a car behind the AV as a confirmed EV, and sends no
command; the same car named by an EvAlert signed with the RSU's trusted key gets the AV its pull-over."""

from __future__ import annotations

import math
import threading
import time
from pathlib import Path

import pytest
from sec_helpers import key

from protocol.corridor import DEFAULT_CORRIDOR, load_corridor
from protocol.enums import AlertState, VehicleMode
from protocol.keys import ddm_health_key, rsu_key, vehicle_key
from protocol.messages import EvAlert, ObjectList, VehicleState
from protocol.security import new_key_pair
from protocol.zenoh_transport import ZenohSettings, ZenohTransport
from scenario.faults import _detected

pytestmark = pytest.mark.serial  # processes, Zenoh or its own timing: make test runs it alone


ROOT = Path(__file__).resolve().parents[2]
AV_X0, EV_X0, AV_V, EV_V = 60.0, 20.0, 13.4, 19.0


def _signed_corridor(tmp_path: Path, rsu_public: str) -> tuple[Path, Path]:
    pem, ddm_public = new_key_pair()
    ddm_key = tmp_path / "ddm.pem"
    ddm_key.write_bytes(pem)
    ddm_key.chmod(0o600)
    p = tmp_path / "corridor.toml"
    p.write_text(DEFAULT_CORRIDOR.read_text()
                 + f'\n[[trust]]\nkey_id = "ddm-1"\nrole = "ddm"\nvehicles = ["av1"]\npublic_key = "{ddm_public}"\n'
                 + f'\n[[trust]]\nkey_id = "rsu1-key"\nrole = "rsu"\nrsu_id = "rsu1"\npublic_key = "{rsu_public}"\n')
    return p, ddm_key


class Scene:
    """The AV in lane 1 at 13.4 m/s and a car 40 m behind it at 19 m/s, as rsu1 and the AV report them."""

    def __init__(self, transport: ZenohTransport, corridor_id: str) -> None:
        self.t, self.c = transport, corridor_id
        self.corridor = load_corridor()
        self.y = self.corridor.road.lane_centre_offset_m(1)
        self.t0 = time.time()
        self.seq = 0

    def pos(self, now: float) -> tuple[float, float]:
        dt = now - self.t0
        return AV_X0 + AV_V * dt, EV_X0 + EV_V * dt

    def publish(self, *, ev_flag: bool) -> None:
        now = time.time()
        self.seq += 1
        av_x, ev_x = self.pos(now)
        objs = [_detected(self.corridor, 1, av_x, self.y, AV_V, 0.0, ev=False, length_m=4.9, width_m=1.9),
                _detected(self.corridor, 2, ev_x, self.y, EV_V, 0.0, ev=ev_flag, length_m=6.5, width_m=2.4)]
        self.t.publish(rsu_key(self.c, "rsu1", "objects"), ObjectList(
            src="rsu1", seq=self.seq, stamp=now, rsu_id="rsu1", frame=self.seq, measurement_time=now, objects=objs))
        lat, lon = self.corridor.to_latlon(av_x, self.y)
        self.t.publish(vehicle_key(self.c, "av1", "state"), VehicleState(
            src="av1", seq=self.seq, stamp=now, vehicle_id="av1", pos_x_m=av_x, pos_y_m=self.y, lat_deg=lat,
            lon_deg=lon, heading_rad=0.0, speed_mps=AV_V, length_m=4.9, width_m=1.9, lane=1,
            mode=VehicleMode.DRIVING))

    def signed_alert(self, signer) -> EvAlert:
        now = time.time()
        _, ev_x = self.pos(now)
        lat, lon = self.corridor.to_latlon(ev_x, self.y)
        k = rsu_key(self.c, "rsu1", "ev")
        return signer.sign_message(k, EvAlert(
            src="rsu1", seq=self.seq, stamp=now, alert_id="rsu1-ev-2", state=AlertState.ACTIVE, rsu_id="rsu1",
            object_id=2, pos_x_m=ev_x, pos_y_m=self.y, lat_deg=lat, lon_deg=lon, vel_x_mps=EV_V, speed_mps=EV_V,
            confidence=0.9, first_seen=self.t0))


@pytest.mark.slow
@pytest.mark.timeout(120)
def test_forged_unsigned_object_list_marking_an_ev_moves_no_car(tmp_path, corridor_id, spawn):
    rsu, rsu_public = key("rsu1-key")
    corridor_file, ddm_key = _signed_corridor(tmp_path, rsu_public)
    proc = spawn("-m", "ddm", "run", "--corridor", str(corridor_file), "--corridor-id", corridor_id, "--key",
                 str(ddm_key), "--startup-listen-s", "0.5")
    transport = ZenohTransport(ZenohSettings())
    commands, health = [], []
    got_cmd = threading.Event()
    try:
        transport.subscribe(vehicle_key(corridor_id, "av1", "cmd"), lambda k, m: (commands.append(m), got_cmd.set()))
        transport.subscribe(ddm_health_key(corridor_id), lambda k, m: health.append(m))
        deadline = time.monotonic() + 40.0
        while not health and time.monotonic() < deadline:
            assert proc.poll() is None, proc.stderr.read()
            time.sleep(0.1)
        assert health, "no Health from the DDM process"
        scene = Scene(transport, corridor_id)
        end = time.monotonic() + 4.0  # 4 s of forged EV objects, closing from 40 m to ~16 m
        while time.monotonic() < end:
            scene.publish(ev_flag=True)
            time.sleep(1 / 15)
        assert commands == [], [c.manoeuvre for c in commands]  # no command for a forged EV
        h = health[-1]
        assert h.counts.get("tracks", 0) >= 2, h.counts  # the DDM did fuse both cars from the forged list
        assert h.auth is not None and h.auth.key_id == "ddm-1"  # the DDM's heartbeat is signed
        # the same car named by a signed EvAlert: the DDM acts (so the silence above was the rule at work)
        deadline = time.monotonic() + 5.0
        k = rsu_key(corridor_id, "rsu1", "ev")
        while not got_cmd.is_set() and time.monotonic() < deadline:
            scene.publish(ev_flag=True)
            transport.publish(k, scene.signed_alert(rsu))
            got_cmd.wait(1 / 15)
        assert commands, "no command after a signed EvAlert"
        assert commands[0].auth is not None and commands[0].auth.key_id == "ddm-1"
        assert commands[0].manoeuvre.value in ("pull_over", "slow_in_lane", "lane_change"), commands[0]
        assert math.isfinite(commands[0].stamp)
    finally:
        transport.close()
