"""Renderer: determinism, labels against the rendered pixels, occlusion, EV lamps and distractors."""

import numpy as np
import pytest

from protocol.enums import ActorKind, Lighting
from protocol.messages import Actor, LightBar, WorldSnapshot
from sim.bodies import ev_lamps_on
from sim.dataset import yolo_line
from sim.render.labels import CLASS_EV, CLASS_VEHICLE, MIN_VISIBLE_FRACTION
from sim.render.renderer import Renderer
from sim.scenario import load_scenario
from sim.vehicles import LIVERY_AMBULANCE, make_style
from sim.world import World


def actor(aid, x, y, kind="car", length=4.5, width=1.8, height=1.5, colour=(120, 120, 120), light_bar=None,
          style=0, brake=False):
    return Actor(actor_id=aid, kind=ActorKind(kind), pos_x_m=x, pos_y_m=y, heading_rad=0.0, length_m=length,
                 width_m=width, height_m=height, speed_mps=10.0, colour_bgr=colour, light_bar=light_bar, style=style,
                 brake_on=brake)


def snap(actors, t=1.0, lighting="day"):
    return WorldSnapshot(src="t", stamp=t, scenario="t", sim_time_s=t, lighting=Lighting(lighting), actors=actors)


def diff_box(a, b):
    """Bounding box and count of the pixels that differ between two renders."""
    d = np.any(np.abs(a.astype(int) - b.astype(int)) > 3, axis=2)
    ys, xs = np.nonzero(d)
    if len(xs) == 0:
        return None, 0
    return (xs.min(), ys.min(), xs.max() + 1, ys.max() + 1), int(d.sum())


