"""Wire conformance bench: an outside client validates every message of an `iea demo` run.

    python bench/wire_conformance_bench.py [--quick] [--json] [--duration-s 30] [--scenario rellis_ev_yield ...]

Starts examples/validate_wire.py (zenoh + msgpack + jsonschema, none of the project's code) subscribed
to iea/**, then runs `iea demo` (every service a separate process over Zenoh on loopback, signed
messages, as `make demo` runs it) and counts the payloads of the demo's corridor that validate against
protocol/schema/*.json. Target: 100 %. Each --scenario adds a run (e.g. hazard_in_lane, whose
HazardAlerts the main scenario does not produce). Messages of other corridors on the same loopback
(another run at the same time) are left out of the figures.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
CLIENT = ROOT / "examples" / "validate_wire.py"


def demo_with_outside_client(scenario: str, duration_s: float, runs: Path) -> dict:
    """One `iea demo` run observed by the outside client: its figures for the demo's corridor."""
    client = subprocess.Popen([sys.executable, str(CLIENT), "--duration-s", str(duration_s + 180),
                               "--idle-stop-s", "8", "--json"], cwd=ROOT, stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True)
    try:
        assert client.stdout is not None
        while (line := client.stdout.readline()) and line.strip() != "ready":
            pass
        t0 = time.monotonic()
        demo = subprocess.run([sys.executable, "-m", "deploy", "demo", "--scenario", scenario, "--duration-s",
                               str(duration_s), "--runs", str(runs)], cwd=ROOT, capture_output=True, text=True,
                              timeout=duration_s + 180)
        demo_s = time.monotonic() - t0
        out, err = client.communicate(timeout=duration_s + 240)
    finally:
        if client.poll() is None:
            client.kill()
    corridor = next((ln.split()[2].rstrip(",") for ln in demo.stdout.splitlines() if ln.startswith("[demo] corridor ")),
                    None)
    if corridor is None or not out.strip():
        raise RuntimeError(f"the demo or the client failed:\n{demo.stdout[-2000:]}\n{demo.stderr[-2000:]}\n{err[-2000:]}")
    result = json.loads(out.strip().splitlines()[-1])
    mine = result["by_corridor"].get(corridor, {"messages": 0, "valid": 0})
    errors = [e for e in result["errors"] if f"iea/{corridor}/" in e]
    return {"scenario": scenario, "corridor": corridor, "demo_wall_s": round(demo_s, 1),
            "demo_verdict": next((ln for ln in demo.stdout.splitlines() if ln.startswith("[demo] PASS")
                                  or ln.startswith("[demo] FAIL")), "?"),
            "messages": mine["messages"], "valid": mine["valid"], "by_kind_all_corridors": result["by_kind"],
            "errors": errors}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--json", action="store_true", help="end with one JSON line of the figures")
    ap.add_argument("--duration-s", type=float, default=30.0, help="scenario time of each run (iea demo: 30)")
    ap.add_argument("--scenario", action="append", default=None,
                    help="scenario to run (repeatable; default rellis_ev_yield, the demo's)")
    ap.add_argument("--runs", default=None,
                    help="where the demo's run folders go (default runs/; with --quick a temporary folder)")
    ap.add_argument("--quick", action="store_true", help="a 10 s demo, its run folder removed after (a smoke run)")
    args = ap.parse_args()
    scenarios = args.scenario or ["rellis_ev_yield"]
    if args.quick:
        args.duration_s = 10.0
    if args.runs is not None or not args.quick:
        return measure(args, scenarios, Path(args.runs or ROOT / "runs"))
    with tempfile.TemporaryDirectory(prefix="wire-") as tmp:
        return measure(args, scenarios, Path(tmp))


def measure(args: argparse.Namespace, scenarios: list[str], runs: Path) -> int:
    """The demo runs of ``scenarios`` observed by the outside client; prints the figures; 0 when every message
    validated."""
    figures: dict = {"runs": []}
    total = valid = 0
    for scenario in scenarios:
        print(f"[wire] iea demo --scenario {scenario} --duration-s {args.duration_s:g}, outside client on iea/** ...",
              flush=True)
        r = demo_with_outside_client(scenario, args.duration_s, runs)
        total, valid = total + r["messages"], valid + r["valid"]
        print(f"  corridor {r['corridor']}: {r['valid']} of {r['messages']} messages valid "
              f"({r['demo_wall_s']:.0f} s; {r['demo_verdict']})")
        for kind, c in r["by_kind_all_corridors"].items():
            print(f"    {kind:<20}{c['valid']:>7} / {c['messages']}")
        for e in r["errors"][:5]:
            print(f"    invalid: {e}")
        figures["runs"].append({k: r[k] for k in ("scenario", "messages", "valid", "by_kind_all_corridors")})
    figures["outside_client_messages"] = total
    figures["outside_client_valid"] = valid
    figures["outside_client_valid_fraction"] = round(valid / total, 6) if total else None
    print(f"outside client: {valid} of {total} messages valid (target 100 %)")
    if args.json:
        print(json.dumps(figures))
    return 0 if total and valid == total else 1


if __name__ == "__main__":
    raise SystemExit(main())
