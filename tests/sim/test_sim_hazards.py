"""Debris in the simulator: kinds and sizes rendered, landing on / cleared from the road on schedule."""

import dataclasses

import numpy as np
import pytest

from sim.camera_source import SimCamera
from sim.scenario import DEBRIS_KINDS, ScenarioError, load_scenario, parse_scenario
from sim.vehicles import make_style
from sim.world import World


def _ids(world):
    return {a.actor_id for a in world.snapshot().actors if a.kind.value == "debris"}


def test_debris_lands_and_is_cleared_on_schedule():
    sc = load_scenario("hazard_falls")
    kinds = {h.kind for h in sc.hazards}
    assert {"barrel", "tyre", "pallet"} <= kinds
    w = World(sc)
    assert _ids(w) == {"hz1", "hz2"}          # the barrel has not fallen yet
    w.run_until(3.05, 0.05)
    assert _ids(w) == {"hz0", "hz1", "hz2"}
    barrel = next(v for v in w.vehicles() if v.vehicle_id == "hz0")
    assert barrel.speed_mps == 0.0 and abs(barrel.x_m - 135.0) < 1e-6
    w.run_until(12.05, 0.05)
    assert _ids(w) == {"hz0", "hz2"}          # the tyre was cleared at 12 s
    # traffic treats the barrel as an obstacle once it is there: nobody drives through it
    w.run_until(20.0, 0.05)
    for v in w.vehicles():
        if v.kind != "debris" and abs(v.d_m - barrel.d_m) < (v.width_m + barrel.width_m) / 2 - 0.2:
            assert abs(v.s_m - barrel.s_m) > (v.length_m + barrel.length_m) / 2 - 0.3, v.vehicle_id


def test_hazard_in_lane_has_several_kinds_and_sizes():
    sc = load_scenario("hazard_in_lane")
    assert len({h.kind for h in sc.hazards}) >= 2
    assert len({(h.length_m, h.width_m, h.height_m) for h in sc.hazards}) >= 2


@pytest.mark.parametrize(("hazard", "field"), [
    ({"s_m": 10.0, "lane": 0, "kind": "sofa"}, "hazard[0].kind"),
    ({"s_m": 10.0, "lane": 0, "appear_s": 5.0, "remove_s": 4.0}, "hazard[0].remove_s"),
    ({"s_m": 10.0, "lane": 0, "offset_m": 9.0}, "hazard[0].offset_m"),
])
def test_bad_hazard_fields_are_named(hazard, field):
    with pytest.raises(ScenarioError, match=field.replace("[", r"\[").replace("]", r"\]")):
        parse_scenario({"scenario": {"name": "x"}, "hazard": [hazard]})


def test_every_debris_kind_renders_its_own_shape():
    sc = load_scenario("hazard_in_lane")
    cam = SimCamera(sc.corridor, "rsu3", seed=0, noise=False, motion_blur=False)
    empty = World(sc).snapshot().model_copy(update={"actors": []})
    base = cam.render(empty).image.astype(int)
    debris = next(a for a in World(sc).snapshot().actors if a.kind.value == "debris")
    masks = {}
    for k, kind in enumerate(DEBRIS_KINDS):
        a = dataclasses.replace(debris, style=make_style(k, 3), length_m=1.0, width_m=0.8, height_m=0.5)
        img = cam.render(empty.model_copy(update={"actors": [a]})).image.astype(int)
        changed = np.abs(img - base).sum(axis=2) > 30
        assert changed.sum() > 100, kind          # visible at 20 m from rsu3
        masks[kind] = changed
    kinds = list(masks)
    for i, a in enumerate(kinds):
        for b in kinds[i + 1:]:
            assert (masks[a] ^ masks[b]).sum() > 20, (a, b)  # distinct silhouettes / shading
