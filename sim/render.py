"""Renderer of an RSU camera's view (OpenCV only, one core, no GPU).

The static scene (sky, tree line, grass, asphalt with a world-anchored texture, shoulder, lane
markings, haze, street-light pools at night, vignetting) is rendered once per camera and lighting
into a cached image. Per frame: vehicles as shaded 3-D part boxes (lower body, glass cabin, cargo box,
light bar) drawn back to front (painter's order by depth) with decals (windows, tail and brake lights,
liveries, EV lamps,
hazard flashers and turn signals of ordinary vehicles: ``sim.lamps``), a cheap ROI glow for lamps that are on, motion blur on vehicle ROIs when the image
motion during the exposure exceeds ~1.5 px, then exposure (a LUT) and sensor noise (a pre-generated
noise texture shifted per frame). Everything is deterministic for a given (snapshot, frame index).

Labels (``labels``) come from the same geometry: the visible part of each vehicle's silhouette in a
per-vehicle id buffer, as a box, with the visible fraction; a vehicle below ``MIN_VISIBLE_FRACTION``
is dropped.

Appearance is derived from ``Actor`` fields: kind, size, colour_bgr, brake_on, light_bar and
``style`` (livery and body details, see ``sim.vehicles``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from protocol.corridor import CameraConfig, Road
from protocol.messages import Actor, WorldSnapshot
from sim.camera import NEAR_M, PinholeCamera
from sim.lamps import AMBER_ON_BGR, SIGNAL_GLOW, SIGNAL_LAMPS, TURN_ON_BGR, signal_decals, signal_on
from sim.vehicles import LIVERY_AMBULANCE, LIVERY_POLICE, LIVERY_TWO_TONE, style_detail, style_livery

MIN_VISIBLE_FRACTION = 0.3
CLASS_VEHICLE = 0
CLASS_EV = 1
CLASS_NAMES = ("vehicle", "ev")

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

GLASS_BGR = np.array([70, 55, 45], dtype=float)
DARK_BGR = np.array([28, 28, 30], dtype=float)
TAIL_OFF_BGR = np.array([40, 40, 120], dtype=float)
TAIL_ON_BGR = (60, 60, 255)
RED_LAMP_BGR = (40, 40, 255)
BLUE_LAMP_BGR = (255, 90, 30)
LAMP_OFF_RED = np.array([60, 60, 150], dtype=float)
LAMP_OFF_BLUE = np.array([140, 80, 60], dtype=float)

# box faces: (corner indices in box_corners order, outward normal in the local frame); u runs left->right
# as seen from outside, v bottom->top
_FACES = {
    "rear": ((1, 0, 4, 5), (-1.0, 0.0, 0.0)),
    "front": ((3, 2, 6, 7), (1.0, 0.0, 0.0)),
    "left": ((2, 1, 5, 6), (0.0, 1.0, 0.0)),
    "right": ((0, 3, 7, 4), (0.0, -1.0, 0.0)),
    "top": ((4, 7, 6, 5), (0.0, 0.0, 1.0)),
}


_FACE_NAMES = tuple(_FACES)
_FACE_IDX = np.array([_FACES[f][0] for f in _FACE_NAMES])


@dataclass
class Part:
    """Axis-aligned box in the vehicle frame (x forward from the centre, y left, z up), in metres."""

    x0: float
    x1: float
    y0: float
    y1: float
    z0: float
    z1: float
    colour: np.ndarray
    top_colour: np.ndarray | None = None
    side_colour: np.ndarray | None = None
    silhouette: bool = True
    inset: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """Top face pulled in at the rear, front and sides (m): sloped windscreens and rear windows."""

    def corners(self) -> np.ndarray:
        x0, x1, y0, y1, z0, z1 = self.x0, self.x1, self.y0, self.y1, self.z0, self.z1
        ir, i_f, i_s = self.inset
        return np.array([[x0, y0, z0], [x0, y1, z0], [x1, y1, z0], [x1, y0, z0],
                         [x0 + ir, y0 + i_s, z1], [x0 + ir, y1 - i_s, z1], [x1 - i_f, y1 - i_s, z1],
                         [x1 - i_f, y0 + i_s, z1]])


@dataclass
class Decal:
    """A quad on one face of a part: u, v fractions of the face (u left->right seen from outside, v up)."""

    part: int
    face: str
    u0: float
    u1: float
    v0: float
    v1: float
    colour: np.ndarray | tuple
    lamp: str = ""  # "", "tail", "ev_red", "ev_blue", "hazard", "turn" (sim.lamps)


@dataclass
class Label:
    actor_id: str
    kind: str
    class_id: int
    bbox_px: tuple[float, float, float, float]  # x1, y1, x2, y2 of the visible part, in the image
    visible_fraction: float
    full_bbox_px: tuple[float, float, float, float]


def ev_lamps_on(light_bar, t_s: float) -> tuple[bool, bool]:
    """(red lit, blue lit) of an EV light bar at time t: alternating = red half / blue half of each
    cycle; strobe = two short flashes of red then two of blue per cycle."""
    if light_bar is None or not light_bar.on or light_bar.frequency_hz <= 0:
        return False, False
    ph = ((t_s - light_bar.phase_s) * light_bar.frequency_hz) % 1.0
    if light_bar.pattern == "strobe":
        red = ph < 0.12 or 0.2 <= ph < 0.32
        blue = 0.5 <= ph < 0.62 or 0.7 <= ph < 0.82
        return red, blue
    return ph < 0.5, ph >= 0.5


DEBRIS_SHAPES = ("box", "rock", "barrel", "pallet", "pipe", "tyre")
"""Debris kind by livery index (``sim.scenario.DEBRIS_KINDS``)."""


def _debris_parts(shape_index: int, detail: int, L: float, W: float, H: float, body: np.ndarray) -> list[Part]:
    """Boxes that give each debris kind its look within its L x W x H footprint (deterministic by detail)."""
    hl, hw = L / 2, W / 2
    rng = np.random.default_rng(detail)
    shape = DEBRIS_SHAPES[shape_index] if shape_index < len(DEBRIS_SHAPES) else "box"
    if shape == "rock":  # a rough boulder: stacked, shrinking, offset blocks
        parts = [Part(-hl, hl, -hw * 0.85, hw * 0.9, 0.0, H * 0.45, body * 0.85)]
        x0, x1, y0, y1 = -hl * 0.8, hl * 0.75, -hw, hw * 0.7
        z = H * 0.4
        for k in range(3):
            jx, jy = rng.uniform(-0.12, 0.12, 2) * (hl, hw)
            parts.append(Part(x0 + jx, x1 + jx, y0 + jy, y1 + jy, z, z + H * 0.22 if k < 2 else H,
                              body * float(rng.uniform(0.85, 1.1)), top_colour=body * 1.15))
            x0, x1, y0, y1, z = x0 * 0.75, x1 * 0.7, y0 * 0.75, y1 * 0.7, z + H * 0.2
        return parts
    if shape == "barrel":  # an upright drum with two darker rims
        r = min(hl, hw)
        parts = [Part(-r, r, -r, r, 0.0, H, body, top_colour=body * 0.7)]
        for zc in (0.3, 0.7):
            parts.append(Part(-r * 1.03, r * 1.03, -r * 1.03, r * 1.03, H * (zc - 0.04), H * (zc + 0.04),
                              body * 0.55, silhouette=False))
        return parts
    if shape == "pallet":  # three runners under a slatted deck
        deck = H * 0.3
        parts = [Part(-hl, hl, y - hw * 0.09, y + hw * 0.09, 0.0, H - deck, body * 0.75)
                 for y in (-hw * 0.9, 0.0, hw * 0.9)]
        n = 5
        for k in range(n):
            x0 = -hl + k * (L / n)
            parts.append(Part(x0, x0 + L / n * 0.7, -hw, hw, H - deck, H, body))
        return parts
    if shape == "pipe":  # a length of pipe lying along the footprint with a dark bore at the ends
        r = min(hw, H / 2)
        return [Part(-hl, hl, -r, r, 0.0, 2 * r, body, top_colour=body * 1.15),
                Part(hl - 0.02, hl + 0.005, -r * 0.6, r * 0.6, r * 0.4, r * 1.6, body * 0.3, silhouette=False)]
    if shape == "tyre":  # lying flat: a black ring (outer block, grey hub on top)
        return [Part(-hl, hl, -hw, hw, 0.0, H, body, top_colour=body * 1.4),
                Part(-hl * 0.4, hl * 0.4, -hw * 0.4, hw * 0.4, H, H * 1.02, np.array([120.0, 120.0, 118.0]),
                     silhouette=False)]
    return [Part(-hl, hl * 0.3, -hw, hw * 0.6, 0.0, H, body),
            Part(-hl * 0.2, hl, -hw * 0.5, hw, 0.0, H * float(rng.uniform(0.4, 0.8)), body * 0.8)]


def _body_parts(actor: Actor) -> tuple[list[Part], list[Decal]]:
    """Parts and decals of a vehicle from its kind, size, colour and style (deterministic)."""
    L, W, H = actor.length_m, actor.width_m, actor.height_m
    hl, hw = L / 2, W / 2
    body = np.array(actor.colour_bgr, dtype=float)
    livery, detail = style_livery(actor.style), style_detail(actor.style)
    kind = actor.kind.value if hasattr(actor.kind, "value") else str(actor.kind)
    parts: list[Part] = []
    decals: list[Decal] = []
    roof = body if livery != LIVERY_TWO_TONE else np.clip(body * 0.6 + 110, 0, 255)
    if kind == "debris":
        return _debris_parts(livery, detail, L, W, H, body), decals
    tail_v = (0.55, 0.85)
    if kind in ("car", "av") or (kind == "ev" and livery == LIVERY_POLICE):
        shape = detail % 3  # 0 sedan, 1 hatchback, 2 SUV
        z_belt = H * (0.55 if shape != 2 else 0.6)
        parts.append(Part(-hl * 0.86, hl * 0.86, -hw * 0.92, hw * 0.92, 0.0, H * 0.22, DARK_BGR))
        parts.append(Part(-hl, hl, -hw, hw, H * 0.18, z_belt, body))
        cab = {0: (-0.62, 0.42), 1: (-0.9, 0.38), 2: (-0.92, 0.5)}[shape]
        cab_len = hl * (cab[1] - cab[0])
        slope = {0: (0.32, 0.38), 1: (0.12, 0.36), 2: (0.1, 0.3)}[shape]
        parts.append(Part(hl * cab[0], hl * cab[1], -hw * 0.86, hw * 0.86, z_belt, H, GLASS_BGR, top_colour=roof,
                          inset=(cab_len * slope[0], cab_len * slope[1], hw * 0.1)))
        pillar = 2
        for face in ("left", "right"):
            for u0, u1 in ((0.12, 0.27), (0.73, 0.88)):
                decals.append(Decal(1, face, u0, u1, 0.0, 0.35, DARK_BGR))
        for face in ("left", "right"):
            decals.append(Decal(pillar, face, 0.46, 0.54, 0.0, 1.0, roof * 0.9))
        for u0, u1 in ((0.04, 0.2), (0.8, 0.96)):
            decals.append(Decal(1, "rear", u0, u1, *tail_v, TAIL_OFF_BGR, "tail"))
        decals.append(Decal(1, "rear", 0.38, 0.62, 0.15, 0.4, np.array([200, 200, 200]) * 0.8))  # plate
        if livery == LIVERY_POLICE:
            for face in ("left", "right"):
                decals.append(Decal(1, face, 0.25, 0.75, 0.0, 1.0, np.array([25, 25, 25])))
        top_z = H
        bar_x = (hl * (cab[0] + cab[1]) / 2 - 0.2, hl * (cab[0] + cab[1]) / 2 + 0.2)
    elif kind in ("van",) or kind == "ev":
        parts.append(Part(-hl * 0.9, hl * 0.9, -hw * 0.92, hw * 0.92, 0.0, H * 0.16, DARK_BGR))
        parts.append(Part(-hl, hl * 0.62, -hw, hw, H * 0.13, H, body, top_colour=roof))
        parts.append(Part(hl * 0.62, hl, -hw, hw, H * 0.13, H * 0.5, body))  # bonnet
        parts.append(Part(hl * 0.62 - 0.05, hl * 0.75, -hw * 0.95, hw * 0.95, H * 0.5, H * 0.82, GLASS_BGR,
                          top_colour=body))
        for u0, u1 in ((0.08, 0.46), (0.54, 0.92)):
            decals.append(Decal(1, "rear", u0, u1, 0.62, 0.85, GLASS_BGR))
        for face in ("left", "right"):
            decals.append(Decal(1, face, 0.72 if face == "left" else 0.05, 0.95 if face == "left" else 0.28,
                                0.6, 0.85, GLASS_BGR))
        for u0, u1 in ((0.02, 0.1), (0.9, 0.98)):
            decals.append(Decal(1, "rear", u0, u1, 0.2, 0.5, TAIL_OFF_BGR, "tail"))
        if livery == LIVERY_AMBULANCE:
            red = np.array([40, 35, 200], dtype=float)
            for face in ("left", "right", "rear"):
                decals.append(Decal(1, face, 0.0, 1.0, 0.36, 0.46, red))
            decals.append(Decal(1, "rear", 0.3, 0.7, 0.5, 0.58, red))  # cross bar
        top_z = H
        bar_x = (hl * 0.62 - 0.35, hl * 0.62 - 0.05)
    elif kind == "truck":
        cargo = body if livery == LIVERY_TWO_TONE or detail % 2 else np.array([225, 225, 225], dtype=float)
        parts.append(Part(-hl * 0.95, hl * 0.95, -hw * 0.9, hw * 0.9, 0.0, H * 0.3, DARK_BGR))
        parts.append(Part(-hl, hl * 0.7, -hw, hw, H * 0.28, H, cargo))
        parts.append(Part(hl * 0.72, hl, -hw * 0.97, hw * 0.97, H * 0.25, H * 0.85, body))
        parts.append(Part(hl * 0.9, hl + 0.02, -hw * 0.9, hw * 0.9, H * 0.55, H * 0.8, GLASS_BGR))
        for u0, u1 in ((0.02, 0.12), (0.88, 0.98)):
            decals.append(Decal(0, "rear", u0, u1, 0.55, 0.8, TAIL_OFF_BGR, "tail"))
        decals.append(Decal(1, "rear", 0.49, 0.51, 0.0, 1.0, cargo * 0.6))
        top_z = H
        bar_x = None
    else:  # bus
        parts.append(Part(-hl * 0.95, hl * 0.95, -hw * 0.9, hw * 0.9, 0.0, H * 0.16, DARK_BGR))
        parts.append(Part(-hl, hl, -hw, hw, H * 0.12, H, body))
        for face in ("left", "right"):
            decals.append(Decal(1, face, 0.03, 0.97, 0.5, 0.85, GLASS_BGR))
        decals.append(Decal(1, "rear", 0.1, 0.9, 0.6, 0.85, GLASS_BGR))
        decals.append(Decal(1, "front", 0.05, 0.95, 0.35, 0.9, GLASS_BGR))
        for u0, u1 in ((0.03, 0.12), (0.88, 0.97)):
            decals.append(Decal(1, "rear", u0, u1, 0.12, 0.3, TAIL_OFF_BGR, "tail"))
        top_z = H
        bar_x = None
    if actor.light_bar is not None and bar_x is not None:
        i = len(parts)
        parts.append(Part(bar_x[0], bar_x[1], -hw * 0.85, hw * 0.85, top_z, top_z + 0.16, DARK_BGR))
        # left half red, right half blue (seen from behind: rear face u runs right->left of the car)
        for face, red_u, blue_u in (("rear", (0.52, 0.98), (0.02, 0.48)), ("front", (0.02, 0.48), (0.52, 0.98))):
            decals.append(Decal(i, face, *red_u, 0.1, 0.9, LAMP_OFF_RED, "ev_red"))
            decals.append(Decal(i, face, *blue_u, 0.1, 0.9, LAMP_OFF_BLUE, "ev_blue"))
        decals.append(Decal(i, "left", 0.05, 0.95, 0.1, 0.9, LAMP_OFF_RED, "ev_red"))
        decals.append(Decal(i, "right", 0.05, 0.95, 0.1, 0.9, LAMP_OFF_BLUE, "ev_blue"))
        decals.append(Decal(i, "top", 0.02, 0.48, 0.05, 0.95, LAMP_OFF_BLUE, "ev_blue"))
        decals.append(Decal(i, "top", 0.52, 0.98, 0.05, 0.95, LAMP_OFF_RED, "ev_red"))
        if kind == "ev" and livery == LIVERY_AMBULANCE:  # rear flashers at the top corners
            decals.append(Decal(1, "rear", 0.02, 0.12, 0.88, 0.97, LAMP_OFF_BLUE, "ev_blue"))
            decals.append(Decal(1, "rear", 0.88, 0.98, 0.88, 0.97, LAMP_OFF_RED, "ev_red"))
    tails = [(dc.part, dc.u0, dc.u1, dc.v0, dc.v1) for dc in decals if dc.lamp == "tail"]
    decals.extend(Decal(*fields) for fields in signal_decals(kind, actor.style, tails))
    return parts, decals


def _face_points(corners: np.ndarray, face: str, u0: float, u1: float, v0: float, v1: float) -> np.ndarray:
    """World points of a (u, v) sub-rectangle of a box face (corners (8, 3) of the part)."""
    a, b, c, d = corners[_FACES[face][0], :]  # a bottom-left, b bottom-right, c top-right, d top-left
    u = np.array([[u0], [u1], [u1], [u0]])
    v = np.array([[v0], [v0], [v1], [v1]])
    bottom = a + (b - a) * u
    return bottom + (d + (c - d) * u - bottom) * v


class Renderer:
    """Renders one camera's view of world snapshots."""

    def __init__(self, camera: CameraConfig, road: Road, seed: int = 0, *, noise: bool = True,
                 motion_blur: bool = True, exposure: bool = True, shadows: bool = True) -> None:
        self.cfg = camera
        self.shadows = shadows
        self.cam = PinholeCamera.from_config(camera)
        self.road = road
        self.seed = int(seed)
        self.w, self.h = camera.width_px, camera.height_px
        self.noise_enabled, self.blur_enabled, self.exposure_enabled = noise, motion_blur, exposure
        self._backgrounds: dict[str, np.ndarray] = {}
        self._noise: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        self._pad = 64
        self._glow_cache: dict[tuple, np.ndarray] = {}

    # ------------------------------------------------------------------ static scene
    def background(self, lighting: str) -> np.ndarray:
        if lighting not in self._backgrounds:
            self._backgrounds[lighting] = self._render_background(lighting)
        return self._backgrounds[lighting]

    def _render_background(self, lighting: str) -> np.ndarray:
        L = LIGHTING[lighting]
        h, w = self.h, self.w
        rng = np.random.default_rng(self.seed + 1000)
        vv, uu = np.mgrid[0:h, 0:w].astype(np.float32)
        rays = self.cam.ray(np.column_stack([uu.ravel(), vv.ravel()])).astype(np.float32)
        dz = rays[:, 2].reshape(h, w)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.where(dz < -1e-4, -self.cam.C[2] / dz, np.inf)
        gx = (self.cam.C[0] + t * rays[:, 0].reshape(h, w)).astype(np.float32)
        gy = (self.cam.C[1] + t * rays[:, 1].reshape(h, w)).astype(np.float32)
        dist = np.where(np.isfinite(t), t, 1e6).astype(np.float32)
        ground = dist < 5e3

        # sky gradient
        sky_top, sky_bot = np.array(L["sky_top"], np.float32), np.array(L["sky_bottom"], np.float32)
        elev = np.clip(dz * 4.0, 0.0, 1.0)[..., None]
        img = sky_bot + (sky_top - sky_bot) * elev

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
        asphalt = np.array(L["asphalt"], np.float32)
        colours = np.stack([np.array(L["grass"], np.float32), np.array(L["shoulder"], np.float32), asphalt,
                            np.array([225, 228, 230], np.float32) * (0.5 + 0.5 * L["scene_gain"]),
                            np.array([40, 185, 215], np.float32) * (0.5 + 0.5 * L["scene_gain"]),
                            asphalt * 0.9, asphalt * 0.8 + 4])
        surf = np.empty((h, w, 3), np.float32)
        surf[:] = colours[0]
        cls = np.zeros((h, w), np.uint8)  # 0 grass, 1 shoulder, 2 asphalt, 3 white, 4 yellow, 5 wheel path, 6 patch
        road = self.road
        W = road.width_m
        step = 1.0
        s_vals = np.arange(0.0, road.length_m + step, step)

        def strip(d0: float, d1: float, value: int, s_from=None, s_to=None) -> None:
            ss = s_vals if s_from is None else np.arange(s_from, s_to + 1e-9, min(step, s_to - s_from))
            x0, y0, _ = road.pose_at(ss, np.full_like(ss, d0))
            x1, y1, _ = road.pose_at(ss, np.full_like(ss, d1))
            p0 = np.column_stack([x0, y0, np.zeros_like(x0)])
            p1 = np.column_stack([x1, y1, np.zeros_like(x1)])
            uv0, z0 = self.cam.project(p0)
            uv1, z1 = self.cam.project(p1)
            for k in range(len(ss) - 1):
                if min(z0[k], z0[k + 1], z1[k], z1[k + 1]) <= NEAR_M:
                    continue
                quad = np.array([uv0[k], uv0[k + 1], uv1[k + 1], uv1[k]])
                if quad[:, 0].max() < -50 or quad[:, 0].min() > w + 50 or quad[:, 1].max() < -50 or quad[:, 1].min() > h + 50:
                    continue
                q = np.clip(np.round(quad * 16), -2**24, 2**24).astype(np.int32)
                cv2.fillConvexPoly(cls, q, value, lineType=cv2.LINE_8, shift=4)
                cv2.fillConvexPoly(surf, q, colours[value].tolist(), lineType=cv2.LINE_AA, shift=4)

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
        surf = surf + tex[..., None] * np.where(grass[..., None], np.array([0.7, 1.0, 0.8], np.float32), 1.0)
        img = np.where(ground[..., None], surf, img)

        # tree line along the horizon
        hv = self.cam.horizon_v_px()
        prof = cv2.resize(rng.uniform(0, 1, (1, w // 16 + 2)).astype(np.float32), (w, 1),
                          interpolation=cv2.INTER_CUBIC)[0]
        prof2 = cv2.resize(rng.uniform(0, 1, (1, w // 4 + 2)).astype(np.float32), (w, 1),
                           interpolation=cv2.INTER_LINEAR)[0]
        tree_h = 6 + 14 * prof + 5 * prof2
        top = hv - tree_h
        trees = (vv >= top[None, :]) & (vv < hv + 3)
        tree_col = np.array(L["grass"], np.float32) * 0.6
        tree_tex = cv2.GaussianBlur(rng.normal(0, 1, (h, w)).astype(np.float32), (0, 0), 1.2) * 10.0
        img = np.where(trees[..., None], tree_col + tree_tex[..., None], img)

        # haze towards the horizon
        haze = (1.0 - np.exp(-dist / L["haze_m"]))[..., None]
        img = np.where(ground[..., None], img * (1 - haze) + sky_bot * haze, img)

        # night: pools of light from street lamps on the right shoulder every 40 m
        if lighting == "night":
            lamps_s = np.arange(10.0, road.length_m, 40.0)
            lx, ly, _ = road.pose_at(lamps_s, np.full_like(lamps_s, -road.shoulder_width_m))
            pool = np.zeros((h, w), np.float32)
            for x0, y0 in zip(lx, ly, strict=True):
                r2 = (gx - x0) ** 2 + (gy - y0) ** 2
                pool += np.exp(-r2 / (2 * 5.0 ** 2))
            img = img * (1.0 + 1.1 * np.clip(pool, 0, 1.5))[..., None]

        # vignetting
        r2 = ((uu - w / 2) / (w / 2)) ** 2 + ((vv - h / 2) / (h / 2)) ** 2
        img = img * (1.0 - 0.18 * r2 / 2)[..., None]
        return np.clip(img, 0, 255).astype(np.uint8)

    # ------------------------------------------------------------------ geometry
    def _actor_geometry(self, actor: Actor):
        """Projected parts of one actor: list of (part, corners_world, uv, depth), decals, depth of centre."""
        parts, decals = _body_parts(actor)
        c, s = math.cos(actor.heading_rad), math.sin(actor.heading_rad)
        rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        origin = np.array([actor.pos_x_m, actor.pos_y_m, 0.0])
        corners = np.stack([p.corners() for p in parts]) @ rot.T + origin  # (P, 8, 3)
        uv, depth = self.cam.project(corners.reshape(-1, 3))
        return parts, decals, corners, uv.reshape(len(parts), 8, 2), depth.reshape(len(parts), 8), rot

    def _ordered(self, snapshot: WorldSnapshot) -> list[tuple[float, Actor]]:
        """Actors in view, far to near (painter's order)."""
        out = []
        C = self.cam.C
        fwd = self.cam.R[2]
        for a in snapshot.actors:
            rel = np.array([a.pos_x_m - C[0], a.pos_y_m - C[1], a.height_m / 2 - C[2]])
            depth = float(rel @ fwd)
            if depth < NEAR_M + a.length_m or depth > 400.0:
                continue
            out.append((float(np.hypot(rel[0], rel[1])), a))
        out.sort(key=lambda t: -t[0])
        return out

    @staticmethod
    def _visible_faces(parts, corners, C) -> list[dict[str, np.ndarray]]:
        """Per part, the faces that face the camera (back-face culling) with their outward unit normals."""
        fc_all = corners[:, _FACE_IDX]  # (P, 5, 4, 3)
        a, b, d = fc_all[:, :, 0], fc_all[:, :, 1], fc_all[:, :, 3]
        e1, e2 = b - a, d - a
        n = np.stack([e1[..., 1] * e2[..., 2] - e1[..., 2] * e2[..., 1],
                      e1[..., 2] * e2[..., 0] - e1[..., 0] * e2[..., 2],
                      e1[..., 0] * e2[..., 1] - e1[..., 1] * e2[..., 0]], axis=-1)
        norm = np.linalg.norm(n, axis=-1, keepdims=True)
        n = n / np.where(norm > 1e-9, norm, 1.0)
        fc = fc_all.mean(axis=2)
        centre = corners.mean(axis=1)[:, None, :]
        n = np.where((np.sum(n * (fc - centre), axis=-1) < 0)[..., None], -n, n)
        vis = (np.sum(n * (C - fc), axis=-1) > 0) & (norm[..., 0] > 1e-9)
        return [{_FACE_NAMES[f]: n[p, f] for f in np.flatnonzero(vis[p])} for p in range(len(parts))]

    def _draw_headlight_pool(self, img: np.ndarray, a: Actor, strength: float) -> None:
        """Light thrown on the road ahead of a vehicle by its headlights (dusk and night)."""
        c, s_ = math.cos(a.heading_rad), math.sin(a.heading_rad)
        fx, fy = a.pos_x_m + c * a.length_m / 2, a.pos_y_m + s_ * a.length_m / 2
        local = np.array([[0.5, -0.8], [0.5, 0.8], [18.0, 3.2], [18.0, -3.2]])
        pts = np.column_stack([fx + local[:, 0] * c - local[:, 1] * s_, fy + local[:, 0] * s_ + local[:, 1] * c,
                               np.zeros(4)])
        uv, depth = self.cam.project(pts)
        if np.any(depth <= NEAR_M):
            return
        x1, y1 = np.floor(uv.min(axis=0)).astype(int) - 6
        x2, y2 = np.ceil(uv.max(axis=0)).astype(int) + 7
        ox1, oy1, ox2, oy2 = max(0, x1), max(0, y1), min(self.w, x2), min(self.h, y2)
        if ox2 - ox1 < 2 or oy2 - oy1 < 2:
            return
        pool = np.zeros((y2 - y1, x2 - x1, 3), np.uint8)
        col = tuple(int(v * strength) for v in (70, 95, 110))
        cv2.fillConvexPoly(pool, np.round((uv - (x1, y1)) * 16).astype(np.int32), col, cv2.LINE_AA, 4)
        pool = cv2.blur(pool, (7, 7))
        img[oy1:oy2, ox1:ox2] = cv2.add(img[oy1:oy2, ox1:ox2], pool[oy1 - y1:oy2 - y1, ox1 - x1:ox2 - x1])

    def _draw_shadow(self, img: np.ndarray, corners: np.ndarray, sun: np.ndarray, strength: float) -> None:
        """Cast shadow on the road: the vehicle's corners projected along the sun onto z = 0, darkened."""
        pts = corners.reshape(-1, 3)
        ground = pts[:, :2] - pts[:, 2:3] * (sun[:2] / max(sun[2], 0.25))
        hull = cv2.convexHull(ground.astype(np.float32)).reshape(-1, 2)
        uv, depth = self.cam.project(np.column_stack([hull, np.zeros(len(hull))]))
        if np.any(depth <= NEAR_M):
            return
        x1, y1 = np.floor(uv.min(axis=0)).astype(int)
        x2, y2 = np.ceil(uv.max(axis=0)).astype(int) + 1
        x1, y1, x2, y2 = max(0, x1), max(0, y1), min(self.w, x2), min(self.h, y2)
        if x2 - x1 < 2 or y2 - y1 < 2:
            return
        mask = np.zeros((y2 - y1, x2 - x1), np.uint8)
        cv2.fillConvexPoly(mask, np.round((uv - (x1, y1)) * 16).astype(np.int32), 255, cv2.LINE_AA, 4)
        roi = img[y1:y2, x1:x2]
        dark = (roi.astype(np.uint16) * int(256 * (1 - strength)) >> 8).astype(np.uint8)
        m = mask > 127
        roi[m] = dark[m]

    # ------------------------------------------------------------------ per frame
    def render(self, snapshot: WorldSnapshot, frame_index: int | None = None) -> np.ndarray:
        """BGR image (h, w, 3) of the snapshot; deterministic for (snapshot, frame_index)."""
        lighting = snapshot.lighting.value if hasattr(snapshot.lighting, "value") else str(snapshot.lighting)
        L = LIGHTING[lighting]
        if frame_index is None:
            frame_index = int(round(snapshot.sim_time_s * self.cfg.fps))
        img = self.background(lighting).copy()
        t = snapshot.sim_time_s
        C = self.cam.C
        sun = np.array(L["sun_dir"], dtype=float)
        sun /= np.linalg.norm(sun)
        gain = L["scene_gain"]
        glows: list[tuple[np.ndarray, tuple, float]] = []
        lamp_pts: dict[tuple[str, str], list] = {}
        drawn = []
        for _dist, a in self._ordered(snapshot):
            geo = self._actor_geometry(a)
            uv, depth = geo[3], geo[4]
            if np.any(depth <= NEAR_M):
                continue
            allx, ally = uv[..., 0], uv[..., 1]
            if allx.max() < -200 or ally.max() < 0 or allx.min() >= self.w + 200 or ally.min() >= self.h:
                continue  # (shadows may reach into the image from a little outside)
            drawn.append((a, geo))
            if L["sun"] > 0.05 and self.shadows:
                self._draw_shadow(img, geo[2], sun, 0.45 * L["sun"] / 0.55)
            if L["running_lights"] and a.kind.value != "debris":
                self._draw_headlight_pool(img, a, 1.0 if lighting == "night" else 0.4)
        for a, geo in drawn:
            parts, decals, corners, uv, depth, rot = geo
            allx, ally = uv[..., 0], uv[..., 1]
            if allx.max() < 0 or allx.min() >= self.w:
                continue
            blur_px = self._blur_vector(a, L["exposure_s"]) if self.blur_enabled else None
            # contact shadow
            fp = corners[0][:4].copy()
            centre = fp.mean(axis=0)
            fp = centre + (fp - centre) * 1.08
            suv, _ = self.cam.project(fp)
            cv2.fillConvexPoly(img, np.round(suv * 16).astype(np.int32), (16, 16, 16), cv2.LINE_AA, 4)
            faces = self._visible_faces(parts, corners, C)
            face_uv: dict[tuple[int, str], np.ndarray] = {}
            for p_i, part in enumerate(parts):
                for name, n in faces[p_i].items():
                    idx, _n_local = _FACES[name]
                    shade = L["ambient"] + L["sun"] * max(0.0, float(n @ sun))
                    if name == "top":
                        col = part.top_colour if part.top_colour is not None else part.colour
                    else:
                        col = part.side_colour if part.side_colour is not None else part.colour
                    if col is GLASS_BGR:
                        shade = 0.6 + 0.5 * shade * (1.3 if name == "top" else 1.0)
                    colour = np.clip(np.asarray(col) * shade * gain, 0, 255)
                    poly = uv[p_i][list(idx)]
                    face_uv[(p_i, name)] = poly
                    cv2.fillConvexPoly(img, np.round(poly * 16).astype(np.int32), colour.tolist(), cv2.LINE_AA, 4)
            red_on, blue_on = ev_lamps_on(a.light_bar, t)
            sig_on = signal_on(a.style, t)
            tail_bright = a.brake_on or L["running_lights"]
            shown = [dc for dc in decals if (dc.part, dc.face) in face_uv]
            if shown:
                all_uv, _ = self.cam.project(np.concatenate(
                    [_face_points(corners[dc.part], dc.face, dc.u0, dc.u1, dc.v0, dc.v1) for dc in shown]))
            for k_dc, dc in enumerate(shown):
                puv = all_uv[4 * k_dc:4 * k_dc + 4]
                lit = False
                if dc.lamp == "turn" and not sig_on:
                    continue  # the tail light under it shows
                if dc.lamp == "tail":
                    if tail_bright:
                        lit = True
                        colour = TAIL_ON_BGR if a.brake_on else (50, 50, 200)
                    else:
                        colour = np.clip(TAIL_OFF_BGR * gain * 1.1, 0, 255).tolist()
                elif dc.lamp == "ev_red" and red_on:
                    lit, colour = True, RED_LAMP_BGR
                elif dc.lamp == "ev_blue" and blue_on:
                    lit, colour = True, BLUE_LAMP_BGR
                elif dc.lamp in SIGNAL_LAMPS and sig_on:
                    lit, colour = True, AMBER_ON_BGR if dc.lamp == "hazard" else TURN_ON_BGR
                else:
                    colour = np.clip(np.asarray(dc.colour, dtype=float) * (0.85 if dc.lamp else 1.0)
                                     * (L["ambient"] + 0.5 * L["sun"]) * gain * 1.3, 0, 255).tolist()
                cv2.fillConvexPoly(img, np.round(puv * 16).astype(np.int32), colour, cv2.LINE_AA, 4)
                if lit:
                    strength = 1.0 if dc.lamp.startswith("ev") else SIGNAL_GLOW if dc.lamp in SIGNAL_LAMPS \
                        else (0.55 if a.brake_on else 0.3)
                    if dc.lamp.startswith("ev") and dc.part == len(parts) - 1:
                        # one halo per light-bar colour (its faces share it)
                        key = (a.actor_id, dc.lamp)
                        if key in lamp_pts:
                            lamp_pts[key][0] = np.vstack([lamp_pts[key][0], puv])
                        else:
                            lamp_pts[key] = [puv, colour, strength]
                    else:
                        glows.append((puv, colour, strength))
            if blur_px is not None:
                self._motion_blur(img, uv, blur_px)
        glows.extend(tuple(v) for v in lamp_pts.values())
        if glows:
            self._draw_glows(img, glows, L["glow"])
        if self.exposure_enabled:
            img = cv2.LUT(img, self._exposure_lut(t, lighting))
        if self.noise_enabled:
            img = self._add_noise(img, lighting, frame_index)
        return img

    def _blur_vector(self, a: Actor, exposure_s: float) -> np.ndarray | None:
        if a.speed_mps < 0.5:
            return None
        p0 = np.array([[a.pos_x_m, a.pos_y_m, a.height_m / 2]])
        step = a.speed_mps * exposure_s
        p1 = p0 + step * np.array([[math.cos(a.heading_rad), math.sin(a.heading_rad), 0.0]])
        uv, depth = self.cam.project(np.vstack([p0, p1]))
        if np.any(depth <= NEAR_M):
            return None
        vec = uv[1] - uv[0]
        return vec if float(np.hypot(*vec)) >= 1.5 else None

    def _motion_blur(self, img: np.ndarray, uv: np.ndarray, vec: np.ndarray) -> None:
        """Blur a vehicle's ROI along its image motion during the exposure."""
        n = int(min(25, math.ceil(float(np.hypot(*vec)))))
        pad = n + 2
        x1 = max(0, int(uv[..., 0].min()) - pad)
        x2 = min(self.w, int(uv[..., 0].max()) + pad)
        y1 = max(0, int(uv[..., 1].min()) - pad)
        y2 = min(self.h, int(uv[..., 1].max()) + pad)
        if x2 - x1 < 3 or y2 - y1 < 3:
            return
        k = np.zeros((2 * n + 1, 2 * n + 1), np.float32)
        direction = vec / max(1e-6, float(np.hypot(*vec)))
        for i in range(n + 1):
            x, y = np.round(n + direction * (i - n / 2)).astype(int)
            k[np.clip(y, 0, 2 * n), np.clip(x, 0, 2 * n)] += 1.0
        k /= k.sum()
        roi = img[y1:y2, x1:x2]
        roi[:] = cv2.filter2D(roi, -1, k, borderType=cv2.BORDER_REPLICATE)

    def _glow_sprite(self, r: int, colour: tuple, with_core: bool, core_r: int) -> np.ndarray:
        """Cached halo sprite (4r+1 square): a Gaussian falloff times the lamp colour, optional hot core."""
        key = (r, colour, with_core, core_r)
        sprite = self._glow_cache.get(key)
        if sprite is None:
            yy, xx = np.mgrid[-2 * r:2 * r + 1, -2 * r:2 * r + 1].astype(np.float32)
            fall = np.exp(-(xx ** 2 + yy ** 2) / (2 * (0.75 * r) ** 2))[..., None]
            sprite = np.clip(fall * np.array(colour, np.float32), 0, 255).astype(np.uint8)
            if with_core:
                cv2.circle(sprite, (2 * r, 2 * r), core_r, (235, 235, 255), -1, cv2.LINE_AA)
            if len(self._glow_cache) > 512:
                self._glow_cache.clear()
            self._glow_cache[key] = sprite
        return sprite

    def _draw_glows(self, img: np.ndarray, glows, scale: float) -> None:
        """Additive halo around lamps that are on (bloom), from cached sprites on small ROIs only."""
        for puv, colour, strength in glows:
            cx, cy = puv.mean(axis=0)
            size = max(2.0, float(np.ptp(puv[:, 0])), float(np.ptp(puv[:, 1])))
            r = int(min(60, max(3, size * 0.55 * scale)))
            col = tuple(int(c * min(1.0, strength * (0.6 + 0.25 * scale))) for c in colour)
            sprite = self._glow_sprite(r, col, strength >= 1.0, max(1, int(size / 12)))
            x1, y1 = int(round(cx)) - 2 * r, int(round(cy)) - 2 * r
            x2, y2 = x1 + 4 * r + 1, y1 + 4 * r + 1
            ox1, oy1, ox2, oy2 = max(0, x1), max(0, y1), min(self.w, x2), min(self.h, y2)
            if ox2 <= ox1 or oy2 <= oy1:
                continue
            sub = sprite[oy1 - y1:oy2 - y1, ox1 - x1:ox2 - x1]
            img[oy1:oy2, ox1:ox2] = cv2.add(img[oy1:oy2, ox1:ox2], sub)

    def _exposure_lut(self, t_s: float, lighting: str) -> np.ndarray:
        """Auto-exposure drift: a slow gain oscillation and a gamma, as a 256-entry LUT."""
        phase = (self.seed % 97) * 0.37
        gain = 1.0 + 0.07 * math.sin(2 * math.pi * t_s / 9.0 + phase) + 0.03 * math.sin(2 * math.pi * t_s / 2.3 + phase)
        gamma = {"day": 0.95, "dusk": 0.9, "night": 0.85}[lighting]
        x = np.arange(256, dtype=np.float32) / 255.0
        return np.clip(255.0 * np.power(np.clip(x * gain, 0, 1), gamma), 0, 255).astype(np.uint8)

    def _add_noise(self, img: np.ndarray, lighting: str, frame_index: int) -> np.ndarray:
        """Sensor noise: a pre-generated Gaussian texture (positive and negative parts), shifted per frame."""
        if lighting not in self._noise:
            rng = np.random.default_rng(self.seed + 7)
            sigma = LIGHTING[lighting]["noise"]
            n = rng.normal(0, sigma, (self.h + self._pad, self.w + self._pad, 3)).astype(np.float32)
            self._noise[lighting] = (np.clip(n, 0, 255).astype(np.uint8), np.clip(-n, 0, 255).astype(np.uint8))
        pos, neg = self._noise[lighting]
        r = np.random.default_rng((self.seed, frame_index))
        dx, dy = (int(v) for v in r.integers(0, self._pad, 2))
        p = pos[dy:dy + self.h, dx:dx + self.w]
        n = neg[dy:dy + self.h, dx:dx + self.w]
        return cv2.subtract(cv2.add(img, p), n)

    # ------------------------------------------------------------------ labels
    def labels(self, snapshot: WorldSnapshot, min_visible_fraction: float = MIN_VISIBLE_FRACTION,
               include_dropped: bool = False) -> list[Label]:
        """Visible boxes of vehicles as rendered: the silhouette (parts) of each vehicle is drawn into an
        id buffer back to front; the label box is the bbox of the pixels each vehicle keeps and the
        visible fraction is kept pixels / full silhouette pixels (in or out of the image)."""
        ids = np.zeros((self.h, self.w), np.uint16)
        entries = []
        for k, (_dist, a) in enumerate(self._ordered(snapshot), start=1):
            kind = a.kind.value if hasattr(a.kind, "value") else str(a.kind)
            parts, _decals, _corners, uv, depth, _rot = self._actor_geometry(a)
            if np.any(depth <= NEAR_M):
                continue
            x1, y1 = uv[..., 0].min(), uv[..., 1].min()
            x2, y2 = uv[..., 0].max(), uv[..., 1].max()
            if x2 < 0 or y2 < 0 or x1 >= self.w or y1 >= self.h:
                continue
            hulls = [cv2.convexHull(np.round(uv[p] * 16).astype(np.int32)) for p in range(len(parts))
                     if parts[p].silhouette]
            for hull in hulls:
                cv2.fillConvexPoly(ids, hull, k, cv2.LINE_8, 4)
            # full silhouette area, unclipped, on an ROI canvas
            ox, oy = int(math.floor(x1)) - 1, int(math.floor(y1)) - 1
            cw, ch = int(math.ceil(x2)) - ox + 2, int(math.ceil(y2)) - oy + 2
            if cw * ch > 4_000_000:
                continue
            canvas = np.zeros((ch, cw), np.uint8)
            for hull in hulls:
                cv2.fillConvexPoly(canvas, hull - np.array([ox * 16, oy * 16], np.int32), 1, cv2.LINE_8, 4)
            full_px = int(np.count_nonzero(canvas))
            if kind == "debris":
                continue  # drawn as an occluder, not a label class
            cls = CLASS_EV if kind == "ev" and a.light_bar is not None and a.light_bar.on else CLASS_VEHICLE
            entries.append((k, a, kind, cls, full_px, (float(x1), float(y1), float(x2), float(y2))))
        out = []
        for k, a, kind, cls, full_px, full_box in entries:
            sel = ids == k
            rows = np.flatnonzero(sel.any(axis=1))
            if len(rows) == 0:
                vis, box = 0.0, (0.0, 0.0, 0.0, 0.0)
            else:
                cols = np.flatnonzero(sel[rows[0]:rows[-1] + 1].any(axis=0))
                vis = float(np.count_nonzero(sel[rows[0]:rows[-1] + 1, cols[0]:cols[-1] + 1])) / max(1, full_px)
                box = (float(cols[0]), float(rows[0]), float(cols[-1] + 1), float(rows[-1] + 1))
            if vis < min_visible_fraction and not include_dropped:
                continue
            out.append(Label(a.actor_id, kind, cls, box, min(1.0, vis), full_box))
        return out


def yolo_line(label: Label, width_px: int, height_px: int) -> str:
    """Darknet/YOLO label line ``class x_centre y_centre w h`` relative to the image (thesis 2.1)."""
    x1, y1, x2, y2 = label.bbox_px
    return (f"{label.class_id} {(x1 + x2) / 2 / width_px:.6f} {(y1 + y2) / 2 / height_px:.6f} "
            f"{(x2 - x1) / width_px:.6f} {(y2 - y1) / height_px:.6f}")
