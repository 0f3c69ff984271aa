"""Label real clips for per-vehicle EV scoring (``rsu.scan_labels``): propose boxes, look, write the label file.

    python bench/label_tool.py propose CLIP [--out DIR] [--every-s 0.5] [--per-sheet 12]
    python bench/label_tool.py write CLIP --viewpoint elevated|roadside|in-car|broadcast
        [--ev "NAME kind=ambulance tracks=3,7 t=0-5.5 lit=0-5.5,7-9"] [--flasher "NAME kind=hazard tracks=12"]
        [--box "NAME T X1 Y1 X2 Y2"] [--gone "NAME T0-T1"] [--note TEXT] [--out bench/labels]

``propose`` runs the project's detector and tracker on the clip (``rsu.scan.scan_video``: COCO YOLOX-Nano,
SORT; no EV-body model, the proposals need only the tracks) and writes, under ``DIR/<clip stem>/``,
contact sheets ``sheet_NN.png``: one frame every ``--every-s`` seconds, each with every track's box and
number, a grid labelled in the clip's own pixels and the time; and ``proposals.json``: every track's box at
those times. Looking at the sheets, one labels by naming track numbers and time ranges:

- ``--ev``: an emergency vehicle: ``tracks=`` the proposal tracks that are it (the first present at a time
  wins), ``t=`` the time range it is labelled over (default: wherever its tracks are), ``lit=`` the time
  ranges its warning lights are visibly on (``all``, ``none``, or ``A-B,C-D``), ``kind=`` what it is;
- ``--flasher``: a vehicle with hazard or turn flashers or an amber beacon (same fields; ``lit=`` when they flash);
- ``--box``: a box read off the grid where the detector missed the vehicle or boxed it wrongly (replaces the
  proposal at that time, or adds one); ``--gone``: a time range in which the vehicle is not in view.

``write`` turns these into ``bench/labels/<clip stem>.json`` (format: ``rsu.scan_labels``; a clip with no
``--ev`` is written as a clip with no EV). Labels are for scoring only: the pipeline never reads them.
"""

from __future__ import annotations

from bench._setup import REAL, ROOT  # noqa: F401  first: one thread per numeric library, before numpy loads

# isort: split
import argparse  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import sys  # noqa: E402
from pathlib import Path  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from rsu.scan_labels import VIEWPOINTS, ClipLabels, LabelledVehicle, write_labels  # noqa: E402

LABELS_DIR = ROOT / "bench" / "labels"
WORK_DIR = Path("/tmp") / "iea_label_tool"
CLIP_FOLDERS = ("ev_videos", "traffic_videos")
SHEET_CELL_W = 560
"""Width of one frame on a contact sheet (pixels); the grid and text keep the clip's own coordinates."""


def find_clip(name: str) -> tuple[Path, str]:
    """The clip named by a path or by its file name / stem under ../shared/data/real/{ev,traffic}_videos."""
    p = Path(name)
    if p.is_file():
        return p, p.parent.name
    for folder in CLIP_FOLDERS:
        for q in sorted((REAL / folder).glob("*")):
            if name in (q.name, q.stem):
                return q, folder
    raise FileNotFoundError(f"clip {name!r}: not a file, nor a clip of {REAL}/{{{','.join(CLIP_FOLDERS)}}}")


def video_info(path: Path) -> dict:
    cap = cv2.VideoCapture(str(path))
    try:
        fps = float(cap.get(cv2.CAP_PROP_FPS)) or 25.0
        n = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
        return dict(width=int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), height=int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT)),
                    fps=round(fps, 3), frames=n, duration_s=round(n / fps, 3))
    finally:
        cap.release()


def sample_times(duration_s: float, every_s: float) -> list[float]:
    return [round(k * every_s, 3) for k in range(int(math.floor(duration_s / every_s + 1e-9)) + 1)]


def propose(clip: str, out: Path, every_s: float, per_sheet: int) -> Path:
    from rsu.scan import scan_video

    path, folder = find_clip(clip)
    info = video_info(path)
    result = scan_video(path, body="none", record_boxes=True)
    times = sample_times(result.duration_s, every_s)
    # per sample time: the frame nearest to it and every track's box in that frame
    frame_ts = sorted({r[0] for rows in result.track_boxes.values() for r in rows})
    boxes_at: dict[float, dict[int, list[float]]] = {t: {} for t in times}
    nearest = {}
    for t in times:
        if frame_ts:
            nearest[t] = min(frame_ts, key=lambda f: abs(f - t))
    for tid, rows in result.track_boxes.items():
        by_t = {r[0]: r[1:5] for r in rows}
        for t in times:
            if t in nearest and nearest[t] in by_t and abs(nearest[t] - t) <= every_s / 2:
                boxes_at[t][tid] = [round(v, 1) for v in by_t[nearest[t]]]
    dest = out / path.stem
    dest.mkdir(parents=True, exist_ok=True)
    for old in dest.glob("sheet_*.png"):
        old.unlink()
    (dest / "proposals.json").write_text(json.dumps(dict(
        clip=path.name, folder=folder, every_s=every_s, **info,
        boxes={f"{t:.3f}": {str(k): v for k, v in b.items()} for t, b in boxes_at.items()})))
    cells = [draw_cell(img, t, boxes_at[t]) for t, img in frames_at(path, times)]
    cols = 3 if info["width"] >= info["height"] else 4
    for k in range(0, len(cells), per_sheet):
        sheet = tile(cells[k:k + per_sheet], cols)
        cv2.imwrite(str(dest / f"sheet_{k // per_sheet:02d}.png"), sheet)
    print(f"{path.name}: {len(times)} times, {len(result.track_boxes)} tracks, sheets in {dest}")
    return dest


