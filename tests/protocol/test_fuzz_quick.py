"""A quick fuzz of all 20 targets in every test run, with a seed that changes with the date
and the commit (so each day and each commit explores new inputs), printed; a crash fails the test with
the payload in hex and the command that regenerates it. ``IEA_FUZZ_SEED=S`` replays a seed;
``IEA_FUZZ_QUICK_N`` sets the inputs per target (default 3,000; ``bench/fuzz_bench.py`` runs 100,000
per target and seed)."""

from __future__ import annotations

import datetime
import hashlib
import os
import subprocess
import time
from pathlib import Path

from bench import fuzz_bench

ROOT = Path(__file__).resolve().parents[2]
N = int(os.environ.get("IEA_FUZZ_QUICK_N", "3000"))


def _commit() -> str:
    try:
        out = subprocess.run(["git", "rev-parse", "--short=12", "HEAD"], cwd=ROOT, capture_output=True, text=True,
                             timeout=10)
    except (OSError, subprocess.SubprocessError):
        return "no-git"
    return out.stdout.strip() if out.returncode == 0 and out.stdout.strip() else "no-git"


def quick_seed() -> tuple[int, str]:
    """(seed, how it was chosen): ``IEA_FUZZ_SEED``, else a hash of the UTC date and the git commit."""
    if os.environ.get("IEA_FUZZ_SEED"):
        return int(os.environ["IEA_FUZZ_SEED"]), "IEA_FUZZ_SEED"
    day, commit = datetime.datetime.now(datetime.UTC).date().isoformat(), _commit()
    seed = int(hashlib.sha256(f"{day}:{commit}".encode()).hexdigest()[:8], 16) % 1_000_000
    return seed, f"UTC date {day}, commit {commit}"


def test_quick_fuzz_every_target_finds_no_crash():
    seed, why = quick_seed()
    print(f"quick fuzz: seed {seed} ({why}), {N} inputs per target; replay with IEA_FUZZ_SEED={seed}")
    t0 = time.perf_counter()
    out = fuzz_bench.run(N, seeds=[seed], say=lambda _s: None)
    seconds = time.perf_counter() - t0
    crashes = {name: t["crash_samples"] for name, t in out["targets"].items() if t["crashes"]}
    assert out["fuzz_crashes"] == 0, (
        f"seed {seed} ({why}): {out['fuzz_crashes']} crashes; each sample holds the payload in hex and "
        f"`python bench/fuzz_bench.py --seeds {seed} --targets NAME --n INDEX+1` regenerates it:\n"
        + "\n".join(f"{name}: {s}" for name, samples in crashes.items() for s in samples))
    assert out["fuzz_targets"] == 20 and out["fuzz_inputs"] == 20 * N
    assert all(t["accepted"] > 0 for t in out["targets"].values())  # every handler saw decodable input
    print(f"quick fuzz: {out['fuzz_inputs']} inputs in {seconds:.1f} s, slowest input "
          f"{out['fuzz_max_input_ms']:.2f} ms CPU, max RSS growth {out['fuzz_max_rss_growth_kb']:.0f} kB")


def test_a_crash_is_reported_with_its_payload_in_hex_and_how_to_regenerate_it(monkeypatch):
    import random

    from bench import fuzz_targets
    from protocol.messages import CommandAck

    def crash(self, payload: bytes) -> bool:
        raise OverflowError("cannot convert float infinity to integer")

    first = fuzz_targets.DecodeTarget(random.Random("5-decode_CommandAck"), CommandAck).payload()
    monkeypatch.setattr(fuzz_targets.DecodeTarget, "feed", crash)
    out = fuzz_bench.run(3, names=["decode_CommandAck"], seeds=[5], say=lambda _s: None)
    assert out["fuzz_crashes"] == 3
    sample = out["targets"]["decode_CommandAck"]["crash_samples"][0]
    assert sample.startswith("OverflowError: cannot convert float infinity to integer")
    assert "regenerate: seed 5, target decode_CommandAck, input 0" in sample
    assert f"payload {len(first)} bytes: {first.hex()}" in sample


def test_a_target_that_fails_to_start_leaves_the_process_as_it_found_it():
    """``run_target`` silences logging and hooks the garbage collector for its inputs: when its target cannot even be
    made (or a stream stops on an exception), the log level, the gc hooks and the heap freeze are put back all the
    same, or a later test in the same process would read no log records."""
    import gc
    import logging

    import pytest

    def broken(_rng):
        raise RuntimeError("target cannot start")

    root = logging.getLogger()
    level, callbacks = root.level, list(gc.callbacks)
    with pytest.raises(RuntimeError, match="cannot start"):
        fuzz_bench.run_target("broken", broken, 10, trace=True)
    assert root.level == level and gc.callbacks == callbacks and gc.get_freeze_count() == 0
