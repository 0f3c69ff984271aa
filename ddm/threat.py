"""Threat value of a road hazard (Clemson hazard navigation report; docs/architecture.md §DDM). Pure.

Procedure 1, distance based (report eq. 2-3)::

    T   = sqrt(((lx_max - lx) / lx_max)^2 + ((ly_max - ly) / ly_max)^2)              (2)
    T_f = (T - T_min) / (T_max - T_min)   if lx <= lx_max and ly <= ly_max, else 0  (3)

with lx the longitudinal and ly the lateral distance from the vehicle to the hazard. Min-max
normalisation runs over the region where the hazard counts as a threat (0 <= lx <= lx_max,
0 <= ly <= ly_max), where T spans [T_min, T_max] = [0, sqrt(2)]: T_f = 1 for a hazard touching the
vehicle's front on its centre line, 0 at the corner (lx_max, ly_max) and outside. The report uses
lx_max = 60 m (the radar's range) and ly_max = 3.7 m (one lane width).

In the corridor the DDM knows both positions in the road (Frenet) frame, so for an AV and a hazard
(:func:`av_hazard_distances`): lx = hazard's near edge minus the AV's front bumper along the road
(a hazard behind the front bumper is no threat: lx < 0 gives 0), ly = |d_hazard - d_av|, the offset
of the hazard's centre from the AV's centre line (what the report's radar measures).

Procedure 2, image based (report eq. 4), on an (h, w) image with a hazard segmentation mask::

    T_f = 1 - sqrt(((x - h)^2 + (y - w/2)^2) / (h^2 + (w/2)^2))                        (4)

where (x, y) = (row, column) of the hazard pixel closest to the bottom-centre pixel (h, w/2).
Also eq. 1, the fused image I = (1 - T_f) I_original + T_f I_segmented.
"""

from __future__ import annotations

import math

import numpy as np

LX_MAX_M = 60.0
"""Report: 6000 cm, the radar's maximum range."""
LY_MAX_M = 3.7
"""Report: 370 cm, one standard lane width."""
T_MIN = 0.0
T_MAX = math.sqrt(2.0)
"""Range of eq. 2 over the threat region 0 <= lx <= lx_max, 0 <= ly <= ly_max."""


def raw_threat(lx_m, ly_m, lx_max_m: float = LX_MAX_M, ly_max_m: float = LY_MAX_M):
    """Eq. 2, T (not normalised); arrays broadcast."""
    if lx_max_m <= 0 or ly_max_m <= 0:
        raise ValueError("lx_max_m and ly_max_m must be > 0")
    lx = np.asarray(lx_m, dtype=float)
    ly = np.asarray(ly_m, dtype=float)
    return np.sqrt(((lx_max_m - lx) / lx_max_m) ** 2 + ((ly_max_m - ly) / ly_max_m) ** 2)


def threat_value(lx_m, ly_m, lx_max_m: float = LX_MAX_M, ly_max_m: float = LY_MAX_M):
    """Eq. 2-3: T_f in [0, 1] from longitudinal distance ``lx_m`` (ahead, m) and lateral distance
    ``ly_m`` (m, its magnitude is used). Outside 0 <= lx <= lx_max or ly > ly_max: 0. Scalars in,
    float out; arrays in, array out."""
    lx = np.asarray(lx_m, dtype=float)
    ly = np.abs(np.asarray(ly_m, dtype=float))
    if not (np.all(np.isfinite(lx)) and np.all(np.isfinite(ly))):
        raise ValueError("threat_value needs finite distances")
    t = raw_threat(lx, ly, lx_max_m, ly_max_m)
    tf = (t - T_MIN) / (T_MAX - T_MIN)
    inside = (lx >= 0.0) & (lx <= lx_max_m) & (ly <= ly_max_m)
    out = np.where(inside, np.clip(tf, 0.0, 1.0), 0.0)
    return float(out) if out.ndim == 0 else out


def av_hazard_distances(av_s_m: float, av_d_m: float, av_length_m: float, hazard_s_m: float, hazard_d_m: float,
                        hazard_length_m: float = 0.0) -> tuple[float, float]:
    """(lx, ly) of a hazard from an AV, both in road coordinates (s along, d across the road):
    lx from the AV's front bumper to the hazard's near edge, ly between the centre lines."""
    lx = (hazard_s_m - hazard_length_m / 2.0) - (av_s_m + av_length_m / 2.0)
    return float(lx), float(abs(hazard_d_m - av_d_m))


def nearest_to_bottom_centre(mask: np.ndarray) -> tuple[int, int] | None:
    """(row, column) of the mask pixel closest to the image's bottom-centre (h, w/2); None if empty."""
    m = np.asarray(mask)
    if m.ndim != 2:
        raise ValueError(f"mask must be 2-D (h, w), got shape {m.shape}")
    rows, cols = np.nonzero(m)
    if len(rows) == 0:
        return None
    h, w = m.shape
    d2 = (rows - h) ** 2 + (cols - w / 2.0) ** 2
    k = int(np.argmin(d2))
    return int(rows[k]), int(cols[k])


def image_threat(mask: np.ndarray, labels: int | tuple[int, ...] | None = None) -> float:
    """Eq. 4 on a segmentation mask of any camera image: boolean (hazard pixels true) or a label
    image with ``labels`` the hazard class id(s). 0 when no hazard pixel."""
    m = np.asarray(mask)
    if labels is not None:
        m = np.isin(m, np.atleast_1d(labels))
    px = nearest_to_bottom_centre(m)
    if px is None:
        return 0.0
    x, y = px
    h, w = m.shape
    return float(1.0 - math.sqrt(((x - h) ** 2 + (y - w / 2.0) ** 2) / (h * h + (w / 2.0) ** 2)))


def fuse_image(original: np.ndarray, segmented: np.ndarray, threat: float) -> np.ndarray:
    """Eq. 1: I = (1 - T_f) I_original + T_f I_segmented (same shape; uint8 in, uint8 out)."""
    if original.shape != segmented.shape:
        raise ValueError(f"images differ in shape: {original.shape} vs {segmented.shape}")
    if not 0.0 <= threat <= 1.0:
        raise ValueError(f"threat must be in [0, 1], got {threat}")
    out = (1.0 - threat) * original.astype(float) + threat * segmented.astype(float)
    return np.clip(np.rint(out), 0, 255).astype(original.dtype) if original.dtype == np.uint8 else out
