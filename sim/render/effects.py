"""Pure per-frame numbers of the renderer (computed with a few array operations, not a Python loop per
lamp, kernel tap or actor), kept apart from ``sim.render.renderer`` so they can be tested alone."""

from __future__ import annotations

import math
from collections.abc import Callable
from functools import cache, lru_cache
from typing import TYPE_CHECKING

import cv2
import numpy as np

from sim.bodies import BLUE_LAMP_BGR, RED_LAMP_BGR, TAIL_OFF_BGR, TAIL_ON_BGR
from sim.lamps import (
    AMBER_ON_BGR,
    BEACON_GLOW,
    BEACON_ON_BGR,
    LED_BLUE_BGR,
    LED_GLOW,
    LED_WHITE_BGR,
    ROOF_LAMPS,
    SIGNAL_GLOW,
    SIGNAL_LAMPS,
    TURN_ON_BGR,
    roof_segment_lit,
)

if TYPE_CHECKING:
    from sim.render.pose import ActorBatch


def line_kernel(vec: np.ndarray) -> tuple[np.ndarray, tuple[int, int]]:
    """Motion-blur kernel for an image motion ``vec`` (px) during the exposure: n + 1 = min(25, ceil(|vec|)) + 1
    samples along the line through the centre of a (2n + 1)^2 grid, normalised; returned as the line's bounding box
    with the anchor (x, y) of the grid's centre in it, the same correlation as the full grid (which OpenCV would
    apply by DFT: a 51 x 51 kernel cost 4 ms a frame at night). The taps are plain floats rounded half to even as
    ``np.round`` does, and the kernel is made once per set of taps (``_taps_kernel``; they repeat from frame to
    frame): 7 us a kernel against 24-35 us with numpy arrays (2-core Xeon)."""
    vx, vy = float(vec[0]), float(vec[1])
    length = math.hypot(vx, vy)
    n = int(min(25, math.ceil(length)))
    dx, dy = vx / max(1e-6, length), vy / max(1e-6, length)
    top = 2 * n
    taps = tuple((min(top, max(0, round(n + dx * (i - n / 2)))), min(top, max(0, round(n + dy * (i - n / 2)))))
                 for i in range(n + 1))
    return _taps_kernel(n, taps)


@lru_cache(maxsize=1024)
def _taps_kernel(n: int, taps: tuple[tuple[int, int], ...]) -> tuple[np.ndarray, tuple[int, int]]:
    """The normalised kernel (float32, read-only) of ``line_kernel``'s taps (x, y) on the (2n + 1)^2 grid, cut to
    their bounding box, and the grid centre's anchor in it."""
    xs, ys = [x for x, _y in taps], [y for _x, y in taps]
    c0, r0 = min(xs), min(ys)
    k = np.zeros((max(ys) - r0 + 1, max(xs) - c0 + 1), np.float32)
    np.add.at(k, (np.array(ys) - r0, np.array(xs) - c0), 1.0)
    k /= k.sum()
    k.flags.writeable = False
    return k, (n - c0, n - r0)


@cache
def halo_falloff(r: int) -> np.ndarray:
    """A halo's Gaussian falloff on its (4r+1)-square sprite, sigma 0.75 r, float32 (4r+1, 4r+1, 1), read-only: made
    once per radius (a sprite's colour changes with its lamp's strength, its falloff does not: a new colour then
    costs one multiply, not the exponential)."""
    yy, xx = np.mgrid[-2 * r:2 * r + 1, -2 * r:2 * r + 1].astype(np.float32)
    fall = np.exp(-(xx ** 2 + yy ** 2) / (2 * (0.75 * r) ** 2))[..., None]
    fall.flags.writeable = False
    return fall


