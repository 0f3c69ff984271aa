"""bench/security_bench.py --quick --no-e2e runs and its last line is the JSON of the bench's figures."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent.parent


def test_security_bench_quick_json():
    r = subprocess.run([sys.executable, "bench/security_bench.py", "--quick", "--no-e2e", "--json"], cwd=ROOT,
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]
    figures = json.loads(r.stdout.strip().splitlines()[-1])
    for k in ("sign_us", "verify_us", "fuzz_inputs", "fuzz_crashes"):
        assert k in figures
    assert figures["sign_us"] > 0 and figures["verify_us"] > 0
    assert figures["fuzz_inputs"] == 17 * 50 and figures["fuzz_crashes"] == 0
