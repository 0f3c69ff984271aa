"""Does a box hold one vehicle where it stands on the road (camera geometry): the EV classifier's optional box gate
(``TrackEvClassifier(box_gate=...)``, ``iea-rsu --ev-box-gate``)."""

from __future__ import annotations

import numpy as np


class SingleVehicleGate:
    """Is a box small enough to hold *one* vehicle where it stands on the road? (camera geometry)

    A fixed camera looking along the road sees vehicles one behind the other; a motion or weak
    detector then returns one box around several of them, and a flashing EV inside such a blob would
    put the EV alert (and its position) on the wrong vehicle. The bottom-centre of the box is
    back-projected to the road (thesis App. B.1, :class:`rsu.localize.GroundProjector`); a cuboid of
    the largest vehicle (``max_length_m`` x ``max_width_m`` x ``max_height_m``, aligned with the road,
    its near edge on that point, extending away from the camera) is projected with K[R|t]; the box
    passes when it is no wider (and, with ``check_height``, no taller) than ``slack`` times that
    cuboid's image box. Height is not judged by default: at night and dusk the detector's boxes grow
    upwards and forwards with the glow of the lamps and the headlight pools (measured on the simulator:
    a height check rejected most lit EVs at night), while several vehicles in one blob make it wider
    than any one vehicle. Sides the image border cuts are not judged; a box whose ground point is not
    on the road in front passes.
    """

    def __init__(self, camera, road=None, *, max_length_m: float = 13.0, max_width_m: float = 2.6,
                 max_height_m: float = 4.2, slack: float = 1.35, check_height: bool = False) -> None:
        from rsu.localize import GroundProjector

        self.projector = GroundProjector(camera)
        self.projection = camera.projection_matrix
        self.size = (int(camera.width_px), int(camera.height_px)) if hasattr(camera, "width_px") else None
        self.road = road
        self.dims = (max_length_m, max_width_m, max_height_m)
        self.slack = slack
        self.check_height = check_height

    def max_box_px(self, u: float, v: float) -> tuple[float, float] | None:
        """(width, height) in pixels of the largest vehicle whose near bottom edge is at pixel (u, v)."""
        xy, ok = self.projector.to_ground(np.array([[u, v]], float))
        if not ok[0]:
            return None
        x, y = xy[0]
        away = np.array([x, y]) - self.projector.centre[:2]
        if self.road is not None:
            s_m, d_m = self.road.to_frenet(x, y)
            heading = float(np.atleast_1d(self.road.pose_at(s_m, d_m)[2])[0])
            along = np.array([np.cos(heading), np.sin(heading)])
            along = along if along @ away >= 0 else -along
        else:
            along = away / max(np.linalg.norm(away), 1e-9)
        side = np.array([-along[1], along[0]])
        length, width, height = self.dims
        pts = [np.array([x, y]) + a * along + b * side for a in (0.0, length) for b in (-width / 2, width / 2)]
        xyz1 = np.array([[p[0], p[1], z, 1.0] for p in pts for z in (0.0, height)])
        uvw = xyz1 @ self.projection.T
        if np.any(uvw[:, 2] <= 0):
            return None
        uv = uvw[:, :2] / uvw[:, 2:3]
        return float(np.ptp(uv[:, 0])), float(np.ptp(uv[:, 1]))

    def __call__(self, box, image_w: int, image_h: int) -> bool:
        x1, y1, x2, y2 = (float(b) for b in box)
        if y2 >= image_h - 2:
            return True  # the near edge is cut off: no ground point to judge from
        size = self.max_box_px((x1 + x2) / 2, y2)
        if size is None:
            return True
        w_max, h_max = size
        wide = x1 > 1 and x2 < image_w - 2 and (x2 - x1) > self.slack * w_max
        tall = self.check_height and y1 > 1 and (y2 - y1) > self.slack * h_max
        return not (wide or tall)
