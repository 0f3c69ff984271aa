"""Renderer of an RSU camera's view (OpenCV only, one core, no GPU).

The static scene (``sim.scenery``: sky, tree line, grass, asphalt, shoulder, lane markings, haze, street lights,
vignetting) is rendered once per camera and lighting into a cached image. Per frame: vehicles as shaded 3-D part
boxes with decals (``sim.bodies``; each actor's body model built once per look and posed, culled and shaded with a
few array operations per frame) drawn back to front (painter's order by depth), cast shadows (a LUT under
a mask), a cheap ROI glow for lamps that
are on, motion blur on vehicle ROIs when the image motion during the exposure exceeds ~1.5 px, then exposure and sensor
noise (``sim.sensor``: the static scene kept exposed at unit gain with each noise slot's noise and scaled by the
frame's gain, the pixels the frame drew on through this frame's exposure table and the slot's noise). Everything is
deterministic for a given (snapshot, frame index).

Labels (``labels``, ``sim.render.labels``) come from the same geometry: the visible part of each vehicle's silhouette
in a per-vehicle id buffer, as a box, with the visible fraction (``sim.dataset`` writes them out).
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from protocol.corridor import CameraConfig
from protocol.messages import Actor, WorldSnapshot
from protocol.road import Road
from sim.bodies import BodyModel, body_model, body_parts, ev_lamps_on
from sim.camera import NEAR_M, PinholeCamera
from sim.lamps import roof_state, signal_on
from sim.render.effects import (
    decal_paint,
    halo_falloff,
    lamp_halos,
    line_kernel,
    queue_lamp_glow,
    shade_faces,
)
from sim.render.labels import MIN_VISIBLE_FRACTION, Label, visible_labels
from sim.render.pose import (
    ActorBatch,
    actor_batch,
    blur_vectors,
    painter_order,
    pool_quads,
    pose_frame,
    shadow_outlines,
    visible_polygons,
)
from sim.scenery import LIGHTING, render_scenery, scenery_geometry
from sim.sensor import (
    GAMMA_SCALE,
    DirtyBands,
    add_noise,
    expose,
    expose_bank,
    expose_spans,
    exposure_scale,
    exposure_table,
    gamma_table,
    noise_bank,
    noise_field,
    noise_offset,
    noise_slot,
    standard_noise,
)


class Renderer:
    """Renders one camera's view of world snapshots."""

    keeps_noisy_scene = True
    """Expose and add noise through the kept noisy static scenes (``_expose_with_noise``) when both are on."""

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
        self._gamma_backgrounds: dict[str, np.ndarray] = {}
        self._noise: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        self._banks: dict[str, list[np.ndarray]] = {}
        self._glow_cache: dict[tuple, np.ndarray] = {}
        self._models: dict[tuple, BodyModel] = {}
        self._last_batch: tuple[tuple, ActorBatch] | None = None
        self._canvas: np.ndarray | None = None
        """What a frame is drawn on before its exposure (with exposure on), kept from frame to frame: the static scene
        of ``_canvas_lighting`` with the last frame's drawing (``_dirty``), which the next frame puts back."""
        self._canvas_lighting: str | None = None
        self._dirty = DirtyBands(self.h, self.w)
        """Where the current frame drew on the canvas (``sim.sensor.DirtyBands``): only there does the exposure put
        pixels through the gamma table; everywhere else it scales the static scene's gamma image."""
        self._ground_m, self._ground_t = self.cam.KR[:, :2].T, self.cam.KR @ self.cam.C
        """A road point (x, y, 0) -> homogeneous pixel: (x, y) @ _ground_m - _ground_t (made once, not per shadow)."""

    # ------------------------------------------------------------------ static scene
    def static_scenes(self) -> tuple[str, ...]:
        """The lightings whose static scene is rendered already (``background`` renders one on first use)."""
        return tuple(sorted(self._backgrounds))

    def noise_lightings(self) -> tuple[str, ...]:
        """The lightings whose sensor-noise texture is made already (``noise_textures`` makes one on first use)."""
        return tuple(sorted(self._noise))

    def background(self, lighting: str) -> np.ndarray:
        if lighting not in self._backgrounds:
            self._backgrounds[lighting] = render_scenery(self.cfg, self.cam, self.road, self.seed, lighting)
        return self._backgrounds[lighting]

    def gamma_background(self, lighting: str) -> np.ndarray:
        """The static scene through the lighting's gamma table (``sim.sensor.gamma_table``, uint16), made on first
        use: what the exposure scales wherever a frame drew nothing."""
        if lighting not in self._gamma_backgrounds:
            self._gamma_backgrounds[lighting] = cv2.LUT(self.background(lighting), gamma_table(lighting))
        return self._gamma_backgrounds[lighting]

    def prepare(self, *lightings: str) -> None:
        """Make the lightings' static scenes, gamma images and sensor-noise fields now, not at the first frame that
        needs them (``SimCamera(prerender=True)``). The static scenes share one ``sim.scenery.scenery_geometry`` and the
        noise fields one ``sim.sensor.standard_noise``, most of a lighting's cost: three lightings' static scenes take
        1.13-1.22 s of CPU instead of 2.07-2.26 s, their noise fields 0.10-0.18 s instead of 0.20-0.27 s (rsu2, 2-core
        Xeon)."""
        missing = [lighting for lighting in dict.fromkeys(lightings) if lighting not in self._backgrounds]
        if len(missing) > 1:
            geometry = scenery_geometry(self.cfg, self.cam, self.road, self.seed)
            for lighting in missing:
                self._backgrounds[lighting] = render_scenery(self.cfg, self.cam, self.road, self.seed, lighting,
                                                             geometry=geometry)
        missing_noise = [lighting for lighting in dict.fromkeys(lightings) if lighting not in self._noise]
        if self.noise_enabled and len(missing_noise) > 1:  # one N(0, 1) field scaled per lighting (sim.sensor)
            standard = standard_noise(self.seed, self.h, self.w)
            for lighting in missing_noise:
                self._noise[lighting] = noise_field(self.seed, lighting, LIGHTING[lighting]["noise"], self.h, self.w,
                                                    standard=standard)
        for lighting in lightings:
            self.background(lighting)
            if self.exposure_enabled and not (self.noise_enabled and self.keeps_noisy_scene):  # (the bank needs none)
                self.gamma_background(lighting)
            if self.noise_enabled:
                self.noise_textures(lighting)

    def _actor_geometry(self, actor: Actor):
        """Projected parts of one actor: list of (part, corners_world, uv, depth), decals, depth of centre."""
        parts, decals = body_parts(actor)
        c, s = math.cos(actor.heading_rad), math.sin(actor.heading_rad)
        rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        origin = np.array([actor.pos_x_m, actor.pos_y_m, 0.0])
        corners = np.stack([p.corners() for p in parts]) @ rot.T + origin  # (P, 8, 3)
        uv, depth = self.cam.project(corners.reshape(-1, 3))
        return parts, decals, corners, uv.reshape(len(parts), 8, 2), depth.reshape(len(parts), 8), rot

    def _ordered(self, snapshot: WorldSnapshot) -> list[Actor]:
        """Actors in view, far to near (painter's order: ``sim.render.pose.painter_order``)."""
        return [snapshot.actors[k] for k in painter_order(snapshot.actors, self.cam)]

    def _draw_headlight_pool(self, img: np.ndarray, uv16: np.ndarray, box: tuple[int, int, int, int],
                             colour: tuple) -> None:
        """Light thrown on the road ahead of a vehicle by its headlights (dusk and night): its pool's pixel quad
        (``uv16``: x 16 rounded, from the box's top-left corner) filled anti-aliased in ``colour`` on the canvas
        ``box`` (``sim.render.pose.pool_quads``: the quad's reach, with the blur's), box-blurred 7 x 7 (zeros beyond
        the box) and added to the image."""
        x1, y1, x2, y2 = box
        pool = np.zeros((y2 - y1, x2 - x1, 3), np.uint8)
        cv2.fillConvexPoly(pool, uv16, colour, cv2.LINE_AA, 4)
        self._add_at(img, cv2.blur(pool, (7, 7), dst=pool, borderType=cv2.BORDER_CONSTANT), x1, y1)  # (in place)

    def _draw_shadow(self, img: np.ndarray, box: tuple[int, int, int, int], outline16: np.ndarray,
                     strength: float) -> None:
        """Cast shadow on the road, its pixel outline x 16 (``outline16``, from its ``box``'s top-left corner:
        ``sim.render.pose.shadow_outlines``) darkened: v * round(256 (1 - strength)) >> 8 (a saturating scale
        rounded down) where the anti-aliased polygon covers more than half."""
        x1, y1, x2, y2 = box
        mask = np.zeros((y2 - y1, x2 - x1), np.uint8)
        cv2.fillConvexPoly(mask, outline16, 255, cv2.LINE_AA, 4)
        self._dirty.mark(x1, y1, x2, y2)
        cv2.threshold(mask, 127, 255, cv2.THRESH_BINARY, dst=mask)
        roi = img[y1:y2, x1:x2]
        # (v k / 256 - 0.4999 rounds to v k >> 8 for every v, k in 0..256)
        cv2.copyTo(cv2.convertScaleAbs(roi, alpha=int(256 * (1 - strength)) / 256, beta=-0.4999), mask, roi)

    # ------------------------------------------------------------------ per frame
    def _model(self, a: Actor) -> BodyModel:
        """The actor's body model, cached by everything ``body_parts`` reads (its look, not its pose)."""
        key = (a.actor_id, a.kind, a.length_m, a.width_m, a.height_m, tuple(a.colour_bgr), a.style,
               a.light_bar is not None)
        model = self._models.get(key)
        if model is None:
            if len(self._models) > 2048:
                self._models.clear()
            model = self._models[key] = body_model(a)
        return model

    def _decal_paint(self, model: BodyModel, lighting: str, brake_on: bool, red_on: bool, blue_on: bool,
                     sig_on: bool, roof: int = 0) -> tuple[list, list]:
        """Per decal, its colour this frame and the lamp it lights (``sim.render.effects.decal_paint``), kept on the
        body model per lighting and lamp states (at most 48 sets; a chasing LED strip's seven roof states
        multiply them)."""
        key = (lighting, brake_on, red_on, blue_on, sig_on, roof)
        paint = model.paint.get(key)
        if paint is None:
            paint = model.paint[key] = decal_paint(model.decals, LIGHTING[lighting], brake_on, red_on, blue_on,
                                                   sig_on, roof)
        return paint

    def _frame_start(self, snapshot: WorldSnapshot, frame_index: int | None) -> tuple:
        """A frame's lighting name, its ``LIGHTING`` entry, the frame index (from the sim time when None), the static
        scene to draw on (``_canvas_for``) and the unit vector towards the sun."""
        lighting = snapshot.lighting.value if hasattr(snapshot.lighting, "value") else str(snapshot.lighting)
        L = LIGHTING[lighting]
        if frame_index is None:
            frame_index = int(round(snapshot.sim_time_s * self.cfg.fps))
        sun = np.array(L["sun_dir"], dtype=float)
        sun /= np.linalg.norm(sun)
        return lighting, L, frame_index, self._canvas_for(lighting), sun

    def _canvas_for(self, lighting: str) -> np.ndarray:
        """The static scene of ``lighting`` to draw a frame on. Without exposure the canvas is the frame handed out:
        a new copy. With it, exposure hands out a new image, so one canvas is drawn on frame after frame, the last
        frame's drawing (``_dirty``) put back."""
        background = self.background(lighting)
        if not self.exposure_enabled:
            return background.copy()
        if self._canvas is None or self._canvas_lighting != lighting:
            self._canvas, self._canvas_lighting = background.copy(), lighting
        else:
            for y1, y2, x1, x2 in self._dirty.spans():
                self._canvas[y1:y2, x1:x2] = background[y1:y2, x1:x2]
        self._dirty.clear()
        return self._canvas

    def _expose_frame(self, img: np.ndarray, lighting: str, t_s: float, frame_index: int) -> np.ndarray:
        """The drawn canvas through the sensor: exposure and noise (``sim.sensor``)."""
        if self.exposure_enabled and self.noise_enabled and self.keeps_noisy_scene:
            return self._expose_with_noise(img, lighting, t_s, frame_index)
        if self.exposure_enabled:
            img = self._expose(img, lighting, t_s)
        if self.noise_enabled:
            slot = noise_slot(self.seed, frame_index)
            img = add_noise(img, self.noise_textures(lighting), noise_offset(self.seed, slot))
        return img

    def _noise_bank(self, lighting: str) -> list[np.ndarray]:
        """The lighting's static scene exposed at unit gain with each noise slot's noise (``sim.sensor.noise_bank``),
        made on first use (~20 ms); one lighting's at a time (22 MB at 1280x720)."""
        bank = self._banks.get(lighting)
        if bank is None:
            self._banks.clear()
            unit = cv2.LUT(self.background(lighting), exposure_table(lighting, 1 / GAMMA_SCALE))
            bank = self._banks[lighting] = noise_bank(unit, self.noise_textures(lighting), self.seed)
        return bank

    def _expose_with_noise(self, canvas: np.ndarray, lighting: str, t_s: float, frame_index: int) -> np.ndarray:
        """The exposed, noisy frame (a new image; ``sim.sensor``): the frame's noise slot's image of the static scene
        (``_noise_bank``) at this frame's gain, and where the frame drew (``_dirty``) the canvas through this frame's
        exposure table with the slot's noise added."""
        scale = exposure_scale(t_s, self.seed, lighting)
        slot = noise_slot(self.seed, frame_index)
        out = expose_bank(self._noise_bank(lighting)[slot], scale)
        return expose_spans(out, canvas, self._dirty.spans(), exposure_table(lighting, scale),
                            self.noise_textures(lighting), noise_offset(self.seed, slot))

    def _expose(self, canvas: np.ndarray, lighting: str, t_s: float) -> np.ndarray:
        """The exposed frame (a new image; ``sim.sensor``): the static scene's gamma image scaled, and where the frame
        drew (``_dirty``) the canvas through this frame's ``sim.sensor.exposure_table`` (the same values)."""
        scale = exposure_scale(t_s, self.seed, lighting)
        out = expose(self.gamma_background(lighting), scale)
        return expose_spans(out, canvas, self._dirty.spans(), exposure_table(lighting, scale))

    def render(self, snapshot: WorldSnapshot, frame_index: int | None = None) -> np.ndarray:
        """BGR image (h, w, 3) of the snapshot; deterministic for (snapshot, frame_index).

        The cached static scene, then per actor its cast shadow and headlight pool (all actors, far to near), then
        per actor (far to near) its contact shadow, visible faces, decals and lamps and motion blur, then the halos of
        the lamps no nearer vehicle hides (``sim.render.effects.hidden_lamps``), exposure and noise: the reference renderer's
        drawing (``bench.render_reference``) with each actor's body model built once (``sim.bodies.body_model``), the
        snapshot's models concatenated once (``sim.render.pose.ActorBatch``) and posed, culled and shaded with a few
        array operations for all actors (``sim.render.pose``)."""
        lighting, L, frame_index, img, sun = self._frame_start(snapshot, frame_index)
        t = snapshot.sim_time_s
        actors = snapshot.actors
        order = painter_order(actors, self.cam)
        if not order:
            return self._expose_frame(img, lighting, t, frame_index)
        batch = self._batch([self._model(a) for a in actors])
        pose = pose_frame(batch, actors, self.cam)
        near, lo, hi = pose.near, pose.lo, pose.hi
        w, h = self.w, self.h
        drawn = [k for k in order if near[k] > NEAR_M and not (hi[k][0] < -200 or hi[k][1] < 0 or lo[k][0] >= w + 200
                                                                or lo[k][1] >= h)]  # (shadows may reach the image)
        cast = L["sun"] > 0.05 and self.shadows
        outlines = (shadow_outlines(batch, pose, drawn, sun, self.cam, self._ground_m, self._ground_t)
                    if cast else {})
        pools = L["running_lights"]
        if pools:
            pool_uv16, pool_boxes = pool_quads(pose, self.cam)
            pool_colour = tuple(int(v * (1.0 if lighting == "night" else 0.4)) for v in (70, 95, 110))
        strength = 0.45 * L["sun"] / 0.55
        for k in drawn:
            if k in outlines:
                self._draw_shadow(img, *outlines[k], strength)
            if pools and pool_boxes[k] is not None and actors[k].kind.value != "debris":
                self._draw_headlight_pool(img, pool_uv16[k], pool_boxes[k], pool_colour)
        drawn = [k for k in drawn if hi[k][0] >= 0 and lo[k][0] < w]  # (in view, not only their shadows)
        if not drawn:
            return self._expose_frame(img, lighting, t, frame_index)
        blurs = blur_vectors(pose, L["exposure_s"]) if self.blur_enabled else None
        vis, colours = shade_faces(batch, pose.rots, pose.positions, self.cam.C, L, sun)
        polygons = visible_polygons(batch, pose, vis, colours)
        faces, face_colours, face_start = polygons.faces, polygons.colours, polygons.face_start
        seen, decal_quads, seen_start = polygons.decals, polygons.decal_quads, polygons.decal_seen_start
        uv, uv16, point_start, decal_start = pose.uv, pose.uv16, batch.point_start, batch.decal_start.tolist()
        lamps: list[tuple[int, tuple, float]] = []  # lit lamp faces: (first point, colour, strength)
        lamp_ranks: list[int] = []  # each one's vehicle's place in ``drawn``
        bars: dict[tuple[int, str], list] = {}  # per (place, lamp): [first points, colour, strength]
        fill = cv2.fillConvexPoly
        for place, k in enumerate(drawn):
            a, model = actors[k], batch.models[k]
            parts, decals = model.parts, model.decals
            box = pose.box[k]
            self._dirty.mark(box[0] - 2, box[1] - 2, box[2] + 3, box[3] + 3)  # (anti-aliased edges reach 1 px out)
            end = point_start[k + 1]
            fill(img, uv16[end - 4:end], (16, 16, 16), cv2.LINE_AA, 4)  # contact shadow
            for f in range(face_start[k], face_start[k + 1]):
                fill(img, faces[f], face_colours[f], cv2.LINE_AA, 4)
            colours, lit = self._decal_paint(model, lighting, a.brake_on, *ev_lamps_on(a.light_bar, t),
                                             signal_on(a.style, t), roof_state(a.style, t))
            d0, q0, bar_part, n_lamps = decal_start[k], point_start[k] + 8 * len(parts), len(parts) - 1, len(lamps)
            for j in range(seen_start[k], seen_start[k + 1]):
                k_dc = seen[j] - d0
                colour = colours[k_dc]
                if colour is None:
                    continue  # a turn signal that is off: the tail light under it shows
                fill(img, decal_quads[j], colour, cv2.LINE_AA, 4)
                lamp = lit[k_dc]
                if lamp is not None:
                    queue_lamp_glow(lamps, bars, (place, lamp), lamp, decals[k_dc].part == bar_part, a.brake_on,
                                    q0 + 4 * k_dc, colour)
            lamp_ranks.extend([place] * (len(lamps) - n_lamps))
            if blurs is not None and blurs[k] is not None:
                self._motion_blur(img, (*lo[k], *hi[k]), blurs[k])
        if lamps or bars:
            self._draw_halos(img, lamp_halos(uv, lamps, lamp_ranks, bars,
                                             np.array([(*lo[k], *hi[k]) for k in drawn], float),
                                             [batch.silhouettes[k] for k in drawn], L["glow"]))
        return self._expose_frame(img, lighting, t, frame_index)

    def _batch(self, models: list[BodyModel]) -> ActorBatch:
        """The ``sim.render.pose.ActorBatch`` of a snapshot's body models, kept while its actors keep their looks
        (the last one)."""
        key = tuple(map(id, models))
        if self._last_batch is None or self._last_batch[0] != key:
            self._last_batch = (key, actor_batch(models))
        return self._last_batch[1]

    def _motion_blur(self, img: np.ndarray, bounds: tuple[float, float, float, float], vec: np.ndarray) -> None:
        """Blur a vehicle's ROI (``bounds``: x_lo, y_lo, x_hi, y_hi of its corners' pixels) along its image
        motion during the exposure: a normalised line kernel of ceil(|vec|) + 1 samples (at most 26)."""
        box = self._blur_box(bounds, vec)
        if box is None:
            return
        x1, y1, x2, y2 = box
        self._dirty.mark(x1, y1, x2, y2)
        k, anchor = line_kernel(vec)
        roi = img[y1:y2, x1:x2]
        roi[:] = cv2.filter2D(roi, -1, k, anchor=anchor, borderType=cv2.BORDER_REPLICATE)

    def _blur_box(self, bounds: tuple[float, float, float, float], vec: np.ndarray) -> tuple[int, int, int, int] | None:
        """The ROI (x1, y1, x2, y2) a motion blur of ``vec`` reaches around ``bounds`` (x_lo, y_lo, x_hi, y_hi px):
        min(25, ceil(|vec|)) + 2 px beyond them, cut to the image; None when under 3 px either way."""
        pad = int(min(25, math.ceil(float(np.hypot(*vec))))) + 2
        x1, x2 = max(0, int(bounds[0]) - pad), min(self.w, int(bounds[2]) + pad)
        y1, y2 = max(0, int(bounds[1]) - pad), min(self.h, int(bounds[3]) + pad)
        return None if x2 - x1 < 3 or y2 - y1 < 3 else (x1, y1, x2, y2)

    def _add_at(self, img: np.ndarray, patch: np.ndarray, x1: int, y1: int) -> None:
        """Saturated add of ``patch`` into the image with its top-left corner at (x1, y1), cut to the image."""
        ox1, oy1 = max(0, x1), max(0, y1)
        ox2, oy2 = min(self.w, x1 + patch.shape[1]), min(self.h, y1 + patch.shape[0])
        if ox2 <= ox1 or oy2 <= oy1:
            return
        self._dirty.mark(ox1, oy1, ox2, oy2)
        roi = img[oy1:oy2, ox1:ox2]
        cv2.add(roi, patch[oy1 - y1:oy2 - y1, ox1 - x1:ox2 - x1], dst=roi)

    def _glow_sprite(self, r: int, colour: tuple, with_core: bool, core_r: int) -> np.ndarray:
        """Cached halo sprite (4r+1 square): a Gaussian falloff times the lamp colour, optional hot core."""
        key = (r, colour, with_core, core_r)
        sprite = self._glow_cache.get(key)
        if sprite is None:
            sprite = np.clip(halo_falloff(r) * np.array(colour, np.float32), 0, 255).astype(np.uint8)
            if with_core:
                cv2.circle(sprite, (2 * r, 2 * r), core_r, (235, 235, 255), -1, cv2.LINE_AA)
            if len(self._glow_cache) >= 512:  # the oldest goes: a moving lamp's sprites change a few at a time
                del self._glow_cache[next(iter(self._glow_cache))]
            self._glow_cache[key] = sprite
        return sprite

    def _draw_halos(self, img: np.ndarray, halos: list[tuple]) -> None:
        """Additive halos around lamps that are on (bloom: ``sim.render.effects.halo_numbers``), from cached sprites on
        small ROIs only."""
        for cx, cy, r, col, hot, core in halos:
            sprite = self._glow_cache.get((r, col, hot, core))
            if sprite is None:
                sprite = self._glow_sprite(r, col, hot, core)
            self._add_at(img, sprite, cx - 2 * r, cy - 2 * r)

    def noise_textures(self, lighting: str) -> tuple[np.ndarray, np.ndarray]:
        """The lighting's sensor-noise texture, a Gaussian field (positive and negative parts, uint8) a little larger
        than the image (``sim.sensor.noise_field``), generated on first use (~0.1 s: ``prepare`` does it)."""
        if lighting not in self._noise:
            self._noise[lighting] = noise_field(self.seed, lighting, LIGHTING[lighting]["noise"], self.h, self.w)
        return self._noise[lighting]

    # ------------------------------------------------------------------ labels
    def labels(self, snapshot: WorldSnapshot, min_visible_fraction: float = MIN_VISIBLE_FRACTION,
               include_dropped: bool = False) -> list[Label]:
        """Visible boxes of vehicles as rendered (``sim.render.labels.visible_labels``)."""
        return visible_labels(self, snapshot, min_visible_fraction, include_dropped)
