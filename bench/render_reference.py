"""The straightforward renderer (each actor's parts built, transformed and shaded from scratch per frame, each cast
shadow darkened with numpy): the reference that ``sim.render.renderer.Renderer``'s cached fast path is tested and
benchmarked against (same pixels within noise), headlight pools and lamp halos included. Not used by the corridor."""

from __future__ import annotations

import math

import cv2
import numpy as np

from protocol.messages import Actor, WorldSnapshot
from sim.bodies import FACE_IDX, FACE_NAMES, FACES, GLASS_BGR, ev_lamps_on, face_points
from sim.camera import NEAR_M
from sim.lamps import roof_state, signal_on
from sim.render.effects import lit_bgr, queue_lamp_glow, shadow_hull, unlit_bgr
from sim.render.renderer import Renderer
from sim.scenery import LIGHTING
from sim.sensor import exposure_lut


class ReferenceRenderer(Renderer):
    """``Renderer`` with per-frame drawing from scratch: the reference for the fast path's tests and bench."""

    keeps_noisy_scene = False  # the exposure table over the whole frame, then the noise (the plain sensor model)

    @staticmethod
    def _visible_faces(parts, corners, C) -> list[dict[str, np.ndarray]]:
        """Per part, the faces that face the camera (back-face culling) with their outward unit normals."""
        fc_all = corners[:, FACE_IDX]  # (P, 5, 4, 3)
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
        return [{FACE_NAMES[f]: n[p, f] for f in np.flatnonzero(vis[p])} for p in range(len(parts))]

    def _polygon_mask(self, uv: np.ndarray) -> tuple[tuple[int, int, int, int], np.ndarray] | None:
        """The polygon ``uv`` (K, 2 px) filled anti-aliased (0-255) on its box (x1, y1, x2, y2: floor to ceil + 1,
        cut to the image); None when the box is under 2 px either way."""
        us, vs = uv[:, 0].tolist(), uv[:, 1].tolist()  # a few points: plain floats beat numpy's per-call cost
        x1, y1 = max(0, math.floor(min(us))), max(0, math.floor(min(vs)))
        x2, y2 = min(self.w, math.ceil(max(us)) + 1), min(self.h, math.ceil(max(vs)) + 1)
        if x2 - x1 < 2 or y2 - y1 < 2:
            return None
        mask = np.zeros((y2 - y1, x2 - x1), np.uint8)
        cv2.fillConvexPoly(mask, np.round(uv * 16).astype(np.int32) - (16 * x1, 16 * y1), 255, cv2.LINE_AA, 4)
        return (x1, y1, x2, y2), mask

    def _draw_shadow(self, img: np.ndarray, corners: np.ndarray, sun: np.ndarray, strength: float) -> None:
        """Cast shadow on the road: the vehicle's corners projected along the sun onto z = 0, darkened."""
        hull = shadow_hull(corners.reshape(-1, 3), sun)
        uv, depth = self.cam.project(np.column_stack([hull, np.zeros(len(hull))]))
        if np.any(depth <= NEAR_M):
            return
        cut = self._polygon_mask(uv)
        if cut is None:
            return
        (x1, y1, x2, y2), mask = cut
        roi = img[y1:y2, x1:x2]
        dark = (roi.astype(np.uint16) * int(256 * (1 - strength)) >> 8).astype(np.uint8)
        m = mask > 127
        roi[m] = dark[m]

    def _canvas_for(self, lighting: str) -> np.ndarray:
        """A fresh copy of the static scene every frame (this renderer draws outside the drawn-on bands' marks)."""
        return self.background(lighting).copy()

    def _expose(self, canvas: np.ndarray, lighting: str, t_s: float) -> np.ndarray:
        """The exposure as one direct table over the whole frame (``sim.sensor.exposure_lut``)."""
        return cv2.LUT(canvas, exposure_lut(t_s, self.seed, lighting))

    def render(self, snapshot: WorldSnapshot, frame_index: int | None = None) -> np.ndarray:
        """BGR image (h, w, 3) of the snapshot; deterministic for (snapshot, frame_index)."""
        lighting, L, frame_index, img, sun = self._frame_start(snapshot, frame_index)
        t = snapshot.sim_time_s
        C = self.cam.C
        gain = L["scene_gain"]
        glows: list[tuple[np.ndarray, tuple, float]] = []
        lamp_pts: dict[tuple[str, str], list] = {}
        drawn = []
        for a in self._ordered(snapshot):
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
        glow_rank: list[int] = []
        for rank, (a, geo) in enumerate(drawn):
            parts, decals, corners, uv, depth, rot = geo
            n_glows = len(glows)
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
                    idx, _n_local = FACES[name]
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
            roof = roof_state(a.style, t)
            tail_bright = a.brake_on or L["running_lights"]
            shown = [dc for dc in decals if (dc.part, dc.face) in face_uv]
            if shown:
                all_uv, _ = self.cam.project(np.concatenate(
                    [face_points(corners[dc.part], dc.face, dc.u0, dc.u1, dc.v0, dc.v1) for dc in shown]))
            for k_dc, dc in enumerate(shown):
                puv = all_uv[4 * k_dc:4 * k_dc + 4]
                if dc.lamp == "turn" and not sig_on:
                    continue  # the tail light under it shows
                colour = lit_bgr(dc.lamp, tail_bright, a.brake_on, red_on, blue_on, sig_on, roof, dc.segment)
                lit = colour is not None
                if not lit:
                    colour = unlit_bgr(dc.colour, dc.lamp, L)
                cv2.fillConvexPoly(img, np.round(puv * 16).astype(np.int32), colour, cv2.LINE_AA, 4)
                if lit:
                    queue_lamp_glow(glows, lamp_pts, (a.actor_id, dc.lamp), dc.lamp, dc.part == len(parts) - 1,
                                    a.brake_on, puv, colour)
            if blur_px is not None:
                self._motion_blur(img, uv, blur_px)
            glow_rank.extend([rank] * (len(glows) - n_glows))
        lamp_pts = {k: (np.vstack(faces), colour, strength) for k, (faces, colour, strength) in lamp_pts.items()}
        ranks = {a.actor_id: k for k, (a, _g) in enumerate(drawn)}
        keys = list(lamp_pts)
        hidden = [lamp_hidden(pts, r, drawn) for pts, r in
                  [(g[0], r) for g, r in zip(glows, glow_rank, strict=True)] + [(lamp_pts[k][0], ranks[k[0]]) for k in keys]]
        lamp_pts = {k: lamp_pts[k] for k, h in zip(keys, hidden[len(glows):], strict=True) if not h}
        glows = [g for g, h in zip(glows, hidden, strict=False) if not h]
        return self._frame_end(img, glows, lamp_pts, lighting, t, frame_index)

    def _motion_blur(self, img: np.ndarray, uv: np.ndarray, vec: np.ndarray) -> None:
        """Blur a vehicle's ROI along its image motion during the exposure (the full-grid kernel)."""
        box = self._blur_box((uv[..., 0].min(), uv[..., 1].min(), uv[..., 0].max(), uv[..., 1].max()), vec)
        if box is None:
            return
        x1, y1, x2, y2 = box
        n = int(min(25, math.ceil(float(np.hypot(*vec)))))
        k = np.zeros((2 * n + 1, 2 * n + 1), np.float32)
        direction = vec / max(1e-6, float(np.hypot(*vec)))
        for i in range(n + 1):
            x, y = np.round(n + direction * (i - n / 2)).astype(int)
            k[np.clip(y, 0, 2 * n), np.clip(x, 0, 2 * n)] += 1.0
        k /= k.sum()
        roi = img[y1:y2, x1:x2]
        roi[:] = cv2.filter2D(roi, -1, k, borderType=cv2.BORDER_REPLICATE)

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
        self._add_at(img, cv2.blur(pool, (7, 7)), x1, y1)

    def _frame_end(self, img: np.ndarray, glows: list, bar_halos: dict, lighting: str, t_s: float,
                   frame_index: int) -> np.ndarray:
        """The lamp halos (``glows`` and the light bars' ``bar_halos``), then exposure and sensor noise."""
        glows.extend(tuple(v) for v in bar_halos.values())
        if glows:
            self._draw_glows(img, glows, LIGHTING[lighting]["glow"])
        return self._expose_frame(img, lighting, t_s, frame_index)

    def _draw_glows(self, img: np.ndarray, glows, scale: float) -> None:
        """Additive halo around lamps that are on (bloom), from cached sprites on small ROIs only."""
        for puv, colour, strength in glows:
            cx, cy = puv.mean(axis=0)
            size = max(2.0, float(np.ptp(puv[:, 0])), float(np.ptp(puv[:, 1])))
            r = int(min(60, max(3, size * 0.55 * scale)))
            col = tuple(int(c * min(1.0, strength * (0.6 + 0.25 * scale))) for c in colour)
            sprite = self._glow_sprite(r, col, strength >= 1.0, max(1, int(size / 12)))
            self._add_at(img, sprite, int(round(cx)) - 2 * r, int(round(cy)) - 2 * r)

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


def lamp_hidden(points_xy: np.ndarray, rank: int, drawn: list) -> bool:
    """Is every face centre of a lamp (quads ``points_xy`` (4k, 2) px) inside a silhouette part of a vehicle drawn
    after its own (``drawn[rank]``: (actor, geometry) far to near)? The plain loop that
    ``sim.render.effects.hidden_lamps`` batches."""
    for cx, cy in points_xy.reshape(-1, 4, 2).mean(axis=1).tolist():
        if not any(cv2.pointPolygonTest(cv2.convexHull(uv[p].astype(np.float32)), (cx, cy), False) > 0
                   for _a, (parts, _d, _c, uv, _z, _r) in drawn[rank + 1:] for p in range(len(parts))
                   if parts[p].silhouette):
            return False
    return True
