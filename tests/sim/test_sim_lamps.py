"""Decoy lamps of ordinary vehicles: hazard flashers and red rear turn signals blink at 1-2 Hz
at the body's corners, a seeded fraction of the traffic has them, and they are never EVs."""

from dataclasses import replace

import numpy as np
import pytest
from lamp_rig import lamp_decals, snap

from protocol.enums import ActorKind
from protocol.messages import Actor
from sim.bodies import face_points
from sim.lamps import (
    DUTY,
    FREQ_MAX_HZ,
    FREQ_MIN_HZ,
    signal_on,
    style_signal,
    with_signal_lamps,
)
from sim.render.labels import CLASS_VEHICLE
from sim.render.renderer import Renderer
from sim.scenario import ScenarioError, load_scenario, parse_scenario
from sim.vehicles import LIVERY_TWO_TONE, make_style, style_detail, style_livery
from sim.world import World


def car(aid, x, y, style, heading=0.0, kind="car", size=(4.5, 1.8, 1.5)):
    return Actor(actor_id=aid, kind=ActorKind(kind), pos_x_m=x, pos_y_m=y, heading_rad=heading, length_m=size[0],
                 width_m=size[1], height_m=size[2], speed_mps=10.0, colour_bgr=(190, 190, 188), style=style)


def lamp_pixels(r: Renderer, a: Actor, lamp: str, face: str) -> list[tuple[int, int]]:
    """Image (x, y) of the centre of each of the actor's decals of that lamp on that face."""
    return sorted((x, y) for x, y, _segment in lamp_decals(r, a, lamp, face))


def face_x_range(r: Renderer, a: Actor, part: int, face: str) -> tuple[float, float]:
    """Image x extent of a face of one of the actor's parts."""
    _parts, _decals, corners, _uv, _depth, _rot = r._actor_geometry(a)
    uv, _ = r.cam.project(face_points(corners[part], face, 0.0, 1.0, 0.0, 1.0))
    return float(uv[:, 0].min()), float(uv[:, 0].max())


def amber(px) -> bool:
    b, g, r = (int(c) for c in px)
    return r >= 220 and b <= 90 and 100 <= g <= 235


def on_off_times(style):
    """A time in the middle of a lit half period and one half a period later (dark)."""
    sig = style_signal(style)
    t_on = sig.phase_s + 0.25 / sig.frequency_hz + 2.0 / sig.frequency_hz
    return t_on, t_on + 0.5 / sig.frequency_hz


def test_style_carries_the_lamps_without_touching_livery_and_detail():
    base = make_style(LIVERY_TWO_TONE, 201)
    for mode in ("hazard", "left", "right"):
        s = with_signal_lamps(base, mode, 1.37, 0.4)
        sig = style_signal(s)
        assert sig.mode == mode and abs(sig.frequency_hz - 1.37) <= 1 / 30 + 1e-9
        assert sig.phase_s * sig.frequency_hz == pytest.approx(0.4, abs=1 / 256)
        assert style_livery(s) == LIVERY_TWO_TONE and style_detail(s) == 201
        assert with_signal_lamps(s, "", 0, 0) == base
    assert style_signal(base) is None and not signal_on(base, 0.3)
    assert FREQ_MIN_HZ <= style_signal(with_signal_lamps(0, "hazard", 9.0, 0.0)).frequency_hz <= FREQ_MAX_HZ


@pytest.mark.parametrize("freq", [1.0, 1.5, 2.0])
def test_lamps_blink_at_their_rate_with_half_duty(freq):
    s = with_signal_lamps(0, "hazard", freq, 0.3)
    f = style_signal(s).frequency_hz
    t = np.arange(0.0, 20.0, 0.001)
    on = np.array([signal_on(s, x) for x in t])
    rises = np.count_nonzero(on[1:] & ~on[:-1])
    assert rises == pytest.approx(20.0 * f, abs=1)
    assert 1.0 <= f <= 2.0
    assert on.mean() == pytest.approx(DUTY, abs=0.02)


def test_hazard_flashers_blink_amber_at_the_four_corners_together(clean_renderer):
    r = clean_renderer
    style = with_signal_lamps(make_style(0, 1), "hazard", 1.5, 0.37)
    t_on, t_off = on_off_times(style)
    assert signal_on(style, t_on) and not signal_on(style, t_off)
    for heading, x, y, face in ((0.0, 30.0, 1.85, "rear"), (np.pi, 40.0, 5.55, "front")):
        a = car("h", x, y, style, heading)
        pts = lamp_pixels(r, a, "hazard", face)
        assert len(pts) == 2, face
        box = r.labels(snap([a], t_on))[0].bbox_px
        lit, dark = r.render(snap([a], t_on)), r.render(snap([a], t_off))
        for px, py in pts:
            assert amber(lit[py, px]), (face, lit[py, px])
            assert not amber(dark[py, px]) and int(dark[py, px][2]) < 200, (face, dark[py, px])
            # low on the body, at its corners (not on the roof, not in the middle)
            assert (py - box[1]) / (box[3] - box[1]) > 0.55, face
        (xl, _), (xr, _) = pts
        x0, x1 = face_x_range(r, a, 1, face)  # the lower body's face
        assert (xl - x0) / (x1 - x0) < 0.2 and (xr - x0) / (x1 - x0) > 0.8, face


