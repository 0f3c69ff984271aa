"""Feature descriptors of a vehicle crop (thesis 2.4.1, docs/architecture.md §EV recognition).

All take a BGR uint8 crop (any size) and return a float32 vector; the ``*_batch`` forms stack many.

- ``pixel_array``: the crop resized to 128x128, flattened, scaled to [0, 1] (49,152 values).
- ``hog``: histogram of oriented gradients, 8 orientations, 10x10-pixel cells, 1x1-cell blocks with
  L1 norm, after a square-root (gamma) transform, on the 128x128 grey crop (as scikit-image's
  ``hog(orientations=8, pixels_per_cell=(10, 10), cells_per_block=(1, 1), block_norm="L1",
  transform_sqrt=True)``): 12 x 12 cells x 8 = 1,152 values. Vectorised with numpy.
- ``colour_histogram``: 3-D RGB histogram with 32 bins per channel (``cv2.calcHist``), normalised to
  sum 1: 32^3 = 32,768 values.
- ``hsv_custom``: the authors' 8-element vector: HSV red area, HSV blue area (fractions of the crop),
  area of the largest red and of the largest blue contour (fractions), and the centroids (x, y as
  fractions of crop width/height) of those two contours (0 when absent). HSV ranges of the authors'
  code (OpenCV scale): red [0,50,50]-[10,255,255], blue [110,50,50]-[130,255,255].
- ``hsv_custom_top``: the same on the top 20% of the crop (where a light bar is).
"""

from __future__ import annotations

import cv2
import numpy as np

PIXEL_SIZE = 128
HOG_ORIENTATIONS = 8
HOG_CELL = 10
HIST_BINS = 32
RED_LO, RED_HI = np.array([0, 50, 50], np.uint8), np.array([10, 255, 255], np.uint8)
BLUE_LO, BLUE_HI = np.array([110, 50, 50], np.uint8), np.array([130, 255, 255], np.uint8)
TOP_FRACTION = 0.2


def _check_crop(crop: np.ndarray) -> np.ndarray:
    if not isinstance(crop, np.ndarray) or crop.ndim != 3 or crop.shape[2] != 3 or crop.dtype != np.uint8:
        raise ValueError(f"expected a BGR uint8 crop of shape (H, W, 3), got "
                         f"{getattr(crop, 'dtype', type(crop))} {getattr(crop, 'shape', '')}")
    if crop.shape[0] < 2 or crop.shape[1] < 2:
        raise ValueError(f"crop of {crop.shape[1]}x{crop.shape[0]} pixels is too small (needs at least 2x2)")
    return crop


def resize_crop(crop: np.ndarray, size: int = PIXEL_SIZE) -> np.ndarray:
    crop = _check_crop(crop)
    interp = cv2.INTER_AREA if crop.shape[0] > size or crop.shape[1] > size else cv2.INTER_LINEAR
    return cv2.resize(crop, (size, size), interpolation=interp)


def pixel_array(crop: np.ndarray) -> np.ndarray:
    return (resize_crop(crop).astype(np.float32) / 255.0).ravel()


def hog(crop: np.ndarray) -> np.ndarray:
    grey = cv2.cvtColor(resize_crop(crop), cv2.COLOR_BGR2GRAY).astype(np.float32) / 255.0
    grey = np.sqrt(grey)
    gy = np.zeros_like(grey)
    gx = np.zeros_like(grey)
    gx[:, 1:-1] = grey[:, 2:] - grey[:, :-2]  # centred differences, zero at the border (as scikit-image)
    gy[1:-1, :] = grey[2:, :] - grey[:-2, :]
    magnitude = np.hypot(gx, gy)
    angle = np.rad2deg(np.arctan2(gy, gx)) % 180.0  # unsigned gradients
    n_cells = PIXEL_SIZE // HOG_CELL
    span = n_cells * HOG_CELL
    width = 180.0 / HOG_ORIENTATIONS
    # each pixel votes its magnitude into the orientation bin its angle falls in
    bins = np.minimum((angle[:span, :span] / width).astype(np.int64), HOG_ORIENTATIONS - 1)
    cell_y, cell_x = np.divmod(np.arange(span * span), span)
    cell_index = (cell_y // HOG_CELL) * n_cells + (cell_x // HOG_CELL)
    flat = cell_index * HOG_ORIENTATIONS + bins.ravel()
    hist = np.bincount(flat, weights=magnitude[:span, :span].ravel(), minlength=n_cells * n_cells * HOG_ORIENTATIONS)
    hist = hist.reshape(n_cells * n_cells, HOG_ORIENTATIONS) / (HOG_CELL * HOG_CELL)
    hist /= hist.sum(axis=1, keepdims=True) + 1e-5  # L1 block norm, 1x1-cell blocks
    return hist.ravel().astype(np.float32)


def colour_histogram(crop: np.ndarray) -> np.ndarray:
    rgb = cv2.cvtColor(_check_crop(crop), cv2.COLOR_BGR2RGB)
    hist = cv2.calcHist([rgb], [0, 1, 2], None, [HIST_BINS] * 3, [0, 256] * 3).ravel()
    return (hist / max(float(hist.sum()), 1.0)).astype(np.float32)


def _largest_contour(mask: np.ndarray) -> tuple[float, float, float]:
    """(area fraction, centroid x fraction, centroid y fraction) of the largest blob of ``mask``."""
    contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    if not contours:
        return 0.0, 0.0, 0.0
    areas = [cv2.contourArea(c) for c in contours]
    i = int(np.argmax(areas))
    h, w = mask.shape
    m = cv2.moments(contours[i])
    if m["m00"] > 0:
        cx, cy = m["m10"] / m["m00"], m["m01"] / m["m00"]
    else:  # a degenerate contour (a line or a point): use its bounding box centre
        x, y, bw, bh = cv2.boundingRect(contours[i])
        cx, cy = x + bw / 2.0, y + bh / 2.0
    return areas[i] / float(h * w), cx / w, cy / h


def hsv_masks(crop: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    hsv = cv2.cvtColor(_check_crop(crop), cv2.COLOR_BGR2HSV)
    return cv2.inRange(hsv, RED_LO, RED_HI), cv2.inRange(hsv, BLUE_LO, BLUE_HI)


def hsv_custom(crop: np.ndarray) -> np.ndarray:
    red, blue = hsv_masks(crop)
    n = float(red.size)
    red_area, blue_area = np.count_nonzero(red) / n, np.count_nonzero(blue) / n
    r_area, r_cx, r_cy = _largest_contour(red)
    b_area, b_cx, b_cy = _largest_contour(blue)
    return np.array([blue_area, red_area, b_area, r_area, b_cx, b_cy, r_cx, r_cy], dtype=np.float32)


def hsv_custom_top(crop: np.ndarray) -> np.ndarray:
    crop = _check_crop(crop)
    rows = max(2, int(round(crop.shape[0] * TOP_FRACTION)))
    return hsv_custom(crop[:rows])


FEATURES = {
    "pixels": pixel_array,
    "hog": hog,
    "colour_hist": colour_histogram,
    "hsv8": hsv_custom,
    "hsv8_top": hsv_custom_top,
}


def extract_batch(name: str, crops: list[np.ndarray]) -> np.ndarray:
    """Stack one feature over many crops: (N, D) float32."""
    if name not in FEATURES:
        raise ValueError(f"unknown feature {name!r}; choose from {sorted(FEATURES)}")
    fn = FEATURES[name]
    return np.stack([fn(c) for c in crops]) if crops else np.zeros((0, 0), np.float32)
