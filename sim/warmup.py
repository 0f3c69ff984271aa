"""The road before a scenario starts, as each camera saw it: warm-up frames for background models.

A deployed RSU's motion (MOG2) and hazard (dual background) detectors learn the road from the camera's
own frames; nobody hands them a picture of the empty road (``iea up`` primes nothing). Lockstep runs and
benches do the same: before scenario time 0, each camera renders ``warmup_s`` of a *pre-roll* world, the
scenario's corridor with its background traffic (another draw of it, ``seed + PREROLL_SEED_OFFSET``) but
none of the scenario's scripted events (no debris, no EV, no AV: they arrive at the start of the
scenario), and the detectors learn their background from those frames, traffic and all. The frames are
what the camera would have recorded in the seconds before; the detectors are told nothing about what in
them is background (the hazard detector's median and MOG2 must drop the moving traffic themselves).

Pure apart from rendering; deterministic for a given scenario seed.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import replace

import numpy as np

from sim.camera_source import SimCamera
from sim.scenario import Scenario
from sim.world import World

WARMUP_S = 6.0
"""Seconds of pre-roll: the hazard detector's initial median needs 9 frames 0.5 s apart (4 s at its 2 Hz)."""
PREROLL_SEED_OFFSET = 7919
"""The pre-roll's traffic is another draw than the scenario's (a different moment of the same road)."""


def preroll_scenario(scenario: Scenario) -> Scenario:
    """The scenario's road and traffic without its scripted actors (AV, EV, debris, distractors), driven by the
    simulator's own traffic model (the scenario's SUMO simulation is already running: libsumo runs one a process)."""
    return replace(scenario, av=None, ev=None, hazards=(), distractors=(),
                   seed=scenario.seed + PREROLL_SEED_OFFSET, traffic_model="project")


def warmup_frames(scenario: Scenario, cameras: dict[str, SimCamera], warmup_s: float = WARMUP_S
                  ) -> Iterator[tuple[str, np.ndarray]]:
    """(rsu_id, BGR image) for every camera at its fps over ``warmup_s`` of the pre-roll world, in time order."""
    if warmup_s < 0:
        raise ValueError(f"warmup_s must be >= 0 s, got {warmup_s}")
    if not cameras or warmup_s == 0:
        return
    world = World(preroll_scenario(scenario))
    fps = max(cam.fps for cam in cameras.values())
    dt_s = 1.0 / fps
    for _ in range(int(round(warmup_s * fps))):
        world.step(dt_s)
        snap = world.snapshot()
        for rsu_id, cam in cameras.items():
            yield rsu_id, cam.render(snap).image