def test_red_turn_signal_blinks_at_one_rear_corner_only(clean_renderer):
    r = clean_renderer
    for side in ("left", "right"):
        style = with_signal_lamps(make_style(0, 0), side, 1.8, 0.1)
        t_on, t_off = on_off_times(style)
        a = car("t", 30.0, 1.85, style)
        (turn,) = lamp_pixels(r, a, "turn", "rear")
        tails = lamp_pixels(r, a, "tail", "rear")
        assert turn in tails and len(tails) == 2
        other = next(p for p in tails if p != turn)
        # seen from behind (rsu1 looks along the traffic), the vehicle's left is the image's left
        assert (turn[0] < other[0]) == (side == "left")
        lit, dark = r.render(snap([a], t_on)), r.render(snap([a], t_off))
        b, g, red = (int(c) for c in lit[turn[1], turn[0]])
        assert red >= 230 and b < 110 and g < 110, lit[turn[1], turn[0]]
        assert int(dark[turn[1], turn[0]][2]) < 170  # back to the unlit tail light
        assert np.abs(lit[other[1], other[0]].astype(int) - dark[other[1], other[0]].astype(int)).max() <= 3
        assert not lamp_pixels(r, a, "turn", "front") and not lamp_pixels(r, a, "hazard", "rear")
        # no amber anywhere
        assert not any(amber(lit[y, x]) for x, y in tails)


@pytest.mark.parametrize("kind,size", [("van", (5.5, 2.0, 2.4)), ("truck", (9.0, 2.5, 3.4)), ("bus", (12.0, 2.5, 3.2))])
def test_other_bodies_show_hazards_beside_their_tail_lights(clean_renderer, kind, size):
    r = clean_renderer
    style = with_signal_lamps(0, "hazard", 1.2, 0.0)
    a = car(kind, 40.0, 1.85, style, kind=kind, size=size)
    t_on, t_off = on_off_times(style)
    pts = lamp_pixels(r, a, "hazard", "rear")
    lit, dark = r.render(snap([a], t_on)), r.render(snap([a], t_off))
    assert len(pts) == 2
    box = r.labels(snap([a], t_on))[0].bbox_px
    for px, py in pts:
        assert amber(lit[py, px]) and not amber(dark[py, px]), (kind, lit[py, px], dark[py, px])
        assert (py - box[1]) / (box[3] - box[1]) > 0.45, kind  # lower half, not a roof bar


def test_traffic_has_decoy_lamp_vehicles_and_none_is_an_ev(corridor):
    sc = load_scenario("ev_two_lanes_dense")
    w = World(sc, seed=301)
    sigs = {v.vehicle_id: style_signal(v.style) for v in w.vehicles()}
    decoys = {vid: s for vid, s in sigs.items() if s is not None}
    modes = {s.mode for s in decoys.values()}
    assert "hazard" in modes and modes & {"left", "right"}
    kinds = {v.vehicle_id: v.kind for v in w.vehicles()}
    assert all(kinds[vid] in ("car", "van", "truck", "bus") for vid in decoys)
    assert all(FREQ_MIN_HZ <= s.frequency_hz <= FREQ_MAX_HZ for s in decoys.values())
    assert sigs["ev1"] is None and all(v.light_bar is None for v in w.vehicles() if v.vehicle_id in decoys)
    # deterministic per seed
    assert {v.vehicle_id: v.style for v in World(sc, seed=301).vehicles()} == {v.vehicle_id: v.style
                                                                              for v in w.vehicles()}
    # ground truth: always class vehicle, seen by the cameras
    renderers = [Renderer(rsu.camera, corridor.road, seed=0) for rsu in corridor.rsus[:2]]
    seen = set()
    while w.t_s < 10.0:
        w.run_until(w.t_s + 1.0)
        s = w.snapshot()
        for a in s.actors:
            if a.actor_id in decoys:
                assert a.kind.value != "ev" and a.light_bar is None
        for r in renderers:
            for lb in r.labels(s):
                if lb.actor_id in decoys:
                    seen.add(lb.actor_id)
                    assert lb.class_id == CLASS_VEHICLE
    assert seen


def test_fractions_are_a_scenario_setting_and_leave_the_traffic_alone():
    sc = load_scenario("rellis_ev_yield")
    d = sc.traffic
    assert d.hazard_flasher_fraction > 0 and d.turn_signal_fraction > 0
    none = replace(sc, traffic=replace(d, hazard_flasher_fraction=0.0, turn_signal_fraction=0.0))
    every = replace(sc, traffic=replace(d, hazard_flasher_fraction=0.5, turn_signal_fraction=0.5))
    w0, w1 = World(none, seed=7), World(every, seed=7)
    assert not any(style_signal(v.style) for v in w0.vehicles())
    for a, b in zip(w0.vehicles(), w1.vehicles(), strict=True):
        assert (a.vehicle_id, a.kind, a.s_m, a.d_m, a.speed_mps) == (b.vehicle_id, b.kind, b.s_m, b.d_m, b.speed_mps)
        assert a.style == b.style & 0xFFF
        assert (style_signal(b.style) is not None) == a.vehicle_id.startswith("v")
    data = {"scenario": {"name": "x"}, "traffic": {"hazard_flasher_fraction": 0.25, "turn_signal_fraction": 0.1}}
    tr = parse_scenario(data).traffic
    assert (tr.hazard_flasher_fraction, tr.turn_signal_fraction) == (0.25, 0.1)
    with pytest.raises(ScenarioError, match="turn_signal_fraction"):
        parse_scenario({"scenario": {"name": "x"}, "traffic": {"hazard_flasher_fraction": 0.7,
                                                                "turn_signal_fraction": 0.6}})
