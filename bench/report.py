"""Run the benches and write ``docs/benchmarks.md`` from their ``--json`` output.

    python -m bench.report --run [--quick] [--only NAME ...] [--outputs runs/bench] [--out docs/benchmarks.md]
    python -m bench.report [--outputs runs/bench] [--out docs/benchmarks.md]
    python -m bench.report --add NAME LOG --command "python bench/NAME.py ... --json"

With ``--run`` each bench of ``bench/suite.py`` (or those of ``--only``) runs as ``python bench/<name>.py --json``
(``--quick``: with its quick run's arguments), one after the other, and its record is saved in ``--outputs`` as
``<name>.json``: the command, the mode (quick or full), the date (UTC), the commit, the machine (cores, CPU model), the wall
and CPU time, the exit status and the figures (its last line of output; the whole output beside it in ``<name>.log``). A
bench that needs ``../shared`` or a program the machine lacks is recorded as skipped, with the reason. Without
``--run`` the records already in ``--outputs`` are used; ``--add`` records the output of a run made by hand (a full
run of hours, in the background). Then the page is written: per bench its key figures, every other figure, the
exact command that reproduces them, the mode, the machine and the date; a bench without a record keeps its section
of the page as it was (``--fresh``: the records alone). Exit status 1 when a bench run failed.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import shutil
import subprocess
import sys
import time
from datetime import UTC, datetime
from pathlib import Path

from bench.suite import BENCHES, Bench, by_name

ROOT = Path(__file__).resolve().parent.parent
SHARED_REAL = ROOT.parent / "shared" / "data" / "real"
"""``../shared/data/real`` beside the repository (as ``bench/_setup.py`` finds it)."""


def machine() -> dict[str, object]:
    """The machine a bench ran on: cores, CPU model, OS, Python and its load (1-minute average) now: on a machine
    shared with other jobs the load moves every timing figure."""
    model = platform.processor() or "unknown"
    cpuinfo = Path("/proc/cpuinfo")
    if cpuinfo.is_file():
        model = next((line.split(":", 1)[1].strip() for line in cpuinfo.read_text().splitlines()
                      if line.startswith("model name")), model)
    return {"cores": os.cpu_count(), "cpu": model, "os": platform.platform(terse=True),
            "python": platform.python_version(), "load_1min": round(os.getloadavg()[0], 1)}


def commit() -> str | None:
    """The repository's commit (short hash, ``+`` when the tree has changes), or None outside a git checkout."""
    try:
        head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True,
                              timeout=10)
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=ROOT,
                               capture_output=True, text=True, timeout=10)
    except (OSError, subprocess.TimeoutExpired):
        return None
    if head.returncode != 0:
        return None
    return head.stdout.strip() + ("+" if dirty.stdout.strip() else "")


def skip_reason(bench: Bench) -> str | None:
    """Why ``bench`` cannot run on this machine, or None."""
    if bench.needs_shared and not SHARED_REAL.is_dir():
        return f"needs {SHARED_REAL} (../shared beside the repository), absent here"
    if bench.needs_tool and shutil.which(bench.needs_tool) is None:
        return f"needs {bench.needs_tool} on PATH, absent here"
    return None


def last_json_object(stdout: str) -> dict | None:
    """The bench's figures: its last line of output when that is one JSON object, else None."""
    lines = stdout.strip().splitlines()
    try:
        figures = json.loads(lines[-1]) if lines else None
    except json.JSONDecodeError:
        return None
    return figures if isinstance(figures, dict) else None


def _children_cpu_s() -> float:
    """CPU seconds (user + system) of this process's finished children and the descendants they waited for."""
    u = resource.getrusage(resource.RUSAGE_CHILDREN)
    return u.ru_utime + u.ru_stime


def run_bench(bench: Bench, quick: bool, outputs: Path) -> dict:
    """Run ``bench`` (a process of its own, from the repository root) and save its record and output in ``outputs``."""
    args = bench.command(quick)
    record: dict = {"bench": bench.name, "mode": "quick" if quick else "full", "command": "python " + " ".join(args),
                    "date": datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC"), "commit": commit(),
                    "machine": machine()}
    reason = skip_reason(bench)
    if reason is not None:
        record.update(skipped=reason)
    else:
        t0, cpu0 = time.monotonic(), _children_cpu_s()
        r = subprocess.run([sys.executable, *args], cwd=ROOT, capture_output=True, text=True,
                           env=dict(os.environ, PYTHONPATH=str(ROOT)))
        record.update(wall_s=round(time.monotonic() - t0, 1), cpu_s=round(_children_cpu_s() - cpu0, 1),
                      exit=r.returncode, figures=last_json_object(r.stdout))
        (outputs / f"{bench.name}.log").write_text(r.stdout + ("\n--- stderr\n" + r.stderr if r.stderr else ""))
    (outputs / f"{bench.name}.json").write_text(json.dumps(record, indent=1) + "\n")
    return record