def halo_numbers(quads: np.ndarray, quad_colours: list, quad_strengths: list[float], bars: list[tuple], scale: float
                 ) -> list[tuple]:
    """Per lamp that is on, its halo: (centre x, y in whole pixels, radius r = clip(0.55 size scale, 3, 60) with
    size = max(2, the points' extent), colour times min(1, strength (0.6 + 0.25 scale)) truncated, hot core when
    strength >= 1, core radius max(1, size / 12)). The lamps: four-point faces (``quads`` (G, 4, 2) px, each with
    its colour BGR and strength), computed together, and light bars (``bars``: per bar its faces' points (4k, 2),
    colour and strength), whose halo spans their faces. Saturated adds commute, so the halos come in any order."""
    centres, sizes = [], []
    if len(quads):
        centres.append(quads.sum(axis=1) * 0.25)  # (the mean's values; np.mean and np.ptp cost more per call)
        sizes.append((quads.max(axis=1) - quads.min(axis=1)).max(axis=1))
    for pts, _c, _s in bars:
        centres.append(pts.sum(axis=0, keepdims=True) / len(pts))
        sizes.append((pts.max(axis=0) - pts.min(axis=0)).max(keepdims=True))
    if not centres:
        return []
    centres, sizes = np.concatenate(centres), np.maximum(2.0, np.concatenate(sizes))
    radii = np.clip(sizes * 0.55 * scale, 3, 60).astype(int).tolist()
    strengths = np.array([*quad_strengths, *(st for _p, _c, st in bars)], float)
    cols = (np.array([*quad_colours, *(c for _p, c, _s in bars)], float)
            * np.minimum(1.0, strengths * (0.6 + 0.25 * scale))[:, None]).astype(int).tolist()
    cores = np.maximum(1, (sizes / 12).astype(int)).tolist()
    return [(cx, cy, r, tuple(col), hot, core) for (cx, cy), r, col, hot, core in
            zip(np.round(centres).astype(int).tolist(), radii, cols, (strengths >= 1.0).tolist(), cores, strict=True)]


