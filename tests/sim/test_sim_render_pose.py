"""sim.render.pose: every actor of a snapshot posed from one concatenation of their body models
(``ActorBatch``) gives each actor's own projection, visible faces and decals."""

import numpy as np

from protocol.corridor import load_corridor
from protocol.enums import ActorKind
from protocol.messages import Actor, LightBar
from sim.bodies import body_model
from sim.camera import PinholeCamera
from sim.render.effects import shade_faces
from sim.render.pose import actor_batch, painter_order, pose_frame, visible_polygons
from sim.scenery import LIGHTING
from sim.vehicles import LIVERY_AMBULANCE, make_style


def _actors():
    kinds = [("car", (4.5, 1.8, 1.5)), ("ev", (6.2, 2.1, 2.6)), ("truck", (9.0, 2.5, 3.4)), ("van", (5.5, 2.0, 2.4))]
    return [Actor(actor_id=f"a{k}", kind=ActorKind(kind), pos_x_m=30.0 + 11 * k, pos_y_m=1.85 + 3.7 * (k % 2),
                  heading_rad=0.05 * k, length_m=size[0], width_m=size[1], height_m=size[2], speed_mps=10.0,
                  colour_bgr=(40, 80, 160), style=make_style(LIVERY_AMBULANCE if kind == "ev" else 0, k),
                  light_bar=LightBar(on=True, pattern="alternating", frequency_hz=2.0) if kind == "ev" else None)
            for k, (kind, size) in enumerate(kinds)]


def test_a_batch_poses_and_culls_each_actor_as_alone():
    cam = PinholeCamera.from_config(load_corridor().rsu("rsu1").camera)
    actors = _actors()
    models = [body_model(a) for a in actors]
    batch = actor_batch(models)
    pose = pose_frame(batch, actors, cam)
    L = LIGHTING["dusk"]
    sun = np.array(L["sun_dir"], float) / np.linalg.norm(L["sun_dir"])
    vis, colours = shade_faces(batch, pose.rots, np.array([(a.pos_x_m, a.pos_y_m, 0.0) for a in actors]), cam.C, L,
                               sun)
    polygons = visible_polygons(batch, pose, vis, colours)
    assert sorted(painter_order(actors, cam)) == list(range(len(actors)))  # all four in view
    for k, (a, md) in enumerate(zip(actors, models, strict=True)):
        c, s = np.cos(a.heading_rad), np.sin(a.heading_rad)
        world = md.points @ np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]).T + (a.pos_x_m, a.pos_y_m, 0.0)
        uv, depth = cam.project(world)
        block = slice(batch.point_start[k], batch.point_start[k + 1])
        np.testing.assert_allclose(pose.uv[block], uv, atol=1e-9)
        corners = uv[:8 * len(md.parts)]
        assert np.isclose(pose.near[k], depth[:8 * len(md.parts)].min())
        np.testing.assert_allclose(pose.lo[k], corners.min(axis=0))
        np.testing.assert_allclose(pose.box[k], [*uv.min(axis=0), *uv.max(axis=0)])
        own_vis = vis[batch.part_start[k]:batch.part_start[k + 1]]
        own16 = pose.uv16[block]
        faces = polygons.faces[polygons.face_start[k]:polygons.face_start[k + 1]]
        np.testing.assert_array_equal(np.array(faces), own16[md.face_points[own_vis]])
        seen = [j - batch.decal_start[k] for j in
                polygons.decals[polygons.decal_seen_start[k]:polygons.decal_seen_start[k + 1]]]
        assert seen == [d for d, dc in enumerate(md.decals) if own_vis[dc.part, md.decal_face[d]]]
        assert seen  # every actor shows some decal from this camera
        sil = np.flatnonzero([p.silhouette for p in md.parts])[:, None] * 8 + np.arange(8)  # its silhouette corners
        np.testing.assert_array_equal(pose.uv[block][sil], pose.uv[batch.silhouettes[k]])
