"""Fuzz every decoder and every service message handler with several seeds.

Inputs (``bench/fuzz_mutator.py``) are valid encodings of each message kind mutated at the msgpack
tree and byte level, on right and wrong keys; 20 targets (``bench/fuzz_targets.py``,
``bench/fuzz_targets_field.py``, ``bench/fuzz_targets_v2x.py``): ``protocol.codec.decode`` for each of the 8 kinds,
the V2X UPER decoder for CAM, DENM and CPM, the LocalBus
rejection path, the DDM's, the vehicle's, the simulator's and the RSU camera's handlers, each fed
through a real ``LocalBus``. Every (target, seed) pair gets its own input stream
(``random.Random(f"{seed}-{target}")``) and a fresh target.

Per target and seed:

- crashes: any exception other than the expected refusal (``ProtocolError`` from ``decode``,
  ``KeyError_`` for an unpublishable key), including one the transport caught and counted in
  ``stats.handler_errors`` and one raised by the scene's own work between inputs (then the sample
  names the last input the handler accepted, the one that left the state behind). Each sample holds
  the payload in hex and the (seed, target, input index) that regenerates it.
- per-input cost: the CPU time of this thread from the bytes handed to the bus (or decoder) to the
  handler's return, ms (``max_input_ms``: what one input costs, GC included; the same less the garbage
  collector's pauses during it is ``max_input_net_gc_ms``, the longest pause ``max_gc_pause_ms``: a
  full collection's cost grows with the process's heap, not with the input; the wall-clock maximum,
  which also holds scheduler stalls from other processes on the host, is ``max_input_wall_ms``). The
  scene's own work between inputs (a DDM or vehicle step, a render every 200 inputs, a fresh car every
  4,000) is timed apart: ``max_step_ms``.
- memory: resident set size growth from 10 % of the run to its end (kB), the size of every
  peer-growable collection at the end, and with ``--tracemalloc`` the traced peak and growth.

    python bench/fuzz_bench.py --seeds 0,1,2 --json   # 100,000 inputs per target and seed: 5.1 M (~45 min)
    python bench/fuzz_bench.py --quick                 # 2,000 per target, seed 0
    python bench/fuzz_bench.py --n 5000 --targets decode_PathSwitchCommand,vehicle_on_cmd --seeds 7

The last line with ``--json``: one JSON object with fuzz_inputs, fuzz_crashes, fuzz_max_input_ms,
fuzz_max_rss_growth_kb (and the per-target figures).
"""

from __future__ import annotations

import argparse
import dataclasses
import gc
import hashlib
import json
import os
import random
import sys
import time
import traceback
import tracemalloc
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from bench.fuzz_targets import (  # noqa: E402
    DdmAckTarget,
    DdmRsuTarget,
    DdmStateTarget,
    DecodeTarget,
    Target,
    TransportTarget,
    _BusTarget,
)
from bench.fuzz_targets_field import (  # noqa: E402
    RsuSnapshotTarget,
    SimStateTarget,
    VehicleCmdTarget,
    VehicleDdmHealthTarget,
    VehicleRsuTarget,
)
from bench.fuzz_targets_v2x import v2x_targets  # noqa: E402
from protocol.messages import MESSAGE_TYPES  # noqa: E402
from protocol.runtime import freeze_startup_heap  # noqa: E402

MAX_HEX_BYTES = 4096
"""Crash payloads up to this size are printed whole in hex; larger ones by their head and SHA-256."""


def all_targets() -> dict[str, Callable[[random.Random], Target]]:
    out: dict[str, Callable[[random.Random], Target]] = {}
    for kind in MESSAGE_TYPES:
        out[f"decode_{kind.KIND}"] = lambda rng, k=kind: DecodeTarget(rng, k)
    out.update({
        "transport_localbus": TransportTarget, "ddm_on_rsu": DdmRsuTarget, "ddm_on_vehicle_state": DdmStateTarget,
        "ddm_on_ack": DdmAckTarget, "vehicle_on_cmd": VehicleCmdTarget, "vehicle_on_rsu": VehicleRsuTarget,
        "vehicle_on_ddm_health": VehicleDdmHealthTarget, "sim_on_state": SimStateTarget,
        "rsu_sim_camera": RsuSnapshotTarget,
    })
    out.update(v2x_targets())
    return out


