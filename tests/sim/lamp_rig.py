"""What the lamp tests of the renderer share: a snapshot of some actors, and where an actor's lamp decals land in
the image."""

from __future__ import annotations

from protocol.enums import Lighting
from protocol.messages import Actor, WorldSnapshot
from sim.bodies import face_points
from sim.render.renderer import Renderer


def snap(actors: list[Actor], t: float, lighting: str = "day") -> WorldSnapshot:
    return WorldSnapshot(src="t", stamp=t, scenario="t", sim_time_s=t, lighting=Lighting(lighting), actors=actors)


def lamp_decals(r: Renderer, a: Actor, lamp: str, face: str) -> list[tuple[int, int, int]]:
    """Image (x, y) of the centre of each of the actor's decals of that lamp on that face, with the decal's segment."""
    _parts, decals, corners, _uv, _depth, _rot = r._actor_geometry(a)
    out = []
    for dc in decals:
        if dc.lamp == lamp and dc.face == face:
            uv, _ = r.cam.project(face_points(corners[dc.part], face, dc.u0, dc.u1, dc.v0, dc.v1).mean(axis=0,
                                                                                                      keepdims=True))
            out.append((int(round(uv[0, 0])), int(round(uv[0, 1])), dc.segment))
    return out
