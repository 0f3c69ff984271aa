"""The V2X attacker's logic (scenario.v2x_attack.Attacker), shared by the lockstep runner and the process attacker:
where the claimed EV is, when the CAM is signed, which key signs it."""

from __future__ import annotations

import math

import pytest
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

from protocol.corridor import load_corridor
from protocol.messages import Actor, WorldSnapshot
from protocol.security import Signer, TrustList, public_key_b64
from protocol.v2x.build import cam_info, station_id
from protocol.v2x.codec import decode
from protocol.v2x.keys import v2x_obu_cam_key
from protocol.v2x.secure import open_envelope
from scenario.v2x_attack import CLAIMED_SPEED_MPS, CLEAR_OF_ACTORS_M, Attacker, view_end_x_m

CORRIDOR = load_corridor(None)
EV_SIGNER = Signer("ev1-up", Ed25519PrivateKey.generate())
TRUST = TrustList.from_entries([{"key_id": "ev1-up", "role": "ev", "station_id": station_id("ev1"),
                                 "public_key": public_key_b64(EV_SIGNER.private_key.public_key())}])


def _actor(actor_id: str, kind: str, x: float, y: float) -> Actor:
    return Actor(actor_id=actor_id, kind=kind, pos_x_m=x, pos_y_m=y, heading_rad=0.0, length_m=4.5, width_m=1.9,
                 height_m=1.5, speed_mps=12.0)


def _snap(sim_time_s: float, actors: list[Actor]) -> WorldSnapshot:
    return WorldSnapshot(src="sim", seq=0, stamp=1000.0 + sim_time_s, scenario="ev_lights_never_on",
                         sim_time_s=sim_time_s, actors=actors)


ROAD = CORRIDOR.road
LANE0, LANE1 = ROAD.lane_centre_offset_m(0), ROAD.lane_centre_offset_m(1)
ACTORS = [_actor("ev1", "ev", -5.0, LANE1), _actor("car1", "car", 40.0, LANE0)]
"""A car at x = 40 m, 12 m/s: a claim at 18 m/s from 30, 40 or 50 m passes within 15 m of it on either lane; from
60 m on its lane it draws away."""


def _cam(payload: bytes):
    return cam_info(decode(open_envelope(payload).payload, expected="CAM"))


def test_forged_signs_under_the_ev_key_id_with_a_key_the_trust_list_does_not_hold():
    a = Attacker("forged", CORRIDOR, "c1", EV_SIGNER)
    assert a.signer.key_id == "ev1-up"
    assert TRUST.key_id_of(a.signer.private_key) is None and TRUST.key_id_of(EV_SIGNER.private_key) == "ev1-up"
    key, payload = a.step(1000.5, _snap(0.5, ACTORS))
    assert key == v2x_obu_cam_key("c1", "ev1") and open_envelope(payload).key_id == "ev1-up"
    info = _cam(payload)
    assert info.station_id == station_id("ev1") and info.light_bar and info.siren
    x, y = CORRIDOR.from_latlon(info.lat_deg, info.lon_deg)
    assert math.hypot(x + 5.0, y - LANE1) < 0.1  # the EV's true place


def test_replayed_signs_with_the_ev_key_two_seconds_in_the_past():
    a = Attacker("replayed", CORRIDOR, "c1", EV_SIGNER)
    assert a.signer is EV_SIGNER and a.signed_at(1000.5) == pytest.approx(998.5)
    _key, payload = a.step(1000.5, _snap(0.5, ACTORS))
    env = open_envelope(payload)
    assert env.key_id == "ev1-up" and env.not_after == pytest.approx(998.5 + (env.not_after - env.not_before) - 0.5)
    assert env.not_before == pytest.approx(998.5 - 0.5)  # seal's 0.5 s skew before the signing time


def test_contradicted_starts_clear_of_every_actor_and_drives_at_18_mps():
    a = Attacker("contradicted", CORRIDOR, "c1", EV_SIGNER)
    assert a.signer is EV_SIGNER
    places = []
    for i in range(11):
        out = a.step(1000.5 + 0.1 * i, _snap(0.5 + 0.1 * i, ACTORS))
        assert out is not None
        info = _cam(out[1])
        places.append(CORRIDOR.from_latlon(info.lat_deg, info.lon_deg))
    x0, y0 = places[0]
    assert all(math.hypot(ac.pos_x_m - x0, ac.pos_y_m - y0) > CLEAR_OF_ACTORS_M for ac in ACTORS)
    assert x0 == pytest.approx(60.0, abs=0.05) and y0 == pytest.approx(LANE0, abs=0.05)  # the first clear point
    speed = math.hypot(places[-1][0] - x0, places[-1][1] - y0) / 1.0
    assert speed == pytest.approx(CLAIMED_SPEED_MPS, abs=0.05)
    assert all(abs(p[1] - y0) < 0.05 for p in places)  # along its lane
    # silent once the claim would leave the last camera's view (x = 150 + 85 m, less 10 m)
    assert view_end_x_m(CORRIDOR) == pytest.approx(225.0)
    t_end = 1000.5 + (225.0 - x0) / CLAIMED_SPEED_MPS
    assert a.step(t_end - 0.05, _snap(9.0, ACTORS)) is not None
    assert a.step(t_end + 0.1, _snap(9.2, ACTORS)) is None


def test_ten_hz_from_the_start_time_only():
    a = Attacker("forged", CORRIDOR, "c1", EV_SIGNER)
    assert a.step(1000.0, _snap(0.45, ACTORS)) is None  # before start_s of scenario time
    sent = [t for t in (1000.5 + 0.01 * i for i in range(100)) if a.step(t, _snap(0.5, ACTORS)) is not None]
    assert len(sent) == 10 and a.sent == 10
    assert all(0.09 < b - x < 0.111 for x, b in zip(sent, sent[1:], strict=False))


def test_an_unknown_kind_is_refused():
    with pytest.raises(ValueError, match="forged, replayed, contradicted"):
        Attacker("jammed", CORRIDOR, "c1", EV_SIGNER)


def test_contradicted_counts_the_cams_it_puts_on_a_car_the_cameras_see():
    a = Attacker("contradicted", CORRIDOR, "c1", EV_SIGNER)
    assert a.near_an_actor(_snap(1.0, ACTORS), 45.0, LANE0) and not a.near_an_actor(_snap(1.0, ACTORS), 60.0, LANE0)
    assert a.step(1000.5, _snap(0.5, ACTORS)) is not None  # from x = 60 m
    parked = [*ACTORS, _actor("car9", "car", 60.0 + CLAIMED_SPEED_MPS * 0.1, LANE0)]
    assert a.step(1000.6, _snap(0.6, parked)) is not None  # the claim is on car9
    assert (a.sent, a.sent_near_actor) == (2, 1)
