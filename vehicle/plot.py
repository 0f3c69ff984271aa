"""Figures of a run as PNG, drawn with OpenCV (report Figs. 12-16).

- ``path.png``: driven path vs the reference paths, with the detection (command) point and the stop point;
- ``speed.png``, ``lateral_error.png``, ``yaw_error.png``, ``yaw_rate_error.png``: over time, with the
  command time marked.
Plain line charts: white background, axes with ticks and labels, a legend.
"""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np

from vehicle.record import read_run

WIDTH, HEIGHT = 1000, 560
MARGIN_L, MARGIN_R, MARGIN_T, MARGIN_B = 90, 30, 50, 70
BLACK, GREY, LIGHT = (0, 0, 0), (120, 120, 120), (225, 225, 225)
COLOURS = [(200, 80, 20), (40, 40, 220), (30, 150, 30), (160, 40, 160)]
FONT = cv2.FONT_HERSHEY_SIMPLEX


def nice_ticks(lo: float, hi: float, n: int = 6) -> np.ndarray:
    if not hi > lo:
        hi = lo + 1.0
    raw = (hi - lo) / n
    mag = 10 ** math.floor(math.log10(raw))
    step = min((m * mag for m in (1, 2, 2.5, 5, 10) if m * mag >= raw), default=10 * mag)
    return np.arange(math.ceil(lo / step) * step, hi + step * 1e-6, step)


def _fmt(v: float) -> str:
    return f"{v:.3g}" if abs(v) < 1e4 else f"{v:.0f}"


