"""The renderer's cached fast path (issue 19: body models built once per look, posed and shaded with array
operations, shadows darkened by a scale, the exposure a gamma image scaled) draws the same pixels as issue 17's
straightforward renderer (``sim.render_reference.ReferenceRenderer``) within noise, and the static scene is rendered
once per lighting."""

import numpy as np
import pytest

from sim.render import Renderer
from sim.render_reference import ReferenceRenderer
from sim.scenario import load_scenario
from sim.world import World

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
            a, b = fast.render(snap, k), ref.render(snap, k)
            d = np.abs(a.astype(int) - b.astype(int))
            # motion blur's cropped kernel rounds a few pixels 1-2 levels apart, and the exposure's fixed point
            # (``sim.sensor``) puts a value a whole level apart where the exact one is within 1/256 of an integer
            # (sensor noise: sigma 2.5-6 levels); nothing else may differ
            assert d.max() <= 3, (scenario, rsu.rsu_id, k, int(d.max()))
            assert (d > 1).mean() < 1e-3 and (d > 0).mean() < 0.05, (scenario, rsu.rsu_id, k, np.bincount(d.ravel()))
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
    for k in (0, 3, 7):  # the light bar's red and blue halves
        s = scene(k / 15.0, lighting)
        d = np.abs(fast.render(s, k).astype(int) - ref.render(s, k).astype(int))
        assert d.max() <= 3 and (d > 1).mean() < 1e-3 and (d > 0).mean() < 0.05, (lighting, k, np.bincount(d.ravel()))


def test_static_scene_rendered_once_per_lighting(corridor, monkeypatch):
    import sim.render as render_mod

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
    import sim.render as render_mod

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
