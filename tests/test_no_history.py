"""The product speaks of itself only: no build history in any tracked file.

Code, docstrings, tests and documents say what the code does and why; how it came to be (issue numbers,
counts of working days, dated diaries, what was tried and dropped, citations of design documents kept outside
the repository) belongs in the commit messages. This test greps every tracked text file (``git ls-files``)
for such phrases and fails listing ``file:line: text`` for each.

The patterns are chosen for few false positives: "session" alone is Zenoh's session API (``zenoh.Session``,
a service's session) and an OS process session, so only a counted or dated work session matches (in the
ordinal or "this ...'s" forms); "#123" matches only as a bare reference in prose (not a CSS colour, a URL
fragment or an upstream ``owner/repo#123``); an ISO date matches anywhere except the few data fixtures
listed in ``DATED_DATA``.
"""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent

EXCLUDE: tuple[str, ...] = ()
"""Paths not scanned: none. A path may be listed only while another branch rewrites it; it must end empty."""

SELF = "tests/test_no_history.py"
"""This file holds examples of every pattern (``test_patterns_*``), so it is not scanned."""

VENDORED: tuple[str, ...] = ("deploy/schema/compose-spec.json", "deploy/schema/docker-compose-1.29.2.json",
                             "deploy/schema/LICENSE")
"""Third-party files kept unmodified (``deploy/schema/README.md``): their upstream's references are theirs."""

DATED_DATA: dict[str, str] = {
    "tests/e2e/test_e2e_bench_hops.py": "a DDM log fixture: its lines start with logging's timestamps",
    "tests/rsu/test_calibration.py": "a surveyed-points CSV fixture with a dated comment line",
    "deploy/schema/README.md": "the release date of a vendored third-party schema (its provenance)",
    "docs/benchmarks.md": "written by bench/report.py: each figure with the date it was measured",
    "tests/bench/test_bench_report.py": "a bench record fixture: the date the report prints",
}
"""Files where an ISO date is data, not a diary: the date pattern alone is not applied to them."""

_ORDINAL = (r"(?:first|second|third|fourth|fifth|sixth|seventh|eighth|ninth|tenth|eleventh|twelfth|\w+teenth|"
            r"twentieth|twenty[- ]?\w+|thirtieth|thirty[- ]?\w+|\d+(?:st|nd|rd|th))")

PATTERNS: dict[str, re.Pattern[str]] = {
    "issue number": re.compile(r"\bissues?\s+#?\d+|\bissue_\d+", re.IGNORECASE),
    "bare #N reference": re.compile(r"(?:^|[\s(\[])#\d{1,4}(?![\w;])"),
    "work session": re.compile(
        rf"\b(?:{_ORDINAL}|this|that|previous|last|next|earlier|later|same)\s+session\b|\bsession by session\b",
        re.IGNORECASE),
    "dated diary": re.compile(r"\b20\d\d-[01]\d-[0-3]\d\b"),
    "tried and dropped": re.compile(r"\btried\b.{0,80}\b(?:not shipped|dropped|reverted)\b|\bnot shipped\b",
                                    re.IGNORECASE),
    "names that lived elsewhere": re.compile(r"\blived here\b|\bkept for (?:backward )?compatibility\b",
                                             re.IGNORECASE),
    "external design document": re.compile(r"\b(?:DESIGN|SPEC)\.md\b|\b(?:DESIGN|SPEC) §"),
}


def _tracked_text_files() -> list[str]:
    if shutil.which("git") is None or not (ROOT / ".git").exists():
        pytest.skip("needs git and a git checkout (git ls-files lists the tracked files); not available here")
    out = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, check=True).stdout
    return [p for p in out.decode("utf-8").split("\0") if p]


def _text(path: Path) -> str | None:
    """The file's text, or None for a binary file (a NUL byte, or not UTF-8) or one that is absent."""
    try:
        data = path.read_bytes()
    except (FileNotFoundError, IsADirectoryError):
        return None
    if b"\0" in data[:8192]:
        return None
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        return None


def history_lines(rel: str, text: str) -> list[str]:
    """``rel:line: [kind] text`` for every line of ``text`` that carries build history."""
    found = []
    for n, line in enumerate(text.splitlines(), 1):
        for kind, pattern in PATTERNS.items():
            if kind == "dated diary" and rel in DATED_DATA:
                continue
            if pattern.search(line):
                found.append(f"{rel}:{n}: [{kind}] {line.strip()[:160]}")
                break
    return found


def test_no_tracked_file_carries_build_history():
    hits: list[str] = []
    for rel in _tracked_text_files():
        if rel == SELF or rel in VENDORED or rel.startswith(EXCLUDE):
            continue
        text = _text(ROOT / rel)
        if text is not None:
            hits.extend(history_lines(rel, text))
    assert not hits, (f"{len(hits)} line(s) carry build history; say what the code does and why, and put how it "
                      "came to be in the commit message:\n" + "\n".join(hits))


WORK = "sess" + "ion"
"""The positive examples below are put together from parts, so that no line of this file reads as history itself."""


@pytest.mark.parametrize("line", [
    "Split out of the messages module (" + "issue" + " 20, item 6).",
    "see Issue #22 for the figures",
    "ISSUE_24_CRASH = b''",
    "fixed in #17 and merged",
    f"measured in the ninth {WORK} on the slow machine",
    f"this {WORK}'s 2-core Xeon",
    f"as in the twenty-seventh {WORK}",
    "Tried on 2026-11-25, not shipped.",
    "a LeakyReLU model was tried and not shipped",
    "names that lived here before",
    "(DESIGN.md \"Transports\")",
    "SPEC §Perception",
])
def test_patterns_catch_history(line):
    assert history_lines("x.py", line), line


@pytest.mark.parametrize("line", [
    "with zenoh.open(conf) as session:",
    "the token exists exactly while the service's session is up",
    "publishers declared once per key on a session",
    "starts each service in its own session (a Ctrl-C in the terminal reaches none of them)",
    "@pytest.fixture(scope=\"session\")",
    "  header { background: #222831; color: #889; }",
    "g.strokeStyle = \"#777\";",
    "openimages_vehicles,\"train/p1.jpg#88,6,152,54\",car,ev,police car",
    "stalls any DROP message queued at the same priority (upstream eclipse-zenoh/zenoh#2584)",
    "commands (in issue order) neither acked nor superseded",
    "valid_until must be later than issued_at",
    "docs/architecture.md §Tracking",
    "p = argparse.ArgumentParser()  # one parser per command",
])
def test_patterns_spare_the_product(line):
    assert not history_lines("x.py", line), line