def shade_faces(batch: ActorBatch, rots: np.ndarray, positions: np.ndarray, camera_centre: np.ndarray, lighting: dict,
                sun: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The part faces of every actor of ``batch`` (a ``sim.render.pose.ActorBatch``; per actor its rotation 3x3 in
    ``rots`` and its (x, y, 0) in ``positions``, m), together: which face the camera ((S, 5) bool over the S parts of
    all) and their shaded colours ((S, 5, 3) BGR floats: base colour x (ambient + sun max(0, n . sun)), glass
    0.6 + 0.5 shade (x 1.3 on top), x the scene gain, clipped)."""
    rots_t = rots.transpose(0, 2, 1)[batch.part_owner]  # (S, 3, 3)
    n_w = batch.normals @ rots_t
    fc_w = batch.centres @ rots_t + positions[batch.part_owner][:, None, :]
    vis = (np.sum(n_w * (camera_centre - fc_w), axis=-1) > 0) & batch.face_ok
    shade = lighting["ambient"] + lighting["sun"] * np.maximum(0.0, n_w @ sun)
    shade = np.where(batch.glass, 0.6 + 0.5 * shade * np.where(batch.top, 1.3, 1.0), shade)
    return vis, np.clip(batch.base_bgr * shade[..., None] * lighting["scene_gain"], 0, 255)


def queue_lamp_glow(glows: list, bar_halos: dict, key: tuple, lamp: str, on_bar: bool, brake_on: bool, face,
                    colour) -> None:
    """Queue the halo of a lit lamp face (``face``: its pixel points, or what stands for them: ``sim.render.renderer`` passes
    its first point's index) with its strength (1 for an EV lamp, ``BEACON_GLOW`` for a beacon, ``SIGNAL_GLOW`` for a
    flasher or turn signal, ``LED_GLOW`` for an LED segment, 0.55 / 0.3 for a tail lamp braking / not): in ``glows``
    as (face, colour, strength), or, the faces of one light-bar colour or beacon (``on_bar``: an EV lamp or a beacon
    on the body's last part), gathered under ``key`` in ``bar_halos`` as [faces, colour, strength]: they share one
    halo."""
    strength = (1.0 if lamp.startswith("ev") else BEACON_GLOW if lamp == "beacon" else SIGNAL_GLOW
                if lamp in SIGNAL_LAMPS else LED_GLOW if lamp.startswith("led") else (0.55 if brake_on else 0.3))
    if (lamp.startswith("ev") or lamp == "beacon") and on_bar:
        bar = bar_halos.get(key)
        if bar is None:
            bar_halos[key] = [[face], colour, strength]
        else:
            bar[0].append(face)
    else:
        glows.append((face, colour, strength))


def shadow_hull(corners: np.ndarray, sun: np.ndarray) -> np.ndarray:
    """A cast shadow's outline on the road: the convex hull (K, 2) of the points (N, 3) projected along the unit
    vector ``sun`` onto z = 0 (the sun's height taken as at least 0.25, so low sun makes long, bounded shadows)."""
    ground = corners[:, :2] - corners[:, 2:3] * (sun[:2] / max(sun[2], 0.25))
    return cv2.convexHull(ground.astype(np.float32)).reshape(-1, 2)


def lit_bgr(lamp: str | None, tail_bright: bool, brake_on: bool, red_on: bool, blue_on: bool, sig_on: bool,
            roof: int = 0, segment: int = 0):
    """The colour of a decal's lamp when it is lit this frame, else None (the decal shows its unlit colour): a tail
    lamp when ``tail_bright`` (braking, or running lights at dusk and night), brighter when braking; the light bar's
    red and blue halves as they flash; the flashers (amber) and turn signals (red) as they blink; a beacon (amber)
    and an LED strip's segments (blue or white) as the roof lamps' state ``roof`` lights them
    (``sim.lamps.roof_state``, ``roof_segment_lit``)."""
    if lamp == "tail":
        return (TAIL_ON_BGR if brake_on else (50, 50, 200)) if tail_bright else None
    if lamp == "ev_red" and red_on:
        return RED_LAMP_BGR
    if lamp == "ev_blue" and blue_on:
        return BLUE_LAMP_BGR
    if lamp in SIGNAL_LAMPS and sig_on:
        return AMBER_ON_BGR if lamp == "hazard" else TURN_ON_BGR
    if roof and lamp in ROOF_LAMPS and roof_segment_lit(roof, segment):
        return BEACON_ON_BGR if lamp == "beacon" else LED_BLUE_BGR if lamp == "led_blue" else LED_WHITE_BGR
    return None


def decal_paint(decals: list, lighting: dict, brake_on: bool, red_on: bool, blue_on: bool, sig_on: bool,
                roof: int = 0) -> tuple[list, list]:
    """Per decal of a body (``sim.bodies.BodyModel.decals``), the colour it is drawn in this frame (a BGR tuple:
    ``lit_bgr`` when its lamp is lit, else ``unlit_bgr``; None for a turn signal that is off, which is not drawn: the
    tail light under it shows) and the lamp it lights (its name, or None), given the ``lighting`` (a
    ``sim.scenery.LIGHTING`` entry) and the actor's lamp states. A pure function of these: ``sim.render.renderer`` keeps it
    per body model and states (the per-decal tests cost ~0.15 ms a frame)."""
    tail_bright = brake_on or bool(lighting["running_lights"])
    colours: list[tuple | None] = []
    lamps: list[str | None] = []
    for dc in decals:
        if dc.lamp == "turn" and not sig_on:
            colours.append(None)
            lamps.append(None)
            continue
        colour = lit_bgr(dc.lamp, tail_bright, brake_on, red_on, blue_on, sig_on, roof, dc.segment) if dc.lamp else None
        colours.append(tuple(unlit_bgr(dc.colour, dc.lamp, lighting)) if colour is None else colour)
        lamps.append(None if colour is None else dc.lamp)
    return colours, lamps


def unlit_bgr(colour, lamp: str | None, lighting: dict) -> list:
    """A decal's colour when not lit, in ``lighting`` (a ``sim.scenery.LIGHTING`` entry), BGR list: a tail lamp's
    dark lens x gain x 1.1; any other decal's colour x (0.85 for a lamp) x (ambient + sun / 2) x gain x 1.3."""
    gain = lighting["scene_gain"]
    if lamp == "tail":
        return np.clip(TAIL_OFF_BGR * gain * 1.1, 0, 255).tolist()
    return np.clip(np.asarray(colour, dtype=float) * (0.85 if lamp else 1.0)
                   * (lighting["ambient"] + 0.5 * lighting["sun"]) * gain * 1.3, 0, 255).tolist()


def hidden_lamps(faces: np.ndarray, counts: list[int], ranks: list[int], bounds: np.ndarray,
                 silhouettes: Callable[[int], np.ndarray]) -> list[bool]:
    """Which lit lamps are hidden behind nearer vehicles, so that they throw no halo. The lamps' face quads in
    pixels (F, 4, 2), lamp by lamp: ``counts[i]`` faces of lamp i, whose vehicle has place ``ranks[i]`` in the
    painter's order (far to near); per vehicle in that order, its pixel bounds (x_lo, y_lo, x_hi, y_hi) in
    ``bounds`` (A, 4) and its silhouette parts' projected corners (P, 8, 2) from ``silhouettes(place)`` (asked only
    for the vehicles a test needs). A lamp is hidden when the centre of every one of its faces lies inside a part of
    a vehicle drawn after it: one bounds test for all faces and vehicles, then ``inside_convex_hulls`` for every
    (face, part) pair that test leaves, together (a hull and a point test per pair cost 0.2 ms a frame,
    these 0.16). A halo is the lens's image of a lamp it sees: without this test a hidden EV's light bar glowed
    through the bus in front of it (simulator, ev_bench tuning seed 80442, rsu4: a false alert on the bus)."""
    if not counts:
        return []
    centres = faces.sum(axis=1) * 0.25  # (F, 2): their means
    face_ranks = np.repeat(ranks, counts)
    bounds = np.asarray(bounds, float).reshape(-1, 4)
    inside = ((centres[:, :1] >= bounds[:, 0]) & (centres[:, :1] <= bounds[:, 2]) & (centres[:, 1:] >= bounds[:, 1])
              & (centres[:, 1:] <= bounds[:, 3]) & (np.arange(len(bounds)) > face_ranks[:, None]))  # (F, A)
    pair_faces, vehicles = np.nonzero(inside)
    covered = np.zeros(len(centres), bool)
    if len(pair_faces):
        wanted = sorted(set(vehicles.tolist()))
        parts = [silhouettes(a) for a in wanted]
        count = np.zeros(len(bounds), int)
        count[wanted] = [len(p) for p in parts]
        first = np.cumsum(count) - count  # each wanted vehicle's first part in the concatenation
        n = count[vehicles]  # per (face, vehicle) pair, its vehicle's parts
        pair = np.repeat(np.arange(len(pair_faces)), n)
        part = first[vehicles][pair] + np.arange(len(pair)) - np.repeat(np.cumsum(n) - n, n)
        hit = inside_convex_hulls(centres[pair_faces[pair]], np.concatenate(parts)[part])
        covered[pair_faces[pair[hit]]] = True
    return np.logical_and.reduceat(covered, np.cumsum([0, *counts[:-1]])).tolist()  # (every lamp has a face)


def lamp_halos(uv: np.ndarray, lamps: list[tuple[int, tuple, float]], ranks: list[int], bars: dict,
               bounds: np.ndarray, silhouettes: list[np.ndarray], scale: float) -> list[tuple]:
    """The halos (``halo_numbers``) of a frame's lit lamps that no nearer vehicle hides (``hidden_lamps``), all
    together. The lamps as ``queue_lamp_glow`` gathers them, each face standing as its first point's index in the
    frame's pixels ``uv``: ``lamps`` (face, colour, strength) with their vehicles' places in the drawing order
    (``ranks``), and the light ``bars`` (per (place, lamp) its faces, colour and strength); per drawn vehicle its
    pixel ``bounds`` and its silhouette parts' corners' indices into ``uv``."""
    bar_list = list(bars.items())
    firsts = [q for q, _c, _s in lamps] + [q for _key, (qs, _c, _s) in bar_list for q in qs]
    faces = uv[np.array(firsts)[:, None] + np.arange(4)]  # (F, 4, 2)
    counts = [1] * len(lamps) + [len(qs) for _key, (qs, _c, _s) in bar_list]
    hidden = hidden_lamps(faces, counts, ranks + [place for (place, _l), _v in bar_list], bounds,
                          lambda k: uv[silhouettes[k]])
    n = len(lamps)
    seen = [i for i in range(n) if not hidden[i]]
    visible_bars, start = [], n
    for j, (_key, (qs, colour, strength)) in enumerate(bar_list):
        if not hidden[n + j]:
            visible_bars.append((faces[start:start + len(qs)].reshape(-1, 2), colour, strength))
        start += len(qs)
    return halo_numbers(faces[seen], [lamps[i][1] for i in seen], [lamps[i][2] for i in seen], visible_bars, scale)


def inside_convex_hulls(points: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """Per point (M, 2), whether it lies strictly inside the convex hull of its corners (M, K, 2), without making the
    hulls: a point is inside exactly when the directions from it to the corners leave no angular gap of pi or more
    (else a line through it has every corner on one side). (M,) bool."""
    d = corners - points[:, None, :]
    angles = np.sort(np.arctan2(d[..., 1], d[..., 0]), axis=1)  # (M, K)
    gaps = np.diff(angles, axis=1, append=angles[:, :1] + 2 * np.pi)
    return gaps.max(axis=1) < np.pi