@dataclass
class Result:
    """One target over one or more seeds (``seeds``); maxima are over all its inputs."""

    name: str
    seeds: list[int] = field(default_factory=list)
    inputs: int = 0
    accepted: int = 0
    """Inputs that decoded (decoders) / reached the handler (services)."""
    rejected: int = 0
    crashes: int = 0
    crash_samples: list[str] = field(default_factory=list)
    mean_input_us: float = 0.0
    max_input_ms: float = 0.0
    """CPU time of the slowest input (this thread: decode + handler, GC included)."""
    max_input_wall_ms: float = 0.0
    """Wall-clock time of the slowest input (also holds stalls caused by other processes)."""
    max_input_net_gc_ms: float = 0.0
    """CPU time of the slowest input less the garbage collector's pauses during it."""
    max_gc_pause_ms: float = 0.0
    """Longest pause of Python's garbage collector (its cost grows with the process's heap, not the input)."""
    slowest_input: str = ""
    """(seed, index, size, head in hex) of the input with the largest CPU time."""
    max_step_ms: float = 0.0
    """CPU time of the slowest piece of the scene's own work between inputs."""
    rss_growth_kb: float = 0.0
    traced_peak_kb: float | None = None
    traced_growth_kb: float | None = None
    """With ``--tracemalloc``: Python/numpy memory still allocated at the end minus at 10 % of the run."""
    state: dict[str, int] = field(default_factory=dict)
    seconds: float = 0.0


def _rss_kb() -> float:
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 1024.0
    except OSError:  # not Linux
        import resource
        return float(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)


def describe_payload(payload: bytes) -> str:
    """The payload in hex (whole up to ``MAX_HEX_BYTES``; else its head, size and SHA-256)."""
    if len(payload) <= MAX_HEX_BYTES:
        return f"{len(payload)} bytes: {payload.hex()}"
    return (f"{len(payload)} bytes, sha256 {hashlib.sha256(payload).hexdigest()}, first {MAX_HEX_BYTES}: "
            f"{payload[:MAX_HEX_BYTES].hex()}")


def _sample(exc: BaseException, where: str, seed: int, name: str, index: int, payload: bytes) -> str:
    tb = "".join(traceback.format_exception(exc)[-3:])[-600:]
    return (f"{type(exc).__name__}: {exc} | {where} | regenerate: seed {seed}, target {name}, input {index} | "
            f"payload {describe_payload(payload)} | {tb}")


def run_target(name: str, factory: Callable[[random.Random], Target], n: int, seed: int = 0,
               trace: bool = False, max_samples: int = 5) -> Result:
    """``n`` inputs of one seed's stream into a fresh target."""
    import logging

    root = logging.getLogger()
    root_level = root.level
    res = Result(name, seeds=[seed])
    thread_ns, wall_ns = time.thread_time_ns, time.perf_counter_ns
    gc_ns, gc_start = [0], [0]

    def on_gc(phase: str, _info: dict) -> None:
        if phase == "start":
            gc_start[0] = thread_ns()
        else:
            pause = thread_ns() - gc_start[0]
            gc_ns[0] += pause
            res.max_gc_pause_ms = max(res.max_gc_pause_ms, pause / 1e6)

    root.setLevel(logging.CRITICAL)  # handler errors are counted, not printed (the level is put back at the end)
    try:
        rng = random.Random(f"{seed}-{name}")
        target = factory(rng)
        freeze_startup_heap()  # as every service does when its run() starts (protocol.runtime)
        if trace:
            tracemalloc.start()
        rss_mark = None
        traced_mark = 0
        total_ns = 0
        last_accepted: tuple[int, bytes] = (-1, b"")
        gc.callbacks.append(on_gc)
        t_start = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # numpy overflow warnings on 1e308 inputs are not crashes
            for i in range(n):
                if i == n // 10:
                    gc.collect()
                    rss_mark = _rss_kb()
                    if trace:
                        traced_mark = tracemalloc.get_traced_memory()[0]
                payload = target.payload()
                g0 = gc_ns[0]
                w0, c0 = wall_ns(), thread_ns()
                try:
                    ok = target.feed(payload)
                except Exception as exc:  # noqa: BLE001 - a crash: record it and go on
                    ok = False
                    res.crashes += 1
                    if len(res.crash_samples) < max_samples:
                        res.crash_samples.append(_sample(exc, "on this input", seed, name, i, payload))
                    if isinstance(target, _BusTarget):  # keep counting per input
                        target.bus.stats.handler_errors = 0
                c1, w1 = thread_ns(), wall_ns()
                dt_ms = (c1 - c0) / 1e6
                total_ns += c1 - c0
                if dt_ms > res.max_input_ms:
                    res.max_input_ms = dt_ms
                    res.slowest_input = f"seed {seed} input {i}: {len(payload)} bytes, head {payload[:24].hex()}"
                res.max_input_wall_ms = max(res.max_input_wall_ms, (w1 - w0) / 1e6)
                res.max_input_net_gc_ms = max(res.max_input_net_gc_ms, dt_ms - (gc_ns[0] - g0) / 1e6)
                res.inputs += 1
                res.accepted += bool(ok)
                if ok:
                    last_accepted = (i, payload)
                try:
                    target.after()
                except Exception as exc:  # noqa: BLE001 - the state an accepted input left broke the scene
                    res.crashes += 1
                    if len(res.crash_samples) < max_samples:
                        res.crash_samples.append(_sample(exc, "in the scene's step after the last accepted input",
                                                         seed, name, last_accepted[0], last_accepted[1]))
                    if isinstance(target, _BusTarget):
                        target.bus.stats.handler_errors = 0
                res.max_step_ms = max(res.max_step_ms, (thread_ns() - c1) / 1e6)
        gc.callbacks.remove(on_gc)
        gc.unfreeze()  # the next target starts from its own start-up heap (before the growth's collect below)
        res.rejected = res.inputs - res.accepted
        res.seconds = time.perf_counter() - t_start
        res.mean_input_us = total_ns / max(1, n) / 1000.0
        payload, last_accepted = b"", (-1, b"")  # the last inputs (up to 256 kB) are not state the target kept
        gc.collect()
        res.rss_growth_kb = _rss_kb() - (rss_mark if rss_mark is not None else _rss_kb())
        if trace:
            current, peak = tracemalloc.get_traced_memory()
            res.traced_peak_kb, res.traced_growth_kb = peak / 1024.0, (current - traced_mark) / 1024.0
            tracemalloc.stop()
        res.state = target.sizes()
    finally:  # the process as it was found, also when a stream stops on an exception (or Ctrl-C)
        if on_gc in gc.callbacks:
            gc.callbacks.remove(on_gc)
        gc.unfreeze()
        root.setLevel(root_level)  # a caller in the same process (a test) logs as before
        if trace and tracemalloc.is_tracing():
            tracemalloc.stop()
    return res


