"""No ground truth in perception: background models learn from the camera's own frames.

The lockstep corridor (and the benches built on it) warm the RSUs' motion and hazard detectors up on
``sim.warmup`` frames: the road with moving traffic before the scenario, never a render of the world with
its actors removed."""

from __future__ import annotations

import numpy as np
import pytest

from scenario.lockstep import CorridorLockstep, LockstepConfig
from sim.camera_source import SimCamera
from sim.scenario import load_scenario
from sim.warmup import preroll_scenario, warmup_frames
from sim.world import World


def test_preroll_has_traffic_but_none_of_the_scenarios_scripted_actors():
    sc = load_scenario("hazard_in_lane")
    pre = preroll_scenario(sc)
    assert pre.av is None and pre.ev is None and pre.hazards == () and pre.seed != sc.seed
    kinds = {a.kind.value for a in World(pre).snapshot().actors}
    assert "debris" not in kinds and kinds, kinds  # traffic, no debris


def test_warmup_frames_are_the_cameras_own_renders_at_its_fps():
    sc = load_scenario("hazard_in_lane")
    cam = SimCamera(sc.corridor, "rsu3", seed=sc.seed)
    frames = list(warmup_frames(sc, {"rsu3": cam}, warmup_s=1.0))
    assert len(frames) == cam.fps and all(rid == "rsu3" for rid, _ in frames)
    assert frames[0][1].shape == (cam.height_px, cam.width_px, 3)
    with pytest.raises(ValueError, match="warmup_s"):
        list(warmup_frames(sc, {"rsu3": cam}, warmup_s=-1.0))


def test_lockstep_never_renders_the_world_without_its_actors(monkeypatch):
    """Every frame any RSU sees (warm-up and run) is a render of a world with its traffic in it, and the
    hazard detectors have learnt a background from those frames before scenario time 0."""
    rendered_actor_counts: list[int] = []
    real_render = SimCamera.render

    def spy(self, snapshot):
        rendered_actor_counts.append(len(snapshot.actors))
        return real_render(self, snapshot)

    monkeypatch.setattr(SimCamera, "render", spy)
    runner = CorridorLockstep(LockstepConfig(scenario="hazard_in_lane", duration_s=0.2, detector="motion"))
    for svc in runner.rsus.values():
        assert svc.pipeline.hazards.fg.ready  # the initial median was taken from the warm-up frames
        assert svc.pipeline.detector.frames_seen >= 30  # MOG2 saw the warm-up frames
    n_warmup = len(rendered_actor_counts)
    runner.run()
    assert len(rendered_actor_counts) > n_warmup
    assert min(rendered_actor_counts) > 0, "a camera rendered a world with every actor removed (ground truth)"


def test_without_warmup_the_hazard_detector_starts_from_the_scenarios_own_frames():
    runner = CorridorLockstep(LockstepConfig(scenario="hazard_in_lane", duration_s=0.2, warmup_s=0.0))
    assert all(not svc.pipeline.hazards.fg.ready for svc in runner.rsus.values())
    assert np.isfinite(runner.duration_s)
