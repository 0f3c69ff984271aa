"""The benches of ``bench/``: what each measures, its key figures, what it needs and the arguments of its quick run.

One table for the tools that run every bench: the smoke test (``tests/bench/test_bench_smoke.py``, every bench in
its quick mode) and the report (``python -m bench.report``, which writes ``docs/benchmarks.md``). A script named
``bench/*_bench.py`` must have a row here; the smoke test fails for one that has none.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

BENCH_DIR = Path(__file__).resolve().parent
"""The folder of the bench scripts."""


@dataclass(frozen=True)
class Bench:
    """One bench script: ``python bench/<name>.py [quick...] --json`` ends its output with one JSON line."""

    name: str
    """The script's name without ``.py`` (``bench/<name>.py``)."""
    title: str
    """What it measures, in one line."""
    figures: tuple[str, ...]
    """The key figures: top-level keys of its JSON line that every run, quick or full, reports."""
    quick: tuple[str, ...] = ("--quick",)
    """The arguments of its quick run (a small but real run of the same code path)."""
    needs_shared: bool = False
    """It reads ``../shared/data/real`` (real photos and videos, the COCO YOLOX-Nano) and has nothing to measure
    without it."""
    needs_tool: str | None = None
    """A program it runs that is not a Python package (found on ``PATH``), if any."""
    processes: bool = False
    """It starts processes (services over Zenoh): its smoke run is marked ``slow`` as well as ``serial``."""
    tested_by: str | None = None
    """A test of its own runs its quick mode and checks its figures' meaning, not only their presence: the
    generic smoke run leaves it to that test."""

    def command(self, quick: bool) -> list[str]:
        """The arguments after ``python``: the script, the quick run's arguments if ``quick``, and ``--json``."""
        return [f"bench/{self.name}.py", *(self.quick if quick else ()), "--json"]


