"""`iea demo`: run what the corridor can do so far, as separate processes over Zenoh on loopback.

Today this starts two processes that exchange every message kind of the protocol over Zenoh
(peer mode, no router) and prints what crossed; it grows into the full rellis_ev_yield scenario
(simulator, 4 RSUs, DDM, vehicle) as those services land.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import uuid
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="iea demo", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rounds", type=int, default=5, help="rounds of messages to exchange")
    args = ap.parse_args(argv)
    corridor = f"demo{uuid.uuid4().hex[:6]}"
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    base = [sys.executable, "-m", "protocol.loopback"]
    print(f"[demo] corridor {corridor}: starting a receiver and a sender process over Zenoh (peer mode, loopback)")
    recv = subprocess.Popen([*base, "receive", "--corridor-id", corridor, "--expect", str(args.rounds),
                             "--timeout-s", "30"], stdout=subprocess.PIPE, text=True, env=env)
    assert recv.stdout is not None
    recv.stdout.readline()
    send = subprocess.run([*base, "send", "--corridor-id", corridor, "--rounds", str(args.rounds + 1)],
                          capture_output=True, text=True, env=env, timeout=60)
    out, _ = recv.communicate(timeout=60)
    result = json.loads(out.strip().splitlines()[-1])
    print(f"{'message kind':<20}{'received':>10}")
    for kind, n in sorted(result["kinds"].items()):
        print(f"{kind:<20}{n:>10}")
    print(f"[demo] rejected inputs: {result['rejected'] or 'none'}; complete: {result['complete']}")
    return 0 if result["complete"] and send.returncode == 0 else 1


if __name__ == "__main__":
    raise SystemExit(main())
