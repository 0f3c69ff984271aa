"""``iea-sim``: run a scenario in real time, render frames, export a dataset.

    iea-sim run rellis_ev_yield [--corridor-id ID] [--record rsu1:out.mp4] [--speed 2.0]
    iea-sim render rellis_ev_yield --t 12.0 --out runs/frames
    iea-sim export-dataset --out datasets/sim --frames 2000 [--scenario NAME ...] [--seed 0]
    iea-sim list
"""

from __future__ import annotations

import argparse
import logging
import signal
import sys
from pathlib import Path

from protocol.transport import ZenohSettings


def _add_run(sub) -> None:
    p = sub.add_parser("run", help="run a scenario in real time, publishing WorldSnapshot at 20 Hz",
                       description="Run a scenario in real time: WorldSnapshot at 20 Hz on iea/{c}/sim/world, "
                                   "Health at 1 Hz; the AV pose follows iea/{c}/vehicle/{veh}/state when published.")
    p.add_argument("scenario", help="scenario name (see 'iea-sim list') or path to a .toml file")
    p.add_argument("--corridor", default=None, help="corridor TOML file (default: the scenario's)")
    p.add_argument("--corridor-id", default=None, help="corridor id used in key expressions (default: the file's)")
    p.add_argument("--record", action="append", default=[], metavar="RSU:FILE.mp4",
                   help="record this RSU camera's rendered view to a video (repeatable)")
    p.add_argument("--speed", type=float, default=1.0, help="time scale: 2.0 runs twice as fast as real time")
    p.add_argument("--duration", type=float, default=None, help="stop after this many sim seconds")
    p.add_argument("--seed", type=int, default=None, help="override the scenario's seed")
    p.add_argument("--wait-for-av", type=float, default=None, metavar="S",
                   help="hold the world at t = 0 until the scenario's AV reports its state from a vehicle process "
                        "(at most S seconds, then start with the scripted AV); use it when a vehicle process drives "
                        "the AV, so the world and the car start together")
    p.add_argument("--lighting", choices=["day", "dusk", "night"], default=None, help="override the lighting")
    ZenohSettings.add_arguments(p)


def _cmd_run(args) -> int:
    from protocol.corridor import load_corridor
    from protocol.transport import ZenohTransport
    from sim.scenario import load_scenario
    from sim.service import Recording, SimService

    if args.wait_for_av is not None and not args.wait_for_av >= 0:
        raise ValueError(f"--wait-for-av wants seconds >= 0, got {args.wait_for_av}")
    corridor = load_corridor(args.corridor) if args.corridor else None
    sc = load_scenario(args.scenario, corridor).with_overrides(seed=args.seed, lighting=args.lighting)
    recs = []
    for item in args.record:
        rsu, sep, path = item.partition(":")
        if not sep or not path:
            raise ValueError(f"--record wants RSU:FILE.mp4, got {item!r}")
        sc.corridor.rsu(rsu)
        recs.append(Recording(rsu, path))
    transport = ZenohTransport(ZenohSettings.from_args(args))
    try:
        svc = SimService(sc, transport, corridor_id=args.corridor_id, speed=args.speed, duration_s=args.duration,
                         recordings=recs)
        signal.signal(signal.SIGTERM, lambda *_: svc.stop())
        signal.signal(signal.SIGINT, lambda *_: svc.stop())
        n = svc.run(wait_for_av_s=args.wait_for_av)
        logging.getLogger("iea.sim").info("published %d snapshots", n)
    finally:
        transport.close()
    return 0


def _cmd_render(args) -> int:
    import cv2

    from sim.render import Renderer
    from sim.scenario import load_scenario
    from sim.world import World

    sc = load_scenario(args.scenario).with_overrides(seed=args.seed, lighting=args.lighting)
    world = World(sc)
    world.run_until(args.t)
    snap = world.snapshot()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    for rsu in sc.corridor.rsus:
        if args.rsu and rsu.rsu_id not in args.rsu:
            continue
        r = Renderer(rsu.camera, sc.corridor.road, seed=world.seed)
        img = r.render(snap)
        if args.boxes:
            for lb in r.labels(snap):
                x1, y1, x2, y2 = (int(round(v)) for v in lb.bbox_px)
                cv2.rectangle(img, (x1, y1), (x2, y2), (0, 255, 255) if lb.class_id else (0, 255, 0), 1)
        path = out / f"{sc.name}_{rsu.rsu_id}_t{args.t:06.2f}.png"
        cv2.imwrite(str(path), img)
        print(path)
    return 0


def _cmd_export(args) -> int:
    from sim.dataset import ExportConfig, export_dataset

    kw = {}
    if args.scenario:
        kw["scenarios"] = args.scenario
    cfg = ExportConfig(out=args.out, frames=args.frames, seed=args.seed, stride_s=args.stride_s,
                       val_every=args.val_every, vary_lighting=not args.no_vary_lighting, rsus=args.rsu or [], **kw)
    counts = export_dataset(cfg, progress=not args.quiet)
    print(" ".join(f"{k}={v}" for k, v in counts.items()))
    return 0


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="iea-sim", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("-v", "--verbose", action="store_true")
    sub = ap.add_subparsers(dest="cmd", required=True)
    _add_run(sub)
    p = sub.add_parser("render", help="render one PNG per RSU camera at a sim time")
    p.add_argument("scenario")
    p.add_argument("--t", type=float, required=True, help="sim time (s)")
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--rsu", action="append", default=[], help="only this RSU (repeatable)")
    p.add_argument("--seed", type=int, default=None)
    p.add_argument("--lighting", choices=["day", "dusk", "night"], default=None)
    p.add_argument("--boxes", action="store_true", help="draw the ground-truth label boxes")
    p = sub.add_parser("export-dataset", help="write a YOLO detection set, EV crops and MOT ground truth")
    p.add_argument("--out", required=True, help="output folder (resumes an export already there)")
    p.add_argument("--frames", type=int, required=True, help="number of camera frames to export")
    p.add_argument("--scenario", action="append", default=[], help="scenario to use (repeatable; default: all five)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--stride-s", type=float, default=0.35,
                   help="sim time between exported frames of a camera (default 0.35: does not alias with 1-4 Hz bars)")
    p.add_argument("--val-every", type=int, default=5, help="every N-th episode is validation")
    p.add_argument("--rsu", action="append", default=[], help="only these cameras (repeatable)")
    p.add_argument("--no-vary-lighting", action="store_true", help="keep each scenario's lighting")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    sub.add_parser("list", help="list the scenarios")
    return ap


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO, format="%(asctime)s %(name)s %(message)s")
    try:
        if args.cmd == "run":
            return _cmd_run(args)
        if args.cmd == "render":
            return _cmd_render(args)
        if args.cmd == "export-dataset":
            return _cmd_export(args)
        from sim.scenario import list_scenarios

        print("\n".join(list_scenarios()))
        return 0
    except (ValueError, KeyError) as exc:  # ScenarioError, CorridorError, ExportError are ValueErrors
        print(f"iea-sim: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    raise SystemExit(main())
