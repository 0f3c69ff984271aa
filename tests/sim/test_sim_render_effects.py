"""The renderer's effect numbers computed with array operations equal the straightforward per-tap and per-lamp
loops (``bench.render_reference``'s arithmetic, restated here)."""

import cv2
import numpy as np
import pytest

from sim.render.effects import halo_numbers, hidden_lamps, line_kernel


def _grid_kernel(vec):
    n = int(min(25, np.ceil(float(np.hypot(*vec)))))
    k = np.zeros((2 * n + 1, 2 * n + 1), np.float32)
    direction = vec / max(1e-6, float(np.hypot(*vec)))
    for i in range(n + 1):
        x, y = np.round(n + direction * (i - n / 2)).astype(int)
        k[np.clip(y, 0, 2 * n), np.clip(x, 0, 2 * n)] += 1.0
    return k / k.sum()


@pytest.mark.parametrize("vec", [(1.6, 0.0), (-7.3, 2.2), (0.4, -12.9), (40.0, 31.0), (3.0, 3.0), (-2.5, -0.5)])
def test_line_kernel_filters_like_the_full_grid(vec):
    vec = np.array(vec)
    k, anchor = line_kernel(vec)
    grid = _grid_kernel(vec)
    assert k.sum() == pytest.approx(1.0) and k.size <= grid.size
    img = np.random.default_rng(0).integers(0, 256, (60, 80, 3), dtype=np.uint8)
    a = cv2.filter2D(img, -1, k, anchor=anchor, borderType=cv2.BORDER_REPLICATE)
    b = cv2.filter2D(img, -1, grid, borderType=cv2.BORDER_REPLICATE)
    assert np.abs(a.astype(int) - b.astype(int)).max() <= 1


def test_halo_numbers_match_the_per_lamp_loop():
    rng = np.random.default_rng(1)
    glows = [(rng.uniform(0, 900, (4, 2)) * rng.uniform(0.001, 0.05), (50, 50, 200), 0.3),
             (rng.uniform(0, 40, (4, 2)) + 600, (0, 0, 255), 1.0),
             (rng.uniform(0, 30, (12, 2)) + 300, (255, 80, 0), 1.0),  # a light bar over three faces
             (np.full((4, 2), 5.0), (0, 160, 255), 0.8)]
    scale = 1.6
    expected = set()
    for puv, colour, strength in glows:  # the straightforward loop
        cx, cy = puv.mean(axis=0)
        size = max(2.0, float(np.ptp(puv[:, 0])), float(np.ptp(puv[:, 1])))
        r = int(min(60, max(3, size * 0.55 * scale)))
        col = tuple(int(c * min(1.0, strength * (0.6 + 0.25 * scale))) for c in colour)
        expected.add((int(round(cx)), int(round(cy)), r, col, strength >= 1.0, max(1, int(size / 12))))
    quads = [g for g in glows if len(g[0]) == 4]
    bars = [g for g in glows if len(g[0]) != 4]
    got = halo_numbers(np.array([q[0] for q in quads]), [q[1] for q in quads], [q[2] for q in quads], bars, scale)
    assert set(got) == expected
    assert halo_numbers(np.zeros((0, 4, 2)), [], [], [], scale) == []