def frames_at(path: Path, times: list[float]) -> list[tuple[float, np.ndarray]]:
    """(t, image) of the frame nearest each of ``times`` on the clip's media clock (its decode timestamps), the clock
    the scan stamps frames with (``rsu.frames.VideoSource``). Seeking by time (``CAP_PROP_POS_MSEC``) lands on frame
    ``t * fps`` instead, another frame once a clip skips frames (the two Indian night clips jump 0.3 s at 8 s): the
    sheet would show each later time's frame 0.3 s late beside the scan's boxes of that time."""
    best: dict[float, tuple[float, np.ndarray]] = {}
    cap = cv2.VideoCapture(str(path))
    try:
        while True:
            ok, img = cap.read()
            if not ok:
                break
            media_s = float(cap.get(cv2.CAP_PROP_POS_MSEC) or 0.0) / 1000.0
            for t in times:
                if t not in best or abs(media_s - t) < best[t][0]:
                    best[t] = (abs(media_s - t), img)
    finally:
        cap.release()
    return [(t, best[t][1]) for t in times if t in best]


def draw_cell(img: np.ndarray, t: float, boxes: dict[int, list[float]]) -> np.ndarray:
    h, w = img.shape[:2]
    scale = SHEET_CELL_W / w if w >= h else SHEET_CELL_W * 0.75 / w
    out = cv2.resize(img, (int(round(w * scale)), int(round(h * scale))), interpolation=cv2.INTER_AREA)
    step = 50 if max(w, h) <= 480 else 100
    for x in range(0, w, step):
        cv2.line(out, (int(x * scale), 0), (int(x * scale), out.shape[0]), (255, 255, 0), 1)
        if x % (2 * step) == 0:
            _text(out, str(x), (int(x * scale) + 2, out.shape[0] - 4), (255, 255, 0), 0.35)
    for y in range(0, h, step):
        cv2.line(out, (0, int(y * scale)), (out.shape[1], int(y * scale)), (255, 255, 0), 1)
        if y % (2 * step) == 0 and y:
            _text(out, str(y), (2, int(y * scale) - 2), (255, 255, 0), 0.35)
    for tid, b in boxes.items():
        x1, y1, x2, y2 = (int(round(v * scale)) for v in b)
        cv2.rectangle(out, (x1, y1), (x2, y2), (0, 255, 0), 1)
        _text(out, str(tid), (x1, max(10, y1 - 2)), (0, 255, 255), 0.45)
    _text(out, f"t={t:.1f}s", (4, 16), (255, 255, 255), 0.55)
    return out


def tile(cells: list[np.ndarray], cols: int) -> np.ndarray:
    h = max(c.shape[0] for c in cells)
    w = max(c.shape[1] for c in cells)
    rows = int(math.ceil(len(cells) / cols))
    sheet = np.zeros((rows * (h + 4), cols * (w + 4), 3), np.uint8)
    for k, c in enumerate(cells):
        r, q = divmod(k, cols)
        sheet[r * (h + 4):r * (h + 4) + c.shape[0], q * (w + 4):q * (w + 4) + c.shape[1]] = c
    return sheet


def _text(img, text, org, colour, size) -> None:
    cv2.putText(img, text, org, cv2.FONT_HERSHEY_SIMPLEX, size, (0, 0, 0), 3, cv2.LINE_AA)
    cv2.putText(img, text, org, cv2.FONT_HERSHEY_SIMPLEX, size, colour, 1, cv2.LINE_AA)


def parse_ranges(text: str, duration_s: float) -> list[tuple[float, float]]:
    """``all`` / ``none`` / ``A-B,C-D`` (seconds) as a list of closed ranges; ValueError naming the bad part."""
    if text == "all":
        return [(0.0, duration_s + 1.0)]
    if text in ("none", ""):
        return []
    out = []
    for part in text.split(","):
        try:
            a, b = (float(v) for v in part.split("-"))
        except ValueError:
            raise ValueError(f"time range {part!r}: expected A-B in seconds (e.g. 0-5.5)") from None
        if b < a:
            raise ValueError(f"time range {part!r}: ends before it starts")
        out.append((a, b))
    return out


