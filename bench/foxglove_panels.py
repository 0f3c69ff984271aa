"""The Foxglove layout's panels drawn from a recording's own Foxglove channels, where Foxglove cannot run.

Reads a recording (`iea record`, `iea demo`, `iea scenario run --inprocess`) and draws, at the moment the
scene first shows an alerted EV (``/scene/objects`` entity with ``alerted: true``), what the layout
``deploy/foxglove/corridor_layout.json`` shows: the 3D panel seen from above (``/scene/road`` and
``/scene/objects``: lines, boxes, labels, around the AV and the EV), the camera of the RSU that raised the
alert (its ``camera/jpeg`` channel), the map (``/map/av1`` and ``/map/ev`` fixes, no tiles), the plot of the
AV's lateral error and speed (``/vehicle/av1/state``) and the log (``/log``). OpenCV draws it; Foxglove is
not involved, only its message types.

    python bench/foxglove_panels.py RUN.mcap OUT.jpg [--json]

With ``--json`` the last line of output is one JSON object: the moment drawn and what each panel holds.
"""

from __future__ import annotations

import argparse
import base64
import json
import math
import sys
from collections import defaultdict
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

W, H = 1400, 820
BG, PANEL, TEXT, DIM = (30, 27, 25), (42, 38, 35), (235, 235, 235), (150, 150, 150)
FONT = cv2.FONT_HERSHEY_SIMPLEX


def bgr(c: dict) -> tuple[int, int, int]:
    return int(c["b"] * 255), int(c["g"] * 255), int(c["r"] * 255)


def t_of(ts: dict) -> float:
    return ts["sec"] + ts["nsec"] * 1e-9


def load(path: Path) -> dict[str, list[tuple[float, dict]]]:
    """Every JSON message of the Foxglove-readable channels, by topic, with its log time (s)."""
    from mcap.reader import make_reader

    out: dict[str, list[tuple[float, dict]]] = defaultdict(list)
    with open(path, "rb") as f:
        for _s, ch, m in make_reader(f).iter_messages(log_time_order=True):
            if ch.message_encoding == "json" and (ch.topic.startswith("/") or ch.topic.endswith("camera/jpeg")):
                out[ch.topic].append((m.log_time * 1e-9, json.loads(m.data)))
    return out


def latest(msgs: list[tuple[float, dict]], t: float) -> dict | None:
    best = None
    for tm, m in msgs:
        if tm > t:
            break
        best = m
    return best


def frame(img: np.ndarray, x: int, y: int, w: int, h: int, title: str) -> np.ndarray:
    cv2.rectangle(img, (x, y), (x + w, y + h), PANEL, -1)
    cv2.rectangle(img, (x, y), (x + w, y + 22), (55, 50, 46), -1)
    cv2.putText(img, title, (x + 8, y + 16), FONT, 0.45, TEXT, 1, cv2.LINE_AA)
    return img[y + 22:y + h, x:x + w]


def draw_scene(view: np.ndarray, road: dict, objects: dict, centre: tuple[float, float], span_m: float) -> int:
    h, w = view.shape[:2]
    scale = w / span_m
    cx, cy = centre

    def px(x: float, y: float) -> tuple[int, int]:
        return int(w / 2 + (x - cx) * scale), int(h / 2 - (y - cy) * scale)

    drawn = 0
    for upd in (road, objects):
        for e in (upd or {}).get("entities", []):
            for ln in e["lines"]:
                pts = np.array([px(p["x"], p["y"]) for p in ln["points"]], np.int32)
                thick = max(1, int(ln["thickness"] * scale * 0.6))
                cv2.polylines(view, [pts], ln["type"] == 1, bgr(ln["color"]), thick, cv2.LINE_AA)
            for c in e["cubes"]:
                q = c["pose"]["orientation"]
                yaw = 2 * math.atan2(q["z"], q["w"])
                x, y = c["pose"]["position"]["x"], c["pose"]["position"]["y"]
                half = np.array([[c["size"]["x"] / 2, c["size"]["y"] / 2]])
                corners = np.array([[1, 1], [1, -1], [-1, -1], [-1, 1]]) * half
                rot = np.array([[math.cos(yaw), -math.sin(yaw)], [math.sin(yaw), math.cos(yaw)]])
                world = corners @ rot.T + [x, y]
                pts = np.array([px(a, b) for a, b in world], np.int32)
                cv2.fillPoly(view, [pts], bgr(c["color"]), cv2.LINE_AA)
                drawn += 1
            for t in e["texts"]:
                p = px(t["pose"]["position"]["x"], t["pose"]["position"]["y"])
                for k, line in enumerate(t["text"].split("\n")):
                    cv2.putText(view, line, (p[0] + 6, p[1] - 8 + 13 * k), FONT, 0.38, bgr(t["color"]), 1, cv2.LINE_AA)
    bar = int(10 * scale)
    cv2.line(view, (12, h - 14), (12 + bar, h - 14), TEXT, 2)
    cv2.putText(view, "10 m", (16 + bar, h - 10), FONT, 0.4, TEXT, 1, cv2.LINE_AA)
    return drawn


