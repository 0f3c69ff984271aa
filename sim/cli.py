"""``iea-sim``: run a scenario in real time, render frames, export a dataset.

    iea-sim run rellis_ev_yield [--corridor-id ID] [--record rsu1:out.mp4] [--speed 2.0]
    iea-sim render rellis_ev_yield --t 12.0 --out runs/frames
    iea-sim export-dataset --out datasets/sim --frames 2000 [--scenario NAME ...] [--seed 0]
    iea-sim list
Every command takes --log-level (default: $IEA_LOG_LEVEL, else INFO).
"""

from __future__ import annotations

import argparse
import sys

from protocol import metrics
from protocol.logsetup import add_log_level_argument, configure_logging
from protocol.zenoh_transport import ZenohSettings


def probability(text: str) -> float:
    """argparse type: a probability in [0, 1] (anything else: exit 2 naming the value)."""
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a probability in [0, 1], got {text!r}") from None
    if not 0.0 <= v <= 1.0:
        raise argparse.ArgumentTypeError(f"must be a probability in [0, 1], got {text}")
    return v


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
    p.add_argument("--wait-for-rsus", default=None, metavar="IDS",
                   help="hold the world at t = 0 until these RSUs are up (their liveliness tokens): 'all' for every "
                        "RSU of the corridor, or comma-separated ids; a scenario started before its cameras measures "
                        "their start-up, not the corridor")
    p.add_argument("--wait-timeout", type=float, default=60.0, metavar="S",
                   help="with --wait-for-rsus: start anyway after S seconds, naming who is missing (default 60)")
    p.add_argument("--lighting", choices=["day", "dusk", "night"], default=None, help="override the lighting")
    p.add_argument("--ev-key", default=None, metavar="PEM",
                   help="an equipped EV signs its CAMs with this key (the corridor trusts it with role ev)")
    p.add_argument("--ev-radio-loss", type=probability, default=None, metavar="P",
                   help="an equipped EV's radio loses each CAM with probability P in [0, 1] (default: the corridor's "
                        "dsrc_loss)")
    p.add_argument("--traffic", choices=["project", "sumo"], default=None,
                   help="who drives the traffic: the simulator's own model or Eclipse SUMO (default: the scenario's)")
    ZenohSettings.add_arguments(p)
    metrics.add_arguments(p)


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="iea-sim", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
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
    for p in sub.choices.values():
        add_log_level_argument(p)
    return ap


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    configure_logging(parser, args)
    from sim.dataset import ExportConfig, export_dataset, render_views
    from sim.scenario import list_scenarios
    from sim.service import run_scenario

    try:
        if args.cmd == "run":
            if args.traffic == "sumo":
                from sim.sumo import sumo_missing

                if (why := sumo_missing()) is not None:
                    print(f"iea-sim: error: --traffic sumo: {why}", file=sys.stderr)
                    return 2
            metrics.serve_from_args(args, "sim", "sim")
            return run_scenario(args.scenario, ZenohSettings.from_args(args), corridor_file=args.corridor,
                                corridor_id=args.corridor_id, record=args.record, speed=args.speed,
                                duration_s=args.duration, seed=args.seed, lighting=args.lighting,
                                wait_for_av_s=args.wait_for_av, wait_for_rsus=args.wait_for_rsus,
                                wait_timeout_s=args.wait_timeout, ev_key=args.ev_key, traffic=args.traffic,
                                ev_radio_loss=args.ev_radio_loss)
        if args.cmd == "render":
            for path in render_views(args.scenario, args.t, args.out, rsus=args.rsu, seed=args.seed,
                                     lighting=args.lighting, boxes=args.boxes):
                print(path)
            return 0
        if args.cmd == "export-dataset":
            kw = {"scenarios": args.scenario} if args.scenario else {}
            cfg = ExportConfig(out=args.out, frames=args.frames, seed=args.seed, stride_s=args.stride_s,
                               val_every=args.val_every, vary_lighting=not args.no_vary_lighting, rsus=args.rsu or [],
                               **kw)
            counts = export_dataset(cfg, progress=not args.quiet)
            print(" ".join(f"{k}={v}" for k, v in counts.items()))
            return 0
        print("\n".join(list_scenarios()))
        return 0
    except (ValueError, KeyError) as exc:  # ScenarioError, CorridorError, ExportError are ValueErrors
        print(f"iea-sim: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    raise SystemExit(main())
