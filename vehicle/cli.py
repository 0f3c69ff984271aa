"""``iea-vehicle``: run the vehicle process, replay the field test in lockstep, plot a run."""

from __future__ import annotations

import argparse
import json
import sys

from protocol import metrics
from protocol.logsetup import add_log_level_argument, configure_logging
from protocol.runtime import stop_on_ctrl_c
from protocol.zenoh_transport import ZenohSettings


def _positive(text: str) -> float:
    v = float(text)
    if not v > 0:
        raise argparse.ArgumentTypeError(f"must be > 0, got {text}")
    return v


def _non_negative(text: str) -> float:
    v = float(text)
    if not v >= 0:
        raise argparse.ArgumentTypeError(f"must be >= 0, got {text}")
    return v


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="iea-vehicle", description=(
        "Autonomous vehicle process of the IEA corridor: follows path-switch commands from the DDM with the "
        "thesis's lateral controller on a simulated dynamic bicycle, publishes its state, stops safely when "
        "it loses the DDM or its localisation."))
    sub = p.add_subparsers(dest="command", required=True)

    run = sub.add_parser("run", help="run the vehicle service over Zenoh in real time")
    run.add_argument("--corridor", metavar="FILE", default=None, help="corridor TOML (default: deploy/corridors/rellis.toml)")
    run.add_argument("--corridor-id", metavar="ID", default=None, help="override the corridor id (key prefix), e.g. for tests")
    run.add_argument("--vehicle", metavar="ID", default="av1", help="vehicle id in the corridor file (default av1)")
    run.add_argument("--start-s", type=_non_negative, default=None, metavar="M",
                     help="start station along the road (m; default: the corridor file's, e.g. a scenario's AV start)")
    run.add_argument("--start-lane", type=int, default=None, metavar="N", help="start lane (0 = rightmost; default: corridor file)")
    run.add_argument("--speed", type=_positive, default=None, metavar="MPS", help="cruise speed (default: corridor file)")
    run.add_argument("--localisation", choices=["gnss", "rsu", "both"], default="gnss",
                     help="own GNSS, the RSUs' track of the car, or both (default gnss)")
    run.add_argument("--gnss-sigma", type=_non_negative, default=0.2, metavar="M", help="GNSS noise sigma (m, default 0.2)")
    run.add_argument("--gnss-rate", type=_positive, default=10.0, metavar="HZ", help="GNSS rate (default 10 Hz)")
    run.add_argument("--gnss-latency", type=_non_negative, default=0.1, metavar="S", help="GNSS latency (default 0.1 s)")
    run.add_argument("--link-timeout", type=_positive, default=3.5, metavar="S",
                     help="fail-safe: stop when no command or DDM health (1 Hz) for this long in a manoeuvre "
                          "(default 3.5 s)")
    run.add_argument("--localisation-stale", type=_positive, default=1.0, metavar="S",
                     help="fail-safe: stop when the newest fix is older than this (default 1 s)")
    run.add_argument("--seed", type=int, default=0, help="seed of the simulated sensors")
    run.add_argument("--duration", type=_positive, default=None, metavar="S", help="exit after this many seconds")
    run.add_argument("--record", metavar="DIR", default=None, help="write the run (npz/csv/json) here on exit")
    run.add_argument("--require-signed", action=argparse.BooleanOptionalAction, default=None,
                     help="refuse unsigned commands (default: on when the corridor file's [[trust]] entries name a "
                          "DDM key; commands are then verified against them whatever this flag says)")
    add_log_level_argument(run)
    ZenohSettings.add_arguments(run)
    metrics.add_arguments(run)

    ls = sub.add_parser("lockstep", help="replay the field test in lockstep (no transport) and write a run folder")
    ls.add_argument("--speed", type=_positive, default=13.4, metavar="MPS", help="cruise speed (default 13.4)")
    ls.add_argument("--radius", type=_positive, default=None, metavar="M", help="curved road of this radius (default straight)")
    ls.add_argument("--sigma", type=_non_negative, default=0.2, metavar="M", help="fix noise sigma (default 0.2)")
    ls.add_argument("--latency", type=_non_negative, default=0.1, metavar="S", help="fix latency (default 0.1)")
    ls.add_argument("--rate", type=_positive, default=10.0, metavar="HZ", help="fix rate (default 10)")
    ls.add_argument("--seed", type=int, default=0)
    ls.add_argument("--out", metavar="DIR", required=True, help="run folder to write")
    ls.add_argument("--plot", action="store_true", help="also write the PNG figures")

    pl = sub.add_parser("plot", help="write the report's figures (PNG) for a run folder")
    pl.add_argument("run_dir", metavar="RUN", help="run folder (run.npz + meta.json)")
    pl.add_argument("--out", metavar="DIR", default=None, help="where to write the PNGs (default: the run folder)")
    return p


def vehicle_options(args: argparse.Namespace):
    """The ``VehicleOptions`` of ``iea-vehicle run``'s parsed arguments."""
    from vehicle.build import VehicleOptions

    return VehicleOptions(
        corridor_file=args.corridor, corridor_id=args.corridor_id, vehicle_id=args.vehicle, start_s_m=args.start_s,
        start_lane=args.start_lane, cruise_speed_mps=args.speed, localisation=args.localisation,
        gnss_sigma_m=args.gnss_sigma, gnss_rate_hz=args.gnss_rate, gnss_latency_s=args.gnss_latency,
        link_timeout_s=args.link_timeout, localisation_stale_s=args.localisation_stale, seed=args.seed,
        record=args.record is not None, require_signed=args.require_signed,
        zenoh=ZenohSettings.from_args(args))


def run_from_args(args: argparse.Namespace, prog: str = "iea-vehicle", attach=None) -> int:
    """Run the vehicle of ``iea-vehicle run``'s parsed arguments (with ``attach``: ``vehicle.build.Attachment``);
    2 with a message for an unknown vehicle or a missing model file."""
    from vehicle.build import run_vehicle

    configure_logging(args.parser, args)
    options = vehicle_options(args)
    metrics.serve_from_args(args, "vehicle", args.vehicle)
    try:
        return run_vehicle(options, args.duration, args.record, attach=attach)
    except KeyError as exc:  # an unknown vehicle
        print(f"{prog}: {exc.args[0]}", file=sys.stderr)
        return 2
    except FileNotFoundError as exc:  # a model file an attached component needs
        print(f"{prog}: {exc}", file=sys.stderr)
        return 2


def _cmd_run(args: argparse.Namespace) -> int:
    return run_from_args(args)


def _cmd_lockstep(args: argparse.Namespace) -> int:
    from vehicle.lockstep import replay_field_test

    print(json.dumps(replay_field_test(args.out, args.speed, args.sigma, args.latency, args.rate, args.radius,
                                       args.seed, args.plot)))
    return 0


def _cmd_plot(args: argparse.Namespace) -> int:
    from vehicle.plot import plot_run

    try:
        for path in plot_run(args.run_dir, args.out):
            print(path)
    except (FileNotFoundError, ValueError) as exc:
        print(f"iea-vehicle plot: {exc}", file=sys.stderr)
        return 2
    return 0


def main(argv: list[str] | None = None) -> int:
    stop_on_ctrl_c()  # SIGINT stops it even when started with SIGINT ignored (protocol.runtime)
    parser = build_parser()
    args = parser.parse_args(argv)
    args.parser = parser
    try:
        return {"run": _cmd_run, "lockstep": _cmd_lockstep, "plot": _cmd_plot}[args.command](args)
    except ValueError as exc:  # bad settings (zenoh endpoints, corridor file)
        print(f"iea-vehicle: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
