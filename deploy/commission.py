"""`iea calibrate RSU --image FRAME --points PAIRS.csv [--corridor FILE] [--write]`: commission a camera.

Reads the surveyed pairs (CSV: ``name,u_px,v_px,x_m,y_m[,z_m]`` in the corridor frame, or
``name,u_px,v_px,lat_deg,lon_deg[,height_m]``), solves the camera (``rsu.calibration.solve``), prints the pose,
the reprojection error per point and overall, the points left out, and the expected ground error per
distance band beside the location-reference method's (``rsu.calibration.error``); writes the check image
(``rsu.calibration.overlay``). ``--write`` puts the pose, the intrinsics and the road-plane pairs into the corridor file,
printing the unified diff first. Exit codes: 0 ok, 1 the pairs give no camera, 2 bad input.
"""

from __future__ import annotations

import argparse
import difflib
import math
import re
import sys
import tomllib
from pathlib import Path

import cv2
import numpy as np

from protocol.corridor import DEFAULT_CORRIDOR, CameraConfig, CorridorError, load_corridor, parse_corridor
from rsu.calibration.error import GROUND_TOLERANCE_M, error_table, format_error_table
from rsu.calibration.overlay import OverlayPoint, check_image
from rsu.calibration.solve import CalibrationError, CameraSolution, SurveyPoint, read_points_csv, solve_camera

_TABLE = re.compile(r"^\s*\[{1,2}\s*[A-Za-z_\"']")
"""A table header line ([x] or [[x]]), not a row of an array of numbers."""
_KEY = re.compile(r"^(\s*)([A-Za-z_][A-Za-z0-9_]*)(\s*=\s*)([^#\n]*?)(\s*(#.*)?)$")


def _fmt(v: float, digits: int = 4) -> str:
    return repr(round(float(v), digits))


def corridor_text_with_camera(text: str, rsu_id: str, cam: CameraConfig, pairs: list[SurveyPoint]) -> str:
    """The corridor TOML ``text`` with the RSU's position, camera block and calibration pairs replaced (or a new
    ``[[rsu]]`` block appended); comments and everything else are kept."""
    lines = text.splitlines()
    calib = ["calibration = ["] + [f"  [{p.u_px:.1f}, {p.v_px:.1f}, {p.x_m:.3f}, {p.y_m:.3f}],  # {p.name}"
                                    for p in pairs] + ["]"]
    camera = {"height_m": _fmt(cam.height_m), "yaw_rad": _fmt(cam.yaw_rad, 6), "pitch_rad": _fmt(cam.pitch_rad, 6),
              "roll_rad": _fmt(cam.roll_rad, 6), "width_px": str(cam.width_px), "height_px": str(cam.height_px),
              "fx_px": _fmt(cam.fx_px, 2), "fy_px": _fmt(cam.fy_px, 2), "cx_px": _fmt(cam.cx_px, 2),
              "cy_px": _fmt(cam.cy_px, 2)}
    starts = [i for i, ln in enumerate(lines) if ln.strip() == "[[rsu]]"]
    block = None
    for s in starts:
        end = next((j for j in range(s + 1, len(lines)) if _TABLE.match(lines[j])
                    and not re.match(r"^\s*\[rsu\.", lines[j])), len(lines))
        sub = next((j for j in range(s + 1, end) if re.match(r"^\s*\[rsu\.camera\]", lines[j])), end)
        if any((m := _KEY.match(lines[j])) and m.group(2) == "id" and m.group(4).strip().strip("\"'") == rsu_id
               for j in range(s + 1, sub)):
            block = (s, sub, end)
    if block is None:
        new = ["", "[[rsu]]", f'id = "{rsu_id}"', f"x_m = {_fmt(cam.x_m)}", f"y_m = {_fmt(cam.y_m)}", *calib,
               "  [rsu.camera]", *(f"  {k} = {v}" for k, v in camera.items())]
        return "\n".join(lines + new) + "\n"
    s, sub, end = block
    head = _set_keys(lines[s:sub], {"x_m": _fmt(cam.x_m), "y_m": _fmt(cam.y_m)})
    head = _replace_array(head, "calibration", calib)
    cam_lines = _set_keys(lines[sub:end], camera, indent="  ")
    return "\n".join(lines[:s] + head + cam_lines + lines[end:]) + "\n"


