"""Hard negatives for EV recognition: a works vehicle's amber roof beacon flashes at its rate, a bus's LED strip is
a steady (or chasing) blue, stop-and-go traffic lights rows of brake lights, and the scenarios that hold them load,
validate and stay ordinary traffic."""

from dataclasses import replace

import numpy as np
import pytest
from lamp_rig import lamp_decals, snap

from protocol.enums import ActorKind
from protocol.messages import Actor
from sim.lamps import (
    BEACON_DUTY,
    LED_SEGMENTS,
    ROOF_ALL_LIT,
    decoy_kind,
    decoy_lit,
    roof_segment_lit,
    roof_state,
    style_roof,
    style_signal,
    with_roof_lamps,
    with_signal_lamps,
)
from sim.render.labels import CLASS_VEHICLE
from sim.scenario import ScenarioError, load_scenario, parse_scenario
from sim.vehicles import LIVERY_WORKS, WORKS_BGR, make_style, style_detail, style_livery
from sim.world import World


def actor(kind, size, style, x=40.0, y=1.85, heading=0.0, colour=(230, 230, 230)):
    return Actor(actor_id="n", kind=ActorKind(kind), pos_x_m=x, pos_y_m=y, heading_rad=heading, length_m=size[0],
                 width_m=size[1], height_m=size[2], speed_mps=5.0, colour_bgr=colour, style=style)


def amber(px) -> bool:
    b, g, r = (int(c) for c in px)
    return r >= 230 and b <= 90 and 120 <= g <= 220


def lamp_blue(px) -> bool:
    b, g, r = (int(c) for c in px)
    return b >= 240 and b - max(g, r) >= 100


def test_roof_lamps_share_the_style_with_livery_detail_and_signal_lamps():
    base = with_signal_lamps(make_style(LIVERY_WORKS, 77), "hazard", 1.5, 0.25)
    s = with_roof_lamps(base, "beacon", 3.0, 0.5)
    roof = style_roof(s)
    assert roof.mode == "beacon" and roof.frequency_hz == pytest.approx(3.0, abs=1 / 12) and not roof.white
    assert roof.phase_s * roof.frequency_hz == pytest.approx(0.5, abs=1 / 256)
    assert style_livery(s) == LIVERY_WORKS and style_detail(s) == 77 and style_signal(s) == style_signal(base)
    # setting the signal lamps again (the SUMO traffic does each step) keeps the roof lamps, and back
    assert style_roof(with_signal_lamps(s, "left", 1.2, 0.0)) == roof
    assert style_roof(with_signal_lamps(s, "", 0.0, 0.0)) == roof and style_signal(with_signal_lamps(s, "", 0, 0)) is None
    assert with_roof_lamps(s, "") == base and style_roof(base) is None
    led = with_roof_lamps(0, "led_chase", 9.0, 0.0, white=True)
    assert style_roof(led).white and style_roof(led).frequency_hz == 4.0
    assert decoy_kind(s) == "beacon" and decoy_kind(led) == "led_strip" and decoy_kind(base) == "hazard"
    assert decoy_kind(make_style(0, 3)) is None
    with pytest.raises(ValueError, match="roof lamp mode"):
        with_roof_lamps(0, "strobe")


@pytest.mark.parametrize("freq", [1.5, 2.5, 4.0])
def test_beacon_flashes_at_its_rate_and_duty(freq):
    s = with_roof_lamps(0, "beacon", freq, 0.3)
    f = style_roof(s).frequency_hz
    t = np.arange(0.0, 10.0, 0.001)
    on = np.array([roof_state(s, x) == ROOF_ALL_LIT for x in t])
    assert np.count_nonzero(on[1:] & ~on[:-1]) == pytest.approx(10.0 * f, abs=1)
    assert on.mean() == pytest.approx(BEACON_DUTY, abs=0.02)
    assert list(map(bool, on[::100])) == [decoy_lit(s, x) for x in t[::100]]


def test_chasing_strip_lights_half_its_segments_and_moves():
    s = with_roof_lamps(0, "led_chase", 2.0, 0.0)
    states = [roof_state(s, t) for t in np.arange(0.0, 0.5, 1 / 60)]
    assert set(states) == set(range(1, LED_SEGMENTS + 1))  # one run along the strip per period
    for st in states:
        assert sum(roof_segment_lit(st, j) for j in range(LED_SEGMENTS)) == LED_SEGMENTS // 2
    assert all(roof_state(with_roof_lamps(0, "led", 2.0, 0.4), t) == ROOF_ALL_LIT for t in (0.0, 0.13, 7.7))


@pytest.mark.parametrize("kind,size", [("van", (5.5, 2.0, 2.4)), ("truck", (9.0, 2.5, 3.4))])
def test_works_beacon_renders_amber_on_the_roof_and_blinks(clean_renderer, kind, size):
    r = clean_renderer
    style = with_roof_lamps(make_style(LIVERY_WORKS, 5), "beacon", 2.0, 0.0)
    period = 1.0 / style_roof(style).frequency_hz
    t_on, t_off = 2 * period + 0.2 * period, 2 * period + 0.7 * period
    a = actor(kind, size, style, colour=WORKS_BGR)
    lit, dark = r.render(snap([a], t_on)), r.render(snap([a], t_off))
    pts = lamp_decals(r, a, "beacon", "rear")
    assert len(pts) == 1
    (px, py, _seg), = pts
    box = r.labels(snap([a], t_on))[0]
    assert box.class_id == CLASS_VEHICLE
    x1, y1, x2, y2 = box.bbox_px
    assert (py - y1) / (y2 - y1) < 0.25 and 0.25 < (px - x1) / (x2 - x1) < 0.75  # on the roof, in the middle
    assert amber(lit[py, px]), lit[py, px]
    assert not amber(dark[py, px]) and int(dark[py, px][2]) < 200, dark[py, px]
    # the bar is wide: most of the middle of the box lights amber along the beacon's row
    row = lit[py, int(x1 + (x2 - x1) * 0.3):int(x1 + (x2 - x1) * 0.7)]
    assert np.mean([amber(p) for p in row]) > 0.6