def draw_map(view: np.ndarray, av: list[tuple[float, float]], ev: list[tuple[float, float]]) -> None:
    h, w = view.shape[:2]
    pts = av + ev
    lat0 = sum(p[0] for p in pts) / len(pts)
    m_lat, m_lon = 111_320.0, 111_320.0 * math.cos(math.radians(lat0))
    xs = [p[1] * m_lon for p in pts]
    ys = [p[0] * m_lat for p in pts]
    span = max(max(xs) - min(xs), (max(ys) - min(ys)) * w / h, 60.0) * 1.2
    cx, cy = (max(xs) + min(xs)) / 2, (max(ys) + min(ys)) / 2
    scale = w / span

    def px(lat: float, lon: float) -> tuple[int, int]:
        return int(w / 2 + (lon * m_lon - cx) * scale), int(h / 2 - (lat * m_lat - cy) * scale)

    for x in range(0, w, 40):
        cv2.line(view, (x, 0), (x, h), (52, 48, 45), 1)
    for y in range(0, h, 40):
        cv2.line(view, (0, y), (w, y), (52, 48, 45), 1)
    if len(av) > 1:
        cv2.polylines(view, [np.array([px(*p) for p in av], np.int32)], False, (217, 217, 0), 2, cv2.LINE_AA)
    for p in ev:
        cv2.circle(view, px(*p), 3, (26, 26, 242), -1, cv2.LINE_AA)
    if av:
        cv2.circle(view, px(*av[-1]), 6, (217, 217, 0), -1, cv2.LINE_AA)
    cv2.putText(view, f"{av[-1][0]:.5f} N {abs(av[-1][1]):.5f} W" if av else "", (8, h - 10), FONT, 0.4, DIM, 1,
                cv2.LINE_AA)
    cv2.putText(view, "AV (cyan), alerted EV (red); WGS84 fixes, no map tiles offline", (8, 16), FONT, 0.4, DIM, 1,
                cv2.LINE_AA)