def merge(results: Sequence[Result]) -> Result:
    """One target's results over its seeds: sums, maxima, the samples of all."""
    out = Result(results[0].name)
    for r in results:
        out.seeds += r.seeds
        out.inputs += r.inputs
        out.accepted += r.accepted
        out.rejected += r.rejected
        out.crashes += r.crashes
        out.crash_samples += r.crash_samples
        out.mean_input_us += r.mean_input_us * r.inputs
        if r.max_input_ms >= out.max_input_ms:
            out.max_input_ms, out.slowest_input = r.max_input_ms, r.slowest_input
        out.max_input_wall_ms = max(out.max_input_wall_ms, r.max_input_wall_ms)
        out.max_input_net_gc_ms = max(out.max_input_net_gc_ms, r.max_input_net_gc_ms)
        out.max_gc_pause_ms = max(out.max_gc_pause_ms, r.max_gc_pause_ms)
        out.max_step_ms = max(out.max_step_ms, r.max_step_ms)
        out.rss_growth_kb = max(out.rss_growth_kb, r.rss_growth_kb)
        if r.traced_peak_kb is not None:
            out.traced_peak_kb = max(out.traced_peak_kb or 0.0, r.traced_peak_kb)
            out.traced_growth_kb = max(out.traced_growth_kb or 0.0, r.traced_growth_kb or 0.0)
        for k, v in r.state.items():
            out.state[k] = max(out.state.get(k, 0), v)
        out.seconds += r.seconds
    out.mean_input_us /= max(1, out.inputs)
    return out


