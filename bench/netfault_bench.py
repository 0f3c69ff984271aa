"""Faults on real network links: the corridor's hosts in network namespaces (``deploy/netlab``).

Every row starts the ``iea up`` topology with each role on its own host (a namespace joined to its router's by
a veth link), plays ``rellis_ev_yield`` and breaks one link around the EV's lights-on with iptables (random loss,
a cut) or tc (a token-bucket cap), or a router host; it is judged by its kind's judge AND the one yield judge
(``deploy.netlab.schedule``). A failed row whose fault alone delays the command past the rig's bound is shown
beyond it. Then the scale row: corridors x RSUs of synthetic object lists at 15 Hz and a DDM per corridor across
namespaces (``deploy.netlab.scale``).

    python bench/netfault_bench.py [--rows NAME ...] [--no-scale] [--corridors 3 --rsus 8] [--json]

Needs CAP_NET_ADMIN, ``ip``, ``iptables`` and ``tc`` (root on Debian: apt-get install iproute2 iptables).
Ends with one JSON line: rows_total, rows_passed, rows_beyond_bound, rows_failed, commands_lost, recovery_s per
cut row, the bounds, per-row figures and the scale row's.
"""

from __future__ import annotations

from bench._setup import ROOT  # noqa: F401  first: one thread per numeric library, before numpy loads

# isort: split
import argparse  # noqa: E402
import json  # noqa: E402
import os  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

FIGURES = ("alert_latency_s", "fault_after_lights_on_s", "commands_issued", "commands_acked", "commands_lost",
           "commands_expired_at_ddm", "ack_latency_p50_s", "ack_latency_max_s", "stale_detected_after_s",
           "recovery_s", "uplink_bytes_per_s", "object_lists_hz", "wall_s")


def main(argv: list[str] | None = None) -> int:
    from deploy.netlab.net import unavailable_reason
    from deploy.netlab.schedule import NET_FAULTS, fault_by_name, summary

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rows", nargs="*", default=None, help="only these rows (names as in the table)")
    ap.add_argument("--no-scale", action="store_true", help="skip the scale row")
    ap.add_argument("--scale-only", action="store_true", help="only the scale row")
    ap.add_argument("--corridors", type=int, default=3)
    ap.add_argument("--rsus", type=int, default=8, help="RSUs per corridor in the scale row")
    ap.add_argument("--window-s", type=float, default=20.0, help="the scale row's measuring window")
    ap.add_argument("--duration-s", type=float, default=22.0, help="scenario time of each row's simulator")
    ap.add_argument("--detector", default="project", help="RSU detector (project, motion or an ONNX path)")
    ap.add_argument("--runs", default=str(ROOT / "runs"), help="where the run folders go")
    ap.add_argument("--sysctl", action="append", default=[], metavar="KEY=VALUE",
                    help="a kernel setting of every host of the rows' labs (repeat), on top of a corridor host's "
                         "(deploy/host_tuning.py: net.ipv4.tcp_thin_linear_timeouts=1)")
    ap.add_argument("--kernel-defaults", action="store_true",
                    help="hosts with the kernel's default settings instead of a corridor host's")
    ap.add_argument("--json", action="store_true", help="end with one JSON line of figures")
    args = ap.parse_args(argv)
    from deploy.host_tuning import HOST_SYSCTLS

    sysctls = {} if args.kernel_defaults else dict(HOST_SYSCTLS)
    for item in args.sysctl:
        key, eq, value = item.partition("=")
        if not eq or not key.startswith("net."):
            ap.error(f"--sysctl {item!r}: expected net.KEY=VALUE (a per-namespace network setting)")
        sysctls[key] = value
    reason = unavailable_reason()
    if reason:
        print(f"netfault_bench: {reason}", file=sys.stderr)
        return 2
    from deploy.netlab.rows import run_table
    from deploy.netlab.scale import run_scale

    t0 = time.monotonic()
    faults = [] if args.scale_only else ([fault_by_name(n) for n in args.rows] if args.rows else list(NET_FAULTS))
    run_root = Path(args.runs)
    print(f"{'row':<34} {'':<6} {'margin':>9}  outcome", flush=True)
    rows = run_table(faults, run_root, say=lambda line: print(line, flush=True), duration_s=args.duration_s,
                     detector=args.detector, sysctls=sysctls)
    figures = summary(rows)
    figures["sysctls"] = sysctls
    figures["rows"] = {r.name: {k: r.details.get(k) for k in FIGURES if k in r.details} | {"verdict": r.verdict,
                                                                                          "margin_s": r.margin_s}
                       for r in rows}
    if rows:
        print("\nper row: alert latency (lights-on -> first EvAlert), commands acked/issued (lost), ack latency "
              "p50/max, stale detection, recovery after the link's return")
        for r in rows:
            d = r.details
            print(f"  {r.name:<34} alert {d.get('alert_latency_s')} s, commands {d.get('commands_acked')}/"
                  f"{d.get('commands_issued')} (lost {d.get('commands_lost')}, expired {d.get('commands_expired_at_ddm')}),"
                  f" ack {d.get('ack_latency_p50_s')}/{d.get('ack_latency_max_s')} s, stale "
                  f"{d.get('stale_detected_after_s')} s, recovery {d.get('recovery_s', '-')} s"
                  + (f", uplink B/s {d['uplink_bytes_per_s']}, object lists Hz {d['object_lists_hz']}"
                     if "uplink_bytes_per_s" in d else ""))
            if r.beyond_bound:
                print(f"      beyond the bound: {r.beyond_bound}")
    if not args.no_scale:
        s = run_scale(args.corridors, args.rsus, args.window_s, run_root=run_root)
        print(f"\nscale: {s['corridors']} corridors x {s['rsus_per_corridor']} RSUs at {s['rate_hz']:.0f} Hz "
              f"({s['object_lists_per_s_offered']:.0f} object lists/s), {s['window_s']} s window")
        for cid, d in s["ddm"].items():
            print(f"  DDM {cid}: decision p50 {d['decision_p50_ms']} ms, p99 {d['decision_p99_ms']} ms, "
                  f"step max {d['step_ms_max']} ms")
        for r in s["router_cpu_cores"]:
            print(f"  router {r}: CPU {s['router_cpu_cores'][r]:.3f} cores, {s['router_bytes_per_s'][r] / 1e3:.0f} kB/s")
        figures["scale"] = s
    from deploy.netlab.net import leftovers
    from deploy.netlab.plan import PREFIX_HEAD, base36

    left = leftovers(PREFIX_HEAD + base36(os.getpid()).rjust(5, "0"))  # every lab this run made
    figures["left_behind"] = {k: len(v) for k, v in left.items()}
    print(f"\nleft behind: {figures['left_behind']}")
    figures["wall_s"] = round(time.monotonic() - t0, 1)
    if args.json:
        print(json.dumps(figures, default=str))
    return 0 if figures["rows_failed"] == 0 and not any(figures["left_behind"].values()) else 1


if __name__ == "__main__":
    try:
        sys.exit(main())
    except KeyboardInterrupt:  # the row's lab removed itself on the way out (deploy.netlab.lab.lab_guard)
        print("netfault_bench: interrupted", file=sys.stderr)
        sys.exit(130)