def draw_plot(view: np.ndarray, series: dict[str, list[tuple[float, float]]], t_mark: float) -> None:
    h, w = view.shape[:2]
    colours = {"lateral_error_m": (80, 180, 255), "speed_mps": (120, 220, 120)}
    t_all = [t for s in series.values() for t, _ in s]
    t0, t1 = min(t_all), max(t_all)
    rows = len(series)
    for i, (name, s) in enumerate(series.items()):
        top, bottom = int(i * h / rows) + 18, int((i + 1) * h / rows) - 8
        vals = [v for _, v in s]
        lo, hi = min(vals), max(vals)
        if hi - lo < 1e-6:
            lo, hi = lo - 1, hi + 1
        pts = np.array([[int(40 + (t - t0) / max(t1 - t0, 1e-6) * (w - 50)),
                         int(bottom - (v - lo) / (hi - lo) * (bottom - top))] for t, v in s], np.int32)
        cv2.polylines(view, [pts], False, colours.get(name, TEXT), 2, cv2.LINE_AA)
        cv2.putText(view, f"{name}  [{lo:.2f} .. {hi:.2f}]", (44, top - 4), FONT, 0.4, colours.get(name, TEXT), 1,
                    cv2.LINE_AA)
    xm = int(40 + (t_mark - t0) / max(t1 - t0, 1e-6) * (w - 50))  # t0, t1: the plotted span
    cv2.line(view, (xm, 0), (xm, h), DIM, 1)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("recording")
    ap.add_argument("out", help="image to write (.jpg or .png)")
    ap.add_argument("--json", action="store_true", help="end with one JSON line of what was drawn")
    args = ap.parse_args(argv)
    data = load(Path(args.recording))
    scenes = data.get("/scene/objects", [])
    alerted = [(t, m) for t, m in scenes if any(
        {"key": "alerted", "value": "true"} in e["metadata"] for e in m["entities"])]
    if not alerted:
        print("foxglove_panels: the recording's scene never shows an alerted EV", file=sys.stderr)
        return 2
    t_alert = alerted[0][0]
    t0 = min(msgs[0][0] for msgs in data.values() if msgs)  # times shown from the recording's start
    t = alerted[min(len(alerted) - 1, 10)][0]  # a second into the alert: the AV's commanded path is out
    objects = latest(scenes, t)
    road = latest(data.get("/scene/road", []), t)
    img = np.full((H, W, 3), BG, np.uint8)
    av_ent = next((e for e in objects["entities"] if e["id"].startswith("av/")), None)
    ev_ent = next((e for e in objects["entities"] if {"key": "alerted", "value": "true"} in e["metadata"]), None)
    ax, ay = (av_ent["cubes"][0]["pose"]["position"]["x"], av_ent["cubes"][0]["pose"]["position"]["y"]) if av_ent \
        else (0.0, 0.0)
    ex, ey = ev_ent["cubes"][0]["pose"]["position"]["x"], ev_ent["cubes"][0]["pose"]["position"]["y"]
    view = frame(img, 8, 8, 820, 470, f"3D  /scene/road  /scene/objects  (top view, t = {t - t0:.1f} s)")
    span = max(90.0, abs(ax - ex) * 1.6)
    boxes = draw_scene(view, road, objects, ((ax + ex) / 2, (ay + ey) / 2), span)
    alert = latest(data.get("/alerts/ev", []), t)
    rsu = alert["rsu_id"] if alert else "rsu1"
    cam_topic = next((k for k in data if k.endswith(f"/rsu/{rsu}/camera/jpeg")), None)
    cam = latest(data.get(cam_topic, []), t) if cam_topic else None
    view = frame(img, 8, 486, 820, 326, f"Image  {cam_topic or '(no camera channel)'}")
    if cam is not None:
        jpg = cv2.imdecode(np.frombuffer(base64.b64decode(cam["data"]), np.uint8), cv2.IMREAD_COLOR)
        vh, vw = view.shape[:2]
        s = min(vw / jpg.shape[1], vh / jpg.shape[0])
        jpg = cv2.resize(jpg, (int(jpg.shape[1] * s), int(jpg.shape[0] * s)), interpolation=cv2.INTER_AREA)
        y0, x0 = (vh - jpg.shape[0]) // 2, (vw - jpg.shape[1]) // 2
        view[y0:y0 + jpg.shape[0], x0:x0 + jpg.shape[1]] = jpg
    view = frame(img, 836, 8, 556, 250, "Map  /map/av1  /map/ev")
    av_fix = [(m["latitude"], m["longitude"]) for tm, m in data.get("/map/av1", []) if tm <= t]
    ev_fix = [(m["latitude"], m["longitude"]) for tm, m in data.get("/map/ev", []) if tm <= t]
    if av_fix or ev_fix:
        draw_map(view, av_fix, ev_fix)
    view = frame(img, 836, 266, 556, 250, "Plot  /vehicle/av1/state.lateral_error_m, .speed_mps")
    states = data.get("/vehicle/av1/state", [])
    series = {"lateral_error_m": [(tm, m["lateral_error_m"]) for tm, m in states],
              "speed_mps": [(tm, m["speed_mps"]) for tm, m in states]}
    if states:
        draw_plot(view, series, t)
    view = frame(img, 836, 524, 556, 288, "Log  /log")
    logs = [(tm, m) for tm, m in data.get("/log", []) if tm <= t]
    for k, (tm, m) in enumerate(logs[-12:]):
        colour = (60, 170, 255) if m["level"] >= 3 else TEXT
        line = f"{tm - t0:6.2f}  {m['name']:>5}  {m['message']}"
        cv2.putText(view, line[:78], (8, 20 + 20 * k), FONT, 0.4, colour, 1, cv2.LINE_AA)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(out), img, [cv2.IMWRITE_JPEG_QUALITY, 85])
    figures = {"t_first_alerted_s": round(t_alert - t0, 2), "t_drawn_s": round(t - t0, 2), "boxes": boxes,
               "camera": cam_topic, "map_fixes": len(av_fix) + len(ev_fix), "plot_points": len(states),
               "log_lines": len(logs), "out": str(out)}
    print(f"[foxglove_panels] {out}: t = {t - t0:.2f} s, {boxes} boxes, camera {cam_topic}, {len(logs)} log lines")
    if args.json:
        print(json.dumps(figures))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
