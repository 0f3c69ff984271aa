"""bench/report.py: docs/benchmarks.md is written from the benches' saved --json records, each figure with the
command that reproduces it, the mode, the machine and the date."""

from __future__ import annotations

import json
import subprocess

import pytest

from bench import report
from bench.suite import by_name

MACHINE = {"cores": 2, "cpu": "Test CPU @ 2.0GHz", "os": "Linux-6", "python": "3.11.9", "load_1min": 7.5}


def record(name: str, **kw) -> dict:
    b = by_name()[name]
    return {"bench": name, "mode": "quick", "command": "python " + " ".join(b.command(quick=True)),
            "date": "2026-01-02 03:04 UTC", "commit": "abc1234", "machine": MACHINE, **kw}


def test_the_page_gives_each_figure_with_its_command_mode_machine_and_date():
    ddm = record("ddm_bench", wall_s=3.5, exit=0,
                 figures={"updates_per_s": 56552.0, "decision_latency_p99_ms": 5.981, "rsus": 8, "tracks": [1, 2]})
    photos = record("ev_photos_bench", skipped="needs ../shared/data/real, absent here")
    page = report.render_markdown([ddm, photos])
    assert "`python bench/ddm_bench.py --quick --json`" in page
    assert "| **updates_per_s** | 56552 |" in page  # a key figure, in bold
    assert "| **decision_latency_p99_ms** | 5.981 |" in page
    assert "| rsus | 8 |" in page and "| tracks | [1, 2] |" in page  # the other figures too
    assert "2 cores, Test CPU @ 2.0GHz" in page and "load 7.5 when it started" in page and "2026-01-02 03:04 UTC" in page and "- mode: quick" in page
    assert "- commit: abc1234" in page
    assert "- skipped: needs ../shared/data/real, absent here" in page
    assert "| [ev_photos_bench](#ev_photos_bench) |" in page and "| skipped |" in page


def test_a_failed_run_is_shown_failed_and_makes_the_report_exit_1(tmp_path):
    (tmp_path / "ddm_bench.json").write_text(json.dumps(record("ddm_bench", wall_s=1.0, exit=1, figures=None)))
    out = tmp_path / "benchmarks.md"
    assert report.main(["--outputs", str(tmp_path), "--out", str(out)]) == 1
    page = out.read_text()
    assert "| failed |" in page and "No figures: the run failed" in page


def test_the_page_is_written_from_saved_records_in_the_suites_order(tmp_path):
    for name in ("zenoh_bench", "calibration_bench"):
        (tmp_path / f"{name}.json").write_text(json.dumps(record(name, wall_s=1.0, exit=0, figures={"x": 1})))
    out = tmp_path / "benchmarks.md"
    assert report.main(["--outputs", str(tmp_path), "--out", str(out)]) == 0
    page = out.read_text()
    assert page.index("## calibration_bench") < page.index("## zenoh_bench")


def test_no_records_is_an_error_that_says_to_run_first(tmp_path, capsys):
    assert report.main(["--outputs", str(tmp_path), "--out", str(tmp_path / "b.md")]) == 2
    assert "--run" in capsys.readouterr().err


def test_the_figures_are_the_last_line_when_it_is_a_json_object():
    assert report.last_json_object('progress\n{"a": 1}\n') == {"a": 1}
    assert report.last_json_object('{"a": 1}\ndone\n') is None
    assert report.last_json_object("[1, 2]\n") is None
    assert report.last_json_object("") is None


def test_a_bench_that_needs_the_shared_data_is_skipped_without_it(monkeypatch, tmp_path):
    monkeypatch.setattr(report, "SHARED_REAL", tmp_path / "absent")
    assert "absent here" in report.skip_reason(by_name()["ev_real_bench"])
    assert report.skip_reason(by_name()["ddm_bench"]) is None


def test_the_commit_is_this_checkouts():
    if not (report.ROOT / ".git").exists():
        pytest.skip("not a git checkout: no commit to record")
    head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=report.ROOT, capture_output=True, text=True)
    assert report.commit().rstrip("+") == head.stdout.strip()


def test_a_bench_without_a_record_keeps_its_section_and_a_run_by_hand_is_added(tmp_path):
    outputs, out = tmp_path / "records", tmp_path / "benchmarks.md"
    outputs.mkdir()
    (outputs / "ddm_bench.json").write_text(json.dumps(record("ddm_bench", wall_s=1.0, exit=0,
                                                              figures={"updates_per_s": 1.0})))
    first = record("protocol_bench", wall_s=2.0, exit=0, figures={"cam_us": 3.0})
    out.write_text(report.render_markdown([json.loads((outputs / "ddm_bench.json").read_text()), first]))
    log = tmp_path / "v2x.log"
    log.write_text("seed 1: ok\n" + json.dumps({"equipped_runs": 10, "forged_commands": 0}) + "\n")
    assert report.main(["--outputs", str(outputs), "--out", str(out), "--add", "v2x_bench", str(log),
                        "--command", "python bench/v2x_bench.py --json --zenoh-seeds 10"]) == 0
    page = out.read_text()
    assert "## protocol_bench" in page and "| cam_us | 3 |" in page  # kept from the page as it was
    assert "`python bench/v2x_bench.py --json --zenoh-seeds 10`" in page and "| forged_commands | 0 |" in page
    assert page.index("## ddm_bench") < page.index("## protocol_bench") < page.index("## v2x_bench")  # suite order
    assert page.count("| [protocol_bench](#protocol_bench)") == 1
    assert report.main(["--outputs", str(outputs), "--out", str(out), "--fresh"]) == 0
    assert "## protocol_bench" not in out.read_text()
    log.write_text("no figures\n")
    with pytest.raises(SystemExit):
        report.main(["--outputs", str(outputs), "--out", str(out), "--add", "v2x_bench", str(log), "--command", "x"])
