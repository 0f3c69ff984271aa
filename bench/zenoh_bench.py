"""Zenoh as the corridor's nervous system: priorities under a flood, presence, late joiners.

Every figure is measured over real Zenoh on loopback, services in client mode around one router
(``iea router``, as ``iea up`` and the compose file deploy them):

1. flood: one process (the simulator's and RSUs' stand-in) floods world snapshots (BACKGROUND, DROP) and
   RSU object lists (DATA, DROP) at ``--snapshot-hz`` / ``--objects-hz``, several times what the
   receiver can decode; another (the DDM's stand-in) sends a PathSwitchCommand every 20 ms; a third
   subscribes to all of it, decoding every message strictly (as the DDM or a vehicle does) and timing
   each command (receive time minus the command's stamp, one host clock); like every service it freezes
   its start-up heap once started (``protocol.runtime.freeze_startup_heap``). Run three times in the same
   bench run: ``prio``, the per-kind QoS of ``protocol.qos`` (commands REAL_TIME, BLOCK, express) with
   bulk kinds received through a ring off the network thread; ``noprio``, every kind sent the same way
   (``qos.FLAT``: DATA, DROP, express) and decoded on the network thread (a transport without priorities);
   ``flat_ring``, one QoS for all but the receiving ring kept (which of the two parts does what).
   And once without a flood (``idle``, per-kind QoS): the floor this machine gives the same measurement.
2. stale: a scripted corridor (``bench/zenoh_corridor_stub.py``: 4 RSUs and an AV, each with its token)
   runs beside a real ``DdmService``; the stub is SIGKILLed and the time until the DDM marks the RSUs
   lost (liveliness token) is taken, ``--repeats`` times.
3. restart: with the stub running, a DDM is started (session open, service construction) and the time
   until its first decision made with the EV in the picture is taken, with the start-up catch-up
   (queries of the RSUs' and the vehicle's latest state) and without it (the live streams alone).

    python bench/zenoh_bench.py [--quick] [--json]

With ``--json`` the last line of output is one JSON object holding the figures.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from deploy.procs import stop_process  # noqa: E402
from protocol import keys, qos  # noqa: E402
from protocol.codec import encode  # noqa: E402
from protocol.examples import example_messages  # noqa: E402
from protocol.messages import PathSwitchCommand, WorldSnapshot  # noqa: E402
from protocol.runtime import freeze_startup_heap  # noqa: E402
from protocol.zenoh_transport import ZenohSettings, ZenohTransport  # noqa: E402

PY = sys.executable
CMD_PERIOD_S = 0.02


def _log(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def start_router(port: int) -> subprocess.Popen:
    p = subprocess.Popen([PY, "-m", "protocol.router", "--listen", f"tcp/127.0.0.1:{port}", "--no-multicast"],
                         cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    _wait_line(p, "router ready", 20.0)
    return p


def _wait_line(p: subprocess.Popen, word: str, timeout_s: float) -> None:
    box: list[str] = []
    t = threading.Thread(target=lambda: box.append(p.stdout.readline()), daemon=True)
    t.start()
    t.join(timeout_s)
    if not box or word not in box[0]:
        p.kill()
        raise RuntimeError(f"{p.args[:4]} did not print {word!r} within {timeout_s} s (got {box})")


def stop(p: subprocess.Popen | None) -> None:
    if p is not None:
        stop_process(p, timeout_s=5.0)


def client(endpoint: str) -> ZenohSettings:
    return ZenohSettings(mode="client", connect=[endpoint])


def pct(xs: list[float], q: float) -> float | None:
    if not xs:
        return None
    xs = sorted(xs)
    return xs[min(len(xs) - 1, int(round(q / 100.0 * (len(xs) - 1))))]


# ---------------------------------------------------------------------------------------------- flood
def big_snapshot(n_actors: int) -> WorldSnapshot:
    snap = next(m for _, m in example_messages("b") if isinstance(m, WorldSnapshot))
    actors = (list(snap.actors) * (n_actors // max(1, len(snap.actors)) + 1))[:n_actors]
    return snap.model_copy(update={"actors": actors})


def _table(mode: str):
    return qos.qos_for_key if mode in ("prio", "idle") else (lambda _k: qos.FLAT)


def flood_child(args: argparse.Namespace) -> int:
    """Publish snapshots and object lists at the given rates (in 10 ms bursts)."""
    table = _table(args.qos)
    t = ZenohTransport(client(args.connect), qos=table)
    c = args.corridor_id
    msgs = dict((type(m).__name__, (k, m)) for k, m in example_messages(c))
    snap = encode(big_snapshot(args.actors))
    objs = encode(msgs["ObjectList"][1])
    print("ready", flush=True)
    time.sleep(args.settle_s - 0.5)  # the flood is on before the first command
    sent = {"snapshots": 0, "objects": 0}
    start = time.monotonic()
    end = start + args.duration_s + 1.0
    tick = 0.01
    while (now := time.monotonic()) < end:
        due_s, due_o = int((now - start) * args.snapshot_hz), int((now - start) * args.objects_hz)
        while sent["snapshots"] < due_s or sent["objects"] < due_o:
            if sent["snapshots"] < due_s:
                t.publish_bytes(keys.sim_world_key(c), snap)
                sent["snapshots"] += 1
            if sent["objects"] < due_o:
                t.publish_bytes(keys.rsu_key(c, "rsu1", "objects"), objs)
                sent["objects"] += 1
        time.sleep(tick)
    t.close()
    print(json.dumps({"sent": sent, "snapshot_bytes": len(snap), "objects_bytes": len(objs)}), flush=True)
    return 0


def command_child(args: argparse.Namespace) -> int:
    """A command every 20 ms, stamped at publication."""
    table = _table(args.qos)
    t = ZenohTransport(client(args.connect), qos=table)
    c = args.corridor_id
    cmd = next(m for _, m in example_messages(c) if isinstance(m, PathSwitchCommand))
    cmd_key = keys.vehicle_key(c, "av1", "cmd")
    print("ready", flush=True)
    time.sleep(args.settle_s)
    end = time.monotonic() + args.duration_s
    n = 0
    while time.monotonic() < end:
        t.publish(cmd_key, cmd.model_copy(update={"seq": n, "stamp": time.time()}))
        n += 1
        time.sleep(CMD_PERIOD_S)
    time.sleep(0.5)
    t.close()
    print(json.dumps({"commands": n}), flush=True)
    return 0


def sink_child(args: argparse.Namespace) -> int:
    """Decode everything strictly; time the commands."""
    t = ZenohTransport(client(args.connect), qos=_table(args.qos), bulk_queue=0 if args.qos == "noprio" else 16)
    c = args.corridor_id
    lat_ms: list[float] = []
    got = {"snapshots": 0, "objects": 0}
    seqs: set[int] = set()

    def on_cmd(_k: str, m) -> None:
        lat_ms.append((time.time() - m.stamp) * 1000.0)
        seqs.add(m.seq)

    t.subscribe(keys.vehicle_key(c, "av1", "cmd"), on_cmd)
    t.subscribe(keys.sim_world_key(c), lambda _k, _m: got.__setitem__("snapshots", got["snapshots"] + 1))
    t.subscribe(keys.rsu_key(c, "rsu1", "objects"), lambda _k, _m: got.__setitem__("objects", got["objects"] + 1))
    # as every service does once started (DDM, vehicle, RSU, simulator): without it a full collection of the
    # start-up heap, triggered by decoding the flood, holds the GIL ~10 ms and every command waits behind it
    freeze_startup_heap()
    print("ready", flush=True)
    time.sleep(args.duration_s + args.settle_s + 6.0)  # outlives the command sender (started after it, imports included)
    t.close()
    print(json.dumps({"latency_ms": lat_ms, "received": got, "commands": len(seqs)}), flush=True)
    return 0


def run_flood(endpoint: str, mode: str, duration_s: float, args: argparse.Namespace) -> dict:
    cid = f"b{os.getpid()}{mode}"
    common = ["--corridor-id", cid, "--connect", endpoint, "--duration-s", str(duration_s), "--settle-s", "2.0",
              "--qos", mode]
    sink = subprocess.Popen([PY, __file__, "_sink", *common], cwd=ROOT, stdout=subprocess.PIPE, text=True)
    _wait_line(sink, "ready", 30.0)
    rates = ("0", "0") if mode == "idle" else (str(args.snapshot_hz), str(args.objects_hz))
    flood = subprocess.Popen([PY, __file__, "_flood", *common, "--actors", str(args.actors), "--snapshot-hz",
                              rates[0], "--objects-hz", rates[1]],
                             cwd=ROOT, stdout=subprocess.PIPE, text=True)
    cmds = subprocess.Popen([PY, __file__, "_cmd", *common], cwd=ROOT, stdout=subprocess.PIPE, text=True)
    _wait_line(flood, "ready", 30.0)
    _wait_line(cmds, "ready", 30.0)
    fout, _ = flood.communicate(timeout=duration_s + 60)
    cout, _ = cmds.communicate(timeout=duration_s + 60)
    sout, _ = sink.communicate(timeout=duration_s + 60)
    f, s = json.loads(fout.strip().splitlines()[-1]), json.loads(sout.strip().splitlines()[-1])
    lat = s["latency_ms"]
    sent = {**f["sent"], "commands": json.loads(cout.strip().splitlines()[-1])["commands"]}
    return {"mode": mode, "commands_sent": sent["commands"], "commands_received": s["commands"],
            "cmd_latency_p50_ms": pct(lat, 50), "cmd_latency_p99_ms": pct(lat, 99), "cmd_latency_max_ms": max(lat or [0]),
            "snapshots_sent": sent["snapshots"], "snapshots_received": s["received"]["snapshots"],
            "objects_sent": sent["objects"], "objects_received": s["received"]["objects"],
            "snapshot_bytes": f["snapshot_bytes"], "objects_bytes": f["objects_bytes"]}


# --------------------------------------------------------------------------------- stale and restart
def start_stub(endpoint: str, cid: str, duration_s: float = 120.0) -> subprocess.Popen:
    p = subprocess.Popen([PY, str(ROOT / "bench" / "zenoh_corridor_stub.py"), "--corridor-id", cid,
                          "--connect", endpoint, "--duration-s", str(duration_s)],
                         cwd=ROOT, stdout=subprocess.PIPE, text=True)
    _wait_line(p, "ready", 30.0)
    return p


def start_ddm(endpoint: str, cid: str, catch_up: bool = True):
    from ddm.build import DdmOptions, build_ddm
    from protocol.clock import WallClock

    t = ZenohTransport(client(endpoint))
    return t, build_ddm(DdmOptions(corridor_id=cid, catch_up=catch_up), t, WallClock())


def wait_for(cond, timeout_s: float, step=None, poll_s: float = 0.002) -> float | None:
    """Seconds until ``cond()`` (``step()`` called between polls, at most every 50 ms); None at the timeout."""
    t0 = time.perf_counter()
    last_step = 0.0
    while time.perf_counter() - t0 < timeout_s:
        if cond():
            return time.perf_counter() - t0
        if step is not None and time.perf_counter() - last_step >= 0.05:
            step()
            last_step = time.perf_counter()
        time.sleep(poll_s)
    return None


def run_stale(endpoint: str, repeats: int) -> list[float]:
    out = []
    for i in range(repeats):
        cid = f"s{os.getpid()}x{i}"
        stub = start_stub(endpoint, cid)
        t, ddm = start_ddm(endpoint, cid)
        try:
            if wait_for(lambda d=ddm: len(d.presence.alive.get("rsu", ())) == 4, 10.0) is None:
                raise RuntimeError("the DDM never saw the stub's 4 RSU tokens")
            time.sleep(0.3)
            t_kill = time.perf_counter()
            stub.kill()
            took = wait_for(lambda d=ddm: len(d.presence.lost("rsu")) == 4 and d.stale_now >= {"rsu1"}, 5.0)
            if took is None:
                raise RuntimeError("the DDM did not mark the killed RSUs lost within 5 s")
            out.append(time.perf_counter() - t_kill)
            _log(f"  stale {i + 1}/{repeats}: {out[-1] * 1000:.1f} ms")
        finally:
            stub.wait(5)
            ddm.close()
            t.close()
    return out


def run_restart(endpoint: str, repeats: int, catch_up: bool) -> list[float]:
    cid = f"r{os.getpid()}{int(catch_up)}"
    stub = start_stub(endpoint, cid)
    out = []
    try:
        time.sleep(1.0)
        for i in range(repeats):
            t0_wall = time.time()
            t, ddm = start_ddm(endpoint, cid, catch_up=catch_up)
            try:
                took = wait_for(lambda d=ddm: d.ev_aware_s is not None, 8.0, step=ddm.step)
                if took is None:
                    raise RuntimeError("the restarted DDM made no EV-aware decision within 8 s")
                out.append(ddm.ev_aware_s - t0_wall)
                _log(f"  restart ({'catch-up' if catch_up else 'streams only'}) {i + 1}/{repeats}: "
                     f"EV-aware after {out[-1] * 1000:.0f} ms")
            finally:
                ddm.close()
                t.close()
            time.sleep(0.3)
    finally:
        stop(stub)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="bench/zenoh_bench.py", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("role", nargs="?", default="bench", choices=["bench", "_flood", "_cmd", "_sink"],
                    help=argparse.SUPPRESS)
    ap.add_argument("--quick", action="store_true", help="1.5 s floods, one kill and restart (a smoke run)")
    ap.add_argument("--json", action="store_true", help="end with one JSON line of the figures")
    ap.add_argument("--flood-s", type=float, default=None, help="seconds of flood per mode (default 8, quick 1.5)")
    ap.add_argument("--actors", type=int, default=200, help="actors per flooded world snapshot (size: 200 is ~20 kB)")
    ap.add_argument("--snapshot-hz", type=float, default=1000.0, help="flooded world snapshots per second")
    ap.add_argument("--objects-hz", type=float, default=3000.0, help="flooded object lists per second")
    ap.add_argument("--repeats", type=int, default=None, help="kills and restarts measured (default 5, quick 1)")
    ap.add_argument("--corridor-id", default="b")
    ap.add_argument("--connect", default=None)
    ap.add_argument("--duration-s", type=float, default=5.0)
    ap.add_argument("--settle-s", type=float, default=1.0)
    ap.add_argument("--qos", choices=["prio", "noprio", "flat_ring", "idle"], default="prio")
    ap.add_argument("--modes", default="idle,prio,noprio,flat_ring",
                    help="flood modes to run, comma-separated (default: all four)")
    ap.add_argument("--flood-only", action="store_true", help="skip the stale and restart measurements")
    args = ap.parse_args(argv)
    if args.role == "_flood":
        return flood_child(args)
    if args.role == "_sink":
        return sink_child(args)
    if args.role == "_cmd":
        return command_child(args)
    bad = set(args.modes.split(",")) - {"idle", "prio", "noprio", "flat_ring"}
    if bad:
        ap.error(f"--modes: unknown {sorted(bad)}; choose from idle, prio, noprio, flat_ring")
    flood_s = args.flood_s or (1.5 if args.quick else 8.0)
    repeats = args.repeats or (1 if args.quick else 5)
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    router = start_router(port)
    figures: dict = {"flood_s": flood_s, "repeats": repeats, "cores": os.cpu_count()}
    try:
        for mode in args.modes.split(","):
            _log(f"flood ({mode}) for {flood_s:g} s ...")
            r = run_flood(endpoint, mode, flood_s, args)
            _log(f"  commands {r['commands_received']}/{r['commands_sent']}, p50 {r['cmd_latency_p50_ms']} ms, "
                 f"p99 {r['cmd_latency_p99_ms']} ms; snapshots {r['snapshots_received']}/{r['snapshots_sent']}, "
                 f"objects {r['objects_received']}/{r['objects_sent']}")
            figures[f"flood_{mode}"] = r
            figures[f"cmd_latency_p99_ms_flood_{mode}"] = r["cmd_latency_p99_ms"]
            figures[f"cmd_received_fraction_flood_{mode}"] = r["commands_received"] / max(1, r["commands_sent"])
        if args.flood_only:
            return _report(figures, args)
        _log("stale detection after SIGKILL ...")
        stale = run_stale(endpoint, repeats)
        figures["stale_detect_s_all"] = stale
        figures["stale_detect_s"] = max(stale)
        figures["stale_detect_s_median"] = statistics.median(stale)
        _log("restart -> EV-aware ...")
        with_cu = run_restart(endpoint, repeats, catch_up=True)
        without = run_restart(endpoint, max(1, repeats // 2), catch_up=False)
        figures["restart_ev_aware_s_all"] = with_cu
        figures["restart_ev_aware_s"] = max(with_cu)
        figures["restart_ev_aware_s_median"] = statistics.median(with_cu)
        figures["restart_ev_aware_s_streams_only"] = statistics.median(without)
    finally:
        stop(router)
    return _report(figures, args)


def _report(figures: dict, args: argparse.Namespace) -> int:
    targets = {"cmd_latency_p99_ms_flood_prio": 5.0, "stale_detect_s": 0.5, "restart_ev_aware_s": 0.2}
    figures["targets_met"] = {k: (figures.get(k) is not None and figures[k] <= v) for k, v in targets.items()}
    for k in ("cmd_latency_p99_ms_flood_idle", "cmd_latency_p99_ms_flood_prio", "cmd_latency_p99_ms_flood_noprio",
              "cmd_latency_p99_ms_flood_flat_ring", "stale_detect_s",
              "restart_ev_aware_s", "restart_ev_aware_s_streams_only"):
        print(f"{k:<36} {figures.get(k)}")
    if args.json:
        print(json.dumps(figures))
    return 0


if __name__ == "__main__":
    sys.exit(main())
