"""Standard V2X figures: the UPER codec, the captured messages, and the EV's radio in the corridor's decisions.

- codec: microseconds per message, UPER encode + decode with constraints checked (median of ``--codec-n``): an
  EV's CAM, an EV alert's DENM, an RSU's CPM with 30 objects.
- captures: every message of ``../shared/data/v2x/captures/`` against its Release 2 ``decode_status``
  (``OK+reenc``: decodes and re-encodes to its bytes; ``(pad)``: but for zero padding; ``ERR``: refused).
- runs (``scenario/v2x_lockstep.py``: the whole corridor in one process on a simulated clock, cameras rendered and
  perceived, with the EV's radio, the RSUs' gateways and the DDM's V2X input): ``ev_equipped_unseen`` over
  ``--seeds`` seeds with the EV equipped (its radio at the corridor's 1 % loss, then at 30 %) and unequipped (the
  vision path); the response is the time from the light bar switching on to the DDM's first command; a run
  yields when the strict judge (``scenario.outcome.judge_run``) passes it. Then ``ev_lights_never_on`` with an
  attacker sending lights-on CAMs: forged (untrusted key), replayed (the EV's own CAMs 2 s late), contradicted
  (a valid key driving an EV through the cameras' clear, empty views): the commands issued in 12 s of attack beyond
  those of the same run without the attacker (``*_commands_raw``: all of them; ``baseline_commands``: the vision
  path's own, e.g. a false alarm).

    python bench/v2x_bench.py --json                       # everything, 10 seeds (long: 40 corridor runs)
    python bench/v2x_bench.py --quick --json                # codec and captures only
    python bench/v2x_bench.py --json --skip-runs --zenoh-seeds 10  # the equipped / unequipped runs as processes

The last line with ``--json``: one JSON object with cam_codec_us, denm_codec_us, cpm30_codec_us, captures_total,
captures_as_expected, equipped_response_median_s, equipped_response_p99_s, unequipped_response_median_s,
unequipped_response_p99_s, equipped_loss30_response_median_s, equipped_runs, equipped_runs_yielded,
unequipped_runs_yielded, forged_commands, replayed_commands, contradicted_commands, runs_mode (and with
``--zenoh-seeds``: zenoh_equipped_* and zenoh_unequipped_* response median, p99, runs, runs_yielded).
"""

from __future__ import annotations

import argparse
import csv
import json
import statistics
import sys
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from protocol.examples import example_messages, object_list  # noqa: E402
from protocol.messages import EvAlert  # noqa: E402
from protocol.v2x.build import ev_cam, ev_denm, rsu_cpm  # noqa: E402
from protocol.v2x.codec import V2xError, decode, encode  # noqa: E402

ATTACK_RUN_S = 12.0
"""Length of an attack run: the attacker sends from 0.5 s on, a command would follow within a second."""
CAPTURES = ROOT.parent / "shared" / "data" / "v2x" / "captures" / "captures.tsv"


def codec_us(kind: str, value: dict[str, Any], n: int) -> tuple[float, int]:
    """(median microseconds of encode + decode, bytes)."""
    data = encode(kind, value)
    decode(data)
    times = []
    for _ in range(n):
        t0 = time.perf_counter()
        decode(encode(kind, value))
        times.append((time.perf_counter() - t0) * 1e6)
    return statistics.median(times), len(data)