class Chart:
    def __init__(self, title: str, xlabel: str, ylabel: str, xlim: tuple[float, float], ylim: tuple[float, float],
                 equal_aspect: bool = False) -> None:
        self.img = np.full((HEIGHT, WIDTH, 3), 255, np.uint8)
        x0, x1 = xlim
        y0, y1 = ylim
        if not x1 > x0:
            x0, x1 = x0 - 1, x1 + 1
        if not y1 > y0:
            y0, y1 = y0 - 1, y1 + 1
        self.pw, self.ph = WIDTH - MARGIN_L - MARGIN_R, HEIGHT - MARGIN_T - MARGIN_B
        if equal_aspect:  # same metres per pixel on both axes
            scale = max((x1 - x0) / self.pw, (y1 - y0) / self.ph)
            cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
            x0, x1 = cx - scale * self.pw / 2, cx + scale * self.pw / 2
            y0, y1 = cy - scale * self.ph / 2, cy + scale * self.ph / 2
        self.x0, self.x1, self.y0, self.y1 = x0, x1, y0, y1
        self._legend: list[tuple[str, tuple[int, int, int]]] = []
        self._axes(title, xlabel, ylabel)

    def px(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        u = MARGIN_L + (np.asarray(x) - self.x0) / (self.x1 - self.x0) * self.pw
        v = MARGIN_T + (self.y1 - np.asarray(y)) / (self.y1 - self.y0) * self.ph
        return np.column_stack([u, v])

    def _axes(self, title: str, xlabel: str, ylabel: str) -> None:
        img = self.img
        left, t, r, b = MARGIN_L, MARGIN_T, MARGIN_L + self.pw, MARGIN_T + self.ph
        for xv in nice_ticks(self.x0, self.x1):
            u = int(round(self.px([xv], [self.y0])[0, 0]))
            cv2.line(img, (u, t), (u, b), LIGHT, 1)
            cv2.line(img, (u, b), (u, b + 6), BLACK, 1)
            s = _fmt(xv)
            (tw, _), _ = cv2.getTextSize(s, FONT, 0.45, 1)
            cv2.putText(img, s, (u - tw // 2, b + 22), FONT, 0.45, BLACK, 1, cv2.LINE_AA)
        for yv in nice_ticks(self.y0, self.y1):
            v = int(round(self.px([self.x0], [yv])[0, 1]))
            cv2.line(img, (left, v), (r, v), LIGHT, 1)
            cv2.line(img, (left - 6, v), (left, v), BLACK, 1)
            s = _fmt(yv)
            (tw, th), _ = cv2.getTextSize(s, FONT, 0.45, 1)
            cv2.putText(img, s, (left - 10 - tw, v + th // 2), FONT, 0.45, BLACK, 1, cv2.LINE_AA)
        cv2.rectangle(img, (left, t), (r, b), BLACK, 1)
        (tw, _), _ = cv2.getTextSize(title, FONT, 0.7, 2)
        cv2.putText(img, title, ((WIDTH - tw) // 2, 32), FONT, 0.7, BLACK, 2, cv2.LINE_AA)
        (tw, _), _ = cv2.getTextSize(xlabel, FONT, 0.55, 1)
        cv2.putText(img, xlabel, (left + (self.pw - tw) // 2, HEIGHT - 18), FONT, 0.55, BLACK, 1, cv2.LINE_AA)
        label = np.full((30, 400, 3), 255, np.uint8)
        (tw, _), _ = cv2.getTextSize(ylabel, FONT, 0.55, 1)
        cv2.putText(label, ylabel, ((400 - tw) // 2, 21), FONT, 0.55, BLACK, 1, cv2.LINE_AA)
        rot = cv2.rotate(label, cv2.ROTATE_90_COUNTERCLOCKWISE)
        y_top = t + (self.ph - 400) // 2
        if y_top >= 0 and y_top + 400 <= HEIGHT:
            img[y_top:y_top + 400, 8:38] = np.minimum(img[y_top:y_top + 400, 8:38], rot)

    def line(self, x: np.ndarray, y: np.ndarray, colour: tuple[int, int, int], label: str | None = None,
             thickness: int = 2) -> None:
        ok = np.isfinite(x) & np.isfinite(y)
        if ok.sum() >= 2:
            pts = np.round(self.px(x[ok], y[ok])).astype(np.int32)
            cv2.polylines(self.img, [pts], False, colour, thickness, cv2.LINE_AA)
        if label:
            self._legend.append((label, colour))

    def hline(self, y: float, colour=GREY, label: str | None = None) -> None:
        self.line(np.array([self.x0, self.x1]), np.array([y, y]), colour, label, 1)

    def vline(self, x: float, colour=GREY, label: str | None = None) -> None:
        self.line(np.array([x, x]), np.array([self.y0, self.y1]), colour, label, 1)

    def marker(self, x: float, y: float, colour, label: str | None = None) -> None:
        u, v = np.round(self.px([x], [y])[0]).astype(int)
        cv2.drawMarker(self.img, (int(u), int(v)), colour, cv2.MARKER_TILTED_CROSS, 16, 2, cv2.LINE_AA)
        if label:
            self._legend.append((label, colour))

    def save(self, path: Path) -> Path:
        x, y = MARGIN_L + self.pw - 10, MARGIN_T + 12
        widths = [cv2.getTextSize(s, FONT, 0.5, 1)[0][0] for s, _ in self._legend]
        if self._legend:
            w = max(widths) + 50
            cv2.rectangle(self.img, (x - w, y - 4), (x, y + 22 * len(self._legend)), (255, 255, 255), -1)
            cv2.rectangle(self.img, (x - w, y - 4), (x, y + 22 * len(self._legend)), GREY, 1)
            for i, (s, c) in enumerate(self._legend):
                yy = y + 11 + 22 * i
                cv2.line(self.img, (x - w + 8, yy), (x - w + 36, yy), c, 2, cv2.LINE_AA)
                cv2.putText(self.img, s, (x - w + 42, yy + 5), FONT, 0.5, BLACK, 1, cv2.LINE_AA)
        if not cv2.imwrite(str(path), self.img):
            raise OSError(f"could not write {path}")
        return path


def _limits(*arrays: np.ndarray, pad: float = 0.08, symmetric: bool = False) -> tuple[float, float]:
    vals = np.concatenate([np.asarray(a, float)[np.isfinite(a)] for a in arrays]) if arrays else np.zeros(1)
    if vals.size == 0:
        return -1.0, 1.0
    lo, hi = float(vals.min()), float(vals.max())
    if symmetric:
        m = max(abs(lo), abs(hi), 1e-3)
        return -m * (1 + pad), m * (1 + pad)
    span = max(hi - lo, 1e-3)
    return lo - pad * span, hi + pad * span


def plot_run(run_dir: str | Path, out_dir: str | Path | None = None) -> list[Path]:
    """Write the report's figures for a run folder; returns the PNG paths."""
    cols, paths, meta = read_run(run_dir)
    out = Path(out_dir) if out_dir is not None else Path(run_dir)
    out.mkdir(parents=True, exist_ok=True)
    t = cols["t_s"]
    cmd_events = [e for e in meta.get("events", []) if e.get("event") == "command"]
    written = []

    # Fig. 12: path vs reference with the detection point
    xl = _limits(cols["x_m"], pad=0.05)
    yl = _limits(cols["y_m"], pad=0.3)
    near = 0.5 * max(xl[1] - xl[0], yl[1] - yl[0])
    cx, cy = 0.5 * (xl[0] + xl[1]), 0.5 * (yl[0] + yl[1])
    paths = {v: p[(np.abs(p[:, 0] - cx) <= near) & (np.abs(p[:, 1] - cy) <= near)] for v, p in paths.items()}
    yl = _limits(cols["y_m"], *[p[:, 1] for p in paths.values() if len(p)], pad=0.3)
    ch = Chart(f"Path vs reference ({meta.get('scenario', 'run')})", "x (m)", "y (m)", xl, yl, equal_aspect=False)
    for i, (_version, pts) in enumerate(sorted(paths.items())):
        ch.line(pts[:, 0], pts[:, 1], LIGHT if i == 0 and len(paths) > 1 else GREY,
                "original reference" if i == 0 else ("new reference" if i == 1 else None), 2)
    ch.line(cols["x_m"], cols["y_m"], COLOURS[0], "vehicle (truth)")
    for e in cmd_events:
        ch.marker(e["x_m"], e["y_m"], COLOURS[1], "detection / command")
        if e.get("stop_point"):
            ch.marker(e["stop_point"][0], e["stop_point"][1], COLOURS[2], "stop point")
    written.append(ch.save(out / "path.png"))

    def time_chart(name: str, title: str, ylabel: str, series: list[tuple[np.ndarray, str]], symmetric: bool,
                   bands: tuple[float, ...] = ()) -> None:
        yl = _limits(*[s for s, _ in series], *(np.array([b]) for b in bands), symmetric=symmetric)
        c = Chart(title, "time (s)", ylabel, (float(t[0]), float(t[-1])), yl)
        c.hline(0.0)
        for b in bands:
            c.hline(b, (150, 150, 230))
        for e in cmd_events:
            c.vline(e["t_s"], COLOURS[1], "command received")
        for i, (s, label) in enumerate(series):
            c.line(t, s, COLOURS[(i * 2) % len(COLOURS)], label)
        written.append(c.save(out / name))

    time_chart("speed.png", "Vehicle speed", "speed (m/s)",
               [(cols["speed_mps"], "speed"), (cols["speed_ref_mps"], "reference")], False)
    time_chart("lateral_error.png", "Lateral error", "lateral error (m)",
               [(cols["lateral_error_m"], "truth"), (cols["est_lateral_error_m"], "as estimated")], True)
    time_chart("yaw_error.png", "Yaw error", "yaw error (rad)",
               [(cols["yaw_error_rad"], "truth"), (cols["est_yaw_error_rad"], "as estimated")], True)
    time_chart("yaw_rate_error.png", "Yaw-rate error", "yaw-rate error (rad/s)",
               [(cols["yaw_rate_error_rps"], "truth")], True)
    return written