def _set_keys(lines: list[str], values: dict[str, str], indent: str = "") -> list[str]:
    out, done = list(lines), set()
    for i, ln in enumerate(out):
        m = _KEY.match(ln)
        if m and m.group(2) in values:
            out[i] = f"{m.group(1)}{m.group(2)}{m.group(3)}{values[m.group(2)]}{m.group(5)}"
            done.add(m.group(2))
    last = max((i for i, ln in enumerate(out) if _KEY.match(ln) or _TABLE.match(ln)), default=len(out) - 1)
    missing = [f"{indent}{k} = {v}" for k, v in values.items() if k not in done]
    return out[:last + 1] + missing + out[last + 1:]


def _replace_array(lines: list[str], key: str, new: list[str]) -> list[str]:
    start = next((i for i, ln in enumerate(lines) if re.match(rf"^\s*{key}\s*=", ln)), None)
    if start is None:
        return lines + new
    depth, end = 0, start
    for end in range(start, len(lines)):
        depth += lines[end].split("#")[0].count("[") - lines[end].split("#")[0].count("]")
        if depth <= 0:
            break
    return lines[:start] + new + lines[end + 1:]


def read_frame(path: str, frame_s: float) -> np.ndarray:
    """An image file, or the frame at ``frame_s`` of a video."""
    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"--image {path}: no such file")
    img = cv2.imread(str(p), cv2.IMREAD_COLOR)
    if img is None:
        cap = cv2.VideoCapture(str(p))
        cap.set(cv2.CAP_PROP_POS_MSEC, 1000.0 * frame_s)
        ok, img = cap.read()
        cap.release()
        if not ok:
            raise ValueError(f"--image {path}: neither an image nor a video OpenCV can read")
    return img