def test_bus_led_strip_is_a_steady_blue_and_a_chase_moves(clean_renderer):
    r = clean_renderer
    size = (12.0, 2.5, 3.2)
    steady = actor("bus", size, with_roof_lamps(make_style(0, 2), "led", 2.0, 0.0))
    pts = lamp_decals(r, steady, "led_blue", "rear")
    assert len(pts) == LED_SEGMENTS
    frames = [r.render(snap([steady], t)) for t in (0.0, 0.1, 0.23, 0.41)]
    for px, py, _seg in pts:
        assert all(lamp_blue(f[py, px]) for f in frames), [f[py, px] for f in frames]
        assert max(int(np.abs(f[py, px].astype(int) - frames[0][py, px].astype(int)).max()) for f in frames) <= 2
    chase = replace(steady, style=with_roof_lamps(make_style(0, 2), "led_chase", 2.0, 0.0))
    lit_sets = set()
    for t in (0.01, 0.26):  # half a period apart: the lit block has moved to the other half
        img = r.render(snap([chase], t))
        lit = frozenset(seg for px, py, seg in lamp_decals(r, chase, "led_blue", "rear") if lamp_blue(img[py, px]))
        assert len(lit) == LED_SEGMENTS // 2
        lit_sets.add(lit)
    assert len(lit_sets) == 2


def test_scenarios_with_the_negatives_load_and_validate():
    rw = load_scenario("roadworks")
    assert [(w.body, w.speed_mps) for w in rw.works] == [("van", 0.0), ("truck", 3.0)]
    assert rw.works[0].offset_m < -2.0 and rw.works[1].hazard_flashers
    jam = load_scenario("dusk_jam")
    assert jam.lighting == "dusk" and jam.traffic.stop_and_go_period_s > 0 and jam.traffic.bus_led_fraction > 0
    d = parse_scenario({"scenario": {"name": "x"}, "works": [{"s_m": 150.0}]})
    assert d.works[0].body == "van" and d.works[0].beacon_hz == 2.5 and d.traffic.bus_led_fraction == 0.25
    assert d.traffic.stop_and_go_period_s == 0.0
    for bad, field in (({"works": [{"s_m": 150.0, "body": "bus"}]}, r"works\[0\]\.body.*'van', 'truck'"),
                       ({"works": [{"s_m": 150.0, "beacon_hz": 9.0}]}, r"works\[0\]\.beacon_hz"),
                       ({"works": [{"s_m": 150.0, "colour": "red"}]}, "colour"),
                       ({"works": [{"lane": 0}]}, r"works\[0\]\.s_m"),
                       ({"works": [{"s_m": 150.0, "lane": 5}]}, r"works\[0\]\.lane"),
                       ({"traffic": {"stop_and_go_period_s": 1.0}}, r"traffic\.stop_and_go_period_s.*0 \(off\)"),
                       ({"traffic": {"bus_led_fraction": 1.5}}, r"traffic\.bus_led_fraction")):
        with pytest.raises(ScenarioError, match=field):
            parse_scenario({"scenario": {"name": "x"}, **bad})


def test_works_vehicles_and_led_buses_are_seeded_ordinary_traffic():
    sc = load_scenario("roadworks")
    w = World(sc, seed=5)
    vs = {v.vehicle_id: v for v in w.vehicles()}
    assert decoy_kind(vs["w0"].style) == decoy_kind(vs["w1"].style) == "beacon"
    assert style_signal(vs["w1"].style).mode == "hazard" and vs["w0"].is_static
    leds = [v for v in vs.values() if v.kind == "bus" and decoy_kind(v.style) == "led_strip"]
    assert leds and all(v.kind == "bus" for v in vs.values() if decoy_kind(v.style) == "led_strip")
    assert {k: v.style for k, v in vs.items()} == {v.vehicle_id: v.style for v in World(sc, seed=5).vehicles()}
    s0 = vs["w0"].s_m
    w.run_until(2.0)
    assert vs["w0"].s_m == s0 and 0 < vs["w1"].s_m - 215.0 < 7.0
    assert all(a.kind.value != "ev" and a.light_bar is None for a in w.snapshot().actors
               if decoy_kind(a.style) is not None)
    # the LED strips are drawn last: the traffic is that of a fraction of 0
    none = World(replace(sc, traffic=replace(sc.traffic, bus_led_fraction=0.0)), seed=5)
    assert [(v.vehicle_id, v.s_m, v.d_m) for v in none.vehicles()] == [(v.vehicle_id, v.s_m, v.d_m)
                                                                        for v in World(sc, seed=5).vehicles()]
    assert not any(style_roof(v.style) for v in none.vehicles() if v.vehicle_id.startswith("v"))


def test_stop_and_go_waves_light_rows_of_brake_lights():
    sc = load_scenario("dusk_jam")
    w = World(sc, seed=3)
    braking = []
    while w.t_s < 8.0:
        w.run_until(w.t_s + 0.5, dt_s=0.1)
        braking.append(sum(v.brake_on for v in w.vehicles() if v.vehicle_id.startswith("v")))
    assert max(braking) >= 5
    calm = World(replace(sc, traffic=replace(sc.traffic, stop_and_go_period_s=0.0)), seed=3)
    calm.run_until(8.0, dt_s=0.1)
    assert [(v.vehicle_id, v.kind) for v in calm.vehicles()] == [(v.vehicle_id, v.kind) for v in w.vehicles()]
