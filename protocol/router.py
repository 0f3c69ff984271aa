"""`iea router` / `iea-router`: a Zenoh router started from the Python package (no zenohd needed).

Services in client mode (`--connect tcp/HOST:7447`) join it; peers on the same host find it by
scouting. Docker deployments use the official zenohd image instead; both speak the same protocol.
"""

from __future__ import annotations

import argparse
import json
import logging
import signal
import sys
import threading
import time

from protocol.logsetup import add_log_level_argument, configure_logging
from protocol.qos import ROUTER_NETWORK_QOS

log = logging.getLogger("iea.router")


def build_parser(prog: str = "iea-router") -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog=prog,
        description="Start a Zenoh router for an IEA corridor (mode router). Services join it with "
        "--connect tcp/<host>:<port>. Runs until interrupted (Ctrl-C / SIGTERM).",
    )
    ap.add_argument("--listen", action="append", metavar="ENDPOINT", default=None,
                    help="endpoint to listen on (repeatable; default tcp/127.0.0.1:7447; "
                         "use tcp/0.0.0.0:7447 to accept other hosts)")
    ap.add_argument("--config", metavar="FILE", default=None,
                    help="a Zenoh JSON5 router config (TLS, ACL: see deploy/zenoh/); --listen overrides its endpoints")
    ap.add_argument("--no-multicast", action="store_true", help="disable multicast scouting")
    ap.add_argument("--duration-s", type=float, default=None, help="stop after this many seconds (for tests)")
    add_log_level_argument(ap)
    return ap


def open_router(listen: list[str], config_file: str | None = None, multicast: bool = True):
    import zenoh

    return zenoh.open(router_config(listen, config_file, multicast))


def router_config(listen: list[str], config_file: str | None = None, multicast: bool = True):
    """The Zenoh config of ``iea router``: ``config_file`` (or defaults) with the listen endpoints, scouting and
    the project's ``qos/network`` (``protocol.qos.ROUTER_NETWORK_QOS``) set."""
    import zenoh

    conf = zenoh.Config.from_file(config_file) if config_file else zenoh.Config()
    conf.insert_json5("mode", json.dumps("router"))
    if listen:
        conf.insert_json5("listen/endpoints", json.dumps(listen))
    conf.insert_json5("qos/network", json.dumps(ROUTER_NETWORK_QOS))  # forwarding never blocks
    if not multicast:
        conf.insert_json5("scouting/multicast/enabled", "false")
    elif not config_file:
        conf.insert_json5("scouting/multicast/interface", json.dumps("lo"))
    return conf


def main(argv: list[str] | None = None, prog: str = "iea-router") -> int:
    parser = build_parser(prog)
    args = parser.parse_args(argv)
    configure_logging(parser, args)
    listen = args.listen or ([] if args.config else ["tcp/127.0.0.1:7447"])
    for ep in listen:
        if "/" not in ep:
            print(f"error: --listen {ep!r} must look like tcp/127.0.0.1:7447", file=sys.stderr)
            return 2
    try:
        session = open_router(listen, args.config, multicast=not args.no_multicast)
    except Exception as exc:  # zenoh raises ZError with a readable message
        print(f"error: could not start the Zenoh router on {listen}: {exc}", file=sys.stderr)
        return 1
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    log.info("zenoh router %s listening on %s", session.zid(), ", ".join(listen) or "(config)")
    print(f"router ready: {', '.join(listen) or args.config}", flush=True)
    deadline = None if args.duration_s is None else time.monotonic() + args.duration_s
    while not stop.is_set() and (deadline is None or time.monotonic() < deadline):
        stop.wait(0.2)
    session.close()
    log.info("router stopped")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