def report(sol: CameraSolution) -> str:
    c, sd = sol.camera, sol.pose_sigma
    lines = [f"camera: x {c.x_m:.3f} +- {sd['x_m']:.3f} m, y {c.y_m:.3f} +- {sd['y_m']:.3f} m, "
             f"height {c.height_m:.3f} +- {sd['height_m']:.3f} m",
             f"        yaw {math.degrees(c.yaw_rad):.3f} +- {sd['yaw_deg']:.3f} deg, pitch "
             f"{math.degrees(c.pitch_rad):.3f} +- {sd['pitch_deg']:.3f} deg, roll {math.degrees(c.roll_rad):.3f} "
             f"+- {sd['roll_deg']:.3f} deg",
             f"        fx {c.fx_px:.1f}" + (f" +- {sd['fx_px']:.1f} px (solved)" if sol.focal_solved else " px (given)")
             + f", principal point ({c.cx_px:.1f}, {c.cy_px:.1f}), k1 "
             + (f"{sol.dist[0]:+.4f} +- {sd['k1']:.4f} (solved)" if sol.distortion_solved else "0")]
    lines += [f"note: {n}" for n in sol.notes]
    lines.append(f"reprojection error: {sol.rms_px:.2f} px RMS over {len(sol.kept)} of {len(sol.points)} points "
                 f"(a point beyond {sol.flag_px:.1f} px is left out)")
    for r in sol.residuals:
        lines.append(f"  {r.name:<12} measured ({r.measured_uv[0]:7.1f}, {r.measured_uv[1]:7.1f})  reprojected "
                     f"({r.reprojected_uv[0]:7.1f}, {r.reprojected_uv[1]:7.1f})  {r.error_px:6.2f} px"
                     + ("  LEFT OUT: disagrees with the others" if r.flagged else ""))
    if sol.flagged:
        lines.append(f"points that disagree: {', '.join(sol.flagged)} (check their pixel and survey record)")
    return "\n".join(lines)


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="iea calibrate", description=__doc__.split("\n\n")[1], formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="Survey 8 or more points spread over the whole image (near and far, left and right; poles or sign "
               "tops with their height help), not only along the road: points on one line leave the roll free. "
               "example: iea calibrate rsu1 --image frame.png --points rsu1_pairs.csv --write")
    ap.add_argument("rsu", help="RSU id (a new id adds an [[rsu]] block with --write)")
    ap.add_argument("--image", required=True, help="a frame of the camera (image file, or a video: see --frame-s)")
    ap.add_argument("--frame-s", type=float, default=0.0, help="time of the frame in a video (s)")
    ap.add_argument("--points", required=True, help="CSV of surveyed pairs (see above)")
    ap.add_argument("--corridor", default=str(DEFAULT_CORRIDOR), help="corridor file (default: rellis)")
    ap.add_argument("--fx-px", type=float, default=None,
                    help="focal length guess (px); default: the corridor's camera, else a sweep")
    ap.add_argument("--solve-focal", choices=["auto", "yes", "no"], default="auto",
                    help="auto: solve the focal length when the points fix it (1-sigma < 2 %%)")
    ap.add_argument("--solve-distortion", choices=["auto", "yes", "no"], default="auto",
                    help="auto: solve k1 from 12+ points when significant (it is reported; the corridor's "
                         "camera model is pinhole, so it is not written)")
    ap.add_argument("--pixel-sigma-px", type=float, default=1.0, help="detection pixel noise for the error table")
    ap.add_argument("--check-image", default=None, help="where to write the check image (default RSU_check.jpg)")
    ap.add_argument("--write", action="store_true", help="write pose and pairs into the corridor file (diff shown)")
    return ap


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        corridor = load_corridor(args.corridor)
        frame = read_frame(args.image, args.frame_s)
        old = next((r for r in corridor.rsus if r.rsu_id == args.rsu), None)
        pts = read_points_csv(Path(args.points).read_text(encoding="utf-8"), corridor.from_latlon, args.points)
    except (CorridorError, FileNotFoundError, ValueError, OSError) as exc:
        print(f"iea calibrate: {exc}", file=sys.stderr)
        return 2
    h, w = frame.shape[:2]
    fx = args.fx_px
    cx = cy = None
    if old is not None and (old.camera.width_px, old.camera.height_px) == (w, h):
        fx = fx or old.camera.fx_px
        cx, cy = old.camera.cx_px, old.camera.cy_px
    elif old is not None:
        print(f"note: the corridor's {args.rsu} camera is {old.camera.width_px}x{old.camera.height_px}, the frame "
              f"{w}x{h}: its intrinsics are not used")
    print(f"{args.rsu}: {len(pts)} pairs, frame {w}x{h}", flush=True)
    try:
        sol = solve_camera(pts, w, h, fx_px=fx, cx_px=cx, cy_px=cy, solve_focal=args.solve_focal,
                           solve_distortion=args.solve_distortion, pixel_sigma_px=args.pixel_sigma_px,
                           fps=old.camera.fps if old else 15.0)
    except CalibrationError as exc:
        print(f"iea calibrate: {exc}", file=sys.stderr)
        return 1
    print(report(sol))
    max_range = old.max_range_m if old is not None and old.max_range_m else 100.0
    rows = error_table(sol, corridor.road, max_range, args.pixel_sigma_px)
    print(format_error_table(rows, args.pixel_sigma_px))
    out = Path(args.check_image or f"{args.rsu}_check.jpg")
    pts_o = [OverlayPoint(r.name, r.measured_uv, r.reprojected_uv, r.flagged) for r in sol.residuals]
    img = check_image(frame, sol.camera, corridor.road, dist=sol.dist, max_range_m=max_range, points=pts_o,
                      title=f"{args.rsu}: {sol.rms_px:.2f} px RMS")
    if not cv2.imwrite(str(out), img, [cv2.IMWRITE_JPEG_QUALITY, 85]):
        print(f"iea calibrate: cannot write the check image {out}", file=sys.stderr)
        return 2
    print(f"check image: {out}")
    ground = [p for p in sol.kept if abs(p.z_m) <= GROUND_TOLERANCE_M]
    if not args.write:
        print(f"(--write puts the pose and {len(ground)} road-plane pairs into {args.corridor})")
        return 0
    path = Path(args.corridor)
    text = path.read_text(encoding="utf-8")
    new = corridor_text_with_camera(text, args.rsu, sol.camera, ground)
    try:
        parse_corridor(tomllib.loads(new), str(path)).rsu(args.rsu)
    except (tomllib.TOMLDecodeError, CorridorError, KeyError) as exc:
        print(f"iea calibrate: the updated corridor would not load ({exc}); nothing written", file=sys.stderr)
        return 2
    sys.stdout.writelines(difflib.unified_diff(text.splitlines(True), new.splitlines(True), str(path), str(path)))
    path.write_text(new, encoding="utf-8")
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
