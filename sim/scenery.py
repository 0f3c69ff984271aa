"""The static scene of an RSU camera's view for the renderer (``sim.render.renderer``): sky, tree line, grass, asphalt with a
world-anchored texture, shoulder, lane markings, haze, street-light pools at night and vignetting, per lighting
(``LIGHTING``); rendered once per camera and lighting."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from protocol.corridor import CameraConfig
from protocol.road import Road
from sim.camera import NEAR_M, PinholeCamera

# per lighting: ambient, sun strength, sun direction (towards the sun), sky top/bottom (BGR), grass, asphalt,
# haze distance (m), exposure time (s), noise sigma, lamps glow scale, running lights on
LIGHTING = {
    "day": dict(ambient=0.55, sun=0.55, sun_dir=(0.25, -0.55, 0.8), sky_top=(235, 190, 140),
                sky_bottom=(235, 225, 210), grass=(70, 125, 95), asphalt=(100, 102, 104), shoulder=(125, 128, 130),
                haze_m=900.0, exposure_s=1 / 250, noise=2.5, glow=1.0, running_lights=False, scene_gain=1.0),
    "dusk": dict(ambient=0.40, sun=0.30, sun_dir=(-0.8, 0.3, 0.2), sky_top=(120, 90, 80),
                 sky_bottom=(110, 150, 225), grass=(50, 80, 70), asphalt=(80, 80, 84), shoulder=(95, 96, 100),
                 haze_m=500.0, exposure_s=1 / 60, noise=4.0, glow=1.6, running_lights=True, scene_gain=0.62),
    "night": dict(ambient=0.22, sun=0.0, sun_dir=(0.0, 0.0, 1.0), sky_top=(40, 20, 12),
                  sky_bottom=(60, 40, 30), grass=(30, 42, 38), asphalt=(62, 62, 64), shoulder=(70, 70, 72),
                  haze_m=250.0, exposure_s=1 / 30, noise=6.0, glow=2.6, running_lights=True, scene_gain=0.32),
}


@dataclass(frozen=True)
class SceneryGeometry:
    """What a camera's static scene is in every lighting (``scenery_geometry``): the view rays' ground hits, the
    world-anchored textures (the class mask decides which texture), the road's surface polygons, the tree line and the
    vignetting. Only the colours, the sky, the haze and the night's lamp pools depend on the lighting
    (``render_scenery``)."""

    dz: np.ndarray
    """Per pixel, the z of its unit view ray (float32, h x w)."""
    dist: np.ndarray
    """Distance along the ray to the ground (1e6 where the ray misses it)."""
    ground: np.ndarray
    """Rays that hit the ground within 5 km (bool)."""
    gx: np.ndarray
    gy: np.ndarray
    """Where each ray hits the ground (m, float32)."""
    quads: tuple[tuple[np.ndarray, int], ...]
    """The road's surface polygons (1/16 px, int32) and their class (0 grass, 1 shoulder, 2 asphalt, 3 white,
    4 yellow, 5 wheel path, 6 patch), in drawing order."""
    texture: np.ndarray
    """The ground's texture added to the surface colours (float32, h x w x 3)."""
    trees: np.ndarray
    """The tree line along the horizon (bool)."""
    tree_tex: np.ndarray
    """The tree line's texture (float32, h x w)."""
    vignette: np.ndarray
    """The vignetting factor (float32, h x w)."""