def parse_vehicle(spec: str, role: str, duration_s: float) -> dict:
    name, *fields = spec.split()
    d = dict(name=name, role=role, kind="ambulance" if role == "ev" else "hazard", tracks=[],
             t=None, lit="all")
    for f in fields:
        key, _, val = f.partition("=")
        if key == "kind":
            d["kind"] = val
        elif key == "tracks":
            d["tracks"] = [int(v) for v in val.split(",") if v]
        elif key == "t":
            d["t"] = parse_ranges(val, duration_s)
        elif key == "lit":
            d["lit"] = val
        else:
            raise ValueError(f"{spec!r}: unknown field {key!r} (kind=, tracks=, t=, lit=)")
    d["lit"] = parse_ranges(d["lit"], duration_s)
    return d


def in_ranges(t: float, ranges: list[tuple[float, float]] | None) -> bool:
    return ranges is None or any(a - 1e-6 <= t <= b + 1e-6 for a, b in ranges)


def build_labels(proposals: dict, viewpoint: str, vehicles: list[dict], boxes: list[str], gone: list[str],
                 note: str) -> ClipLabels:
    """The label file from the proposals and the choices (pure: what ``write`` saves)."""
    duration_s = float(proposals["duration_s"])
    by_name = {v["name"]: v for v in vehicles}
    manual: dict[str, dict[float, list[float]]] = {n: {} for n in by_name}
    for b in boxes:
        parts = b.split()
        if len(parts) != 6 or parts[0] not in by_name:
            raise ValueError(f"--box {b!r}: expected 'NAME T X1 Y1 X2 Y2' with NAME one of {sorted(by_name)}")
        manual[parts[0]][round(float(parts[1]), 3)] = [float(v) for v in parts[2:]]
    away: dict[str, list[tuple[float, float]]] = {n: [] for n in by_name}
    for g in gone:
        n, _, r = g.partition(" ")
        if n not in by_name:
            raise ValueError(f"--gone {g!r}: expected 'NAME T0-T1' with NAME one of {sorted(by_name)}")
        away[n] += parse_ranges(r.strip(), duration_s)
    out = []
    for v in vehicles:
        keys: dict[float, list[float]] = {}
        for ts, b in proposals["boxes"].items():
            t = float(ts)
            if not in_ranges(t, v["t"]):
                continue
            for tid in v["tracks"]:
                if str(tid) in b:
                    keys[t] = b[str(tid)]
                    break
        keys.update(manual[v["name"]])
        frames = [(t, *box, in_ranges(t, v["lit"])) for t, box in sorted(keys.items())
                  if not any(a <= t <= b for a, b in away[v["name"]])]
        if not frames:
            raise ValueError(f"vehicle {v['name']!r}: no box (its tracks are absent in t=, and no --box)")
        out.append(LabelledVehicle(v["name"], v["role"], v["kind"], tuple(frames)))
    return ClipLabels(proposals["clip"], proposals["folder"], viewpoint, int(proposals["width"]),
                      int(proposals["height"]), float(proposals["fps"]), duration_s, tuple(out), note)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    p = sub.add_parser("propose", help="detector + tracker proposals and contact sheets")
    p.add_argument("clip")
    p.add_argument("--out", type=Path, default=WORK_DIR)
    p.add_argument("--every-s", type=float, default=0.5)
    p.add_argument("--per-sheet", type=int, default=12)
    w = sub.add_parser("write", help="the label file from the proposals and your choices")
    w.add_argument("clip")
    w.add_argument("--viewpoint", required=True, choices=VIEWPOINTS)
    w.add_argument("--ev", action="append", default=[], help="'NAME kind=K tracks=A,B t=A-B lit=A-B,...'")
    w.add_argument("--flasher", action="append", default=[], help="same fields as --ev")
    w.add_argument("--box", action="append", default=[], help="'NAME T X1 Y1 X2 Y2' (clip pixels)")
    w.add_argument("--gone", action="append", default=[], help="'NAME T0-T1': not in view")
    w.add_argument("--note", default="")
    w.add_argument("--work", type=Path, default=WORK_DIR, help="where propose wrote its proposals")
    w.add_argument("--out", type=Path, default=LABELS_DIR)
    args = ap.parse_args(argv)
    try:
        if args.cmd == "propose":
            propose(args.clip, args.out, args.every_s, args.per_sheet)
            return 0
        path, folder = find_clip(args.clip)
        prop_file = args.work / path.stem / "proposals.json"
        if prop_file.is_file():
            proposals = json.loads(prop_file.read_text())
        elif not (args.ev or args.flasher):  # a clip with no vehicle to label needs no proposals
            proposals = dict(clip=path.name, folder=folder, boxes={}, **video_info(path))
        else:
            raise FileNotFoundError(f"{prop_file} absent: run `label_tool.py propose {args.clip}` first")
        vehicles = [parse_vehicle(s, "ev", proposals["duration_s"]) for s in args.ev]
        vehicles += [parse_vehicle(s, "flasher", proposals["duration_s"]) for s in args.flasher]
        labels = build_labels(proposals, args.viewpoint, vehicles, args.box, args.gone, args.note)
        dest = write_labels(labels, args.out / f"{path.stem}.json")
        print(f"{dest}: {len(labels.vehicles)} vehicles ({sum(v.role == 'ev' for v in labels.vehicles)} EV)")
    except (FileNotFoundError, ValueError) as exc:
        print(f"label_tool: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