def load_records(outputs: Path) -> list[dict]:
    """The records saved in ``outputs``, in the suite's order (benches without one left out)."""
    out = []
    for bench in BENCHES:
        path = outputs / f"{bench.name}.json"
        if path.is_file():
            out.append(json.loads(path.read_text()))
    return out


def failed(record: dict) -> bool:
    return "skipped" not in record and (record.get("exit") != 0 or record.get("figures") is None)


def _value(v: object) -> str:
    if isinstance(v, float):
        return f"{v:.0f}" if abs(v) >= 1000 else f"{v:.4g}"
    if isinstance(v, dict | list):
        text = json.dumps(v, separators=(", ", ": "))
        return text if len(text) <= 160 else text[:157] + "..."
    return str(v)


def _machine_line(m: dict) -> str:
    load = "" if m.get("load_1min") is None else f"; load {m['load_1min']} when it started"
    return f"{m.get('cores')} cores, {m.get('cpu')}; {m.get('os')}, Python {m.get('python')}{load}"


def record_from_log(bench: Bench, log: Path, command: str, mode: str) -> dict:
    """The record of a run made outside the report (a long full run, started by hand): its figures are the
    last line of ``log`` (its output), its date the log's time; the machine is this one."""
    figures = last_json_object(log.read_text(errors="replace"))
    if figures is None:
        raise ValueError(f"{log}: its last line is not one JSON object of figures (run the bench with --json)")
    when = datetime.fromtimestamp(log.stat().st_mtime, UTC).strftime("%Y-%m-%d %H:%M UTC")
    here = {k: v for k, v in machine().items() if k != "load_1min"}  # the load now says nothing of the run's
    return {"bench": bench.name, "mode": mode, "command": command, "date": when, "commit": commit(),
            "machine": here, "exit": 0, "figures": figures}


def kept_sections(page: str) -> dict[str, tuple[str, str]]:
    """Per bench of an existing page: (its row of the summary table, its section), to keep a bench whose
    record is not at hand when the page is written again."""
    rows = {line.split("](#", 1)[0][3:]: line for line in page.splitlines() if line.startswith("| [")}
    out = {}
    for part in page.split("\n## ")[1:]:
        name = part.split("\n", 1)[0].strip()
        if name in rows:
            out[name] = (rows[name], "## " + part.rstrip("\n"))
    return out


