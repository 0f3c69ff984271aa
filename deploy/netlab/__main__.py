"""``python -m deploy.netlab``: the network lab from the command line.

    python -m deploy.netlab up [--segments 2] [--no-sim] [--rsus N] [--duration-s S]   the corridor in namespaces
    python -m deploy.netlab clean [--prefix PREFIX]                                    remove a lab's leftovers

``up`` prints ``lab up: prefix PREFIX`` once every service is started and removes everything it made when it
ends (``--duration-s``, Ctrl-C or SIGTERM). ``clean`` without ``--prefix`` removes the labs of processes that
no longer run.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from deploy.netlab.net import LabUnavailable, cleanup_prefix, cleanup_stale, unavailable_reason


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m deploy.netlab", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    up = sub.add_parser("up", help="the iea up topology, each role in its own network namespace")
    up.add_argument("--segments", type=int, default=0, help="segment routers (iea deploy mesh layout; 0: one router)")
    up.add_argument("--no-sim", action="store_true", help="no simulator")
    up.add_argument("--rsus", type=int, default=None, metavar="N", help="only the first N RSUs (0: none)")
    up.add_argument("--detector", default="project", help="RSU detector (project, motion or an ONNX path)")
    up.add_argument("--duration-s", type=float, default=None, help="stop after this long (default: Ctrl-C)")
    up.add_argument("--runs", default="runs", help="where the run folder goes")
    clean = sub.add_parser("clean", help="remove a lab's namespaces, links and processes")
    clean.add_argument("--prefix", default=None, help="this lab (default: every lab whose process is gone)")
    args = ap.parse_args(argv)
    if args.cmd == "clean":
        if args.prefix:
            found = cleanup_prefix(args.prefix)
            print(f"removed {found}")
        else:
            print(f"removed stale labs: {cleanup_stale() or 'none'}")
        return 0
    reason = unavailable_reason()
    if reason:
        print(f"netlab: {reason}", file=sys.stderr)
        return 2
    from deploy.netlab.lab import Lab, lab_guard, run_dir_for
    from protocol.corridor import load_corridor

    rsu_ids = None if args.rsus is None else [r.rsu_id for r in load_corridor().rsus[:args.rsus]]
    with lab_guard():
        lab = None
        try:
            lab = Lab(segments=args.segments, run_dir=run_dir_for(Path(args.runs), "up"),
                      with_sim=not args.no_sim, rsu_ids=rsu_ids, detector=args.detector, restart="no")
            lab.start()
            print(f"lab up: prefix {lab.plan.prefix}; monitor {lab.endpoint}; run folder {lab.run_dir}", flush=True)
            end = None if args.duration_s is None else time.monotonic() + args.duration_s
            while end is None or time.monotonic() < end:
                time.sleep(0.2)
        except KeyboardInterrupt:
            print("netlab: interrupted: removing the lab", flush=True)
        except LabUnavailable as exc:
            print(f"netlab: {exc}", file=sys.stderr)
            return 2
        finally:
            if lab is not None:
                lab.stop()
                print(f"lab down: prefix {lab.plan.prefix}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
