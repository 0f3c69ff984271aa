"""The DDM acts on an equipped EV's CAM passed on by an RSU radio (in process, lockstep): before any camera sees
the EV; never on a forged, replayed or camera-contradicted CAM."""

from __future__ import annotations

import math
from dataclasses import replace

import pytest
from ddm_rig import Rig, lane_y

from ddm.service import DdmService
from protocol.security import Signer, load_private_key, new_key_pair
from protocol.v2x.build import ev_cam, station_id
from protocol.v2x.codec import encode
from protocol.v2x.keys import v2x_obu_cam_key
from protocol.v2x.secure import seal
from rsu.v2x_gateway import V2xGateway

EV_ID = "ev1"


def _signer(tmp_path, name: str) -> tuple[Signer, str]:
    pem, public = new_key_pair()
    path = tmp_path / f"{name}.pem"
    path.write_bytes(pem)
    return Signer(name, load_private_key(path)), public


class V2xRig:
    """The DDM rig on a corridor trusting rsu1's key and the EV's key; rsu1's gateway relays what its radio hears."""

    def __init__(self, tmp_path, *, ev_x: float, ev_visible: bool, av_x: float = 40.0) -> None:
        self.rig = rig = Rig()
        self.rsu_signer, rsu_pub = _signer(tmp_path, "rsu1-key")
        self.ev_signer, ev_pub = _signer(tmp_path, "ev1-key")
        self.corridor = replace(rig.corridor, trust=(
            {"key_id": "rsu1-key", "role": "rsu", "rsu_id": "rsu1", "public_key": rsu_pub},
            {"key_id": "ev1-key", "role": "ev", "station_id": station_id(EV_ID), "public_key": ev_pub}))
        rig.svc.close()
        rig.corridor = self.corridor
        rig.svc = DdmService(rig.bus, rig.clock, self.corridor, rig.config, verify_alerts=False)
        self.gw = V2xGateway(rig.bus, self.corridor, rig.c, "rsu1", clock=rig.clock.now, signer=self.rsu_signer,
                             radio_range_m=400.0).start()
        rig.add("av1", av_x, 1, 13.4)
        self.ev = rig.add("ev", ev_x, 1, 25.0)
        self.ev.visible = ev_visible
        self.lights = True
        self.signer = self.ev_signer
        self.cam_pos = None
        """A claimed position ``f(t) -> (x, y)`` instead of the EV's own."""
        self.captured: list[bytes] = []
        self.send = True
        rig.hooks.append(self.broadcast)

    def cam_payload(self, t: float) -> bytes:
        x, y = (self.ev.x, self.ev.y) if self.cam_pos is None else self.cam_pos(t)
        lat, lon = self.corridor.to_latlon(x, y)
        key = v2x_obu_cam_key(self.rig.c, EV_ID)
        cam = encode("CAM", ev_cam(station_id(EV_ID), t, lat, lon, 0.0, 25.0, self.lights, self.lights))
        return seal(self.signer, key, cam, t)

    def broadcast(self) -> None:
        t = self.rig.clock.now()
        payload = self.cam_payload(t)
        self.captured.append(payload)
        if self.send:
            self.rig.bus.publish_bytes(v2x_obu_cam_key(self.rig.c, EV_ID), payload)

    @property
    def commands(self) -> int:
        return len(self.rig.commands)


def test_an_equipped_ev_no_camera_sees_is_acted_on_from_its_cam(tmp_path):
    s = V2xRig(tmp_path, ev_x=-130.0, ev_visible=False)
    s.rig.run(2.0)
    v2x = s.rig.svc.v2x
    assert s.gw.counts["rx"] >= 18 and v2x.counts["v2x"] >= 15, (s.gw.counts, v2x.counts)
    assert s.ev.x < -60.0  # still beyond every camera
    assert s.commands >= 1 and v2x.evidence[station_id(EV_ID)] == "v2x"


def test_the_cam_and_the_cameras_agree_vision_and_v2x(tmp_path):
    s = V2xRig(tmp_path, ev_x=-30.0, ev_visible=True, av_x=60.0)
    s.rig.run(1.5)
    assert s.rig.svc.v2x.evidence[station_id(EV_ID)] == "vision+v2x"


def test_a_forged_cam_moves_no_car(tmp_path):
    s = V2xRig(tmp_path, ev_x=-130.0, ev_visible=False)
    s.signer, _ = _signer(tmp_path, "ev1-key")  # the right key id, another private key
    s.rig.run(2.0)
    assert s.commands == 0
    assert s.rig.svc.rejected["v2x_bad_signature"] >= 18


def test_a_replayed_cam_moves_no_car(tmp_path):
    s = V2xRig(tmp_path, ev_x=-130.0, ev_visible=False)
    s.send = False
    s.rig.run(2.0)  # an attacker records the EV's CAMs off the air...
    recorded = list(s.captured)
    s.rig.hooks.clear()

    def replay() -> None:  # ...and plays them back later
        if recorded:
            s.rig.bus.publish_bytes(v2x_obu_cam_key(s.rig.c, EV_ID), recorded.pop(0))

    s.rig.hooks.append(replay)
    s.rig.run(2.0)
    assert s.commands == 0
    assert s.rig.svc.rejected["v2x_expired"] >= 15


def test_replays_within_the_window_are_refused_as_replayed(tmp_path):
    s = V2xRig(tmp_path, ev_x=-130.0, ev_visible=False)
    s.lights = False  # an EV off duty: its CAMs are believed but ask for nothing
    s.rig.run(0.5)
    old = s.captured[0]
    s.rig.bus.publish_bytes(v2x_obu_cam_key(s.rig.c, EV_ID), old)
    assert s.rig.svc.rejected["v2x_replayed"] == 1 and s.commands == 0


def test_a_cam_the_cameras_contradict_is_not_believed_alone(tmp_path):
    s = V2xRig(tmp_path, ev_x=-130.0, ev_visible=False)
    t0 = s.rig.clock.now()
    s.cam_pos = lambda t: (20.0 + 25.0 * (t - t0), lane_y(1))  # an EV driving through rsu1's and rsu2's empty view
    s.rig.run(2.0)
    assert s.commands == 0
    assert s.rig.svc.v2x.counts["contradicted"] >= 15 and s.rig.svc.v2x.counts["v2x"] == 0


@pytest.mark.parametrize("heading", [0.0, math.pi])
def test_the_lights_going_off_clears_the_v2x_alert(tmp_path, heading):
    s = V2xRig(tmp_path, ev_x=-130.0, ev_visible=False)
    s.rig.run(1.0)
    s.lights = False
    s.rig.run(0.3)
    assert s.rig.svc.v2x.counts["alerts_cleared"] == 1 and station_id(EV_ID) not in s.rig.svc.v2x.active
