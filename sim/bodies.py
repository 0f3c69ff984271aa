"""Vehicle bodies for the renderer (``sim.render.renderer``): each actor as shaded 3-D part boxes in its own frame (lower
body, glass cabin, cargo box, light bar, a works vehicle's beacon; debris shapes) with decals (windows, tail and
brake lights, liveries, EV lamps, hazard flashers, turn signals, beacons and LED strips: ``sim.lamps``), derived
from the ``Actor`` fields (kind, size, colour_bgr, brake_on, light_bar and ``style``: ``sim.vehicles``)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from protocol.messages import Actor
from sim.lamps import BEACON_OFF_BGR, LED_OFF_BGR, LED_SEGMENTS, signal_decals, style_roof
from sim.vehicles import (
    LIVERY_AMBULANCE,
    LIVERY_POLICE,
    LIVERY_TWO_TONE,
    LIVERY_WORKS,
    style_detail,
    style_livery,
)

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
FACES = {
    "rear": ((1, 0, 4, 5), (-1.0, 0.0, 0.0)),
    "front": ((3, 2, 6, 7), (1.0, 0.0, 0.0)),
    "left": ((2, 1, 5, 6), (0.0, 1.0, 0.0)),
    "right": ((0, 3, 7, 4), (0.0, -1.0, 0.0)),
    "top": ((4, 7, 6, 5), (0.0, 0.0, 1.0)),
}


FACE_NAMES = tuple(FACES)
FACE_IDX = np.array([FACES[f][0] for f in FACE_NAMES])


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
    lamp: str = ""  # "", "tail", "ev_red", "ev_blue", "hazard", "turn", "beacon", "led_blue", "led_white" (sim.lamps)
    segment: int = 0
    """An LED strip's segment along its face (``sim.lamps.roof_segment_lit``)."""




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


def debris_parts(shape_index: int, detail: int, L: float, W: float, H: float, body: np.ndarray) -> list[Part]:
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


def body_parts(actor: Actor) -> tuple[list[Part], list[Decal]]:
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
        return debris_parts(livery, detail, L, W, H, body), decals
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
    if livery == LIVERY_WORKS and kind in ("van", "truck"):
        chevron_part = 1
        for j in range(6):  # red and yellow stripes across the lower rear
            decals.append(Decal(chevron_part, "rear", j / 6, (j + 1) / 6, 0.05, 0.4,
                                np.array([40, 35, 200.0]) if j % 2 == 0 else np.array([30, 215, 245.0])))
    roof_lamps = style_roof(actor.style)
    if roof_lamps is not None and roof_lamps.mode == "beacon" and kind in ("car", "van", "truck"):
        bx = {"car": (-0.2, 0.2), "van": (hl * 0.62 - 0.4, hl * 0.62 - 0.1),
              "truck": (hl * 0.7 - 0.5, hl * 0.7 - 0.15)}[kind]
        i = len(parts)  # the last part, like a light bar: its lit faces share one halo
        parts.append(Part(bx[0], bx[1], -hw * 0.75, hw * 0.75, top_z, top_z + 0.15, DARK_BGR))
        for face in ("rear", "front", "left", "right", "top"):
            decals.append(Decal(i, face, 0.04, 0.96, 0.12, 0.92, BEACON_OFF_BGR, "beacon"))
    elif roof_lamps is not None and roof_lamps.mode != "beacon" and kind == "bus":
        lamp = "led_white" if roof_lamps.white else "led_blue"
        # face: (u span, v span): the strips along the roof edge, the destination boards front and rear
        for face, (u0, u1), (v0, v1) in (("left", (0.03, 0.97), (0.9, 0.96)), ("right", (0.03, 0.97), (0.9, 0.96)),
                                         ("front", (0.15, 0.85), (0.91, 0.98)), ("rear", (0.25, 0.75), (0.88, 0.95))):
            step = (u1 - u0) / LED_SEGMENTS
            for j in range(LED_SEGMENTS):  # u seen from outside: front to back on the left face, back to front on
                seg = j if face in ("left", "front") else LED_SEGMENTS - 1 - j  # the right: the chase runs backwards
                decals.append(Decal(1, face, u0 + j * step, u0 + (j + 0.9) * step, v0, v1, LED_OFF_BGR, lamp, seg))
    tails = [(dc.part, dc.u0, dc.u1, dc.v0, dc.v1) for dc in decals if dc.lamp == "tail"]
    decals.extend(Decal(*fields) for fields in signal_decals(kind, actor.style, tails))
    return parts, decals


