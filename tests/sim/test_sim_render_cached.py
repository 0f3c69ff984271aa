"""The renderer's cached fast path (body models built once per look, posed and shaded with array
operations, shadows darkened by a scale, the static scene kept exposed at unit gain with each noise slot's noise and
scaled per frame) draws the same pixels as the straightforward renderer (``bench.render_reference.
ReferenceRenderer``) within noise, and the static scene is rendered once per lighting."""

import cv2
import numpy as np
import pytest

from bench.render_reference import ReferenceRenderer
from sim.render.renderer import Renderer
from sim.scenario import load_scenario
from sim.scenery import LIGHTING
from sim.world import World


def assert_within_noise(a: np.ndarray, b: np.ndarray, lighting: str, where) -> None:
    """Frames ``a`` and ``b`` differ by no more than their sensor noise (sigma 2.5 / 4 / 6 levels by day / dusk /
    night) and without structure. The fast path applies the frame's gain after the static scene's noise (a sensor's
    gain amplifies its read noise), so a pixel may differ by a level of rounding (the kept scene is 8-bit: a scene's
    mean moves by up to half a level) and the gain's share of its noise (under 11 %); where the value saturates, by
    the noise itself. Motion blur's cropped kernel rounds a few pixels
    1-2 levels apart. Anything drawn differently (a face, a lamp, a shadow) would differ by tens of levels over
    whole patches, which the local means catch."""
    d = a.astype(int) - b.astype(int)
    m = np.abs(d)
    sigma = LIGHTING[lighting]["noise"]
    assert m.max() <= 3 * sigma, (where, int(m.max()))
    assert (m > 2).mean() < 5e-4 and (m > 1).mean() < 0.01, (where, np.bincount(m.ravel()))
    assert abs(d.mean()) < 0.5 and m.mean() < 0.7, (where, float(d.mean()), float(m.mean()))
    local = np.abs(cv2.blur(d.astype(np.float32), (15, 15)))
    assert local.max() <= 2.0, (where, float(local.max()))  # no patch drawn differently


CASES = [("ev_two_lanes_dense", 8.0), ("rellis_ev_yield", 6.0), ("night_ev", 5.0), ("hazard_in_lane", 7.0),
         ("ev_lights_never_on", 12.0)]


@pytest.mark.parametrize(("scenario", "t_s"), CASES)
def test_fast_path_draws_the_reference_pixels(corridor, scenario, t_s):
    sc = load_scenario(scenario)
    world = World(sc, seed=3)
    world.run_until(t_s)
    snaps = [world.snapshot()]
    world.run_until(t_s + 0.4)
    snaps.append(world.snapshot())
    compared = 0
    for rsu in corridor.rsus:
        fast, ref = (cls(rsu.camera, corridor.road, seed=3) for cls in (Renderer, ReferenceRenderer))
        ref._backgrounds = fast._backgrounds  # one static scene for both (it is not what is compared)
        for k, snap in enumerate(snaps):
            assert_within_noise(fast.render(snap, k), ref.render(snap, k), snap.lighting.value, (scenario, rsu.rsu_id, k))
            compared += len(fast._models) > 0
    assert compared > 0  # some camera saw actors


@pytest.mark.parametrize("lighting", ["day", "dusk", "night"])
def test_fast_path_matches_in_every_lighting_with_blur_shadows_and_lamps(corridor, lighting):
    import sys
    from pathlib import Path
    sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "bench"))
    from sim_bench import scene  # 20 vehicles, an EV with its bar on, brake lights, moving

    cam = corridor.rsu("rsu1").camera
    fast, ref = Renderer(cam, corridor.road, seed=1), ReferenceRenderer(cam, corridor.road, seed=1)
    ref._backgrounds = fast._backgrounds
    for k in (0, 3, 7):  # the light bar's red and blue halves; a chasing LED strip's blocks, a beacon on and off
        for negatives in (False, True):
            s = scene(k / 15.0, lighting, negatives)
            assert_within_noise(fast.render(s, k), ref.render(s, k), lighting, (k, negatives))


def test_static_scene_rendered_once_per_lighting(corridor, monkeypatch):
    import sim.render.renderer as render_mod

    calls = []
    real = render_mod.render_scenery
    monkeypatch.setattr(render_mod, "render_scenery", lambda *a: calls.append(a[-1]) or real(*a))
    r = Renderer(corridor.rsu("rsu2").camera, corridor.road, seed=0)
    world = World(load_scenario("rellis_ev_yield"), seed=0)
    for k in range(4):
        world.run_until(2.0 + k * 0.2)
        r.render(world.snapshot(), k)
    snap = world.snapshot()
    r.render(snap.model_copy(update={"lighting": "night"}), 9)
    r.render(snap, 10)
    assert calls == ["day", "night"]


def test_lightings_prepared_together_share_one_geometry_and_draw_the_same_scenes(corridor, monkeypatch):
    """Renderer.prepare(*lightings): one sim.scenery.scenery_geometry for every lighting it makes, and each static
    scene identical to the one rendered alone."""
    import sim.render.renderer as render_mod

    made = []
    real = render_mod.scenery_geometry
    monkeypatch.setattr(render_mod, "scenery_geometry", lambda *a: made.append(a) or real(*a))
    cam = corridor.rsu("rsu3").camera
    together = Renderer(cam, corridor.road, seed=4)
    together.prepare("day", "night", "day")
    assert len(made) == 1 and together.static_scenes() == ("day", "night")
    alone = Renderer(cam, corridor.road, seed=4)
    assert np.array_equal(together.background("night"), alone.background("night"))
    together.prepare("night", "dusk")  # one lighting missing: rendered alone, no shared geometry needed
    assert len(made) == 1 and together.static_scenes() == ("day", "dusk", "night")
    # the noise fields scale one N(0, 1) field: the values each lighting's own draw gives
    assert all(np.array_equal(a, b) for a, b in zip(together.noise_textures("night"), alone.noise_textures("night"),
                                                    strict=True))