def render_markdown(records: list[dict], kept: dict[str, tuple[str, str]] | None = None) -> str:
    """The page of ``records`` (what :func:`run_bench` saves); a bench of the suite without a record keeps its
    row and section from ``kept`` (:func:`kept_sections` of the page as it was)."""
    suite = by_name()
    have = {r["bench"] for r in records}
    kept = {k: v for k, v in (kept or {}).items() if k not in have and k in suite}
    order = [b.name for b in BENCHES]
    entries = sorted([(order.index(r["bench"]), r) for r in records if r["bench"] in suite]
                     + [(order.index(k), k) for k in kept], key=lambda e: e[0])
    lines = ["# Benchmarks", "",
             "Written by `python -m bench.report` from the benches' `--json` output; do not edit by hand. "
             "`make bench` runs every bench in full and writes this page again; "
             "`python -m bench.report --run --quick` does the same with the quick runs (a small but real run of "
             "each bench's code path: fewer seeds, frames, clips, iterations; its figures are not the full run's).",
             "", "Each figure's bench, mode, date and machine are given with it; the command reproduces it from the "
             "repository root.", "", "| bench | measures | mode | date | wall s | CPU s | status |",
             "|---|---|---|---|---|---|---|"]
    for _, r in entries:
        if isinstance(r, str):
            lines.append(kept[r][0])
            continue
        b = suite.get(r["bench"])
        status = ("skipped" if "skipped" in r else "failed" if failed(r) else "ok")
        lines.append(f"| [{r['bench']}](#{r['bench']}) | {b.title if b else ''} | {r['mode']} | "
                     f"{r['date']} | {r.get('wall_s', '')} | {r.get('cpu_s', '')} | {status} |")
    for _, r in entries:
        if isinstance(r, str):
            lines += ["", kept[r][1]]
            continue
        b = suite.get(r["bench"])
        lines += ["", f"## {r['bench']}", ""]
        if b is not None:
            lines += [b.title + ".", ""]
        lines += [f"- command: `{r['command']}`", f"- mode: {r['mode']}", f"- date: {r['date']}",
                  f"- machine: {_machine_line(r['machine'])}"]
        if r.get("commit"):
            lines += [f"- commit: {r['commit']}"]
        if "skipped" in r:
            lines += [f"- skipped: {r['skipped']}"]
            continue
        if r.get("wall_s") is not None:
            lines += [f"- wall time: {r.get('wall_s')} s (CPU {r.get('cpu_s')} s), exit status {r.get('exit')}"]
        else:
            lines += ["- run by hand (the command above), its output recorded with `python -m bench.report --add`"]
        figures = r.get("figures")
        if figures is None:
            lines += ["", f"No figures: the run failed (its output: `{r['bench']}.log` in the outputs folder)."]
            continue
        key = [k for k in (b.figures if b else ()) if k in figures]
        rest = [k for k in figures if k not in key]
        lines += ["", "| figure | value |", "|---|---|"]
        lines += [f"| **{k}** | {_value(figures[k])} |" for k in key]
        lines += [f"| {k} | {_value(figures[k])} |" for k in rest]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--run", action="store_true", help="run the benches first (else use the saved records)")
    ap.add_argument("--quick", action="store_true", help="with --run: each bench's quick run")
    ap.add_argument("--only", nargs="+", default=None, metavar="NAME", help="with --run: only these benches")
    ap.add_argument("--outputs", type=Path, default=ROOT / "runs" / "bench", help="the records' folder")
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "benchmarks.md", help="the page to write")
    ap.add_argument("--add", nargs=2, metavar=("NAME", "LOG"), default=None,
                    help="record the output LOG of a run of bench NAME made by hand (with --command), then write "
                         "the page")
    ap.add_argument("--command", default=None, help="with --add: the command that made LOG")
    ap.add_argument("--mode", choices=["full", "quick"], default="full", help="with --add: the run's mode")
    ap.add_argument("--fresh", action="store_true",
                    help="a page of the records alone (else a bench without a record keeps its section)")
    args = ap.parse_args(argv)
    suite = by_name()
    unknown = sorted(set(args.only or ()) - set(suite))
    if unknown:
        ap.error(f"--only: no bench named {unknown}; the benches: {', '.join(suite)}")
    if args.add:
        name, log = args.add[0], Path(args.add[1])
        if name not in suite:
            ap.error(f"--add: no bench named {name!r}; the benches: {', '.join(suite)}")
        if not args.command:
            ap.error("--add needs --command: the command that made the log")
        if not log.is_file():
            ap.error(f"--add: {log} is not a file")
        try:
            rec = record_from_log(suite[name], log, args.command, args.mode)
        except ValueError as exc:
            ap.error(str(exc))
        args.outputs.mkdir(parents=True, exist_ok=True)
        (args.outputs / f"{name}.json").write_text(json.dumps(rec, indent=1) + "\n")
    if args.run:
        args.outputs.mkdir(parents=True, exist_ok=True)
        for name in args.only or suite:
            print(f"== {name}", flush=True)
            r = run_bench(suite[name], args.quick, args.outputs)
            print(f"   {r.get('skipped') or ('FAILED' if failed(r) else 'ok')} ({r.get('wall_s', 0)} s)", flush=True)
    records = load_records(args.outputs)
    if not records:
        print(f"bench.report: no records in {args.outputs}: run with --run first", file=sys.stderr)
        return 2
    kept = None if args.fresh or not args.out.is_file() else kept_sections(args.out.read_text())
    args.out.write_text(render_markdown(records, kept))
    bad = [r["bench"] for r in records if failed(r)]
    print(f"wrote {args.out} ({len(records)} benches" + (f"; failed: {', '.join(bad)})" if bad else ")"))
    return 1 if bad else 0


if __name__ == "__main__":
    raise SystemExit(main())