def face_points(corners: np.ndarray, face: str, u0: float, u1: float, v0: float, v1: float) -> np.ndarray:
    """World points of a (u, v) sub-rectangle of a box face (corners (8, 3) of the part)."""
    a, b, c, d = corners[FACES[face][0], :]  # a bottom-left, b bottom-right, c top-right, d top-left
    u = np.array([[u0], [u1], [u1], [u0]])
    v = np.array([[v0], [v0], [v1], [v1]])
    bottom = a + (b - a) * u
    return bottom + (d + (c - d) * u - bottom) * v




@dataclass
class BodyModel:
    """An actor's body in its own frame, built once per look (``body_model``) and posed per frame by the renderer:
    part corners, each part face's outward unit normal and centre, base colours, decal quads and the contact-shadow
    footprint (the lower body's bottom grown 8 %), stacked so one matrix product poses and projects them all."""

    parts: list[Part]
    decals: list[Decal]
    points: np.ndarray  # (8P + 4D + 4, 3): part corners, decal quads, contact footprint
    normals: np.ndarray  # (P, 5, 3) outward unit normals of the faces (FACE_NAMES order)
    centres: np.ndarray  # (P, 5, 3) face centres
    face_ok: np.ndarray  # (P, 5) the face has an area
    base_bgr: np.ndarray  # (P, 5, 3) colour before shading: top colour on top faces, side colour elsewhere
    glass: np.ndarray  # (P, 5) glass faces (shaded brighter)
    top: np.ndarray  # (P, 5) top faces
    decal_part: np.ndarray  # (D,) part index of each decal
    decal_face: np.ndarray  # (D,) face index (FACE_NAMES) of each decal
    face_points: np.ndarray  # (P, 5, 4) each part face's corners: indices into ``points``
    decal_points: np.ndarray  # (D, 4) each decal quad's corners: indices into ``points``
    paint: dict[tuple, tuple] = field(default_factory=dict)  # per lighting and lamp states, the decals' colours (renderer's)


def body_model(actor: Actor) -> BodyModel:
    """``body_parts`` of ``actor`` with the geometry the renderer needs, in the vehicle frame."""
    parts, decals = body_parts(actor)
    corners = np.stack([p.corners() for p in parts])  # (P, 8, 3)
    fc = corners[:, FACE_IDX]  # (P, 5, 4, 3)
    a, b, d = fc[:, :, 0], fc[:, :, 1], fc[:, :, 3]
    n = np.cross(b - a, d - a)
    norm = np.linalg.norm(n, axis=-1, keepdims=True)
    n = n / np.where(norm > 1e-9, norm, 1.0)
    centres = fc.mean(axis=2)
    n = np.where((np.sum(n * (centres - corners.mean(axis=1)[:, None, :]), axis=-1) < 0)[..., None], -n, n)
    top = np.zeros((len(parts), len(FACE_NAMES)), bool)
    top[:, FACE_NAMES.index("top")] = True
    base = np.empty((len(parts), len(FACE_NAMES), 3))
    glass = np.zeros_like(top)
    for i, p in enumerate(parts):
        side = p.side_colour if p.side_colour is not None else p.colour
        up = p.top_colour if p.top_colour is not None else p.colour
        for f in range(len(FACE_NAMES)):
            col = up if top[i, f] else side
            base[i, f] = col
            glass[i, f] = col is GLASS_BGR
    quads = [face_points(corners[dc.part], dc.face, dc.u0, dc.u1, dc.v0, dc.v1) for dc in decals]
    foot = corners[0, :4]
    foot = foot.mean(axis=0) + (foot - foot.mean(axis=0)) * 1.08
    points = np.concatenate([corners.reshape(-1, 3), *quads, foot])
    return BodyModel(parts, decals, points, n, centres, norm[..., 0] > 1e-9, base, glass, top,
                     np.array([dc.part for dc in decals], dtype=int),
                     np.array([FACE_NAMES.index(dc.face) for dc in decals], dtype=int),
                     8 * np.arange(len(parts))[:, None, None] + FACE_IDX,
                     (8 * len(parts) + np.arange(4 * len(decals))).reshape(-1, 4))