def iou(a, b):
    ix = max(0.0, min(a[2], b[2]) - max(a[0], b[0]))
    iy = max(0.0, min(a[3], b[3]) - max(a[1], b[1]))
    inter = ix * iy
    return inter / ((a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter)


def test_renders_are_deterministic_per_seed(corridor):
    sc = load_scenario("rellis_ev_yield")
    imgs = []
    for seed in (5, 5, 6):
        w = World(sc, seed=seed)
        w.run_until(6.0)
        r = Renderer(corridor.rsu("rsu1").camera, corridor.road, seed=seed)
        imgs.append(r.render(w.snapshot(), frame_index=90))
    assert imgs[0].shape == (720, 1280, 3) and imgs[0].dtype == np.uint8
    assert np.array_equal(imgs[0], imgs[1])
    assert not np.array_equal(imgs[0], imgs[2])


def test_noise_changes_per_frame_but_not_per_call(corridor):
    r = Renderer(corridor.rsu("rsu1").camera, corridor.road, seed=1)
    s = snap([actor("a", 50.0, 1.85)])
    a, b, c = r.render(s, 1), r.render(s, 1), r.render(s, 2)
    assert np.array_equal(a, b)
    d = np.abs(a.astype(int) - c.astype(int))
    assert d.mean() > 0.5  # sensor noise differs frame to frame


def test_labels_match_the_rendered_pixels(clean_renderer):
    """Recompute every label from pixels: render with and without each vehicle; the pixels that change
    are the ones the vehicle shows."""
    r = clean_renderer
    actors = [actor("near", 40.0, 1.85, colour=(30, 30, 180)), actor("mid", 60.0, 5.55, kind="van", length=5.5,
              width=2.0, height=2.4, colour=(230, 230, 230)), actor("far", 95.0, 1.85, colour=(170, 70, 25)),
              actor("truck", 75.0, 1.85, kind="truck", length=9.0, width=2.5, height=3.4)]
    full = r.render(snap(actors))
    labels = {lb.actor_id: lb for lb in r.labels(snap(actors))}
    assert set(labels) == {a.actor_id for a in actors}
    for a in actors:
        without = r.render(snap([b for b in actors if b is not a]))
        box, _ = diff_box(full, without)
        assert box is not None
        lb = labels[a.actor_id]
        assert lb.class_id == CLASS_VEHICLE
        assert np.abs(np.array(lb.bbox_px) - np.array(box)).max() <= 2.0, (a.actor_id, lb.bbox_px, box)
        # the YOLO line is that box, relative to the image size
        c, xc, yc, bw, bh = (float(v) for v in yolo_line(lb, r.w, r.h).split())
        assert c == 0 and xc * r.w == pytest.approx((box[0] + box[2]) / 2, abs=3)
        assert bw * r.w == pytest.approx(box[2] - box[0], abs=4) and bh * r.h == pytest.approx(box[3] - box[1], abs=4)


def test_occluded_vehicle_is_truncated_then_dropped(clean_renderer):
    r = clean_renderer
    # a bus near the camera hides part of the car behind it (as seen from rsu1)
    bus = actor("bus", 38.0, 1.85, kind="bus", length=12.0, width=2.5, height=3.2, colour=(40, 160, 230))
    cases = {"partly": actor("car", 58.0, 4.8), "hidden": actor("car", 48.0, 1.85)}
    alone_px = {}
    for name, car in cases.items():
        s_both, s_car, s_bus = snap([bus, car]), snap([car]), snap([bus])
        empty = r.render(snap([]))
        _, alone_px[name] = diff_box(r.render(s_car), empty)
        box_vis, vis_px = diff_box(r.render(s_both), r.render(s_bus))
        labels = {lb.actor_id: lb for lb in r.labels(s_both, include_dropped=True)}
        lb = labels["car"]
        frac_pixels = vis_px / alone_px[name]
        assert lb.visible_fraction == pytest.approx(frac_pixels, abs=0.08), name
        kept = {x.actor_id for x in r.labels(s_both)}
        if name == "partly":
            assert 0.3 < lb.visible_fraction < 0.95
            assert "car" in kept
            full_w = lb.full_bbox_px[2] - lb.full_bbox_px[0]
            full_h = lb.full_bbox_px[3] - lb.full_bbox_px[1]
            w, h = lb.bbox_px[2] - lb.bbox_px[0], lb.bbox_px[3] - lb.bbox_px[1]
            assert w * h < 0.8 * full_w * full_h  # truncated to what shows
            assert iou(lb.bbox_px, box_vis) > 0.8
        else:
            assert lb.visible_fraction < MIN_VISIBLE_FRACTION
            assert "car" not in kept


def test_vehicle_cut_by_image_border_is_clipped(clean_renderer):
    r = clean_renderer
    a = actor("edge", 20.0, 12.0)  # left of the road, partly out of the image near the camera
    lbs = r.labels(snap([a]), include_dropped=True)
    assert lbs and lbs[0].bbox_px[0] >= 0 and lbs[0].full_bbox_px[0] < 0
    assert lbs[0].visible_fraction < 1.0


def test_ev_lamps_are_bright_saturated_red_and_blue_and_alternate(clean_renderer):
    r = clean_renderer
    lb = LightBar(on=True, pattern="alternating", frequency_hz=2.0, phase_s=0.0)
    ev = actor("ev", 45.0, 1.85, kind="ev", length=6.2, width=2.1, height=2.6, colour=(240, 240, 240),
               light_bar=lb, style=make_style(LIVERY_AMBULANCE, 1))
    red_t, blue_t = 0.1, 0.35  # 2 Hz: red in the first half of each 0.5 s cycle
    assert ev_lamps_on(lb, red_t) == (True, False) and ev_lamps_on(lb, blue_t) == (False, True)
    import cv2

    counts = {}
    for name, t in (("red", red_t), ("blue", blue_t)):
        img = r.render(snap([ev], t=t))
        hsv = cv2.cvtColor(img, cv2.COLOR_BGR2HSV)
        sat = hsv[..., 1] > 150
        bright = hsv[..., 2] > 200
        red = sat & bright & ((hsv[..., 0] < 8) | (hsv[..., 0] > 170))
        blue = sat & bright & (hsv[..., 0] > 100) & (hsv[..., 0] < 130)
        counts[name] = (int(red.sum()), int(blue.sum()))
    # (the ambulance's red livery band is saturated red too: compare the two lamp phases)
    assert counts["red"][0] > counts["blue"][0] + 30 and counts["red"][1] < 5
    assert counts["blue"][1] > 30 and counts["blue"][1] > counts["red"][1] + 30
    # lights on -> class ev; the same body with lights off is a plain vehicle
    assert r.labels(snap([ev]))[0].class_id == CLASS_EV
    off = actor("ev", 45.0, 1.85, kind="ev", length=6.2, width=2.1, height=2.6, colour=(240, 240, 240),
                light_bar=LightBar(on=False), style=make_style(LIVERY_AMBULANCE, 1))
    assert r.labels(snap([off]))[0].class_id == CLASS_VEHICLE
    img_off = r.render(snap([off], t=red_t))
    hsv = cv2.cvtColor(img_off, cv2.COLOR_BGR2HSV)
    assert int(((hsv[..., 1] > 150) & (hsv[..., 2] > 200) & (hsv[..., 0] > 100) & (hsv[..., 0] < 130)).sum()) < 5


def test_strobe_pattern_has_dark_gaps():
    lb = LightBar(on=True, pattern="strobe", frequency_hz=2.0, phase_s=0.0)
    states = [ev_lamps_on(lb, t) for t in np.arange(0, 0.5, 0.005)]
    assert any(s == (False, False) for s in states)
    assert any(s[0] for s in states) and any(s[1] for s in states)
    assert not any(s[0] and s[1] for s in states)


def test_brake_lights_light_up_red(clean_renderer):
    r = clean_renderer
    off = r.render(snap([actor("c", 40.0, 1.85, colour=(200, 200, 200))]))
    on = r.render(snap([actor("c", 40.0, 1.85, colour=(200, 200, 200), brake=True)]))
    import cv2

    def red_px(img):
        hsv = cv2.cvtColor(img, cv2.COLOR_BGR2HSV)
        return int(((hsv[..., 1] > 120) & (hsv[..., 2] > 200) & ((hsv[..., 0] < 8) | (hsv[..., 0] > 170))).sum())

    assert red_px(on) > red_px(off) + 10


def test_lighting_darkens_the_scene(corridor):
    r = Renderer(corridor.rsu("rsu1").camera, corridor.road, seed=0, noise=False, exposure=False)
    means = {lt: float(r.render(snap([], lighting=lt)).mean()) for lt in ("day", "dusk", "night")}
    assert means["day"] > means["dusk"] > means["night"]


def test_lookalike_scenario_never_labels_an_ev(corridor):
    sc = load_scenario("ev_lights_never_on")
    w = World(sc)
    renderers = [Renderer(r.camera, corridor.road, seed=0) for r in corridor.rsus[:2]]
    seen_kinds = set()
    while w.t_s < 20.0:
        w.run_until(w.t_s + 2.0)
        s = w.snapshot()
        for r in renderers:
            for lb in r.labels(s):
                seen_kinds.add(lb.kind)
                assert lb.class_id == CLASS_VEHICLE
    assert {"ev", "van", "car"} <= seen_kinds  # the lookalikes were in view


def test_motion_blur_and_exposure_vary_the_image(corridor):
    cam = corridor.rsu("rsu1").camera
    fast = Actor(actor_id="f", kind=ActorKind.CAR, pos_x_m=30.0, pos_y_m=-1.0, heading_rad=0.0, length_m=4.5,
                 width_m=1.8, height_m=1.5, speed_mps=30.0, colour_bgr=(30, 30, 30))
    s = snap([fast], lighting="night")
    sharp = Renderer(cam, corridor.road, noise=False, exposure=False, motion_blur=False).render(s, 0)
    blurred = Renderer(cam, corridor.road, noise=False, exposure=False, motion_blur=True).render(s, 0)
    assert np.abs(sharp.astype(int) - blurred.astype(int)).sum() > 1000
    r = Renderer(cam, corridor.road, noise=False, motion_blur=False)
    means = [float(r.render(snap([], t=t), 0).mean()) for t in (0.0, 2.0, 4.0)]
    assert max(means) - min(means) > 1.0  # auto-exposure drifts over time


def test_a_frame_owes_nothing_to_the_frames_before_it(corridor):
    """The renderer draws on one canvas frame after frame: a frame is the same as a fresh renderer's, and a frame
    handed out is not changed by the next ones."""
    cam = corridor.rsu("rsu1").camera
    busy = snap([actor(f"v{k}", 30.0 + 12.0 * k, 1.85 + 3.7 * (k % 2)) for k in range(6)])
    empty = snap([actor("a", 90.0, 5.55)])
    r = Renderer(cam, corridor.road, seed=4)
    first = r.render(busy, 3)
    kept = first.copy()
    after = r.render(empty, 4)
    assert np.array_equal(after, Renderer(cam, corridor.road, seed=4).render(empty, 4))
    assert np.array_equal(first, kept)
