"""``iea-ddm``: run the driving-decision service on a corridor (argument parsing only)."""

from __future__ import annotations

import argparse
import sys

from ddm.config import DdmConfig
from protocol import metrics
from protocol.logsetup import add_log_level_argument, configure_logging


def build_parser() -> argparse.ArgumentParser:
    from protocol.zenoh_transport import ZenohSettings

    p = argparse.ArgumentParser(
        prog="iea-ddm",
        description="Driving-decision service: fuses every RSU of a corridor into one picture, decides how each "
                    "autonomous vehicle responds to emergency vehicles and sends path-switch commands "
                    "(retransmitted until acknowledged).",
    )
    sub = p.add_subparsers(dest="command", required=True)
    r = sub.add_parser("run", help="run the service until interrupted (SIGINT/SIGTERM)")
    r.add_argument("--corridor", metavar="FILE", default=None,
                   help="corridor TOML file (default: deploy/corridors/rellis.toml)")
    r.add_argument("--corridor-id", metavar="ID", default=None,
                   help="corridor id used in the key expressions (default: the file's id)")
    r.add_argument("--ddm-id", metavar="ID", default="ddm", help="this service's id in messages (default: ddm)")
    r.add_argument("--rate-hz", type=float, default=DdmConfig.rate_hz, help="decision loop rate (default: 20)")
    r.add_argument("--startup-listen-s", type=float, default=DdmConfig.startup_listen_s,
                   help="listen this long after start before commanding (default: 1.0)")
    r.add_argument("--key", metavar="PEM", default=None,
                   help="Ed25519 private key (from `iea keys new`) that signs every command; its [[trust]] entry "
                        "must be in the corridor file for vehicles to accept the commands")
    r.add_argument("--key-id", metavar="ID", default=None,
                   help="key id of --key (default: the corridor trust entry holding its public key)")
    r.add_argument("--verify-alerts", action=argparse.BooleanOptionalAction, default=None,
                   help="refuse EV/hazard alerts without a valid RSU signature (default: on when the corridor "
                        "file trusts RSU keys)")
    add_log_level_argument(r)
    ZenohSettings.add_arguments(r)
    metrics.add_arguments(r)
    return p


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    configure_logging(parser, args, stream=sys.stderr)
    from ddm.build import DdmOptions, run_ddm
    from protocol.corridor import CorridorError
    from protocol.zenoh_transport import ZenohSettings

    try:
        options = DdmOptions(
            corridor_file=args.corridor, corridor_id=args.corridor_id, ddm_id=args.ddm_id,
            config=DdmConfig(rate_hz=args.rate_hz, startup_listen_s=args.startup_listen_s), key=args.key,
            key_id=args.key_id, verify_alerts=args.verify_alerts, zenoh=ZenohSettings.from_args(args))
        metrics.serve_from_args(args, "ddm", "ddm")
        return run_ddm(options)
    except (CorridorError, ValueError, FileNotFoundError) as exc:
        print(f"iea-ddm: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    raise SystemExit(main())