def codec_figures(n: int) -> dict[str, Any]:
    alert = next(m for _k, m in example_messages("bench", stamp=1.7e9) if isinstance(m, EvAlert))
    cam_us, cam_b = codec_us("CAM", ev_cam(7, 1.7e9, 30.63, -96.47, 0.3, 20.0, True, True), n)
    denm_us, denm_b = codec_us("DENM", ev_denm(alert, 9, 1.7e9), n)
    cpm_us, cpm_b = codec_us("CPM", rsu_cpm(object_list(30, 1.7e9), 9, 30.63, -96.47, 0.0, 0.0), max(20, n // 10))
    return {"cam_codec_us": round(cam_us, 1), "denm_codec_us": round(denm_us, 1), "cpm30_codec_us": round(cpm_us, 1),
            "cam_bytes": cam_b, "denm_bytes": denm_b, "cpm30_bytes": cpm_b}


def capture_figures(path: Path = CAPTURES) -> dict[str, Any]:
    if not path.exists():
        return {"captures_total": 0, "captures_as_expected": 0, "captures_note": f"{path} not found"}
    with path.open(encoding="utf-8") as f:
        rows = list(csv.DictReader(f, delimiter="\t"))
    ok, wrong = 0, []
    for row in rows:
        data = bytes.fromhex(row["payload_hex"])
        status = next(e.split(":", 1)[1] for e in row["decode_status"].split() if e.startswith(("r2_cam:", "r2_denm:")))
        try:
            msg = decode(data)
            again = encode(msg.kind, msg.value)
            good = again == data if status == "OK+reenc" else (
                status == "OK+reenc(pad)" and data.startswith(again) and not any(data[len(again):]))
        except V2xError:
            good = status == "ERR"
        ok += good
        if not good:
            wrong.append(row["id"])
    return {"captures_total": len(rows), "captures_as_expected": ok, "captures_wrong": wrong}


def _percentile(xs: list[float], q: float) -> float | None:
    if not xs:
        return None
    xs = sorted(xs)
    k = min(len(xs) - 1, max(0, round(q * (len(xs) - 1))))
    return round(xs[k], 3)


def one_run(scenario: str, seed: int, duration_s: float | None = None, **setup: Any) -> dict[str, Any]:
    from scenario.lockstep import LockstepConfig, ev_lights_on
    from scenario.outcome import judge_run
    from scenario.v2x_lockstep import V2xLockstep, V2xSetup

    run = V2xLockstep(LockstepConfig(scenario=scenario, seed=seed, duration_s=duration_s),
                      v2x=V2xSetup(radio_seed=seed, **setup))
    m = run.run()
    passed, why = judge_run(m, ev_lights_on=ev_lights_on(run.scenario, run.duration_s))
    rel = m.get("events_since_lights_on_s") or {}
    verdict = m.get("yield") or {}
    return {"seed": seed, "response_s": rel.get("command_published"), "first_camera_alert_s": rel.get("first_ev_alert"),
            "ev_delay_s": verdict.get("ev_delay_s"), "passed": passed, "why": why,
            "commands": len(m.get("commands") or []), "v2x": m.get("v2x"), "wall_s": m.get("wall_s")}


GROUPS = ("equipped", "unequipped", "equipped_loss30", "attacks")


def run_figures(seeds: list[int], attack_seeds: list[int], say, only: tuple[str, ...] = GROUPS) -> dict[str, Any]:
    out: dict[str, Any] = {"runs_mode": "lockstep (one process, simulated clock)"}
    groups = {"equipped": dict(equipped=True), "unequipped": dict(equipped=False),
              "equipped_loss30": dict(equipped=True, radio_loss=0.3)}
    groups = {k: v for k, v in groups.items() if k in only}
    runs: dict[str, list[dict[str, Any]]] = {}
    for name, setup in groups.items():
        runs[name] = []
        for s in seeds:
            r = one_run("ev_equipped_unseen", s, **setup)
            runs[name].append(r)
            say(f"{name} seed {s}: response {r['response_s']} s, first camera alert {r['first_camera_alert_s']} s, "
                f"{r['why']} ({r['wall_s']} s wall)")
        resp = [r["response_s"] for r in runs[name] if r["response_s"] is not None]
        out[f"{name}_response_median_s"] = None if not resp else round(statistics.median(resp), 3)
        out[f"{name}_response_p99_s"] = _percentile(resp, 0.99)
        delays = [r["ev_delay_s"] for r in runs[name] if r["ev_delay_s"] is not None]
        out[f"{name}_ev_delay_median_s"] = None if not delays else round(statistics.median(delays), 3)
        out[f"{name}_runs"] = len(runs[name])
        out[f"{name}_runs_yielded"] = sum(r["passed"] for r in runs[name])
    if "attacks" in only:  # the same run without the attacker: what the cameras alone make the DDM do
        baseline = {}
        for s in attack_seeds:
            r = one_run("ev_lights_never_on", s, duration_s=ATTACK_RUN_S)
            baseline[s] = r["commands"]
            say(f"no attack seed {s}: {r['commands']} commands (the vision path's own)")
        out["baseline_commands"] = sum(baseline.values())
    for attack in ("forged", "replayed", "contradicted") if "attacks" in only else ():
        total = raw = 0
        for s in attack_seeds:
            r = one_run("ev_lights_never_on", s, duration_s=ATTACK_RUN_S, attack=attack)
            raw += r["commands"]
            total += max(0, r["commands"] - baseline[s])
            say(f"{attack} seed {s}: {r['commands']} commands ({baseline[s]} without the attack); DDM V2X "
                f"{r['v2x']['ddm']} refused {r['v2x']['ddm_rejected']}")
        out[f"{attack}_commands"] = total
        out[f"{attack}_commands_raw"] = raw
    out["runs"] = {k: [{kk: r[kk] for kk in ("seed", "response_s", "first_camera_alert_s", "ev_delay_s", "passed", "why")}
                       for r in v] for k, v in runs.items()}
    return out


def zenoh_run(seed: int, equipped: bool, run_root: Path, duration_s: float) -> dict[str, Any]:
    """One ``ev_equipped_unseen`` run as processes (``iea up``: router, DDM, RSUs, vehicle, simulator), with
    ``--v2x`` (gateways, the EV's key) when ``equipped``; the response and the strict judge's verdict."""
    from deploy.up import Up
    from scenario.outcome import judge_run

    up = Up(scenario="ev_equipped_unseen", port=0, run_dir=run_root / f"v2x-{'eq' if equipped else 'uneq'}-{seed}",
            duration_s=duration_s, seed=seed, restart="no", v2x=equipped)
    try:
        up.start()
        up.wait_for_scenario(duration_s + 40)
    finally:
        up.stop()
    m = up.metrics()
    passed, why = judge_run(m, ev_lights_on=True)
    rel = m.get("events_since_lights_on_s") or {}
    return {"seed": seed, "response_s": rel.get("command_published"), "first_camera_alert_s": rel.get("first_ev_alert"),
            "passed": passed, "why": why}


def zenoh_figures(seeds: list[int], say, run_root: Path) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for name, equipped in (("zenoh_equipped", True), ("zenoh_unequipped", False)):
        runs = []
        for s in seeds:
            r = zenoh_run(s, equipped, run_root, 24.0)
            runs.append(r)
            say(f"{name} seed {s}: response {r['response_s']} s, first camera alert {r['first_camera_alert_s']} s, "
                f"{r['why']}")
        resp = [r["response_s"] for r in runs if r["response_s"] is not None]
        out[f"{name}_response_median_s"] = None if not resp else round(statistics.median(resp), 3)
        out[f"{name}_response_p99_s"] = _percentile(resp, 0.99)
        out[f"{name}_runs"] = len(runs)
        out[f"{name}_runs_yielded"] = sum(r["passed"] for r in runs)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--json", action="store_true", help="end with one JSON line of figures")
    ap.add_argument("--quick", action="store_true", help="the codec (50 messages each) and the captures, no corridor runs")
    ap.add_argument("--seeds", type=int, default=10, help="seeds per configuration (default 10)")
    ap.add_argument("--attack-seeds", type=int, default=3, help="seeds per attack (default 3)")
    ap.add_argument("--codec-n", type=int, default=500)
    ap.add_argument("--skip-runs", action="store_true", help="codec and captures only")
    ap.add_argument("--groups", default=",".join(GROUPS), help=f"lockstep groups to run (default {','.join(GROUPS)})")
    ap.add_argument("--zenoh-seeds", type=int, default=0,
                    help="also run ev_equipped_unseen as processes over Zenoh (iea up), equipped and not, N seeds each")
    ap.add_argument("--zenoh-first-seed", type=int, default=1, help="the Zenoh runs' first seed (default 1)")
    ap.add_argument("--runs-dir", default=str(ROOT / "runs"), help="where the Zenoh runs' folders go")
    args = ap.parse_args(argv)

    def say(s: str) -> None:
        print(s, flush=True)

    if args.quick:
        args.codec_n, args.skip_runs, args.zenoh_seeds = 50, True, 0
    figures: dict[str, Any] = {}
    figures.update(codec_figures(args.codec_n))
    say(f"codec: CAM {figures['cam_codec_us']} us ({figures['cam_bytes']} B), DENM {figures['denm_codec_us']} us "
        f"({figures['denm_bytes']} B), CPM of 30 objects {figures['cpm30_codec_us']} us ({figures['cpm30_bytes']} B)")
    figures.update(capture_figures())
    say(f"captures: {figures['captures_as_expected']} of {figures['captures_total']} as their table says")
    if not args.skip_runs:
        only = tuple(g for g in args.groups.split(",") if g)
        bad = sorted(set(only) - set(GROUPS))
        if bad:
            ap.error(f"unknown group(s) {bad}; expected some of {list(GROUPS)}")
        figures.update(run_figures(list(range(1, args.seeds + 1)), list(range(1, args.attack_seeds + 1)), say, only))
    if args.zenoh_seeds:
        first = args.zenoh_first_seed
        figures.update(zenoh_figures(list(range(first, first + args.zenoh_seeds)), say, Path(args.runs_dir)))
    if args.json:
        print(json.dumps(figures))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