BENCHES: tuple[Bench, ...] = (
    Bench("calibration_bench", "Camera commissioning from 8 surveyed points: pose and ground error",
          ("pose_position_error_m", "pose_angle_error_deg", "ground_error_60m_median_m")),
    Bench("control_bench", "Vehicle control: lane change and stop, lateral error, stability margin, cost per step",
          ("max_lateral_error_m", "settled_lateral_error_m", "stop_error_m", "stability_min_damping",
           "controller_step_us"),
          tested_by="tests/vehicle/test_vehicle_plot.py"),
    Bench("ddm_bench", "DDM throughput and decision latency under many RSUs' object lists",
          ("updates_per_s", "decision_latency_p99_ms", "alert_to_command_cpu_p99_ms", "decisions"),
          tested_by="tests/ddm/test_ddm_bench.py"),
    Bench("detector_size_bench", "The project detector's MOTA, mAP and CPU against its input size",
          ("sizes", "chosen_input", "shipped_input")),
    Bench("driving_bench", "Learned end-to-end steering (cases 1-3) against the infrastructure-guided controller",
          ("episodes", "iea_traj_rmse_m", "case1_traj_rmse_m", "case2_traj_rmse_m", "case3_traj_rmse_m",
           "iea_collisions", "learned_collisions")),
    Bench("e2e_bench", "The corridor end to end as processes over Zenoh: lights on -> response -> manoeuvre",
          ("lights_on_to_response_median_s", "lights_on_to_alert_median_s", "rsu_fps_min", "runs_yield_ok"),
          processes=True),
    Bench("ev_bench", "EV identification on simulator renders: track recall, false alerts, lights on -> alert",
          ("track_recall", "false_alerts", "lights_on_to_alert_median_s", "false_alerts_on_decoy_lamps"),
          tested_by="tests/rsu/test_ev_bench_smoke.py"),
    Bench("ev_photos_bench", "EV classification of real whole-scene photos (detector, then classifiers)",
          ("images", "best", "accuracy", "precision", "recall", "f_measure"), needs_shared=True),
    Bench("ev_real_bench", "EV recognition on labelled real clips, scored per vehicle; photos; the held-out split",
          ("ev_recall", "alert_delay_median_s", "alert_delay_max_s", "wrong_vehicle_alerts", "traffic_false_alerts",
           "traffic_video_s", "by_viewpoint", "real_ev_clips_alerted"),
          needs_shared=True, tested_by="tests/rsu/test_ev_real_bench_quick.py"),
    Bench("foxglove_bench", "The live Foxglove bridge's cost during the demo and the recordings' size per minute",
          ("bridge_cpu_percent", "bridge_msgs_per_s", "client_ok", "recording_mb_per_min",
           "recording_mb_per_min_no_camera"), processes=True, needs_tool="node"),
    Bench("fuzz_bench", "Fuzzing every decoder and service message handler: crashes, cost per input, memory",
          ("fuzz_inputs", "fuzz_crashes", "fuzz_max_input_ms", "fuzz_max_rss_growth_kb")),
    Bench("hazard_bench", "Road hazards on simulator renders: recall, false alarms, the AV's clearance",
          ("hazard_recall", "hazard_false_alarms", "min_clearance_m", "collisions")),
    Bench("netfault_bench", "Faults on real network links: the corridor's hosts in network namespaces",
          ("rows_total", "rows_passed", "rows_beyond_bound", "rows_failed", "commands_lost"), processes=True,
          tested_by="tests/netlab/test_rows.py"),
    Bench("protocol_bench", "Codec cost per message and Zenoh loopback throughput and latency",
          ("codec_roundtrip_us_30obj", "objectlist_30obj_bytes", "zenoh_msgs_per_s", "zenoh_latency_p99_ms"),
          processes=True),
    Bench("render_split_bench", "Where a rendered frame's CPU goes, per lighting and stage",
          ("render_ms_day", "render_ms_dusk", "render_ms_night", "geometry_ms_day"),
          tested_by="tests/sim/test_sim_bench.py"),
    Bench("rsu_bench", "RSU perception: SORT against the reference, fps per stage, MOTA/IDF1, EV-body cost",
          ("tracker_speedup_min", "tracker_same_tracks", "mota", "idf1", "fps_end_to_end"),
          tested_by="tests/rsu/test_rsu_bench.py"),
    Bench("security_bench", "Signature cost, its effect on command latency over Zenoh, fuzzing",
          ("sign_us", "verify_us", "e2e_signed_ms_mean", "e2e_unsigned_ms_mean", "e2e_lost", "fuzz_crashes"),
          processes=True),
    Bench("sim_bench", "Simulator cost: render fps per lighting, world steps, snapshots",
          ("render_ms", "render_ms_dusk", "render_ms_night", "render_ms_max", "world_steps_per_s"),
          tested_by="tests/sim/test_sim_bench.py"),
    Bench("sumo_bench", "SUMO traffic beside the project's own: step and snapshot cost, the corridor on SUMO traffic",
          ("sumo_step_ms_50", "own_step_ms_50", "sumo_step_ms_200", "own_step_ms_200"),
          quick=("--quick", "--parts", "step")),
    Bench("v2x_bench", "Standard V2X: ETSI CAM/DENM/CPM codec, captured messages, the EV's radio in the decisions",
          ("cam_codec_us", "denm_codec_us", "cpm30_codec_us", "captures_total", "captures_as_expected")),
    Bench("view_bench", "The cost of `iea view` during the demo and the page's update rate in a browser",
          ("view_cpu_percent", "page_update_hz", "page_saw_alert"), processes=True, needs_tool="chromium"),
    Bench("wire_conformance_bench", "An outside client validates every wire message of an `iea demo` run",
          ("outside_client_messages", "outside_client_valid", "outside_client_valid_fraction"), processes=True,
          tested_by="tests/protocol/test_wire_conformance.py"),
    Bench("zenoh_bench", "Zenoh under a flood: command latency by QoS, presence loss, late joiners",
          ("cmd_latency_p99_ms_flood_idle", "cmd_latency_p99_ms_flood_prio", "cmd_latency_p99_ms_flood_noprio",
           "stale_detect_s", "restart_ev_aware_s"), processes=True),
)
"""Every bench, by script name."""


def bench_scripts() -> list[str]:
    """The names of the bench scripts on disk (``bench/*_bench.py``), sorted."""
    return sorted(p.stem for p in BENCH_DIR.glob("*_bench.py"))


def by_name() -> dict[str, Bench]:
    return {b.name: b for b in BENCHES}