def run(n: int, names: list[str] | None = None, seeds: Sequence[int] = (0,), trace: bool = False,
        say: Callable[[str], None] = print) -> dict[str, Any]:
    """``n`` inputs per target and seed; returns the figures (see the module docstring)."""
    targets = all_targets()
    names = names or list(targets)
    unknown = [x for x in names if x not in targets]
    if unknown:
        raise SystemExit(f"unknown targets {unknown}; known: {', '.join(targets)}")
    say(f"{'target':<24}{'seed':>5}{'inputs':>9}{'reached':>9}{'crashes':>8}{'mean_us':>9}{'max_ms':>8}"
        f"{'wall_ms':>9}{'step_ms':>9}{'rss_kb':>8}  state sizes at the end")
    merged = []
    for name in names:
        per_seed = []
        for seed in seeds:
            r = run_target(name, targets[name], n, seed, trace)
            per_seed.append(r)
            state = " ".join(f"{k}={v}" for k, v in r.state.items())
            say(f"{name:<24}{seed:>5}{r.inputs:>9}{r.accepted:>9}{r.crashes:>8}{r.mean_input_us:>9.1f}"
                f"{r.max_input_ms:>8.2f}{r.max_input_wall_ms:>9.1f}{r.max_step_ms:>9.1f}{r.rss_growth_kb:>8.0f}  "
                f"{state}" + (f" traced_peak_kb={r.traced_peak_kb:.0f} traced_growth_kb={r.traced_growth_kb:.0f}"
                              if trace else ""))
            for s in r.crash_samples:
                say(f"    crash: {s}")
        merged.append(merge(per_seed))
    if len(seeds) > 1:
        say(f"per target over seeds {','.join(map(str, seeds))}:")
        for r in merged:
            say(f"  {r.name:<24}{r.inputs:>9} inputs {r.crashes:>3} crashes, slowest input {r.max_input_ms:6.2f} ms "
                f"({r.slowest_input}), {r.max_input_net_gc_ms:.2f} ms less GC pauses (longest pause "
                f"{r.max_gc_pause_ms:.1f} ms), rss +{r.rss_growth_kb:.0f} kB")
    traced = [r.traced_growth_kb for r in merged if r.traced_growth_kb is not None]
    return {
        "fuzz_inputs": sum(r.inputs for r in merged),
        "fuzz_crashes": sum(r.crashes for r in merged),
        "fuzz_max_input_ms": round(max((r.max_input_ms for r in merged), default=0.0), 3),
        "fuzz_max_rss_growth_kb": max((r.rss_growth_kb for r in merged), default=0.0),
        "fuzz_max_input_wall_ms": round(max((r.max_input_wall_ms for r in merged), default=0.0), 3),
        "fuzz_max_input_net_gc_ms": round(max((r.max_input_net_gc_ms for r in merged), default=0.0), 3),
        "fuzz_max_gc_pause_ms": round(max((r.max_gc_pause_ms for r in merged), default=0.0), 3),
        "fuzz_max_step_ms": round(max((r.max_step_ms for r in merged), default=0.0), 3),
        "fuzz_seeds": list(seeds),
        "fuzz_inputs_per_target": n,
        "fuzz_targets": len(merged),
        "fuzz_max_traced_growth_kb": max(traced) if traced else None,
        "fuzz_seconds": round(sum(r.seconds for r in merged), 1),
        "targets": {r.name: dataclasses.asdict(r) for r in merged},
    }


def _seed_list(text: str) -> list[int]:
    try:
        seeds = [int(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"--seeds takes integers separated by commas, e.g. 0,1,2; got {text!r}") from None
    if not seeds:
        raise argparse.ArgumentTypeError("--seeds needs at least one seed")
    return seeds


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=100_000, help="inputs per target and seed (default 100,000)")
    ap.add_argument("--quick", action="store_true", help="2,000 inputs per target and seed")
    ap.add_argument("--targets", default=None, help="comma-separated subset (default: all 17)")
    ap.add_argument("--seeds", type=_seed_list, default=[0], metavar="S,S,...",
                    help="input streams to run, each over every target (default 0)")
    ap.add_argument("--tracemalloc", action="store_true", help="also trace Python allocations (slower)")
    ap.add_argument("--json", action="store_true", help="last line: one JSON object of the figures")
    args = ap.parse_args(argv)
    if args.n < 1:
        ap.error("--n must be at least 1")
    n = 2000 if args.quick else args.n
    out = run(n, args.targets.split(",") if args.targets else None, args.seeds, args.tracemalloc)
    print(f"fuzz: {out['fuzz_inputs']} inputs over {out['fuzz_targets']} targets x seeds {out['fuzz_seeds']}, "
          f"{out['fuzz_crashes']} crashes, slowest input {out['fuzz_max_input_ms']:.2f} ms CPU "
          f"({out['fuzz_max_input_wall_ms']:.1f} ms wall, {out['fuzz_max_input_net_gc_ms']:.2f} ms less GC pauses, "
          f"longest GC pause {out['fuzz_max_gc_pause_ms']:.1f} ms), max RSS growth {out['fuzz_max_rss_growth_kb']:.0f} kB, "
          f"{out['fuzz_seconds']:.0f} s")
    if args.json:
        print(json.dumps(out))
    return 1 if out["fuzz_crashes"] else 0


if __name__ == "__main__":
    raise SystemExit(main())