def scenery_geometry(camera: CameraConfig, cam: PinholeCamera, road: Road, seed: int) -> SceneryGeometry:
    """The lighting-independent part of ``camera``'s static scene (``SceneryGeometry``): made once for all the
    lightings of a camera (``sim.render.renderer.Renderer.prepare``), it is most of a lighting's cost."""
    h, w = camera.height_px, camera.width_px
    rng = np.random.default_rng(seed + 1000)
    vv, uu = np.mgrid[0:h, 0:w].astype(np.float32)
    rays = cam.ray(np.column_stack([uu.ravel(), vv.ravel()])).astype(np.float32)
    dz = rays[:, 2].reshape(h, w)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(dz < -1e-4, -cam.C[2] / dz, np.inf)
    gx = (cam.C[0] + t * rays[:, 0].reshape(h, w)).astype(np.float32)
    gy = (cam.C[1] + t * rays[:, 1].reshape(h, w)).astype(np.float32)
    dist = np.where(np.isfinite(t), t, 1e6).astype(np.float32)
    ground = dist < 5e3

    # world-anchored textures (perspective-correct): coarse + fine noise tiles sampled at (x, y)
    tex_size = 512
    fine = rng.normal(0, 1, (tex_size, tex_size)).astype(np.float32)
    fine = cv2.GaussianBlur(fine, (0, 0), 0.8)
    coarse = cv2.resize(rng.normal(0, 1, (32, 32)).astype(np.float32), (tex_size, tex_size),
                        interpolation=cv2.INTER_CUBIC)
    ppm_fine, ppm_coarse = 20.0, 2.0
    mapx = np.mod(np.where(ground, gx, 0) * ppm_fine, tex_size).astype(np.float32)
    mapy = np.mod(np.where(ground, gy, 0) * ppm_fine, tex_size).astype(np.float32)
    t_fine = cv2.remap(fine, mapx, mapy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP)
    # fade the fine texture with distance (it would alias into noise far away)
    t_fine *= np.clip(30.0 / np.maximum(dist, 1.0), 0.15, 1.0)
    mapx = np.mod(np.where(ground, gx, 0) * ppm_coarse, tex_size).astype(np.float32)
    mapy = np.mod(np.where(ground, gy, 0) * ppm_coarse, tex_size).astype(np.float32)
    t_coarse = cv2.remap(coarse, mapx, mapy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP)

    # road surfaces and markings as projected polygons into a class mask
    cls = np.zeros((h, w), np.uint8)  # 0 grass, 1 shoulder, 2 asphalt, 3 white, 4 yellow, 5 wheel path, 6 patch
    quads: list[tuple[np.ndarray, int]] = []
    W = road.width_m
    step = 1.0
    s_vals = np.arange(0.0, road.length_m + step, step)

    def strip(d0: float, d1: float, value: int, s_from=None, s_to=None) -> None:
        ss = s_vals if s_from is None else np.arange(s_from, s_to + 1e-9, min(step, s_to - s_from))
        x0, y0, _ = road.pose_at(ss, np.full_like(ss, d0))
        x1, y1, _ = road.pose_at(ss, np.full_like(ss, d1))
        p0 = np.column_stack([x0, y0, np.zeros_like(x0)])
        p1 = np.column_stack([x1, y1, np.zeros_like(x1)])
        uv0, z0 = cam.project(p0)
        uv1, z1 = cam.project(p1)
        for k in range(len(ss) - 1):
            if min(z0[k], z0[k + 1], z1[k], z1[k + 1]) <= NEAR_M:
                continue
            quad = np.array([uv0[k], uv0[k + 1], uv1[k + 1], uv1[k]])
            if quad[:, 0].max() < -50 or quad[:, 0].min() > w + 50 or quad[:, 1].max() < -50 or quad[:, 1].min() > h + 50:
                continue
            q = np.clip(np.round(quad * 16), -2**24, 2**24).astype(np.int32)
            cv2.fillConvexPoly(cls, q, value, lineType=cv2.LINE_8, shift=4)
            quads.append((q, value))

    strip(-road.shoulder_width_m, 0.0, 1)
    strip(0.0, W, 2)
    for lane in range(road.lanes):  # darker, polished wheel paths
        c = (lane + 0.5) * road.lane_width_m
        strip(c - 1.1, c - 0.55, 5)
        strip(c + 0.55, c + 1.1, 5)
    for s0 in rng.uniform(0, road.length_m - 8, int(road.length_m / 40)):  # patched asphalt
        d0 = float(rng.uniform(0, W - 2.0))
        strip(d0, d0 + float(rng.uniform(0.8, 2.0)), 6, s0, s0 + float(rng.uniform(2.0, 8.0)))
    strip(W, W + 0.6, 1)
    strip(0.15, 0.30, 3)  # right edge line
    strip(W - 0.3, W - 0.15, 4)  # left edge line (yellow)
    dash, period = 3.0, 12.0
    for lane in range(1, road.lanes):
        d = lane * road.lane_width_m
        for s0 in np.arange(0.0, road.length_m - dash, period):
            strip(d - 0.075, d + 0.075, 3, s0, s0 + dash)

    grass = cls == 0
    tex = np.where(grass, 16.0 * t_fine + 11.0 * t_coarse, 6.0 * t_fine + 5.0 * t_coarse)
    texture = tex[..., None] * np.where(grass[..., None], np.array([0.7, 1.0, 0.8], np.float32), 1.0)

    # tree line along the horizon
    hv = cam.horizon_v_px()
    prof = cv2.resize(rng.uniform(0, 1, (1, w // 16 + 2)).astype(np.float32), (w, 1),
                      interpolation=cv2.INTER_CUBIC)[0]
    prof2 = cv2.resize(rng.uniform(0, 1, (1, w // 4 + 2)).astype(np.float32), (w, 1),
                       interpolation=cv2.INTER_LINEAR)[0]
    tree_h = 6 + 14 * prof + 5 * prof2
    top = hv - tree_h
    trees = (vv >= top[None, :]) & (vv < hv + 3)
    tree_tex = cv2.GaussianBlur(rng.normal(0, 1, (h, w)).astype(np.float32), (0, 0), 1.2) * 10.0

    r2 = ((uu - w / 2) / (w / 2)) ** 2 + ((vv - h / 2) / (h / 2)) ** 2
    return SceneryGeometry(dz=dz, dist=dist, ground=ground, gx=gx, gy=gy, quads=tuple(quads),
                           texture=texture, trees=trees, tree_tex=tree_tex, vignette=1.0 - 0.18 * r2 / 2)


def render_scenery(camera: CameraConfig, cam: PinholeCamera, road: Road, seed: int, lighting: str,
                   geometry: SceneryGeometry | None = None) -> np.ndarray:
    """The static scene seen by ``camera`` (``cam``: its pinhole model) in ``lighting`` (a key of ``LIGHTING``);
    ``geometry``: its ``scenery_geometry``, made here when not given (a camera's lightings share one)."""
    L = LIGHTING[lighting]
    g = geometry if geometry is not None else scenery_geometry(camera, cam, road, seed)
    h, w = camera.height_px, camera.width_px

    # sky gradient
    sky_top, sky_bot = np.array(L["sky_top"], np.float32), np.array(L["sky_bottom"], np.float32)
    elev = np.clip(g.dz * 4.0, 0.0, 1.0)[..., None]
    img = sky_bot + (sky_top - sky_bot) * elev

    # road surfaces and markings in this lighting's colours
    asphalt = np.array(L["asphalt"], np.float32)
    colours = np.stack([np.array(L["grass"], np.float32), np.array(L["shoulder"], np.float32), asphalt,
                        np.array([225, 228, 230], np.float32) * (0.5 + 0.5 * L["scene_gain"]),
                        np.array([40, 185, 215], np.float32) * (0.5 + 0.5 * L["scene_gain"]),
                        asphalt * 0.9, asphalt * 0.8 + 4])
    surf = np.empty((h, w, 3), np.float32)
    surf[:] = colours[0]
    fills = [c.tolist() for c in colours]
    for q, value in g.quads:
        cv2.fillConvexPoly(surf, q, fills[value], lineType=cv2.LINE_AA, shift=4)
    surf = surf + g.texture
    img = np.where(g.ground[..., None], surf, img)

    # tree line along the horizon
    tree_col = np.array(L["grass"], np.float32) * 0.6
    img = np.where(g.trees[..., None], tree_col + g.tree_tex[..., None], img)

    # haze towards the horizon
    haze = (1.0 - np.exp(-g.dist / L["haze_m"]))[..., None]
    img = np.where(g.ground[..., None], img * (1 - haze) + sky_bot * haze, img)

    # night: pools of light from street lamps on the right shoulder every 40 m
    if lighting == "night":
        lamps_s = np.arange(10.0, road.length_m, 40.0)
        lx, ly, _ = road.pose_at(lamps_s, np.full_like(lamps_s, -road.shoulder_width_m))
        pool = np.zeros((h, w), np.float32)
        for x0, y0 in zip(lx, ly, strict=True):
            r2 = (g.gx - x0) ** 2 + (g.gy - y0) ** 2
            pool += np.exp(-r2 / (2 * 5.0 ** 2))
        img = img * (1.0 + 1.1 * np.clip(pool, 0, 1.5))[..., None]

    # vignetting
    img = img * g.vignette[..., None]
    return np.clip(img, 0, 255).astype(np.uint8)