def test_shade_faces_of_several_actors_equal_each_actors_own():
    from protocol.enums import ActorKind
    from protocol.messages import Actor
    from sim.bodies import body_model
    from sim.render.effects import shade_faces
    from sim.render.pose import actor_batch
    from sim.scenery import LIGHTING

    actors = [Actor(actor_id=f"a{k}", kind=ActorKind(kind), pos_x_m=20.0 + 9 * k, pos_y_m=1.85 + 3.7 * (k % 2),
                    heading_rad=0.3 * k, length_m=size[0], width_m=size[1], height_m=size[2], speed_mps=10.0,
                    colour_bgr=(40, 80, 160))
              for k, (kind, size) in enumerate([("car", (4.5, 1.8, 1.5)), ("truck", (9.0, 2.5, 3.4)),
                                                ("van", (5.5, 2.0, 2.4))])]
    cam_c, L = np.array([0.0, -8.0, 7.0]), LIGHTING["dusk"]
    sun = np.array(L["sun_dir"], float) / np.linalg.norm(L["sun_dir"])
    models = [body_model(a) for a in actors]
    batch = actor_batch(models)
    cs = [(np.cos(a.heading_rad), np.sin(a.heading_rad)) for a in actors]
    rots = np.array([[[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]] for c, s in cs])
    vis, colours = shade_faces(batch, rots, np.array([(a.pos_x_m, a.pos_y_m, 0.0) for a in actors]), cam_c, L, sun)
    first = batch.part_start
    assert first[-1] == len(vis) == sum(len(md.parts) for md in models)
    for k, (model, rot, a) in enumerate(zip(models, rots, actors, strict=True)):  # one at a time, as the reference
        x, y = a.pos_x_m, a.pos_y_m
        n_w = model.normals @ rot.T
        fc_w = model.centres @ rot.T + (x, y, 0.0)
        own_vis = (np.sum(n_w * (cam_c - fc_w), axis=-1) > 0) & model.face_ok
        shade = L["ambient"] + L["sun"] * np.maximum(0.0, n_w @ sun)
        shade = np.where(model.glass, 0.6 + 0.5 * shade * np.where(model.top, 1.3, 1.0), shade)
        own = np.clip(model.base_bgr * shade[..., None] * L["scene_gain"], 0, 255)
        np.testing.assert_array_equal(vis[first[k]:first[k + 1]], own_vis)
        np.testing.assert_allclose(colours[first[k]:first[k + 1]], own, atol=1e-9)
        assert own_vis.any() and not own_vis.all()


def _box_corners(x1, y1, x2, y2):
    return np.array([[x1, y1], [x2, y1], [x2, y2], [x1, y2]] * 2, float)


def test_a_lamp_behind_a_nearer_vehicle_is_hidden_and_one_beside_it_is_not():
    bounds = np.array([(100, 100, 140, 130), (90, 110, 160, 200)], float)  # far to near
    parts = [np.array([_box_corners(*b)]) for b in bounds]
    behind = np.array([[118, 118], [122, 118], [122, 122], [118, 122]], float)  # inside the nearer box
    above = behind - (0, 14)  # above the nearer box's top: in view
    faces = np.array([behind, above, behind, behind, above])  # the last lamp: a light bar over two faces
    counts, ranks = [1, 1, 1, 2], [0, 0, 1, 0]
    # the bar is in view while any face is; nothing is drawn after the nearest vehicle
    assert hidden_lamps(faces, counts, ranks, bounds, parts.__getitem__) == [True, False, False, False]
    assert hidden_lamps(np.zeros((0, 4, 2)), [], [], bounds, parts.__getitem__) == []


@pytest.mark.parametrize("renderer", ["cached", "reference"])
def test_an_ev_hidden_behind_a_bus_throws_no_halo(renderer):
    from bench.render_reference import ReferenceRenderer
    from protocol.corridor import load_corridor
    from protocol.enums import ActorKind, Lighting
    from protocol.messages import Actor, LightBar, WorldSnapshot
    from sim.render.renderer import Renderer
    from sim.vehicles import LIVERY_AMBULANCE, make_style

    corridor = load_corridor()
    cls = Renderer if renderer == "cached" else ReferenceRenderer
    r = cls(corridor.rsu("rsu1").camera, corridor.road, seed=1, noise=False)
    bus = Actor(actor_id="bus", kind=ActorKind("bus"), pos_x_m=50.0, pos_y_m=1.85, heading_rad=0.0, length_m=12.0,
                width_m=2.5, height_m=3.2, speed_mps=0.0, colour_bgr=(40, 40, 200), style=make_style(0, 1))
    ev = Actor(actor_id="ev", kind=ActorKind("ev"), pos_x_m=59.0, pos_y_m=1.85, heading_rad=0.0, length_m=4.8,
               width_m=1.9, height_m=1.5, speed_mps=0.0, colour_bgr=(230, 230, 230),
               light_bar=LightBar(on=True, pattern="alternating", frequency_hz=2.0), style=make_style(LIVERY_AMBULANCE, 2))

    def lamp_pixels(actors):
        snap = WorldSnapshot(src="t", stamp=0.3, scenario="t", sim_time_s=0.3, lighting=Lighting("day"), actors=actors)
        hsv = cv2.cvtColor(r.render(snap, 0), cv2.COLOR_BGR2HSV)
        h = hsv[..., 0]
        return int(np.count_nonzero((hsv[..., 1] >= 120) & (hsv[..., 2] >= 240)
                                    & ((h <= 10) | (h >= 170) | ((h >= 100) & (h <= 130)))))

    visible = {lb.actor_id: lb.visible_fraction for lb in r.labels(
        WorldSnapshot(src="t", stamp=0.3, scenario="t", sim_time_s=0.3, lighting=Lighting("day"), actors=[bus, ev]),
        min_visible_fraction=0.0, include_dropped=True)}
    assert visible["ev"] < 0.1  # the bus hides the EV, its light bar included
    assert lamp_pixels([ev]) > 50  # alone, its lit bar and halo are lamp-bright
    assert lamp_pixels([bus, ev]) == 0


