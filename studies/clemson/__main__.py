"""``python -m studies.clemson``: the Clemson comparison's driving data export and its vehicle with learned steering.

    python -m studies.clemson export --out datasets/driving [--train-episodes 24 --val-episodes 6 --test-episodes 8]
    python -m studies.clemson vehicle --case 2 [iea-vehicle run options]
"""

from __future__ import annotations

import argparse
import sys


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="python -m studies.clemson", description=(
        "The Clemson hazard-navigation comparison: export the teacher's dashcam driving data, or run the vehicle "
        "process steered by the dashcam CNN while it drives in lane (the thesis controller keeps commanded "
        "manoeuvres and the fail-safe; it needs the simulator's world)."))
    sub = ap.add_subparsers(dest="cmd", required=True)
    p = sub.add_parser("export", help="dashcam driving data of the teacher on hazard episodes",
                       description="Record (dashcam image, hazard mask, threat values, steering angle) from the "
                                   "thesis controller avoiding debris on seeded roads, three cameras, with the "
                                   "Clemson report's augmentation; split by episode seed (studies/clemson/export.py).")
    p.add_argument("--out", required=True, help="output folder ({train,val,test}.npz, meta.json)")
    p.add_argument("--train-episodes", type=int, default=24)
    p.add_argument("--val-episodes", type=int, default=6)
    p.add_argument("--test-episodes", type=int, default=8, help="held-out episodes (the bench's seeds 2000..)")
    p.add_argument("--stride-s", type=float, default=0.2, help="sim time between recorded frames (default 0.2)")
    p.add_argument("--seed", type=int, default=0, help="seed of the augmentation and sensor noise")
    p.add_argument("--episode-offset", type=int, default=0,
                   help="train seeds start here, val at 1000 + it (a second export on other roads)")
    p.add_argument("--late-triggers", default="", metavar="M,M",
                   help="train/val episodes cycle through the DDM's trigger and these late ones (m to the debris): "
                        "demonstrations of avoiding debris seen late")
    p.add_argument("--quiet", action="store_true", help="no progress line")
    v = sub.add_parser("vehicle", help="iea-vehicle run with the learned steering of one case",
                       description="Every option after --case is an `iea-vehicle run` option.")
    v.add_argument("--case", type=int, choices=(1, 2, 3), required=True,
                   help="1: camera image; 2: image fused with the radar's threat value; 3: with the image's")
    return ap


def main(argv: list[str] | None = None) -> int:
    args, rest = build_parser().parse_known_args(argv)
    if args.cmd == "export":
        if rest:
            print(f"python -m studies.clemson export: unknown arguments {rest}", file=sys.stderr)
            return 2
        from studies.clemson.export import DrivingExportConfig, export_driving

        try:
            counts = export_driving(DrivingExportConfig(
                out=args.out, train_episodes=args.train_episodes, val_episodes=args.val_episodes,
                test_episodes=args.test_episodes, stride_s=args.stride_s, seed=args.seed,
                episode_offset=args.episode_offset,
                late_triggers_m=tuple(float(v) for v in args.late_triggers.split(",") if v.strip())),
                progress=not args.quiet)
        except ValueError as exc:
            print(f"python -m studies.clemson export: error: {exc}", file=sys.stderr)
            return 2
        print(" ".join(f"{k}={v}" for k, v in counts.items()))
        return 0
    from protocol.runtime import stop_on_ctrl_c
    from studies.clemson.learned_steering import attach_camera
    from vehicle.cli import build_parser as vehicle_parser
    from vehicle.cli import run_from_args

    stop_on_ctrl_c()
    parser = vehicle_parser()
    vargs = parser.parse_args(["run", *rest])
    vargs.parser = parser
    case = args.case
    try:
        return run_from_args(vargs, "python -m studies.clemson vehicle",
                             attach=lambda service, transport: attach_camera(service, transport, case))
    except ValueError as exc:
        print(f"python -m studies.clemson vehicle: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    raise SystemExit(main())