def test_inside_convex_hulls_agrees_with_the_hull_and_point_test():
    """sim.render.effects.inside_convex_hulls: the same answers as cv2.convexHull then cv2.pointPolygonTest > 0 on
    random boxes' projected corners and random points (inside, outside, near their edges)."""
    from sim.render.effects import inside_convex_hulls

    rng = np.random.default_rng(5)
    corners = rng.uniform(-40, 40, (400, 8, 2)) * rng.uniform(0.05, 1, (400, 1, 2)) + rng.uniform(0, 200, (400, 1, 2))
    points = corners.mean(axis=1) + rng.normal(0, 8, (400, 2))
    expected = [cv2.pointPolygonTest(cv2.convexHull(c.astype(np.float32)), (float(p[0]), float(p[1])), False) > 0
                for c, p in zip(corners, points, strict=True)]
    got = inside_convex_hulls(points, corners)
    assert 80 < sum(expected) < 320  # both answers are well represented
    assert got.tolist() == expected


def test_decal_paint_is_the_per_decal_rule():
    """sim.render.effects.decal_paint (kept per body model and lamp states by the renderer) gives each decal the
    colour the straightforward per-decal loop draws it in: a lit lamp's colour, else its unlit colour, and no draw at all for
    a turn signal that is off; and names the lamps it lights."""
    from protocol.enums import ActorKind
    from protocol.messages import Actor, LightBar
    from sim.bodies import body_model
    from sim.render.effects import decal_paint, lit_bgr, unlit_bgr
    from sim.scenery import LIGHTING
    from sim.vehicles import LIVERY_AMBULANCE, make_style

    ev = Actor(actor_id="e", kind=ActorKind.EV, pos_x_m=30.0, pos_y_m=1.85, heading_rad=0.0, length_m=6.2,
               width_m=2.1, height_m=2.6, speed_mps=10.0, colour_bgr=(240, 240, 240),
               style=make_style(LIVERY_AMBULANCE, 3), light_bar=LightBar(on=True, pattern="alternating"))
    decals = body_model(ev).decals
    lamps = {dc.lamp for dc in decals}
    assert {"tail", "ev_red", "ev_blue"} <= lamps
    for lighting in ("day", "night"):
        L = LIGHTING[lighting]
        for brake, red, blue, sig in [(False, True, False, False), (True, False, True, True), (False, False, False, True)]:
            colours, lit = decal_paint(decals, L, brake, red, blue, sig)
            for dc, colour, lamp in zip(decals, colours, lit, strict=True):
                if dc.lamp == "turn" and not sig:
                    assert colour is None and lamp is None
                    continue
                on = lit_bgr(dc.lamp, brake or L["running_lights"], brake, red, blue, sig) if dc.lamp else None
                assert colour == (tuple(unlit_bgr(dc.colour, dc.lamp, L)) if on is None else on)
                assert lamp == (dc.lamp if on is not None else None)
            assert any(lamp == "ev_red" for lamp in lit) == red
            assert any(lamp == "tail" for lamp in lit) == (brake or bool(L["running_lights"]))
