"""Standard V2X figures: the UPER codec, the captured messages, and the EV's radio in the corridor's decisions.

- codec: microseconds per message, UPER encode + decode with constraints checked (median of ``--codec-n``): an
  EV's CAM, an EV alert's DENM, an RSU's CPM with 30 objects.
- captures: every message of ``../shared/data/v2x/captures/`` against its Release 2 ``decode_status``
  (``OK+reenc``: decodes and re-encodes to its bytes; ``(pad)``: but for zero padding; ``ERR``: refused).
- corridor runs, in one of two modes (both may run; see the keys below):

  - Zenoh processes (``--zenoh-seeds N``): each run is ``iea up`` (``deploy.up.Up``): a router and every service
    as its own process in client mode, the RSU V2X gateways, signed messages, real time. ``ev_equipped_unseen``
    over N seeds with the EV equipped (its radio at the corridor's 1 % loss, then ``--ev-radio-loss 0.3``; each
    gateway's radio adds the corridor's 1 % on reception) and unequipped (the run without ``--v2x``: no gateway
    hears the EV, the vision path). Then ``ev_lights_never_on`` for ``ATTACK_RUN_S`` (12 s) over
    ``--attack-seeds`` seeds, first without an attacker (the baseline), then with an attacker process
    (``python -m scenario.v2x_attack``: lights-on CAMs at 10 Hz on the EV's CAM key through the corridor's DSRC
    model, as the EV's radio sends) of each kind: forged (a fresh key under the EV's key id), replayed (the EV's
    real key, signed 2 s in the past), contradicted (the EV's real key, an EV at 18 m/s through the cameras'
    clear, empty views).
  - lockstep (unless ``--skip-runs``; ``scenario/v2x_lockstep.py``: the whole corridor in one process on a
    simulated clock, cameras rendered and perceived, the same attacker logic): the same groups over ``--seeds``
    seeds and ``--attack-seeds`` seeds, the attacker's CAMs put straight on the bus.

  The response is the time from the light bar switching on to the DDM's first command; a run yields when the
  strict judge (``scenario.outcome.judge_run``) passes it. An attack's figure is the commands issued in the
  attack run beyond those of the same seed's baseline run (``*_commands_raw``: all of them; ``baseline_commands``:
  the vision path's own, e.g. a false alarm); ``--groups`` picks some of equipped, unequipped, equipped_loss30,
  attacks.

    python bench/v2x_bench.py --quick --json                # codec and captures only
    python bench/v2x_bench.py --json                        # lockstep, 10 seeds (long: 40 corridor runs)
    python bench/v2x_bench.py --json --skip-runs --zenoh-seeds 10 --attack-seeds 3   # processes over Zenoh

The last line with ``--json``: one JSON object with cam_codec_us, denm_codec_us, cpm30_codec_us, captures_total,
captures_as_expected, equipped_response_median_s, equipped_response_p99_s, equipped_ev_delay_median_s,
equipped_runs, equipped_runs_yielded (the same for unequipped_ and equipped_loss30_), forged_commands,
replayed_commands, contradicted_commands (with ``*_commands_raw``, baseline_commands, attack_runs), runs (per
run), and runs_mode: ``zenoh`` (the corridor figures are those of the process runs) or ``lockstep``. With both
modes run, the lockstep figures carry the prefix ``lockstep_``. A process run also gives its run folder, the
DDM's V2X refusals (its Health's ``rejected``, ``v2x_*``) and the CAMs the gateways passed on.
"""

from __future__ import annotations

import argparse
import csv
import json
import re
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
ATTACKS = ("forged", "replayed", "contradicted")
EV_REASON = re.compile(r"\bEV\b")
"""A DDM command for an EV names it in its reason ("... EV track 8 113 m behind ..."); a hazard's names the hazard."""
ZENOH_RUN_S = 24.0
"""Scenario time of a process run of ``ev_equipped_unseen`` (its full length)."""


def response_figures(name: str, runs: list[dict[str, Any]]) -> dict[str, Any]:
    resp = [r["response_s"] for r in runs if r["response_s"] is not None]
    delays = [r["ev_delay_s"] for r in runs if r.get("ev_delay_s") is not None]
    return {f"{name}_response_median_s": None if not resp else round(statistics.median(resp), 3),
            f"{name}_response_p99_s": _percentile(resp, 0.99),
            f"{name}_ev_delay_median_s": None if not delays else round(statistics.median(delays), 3),
            f"{name}_runs": len(runs), f"{name}_runs_yielded": sum(r["passed"] for r in runs)}


def attack_figures(baseline: dict[int, dict[str, Any]], attacked: dict[str, list[dict[str, Any]]],
                   counted: str = "commands") -> dict[str, Any]:
    """Per attack, the ``counted`` commands (``commands``: all; ``ev_commands``: those for an EV) of its runs beyond
    those of the same seed's baseline run, and all commands (``*_commands_raw``)."""
    out: dict[str, Any] = {"baseline_commands": sum(b["commands"] for b in baseline.values())}
    if counted != "commands":
        out[f"baseline_{counted}"] = sum(b[counted] for b in baseline.values())
    for attack, runs in attacked.items():
        out[f"{attack}_commands"] = sum(max(0, r[counted] - baseline[r["seed"]][counted]) for r in runs)
        out[f"{attack}_commands_raw"] = sum(r["commands"] for r in runs)
    out["attack_runs"] = {k: [{kk: r.get(kk) for kk in ("seed", "commands", "ev_commands", "attack_sent",
                                                          "attack_sent_near_actor", "relayed",
                                                          "ddm_v2x_rejected", "run_dir")} for r in v]
                          for k, v in attacked.items()}
    return out


def run_summary(runs: dict[str, list[dict[str, Any]]]) -> dict[str, Any]:
    keys = ("seed", "response_s", "first_camera_alert_s", "ev_delay_s", "passed", "why", "run_dir")
    return {k: [{kk: r.get(kk) for kk in keys} for r in v] for k, v in runs.items()}


def run_figures(seeds: list[int], attack_seeds: list[int], say, only: tuple[str, ...] = GROUPS) -> dict[str, Any]:
    """The lockstep runs (one process, simulated clock)."""
    out: dict[str, Any] = {"runs_mode": "lockstep"}
    groups = {"equipped": dict(equipped=True), "unequipped": dict(equipped=False),
              "equipped_loss30": dict(equipped=True, radio_loss=0.3)}
    runs: dict[str, list[dict[str, Any]]] = {}
    for name, setup in groups.items():
        if name not in only:
            continue
        runs[name] = []
        for s in seeds:
            r = one_run("ev_equipped_unseen", s, **setup)
            runs[name].append(r)
            say(f"lockstep {name} seed {s}: response {r['response_s']} s, first camera alert "
                f"{r['first_camera_alert_s']} s, {r['why']} ({r['wall_s']} s wall)")
        out.update(response_figures(name, runs[name]))
    if "attacks" in only:  # the same run without the attacker: what the cameras alone make the DDM do
        baseline = {}
        for s in attack_seeds:
            r = one_run("ev_lights_never_on", s, duration_s=ATTACK_RUN_S)
            baseline[s] = r
            say(f"lockstep no attack seed {s}: {r['commands']} commands (the vision path's own)")
        attacked: dict[str, list[dict[str, Any]]] = {}
        for attack in ATTACKS:
            attacked[attack] = []
            for s in attack_seeds:
                r = one_run("ev_lights_never_on", s, duration_s=ATTACK_RUN_S, attack=attack)
                r.update(attack_sent=r["v2x"]["attack_sent"], relayed=r["v2x"]["relayed"],
                         ddm_v2x_rejected=r["v2x"]["ddm_rejected"])
                attacked[attack].append(r)
                say(f"lockstep {attack} seed {s}: {r['commands']} commands ({baseline[s]['commands']} without the "
                    f"attack); DDM V2X {r['v2x']['ddm']} refused {r['v2x']['ddm_rejected']}")
        out.update(attack_figures(baseline, attacked))
    out["runs"] = run_summary(runs)
    return out


def zenoh_run(scenario: str, seed: int, run_dir: Path, duration_s: float, *, v2x: bool,
              ev_radio_loss: float | None = None, attack: str | None = None) -> dict[str, Any]:
    """One run as processes (``iea up``: router, DDM, RSUs, vehicle, simulator; with ``v2x`` the RSU gateways and
    the EV's key), ``attack``: and an attacker process (``scenario.v2x_attack``) with the EV's key. The response,
    the strict judge's verdict (a scenario whose EV switches its lights on), the commands, the DDM's V2X refusals
    (its last Health), the CAMs the gateways passed on and the attacker sent."""
    from deploy.up import Up
    from protocol.enums import Role
    from protocol.v2x.keys import v2x_rsu_expr
    from scenario.outcome import judge_run

    up = Up(scenario=scenario, port=0, run_dir=run_dir, duration_s=duration_s, seed=seed, restart="no", v2x=v2x,
            ev_radio_loss=ev_radio_loss)
    if attack is not None:
        up.add_service("attacker", ["-m", "scenario.v2x_attack", "--kind", attack, "--ev-key", str(up.ev_key),
                                    "--seed", str(seed)])
    ddm_health: list[Any] = []
    relayed = [0]
    reasons: list[str] = []

    def on_message(_key: str, msg: Any) -> None:
        if msg.KIND == "Health" and msg.role == Role.DDM:
            ddm_health[:] = [msg]
        elif msg.KIND == "PathSwitchCommand":
            reasons.append(msg.reason)

    def on_relay(_key: str, _payload: bytes) -> None:
        relayed[0] += 1

    t0 = time.monotonic()
    try:
        up.start(extra_subscribers=[on_message])
        if up.transport is not None:
            up.transport.subscribe_bytes(v2x_rsu_expr(up.corridor_id, "rx"), on_relay)
        ended = up.wait_for_scenario(duration_s + 40)
    finally:
        up.stop()
    m = up.metrics()
    (run_dir / "metrics.json").write_text(json.dumps(m, indent=2, default=str) + "\n")
    passed, why = judge_run(m, ev_lights_on=scenario != "ev_lights_never_on")
    if not ended:
        passed, why = False, f"the simulator did not end within {duration_s + 40:.0f} s; {why}"
    rel = m.get("events_since_lights_on_s") or {}
    sent = near = None
    if attack is not None:
        log = up.group.log_path("attacker")
        found = re.findall(r"attack: (\d+) CAMs sent, (\d+) within", log.read_text(errors="replace")) \
            if log.exists() else []
        sent, near = (int(found[-1][0]), int(found[-1][1])) if found else (None, None)
    rejected = {} if not ddm_health else {k: v for k, v in ddm_health[0].rejected.items() if k.startswith("v2x")}
    return {"seed": seed, "response_s": rel.get("command_published"), "first_camera_alert_s": rel.get("first_ev_alert"),
            "ev_delay_s": (m.get("yield") or {}).get("ev_delay_s"), "passed": passed, "why": why,
            "commands": len(m.get("commands") or []), "ev_commands": sum(bool(EV_REASON.search(x)) for x in reasons),
            "ddm_v2x_rejected": rejected, "relayed": relayed[0],
            "attack_sent": sent, "attack_sent_near_actor": near, "run_dir": str(run_dir),
            "exit_codes": m.get("exit_codes"),
            "wall_s": round(time.monotonic() - t0, 1)}


def zenoh_figures(seeds: list[int], attack_seeds: list[int], say, run_root: Path,
                  only: tuple[str, ...] = GROUPS) -> dict[str, Any]:
    """The process runs over Zenoh (``iea up``)."""
    out: dict[str, Any] = {"runs_mode": "zenoh"}
    groups = {"equipped": dict(v2x=True), "unequipped": dict(v2x=False),
              "equipped_loss30": dict(v2x=True, ev_radio_loss=0.3)}
    stamp = time.strftime("%Y%m%d-%H%M%S")
    runs: dict[str, list[dict[str, Any]]] = {}
    for name, setup in groups.items():
        if name not in only:
            continue
        runs[name] = []
        for s in seeds:
            r = zenoh_run("ev_equipped_unseen", s, run_root / f"v2x-{stamp}-{name}-{s}", ZENOH_RUN_S, **setup)
            runs[name].append(r)
            say(f"zenoh {name} seed {s}: response {r['response_s']} s, first camera alert "
                f"{r['first_camera_alert_s']} s, {r['why']}; relayed {r['relayed']} ({r['wall_s']} s wall)")
        out.update(response_figures(name, runs[name]))
    if "attacks" in only:
        baseline = {}
        for s in attack_seeds:
            r = zenoh_run("ev_lights_never_on", s, run_root / f"v2x-{stamp}-baseline-{s}", ATTACK_RUN_S, v2x=True)
            baseline[s] = r
            say(f"zenoh no attack seed {s}: {r['commands']} commands, {r['ev_commands']} for an EV (the vision path's "
                f"own) ({r['wall_s']} s wall)")
        attacked: dict[str, list[dict[str, Any]]] = {}
        for attack in ATTACKS:
            attacked[attack] = []
            for s in attack_seeds:
                r = zenoh_run("ev_lights_never_on", s, run_root / f"v2x-{stamp}-{attack}-{s}", ATTACK_RUN_S,
                              v2x=True, attack=attack)
                attacked[attack].append(r)
                say(f"zenoh {attack} seed {s}: {r['commands']} commands, {r['ev_commands']} for an EV "
                    f"({baseline[s]['commands']}, {baseline[s]['ev_commands']} without the attack); "
                    f"attacker sent {r['attack_sent']} ({r['attack_sent_near_actor']} near a car), gateways passed on "
                    f"{r['relayed']}, DDM refused "
                    f"{r['ddm_v2x_rejected']} ({r['wall_s']} s wall)")
        out.update(attack_figures(baseline, attacked, "ev_commands"))
    out["runs"] = run_summary(runs)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--json", action="store_true", help="end with one JSON line of figures")
    ap.add_argument("--quick", action="store_true", help="the codec (50 messages each) and the captures, no corridor runs")
    ap.add_argument("--seeds", type=int, default=10, help="lockstep seeds per configuration (default 10)")
    ap.add_argument("--attack-seeds", type=int, default=3,
                    help="seeds per attack and of the baseline, lockstep and Zenoh alike (default 3)")
    ap.add_argument("--codec-n", type=int, default=500)
    ap.add_argument("--skip-runs", action="store_true", help="no lockstep runs")
    ap.add_argument("--groups", default=",".join(GROUPS),
                    help=f"corridor groups to run, lockstep and Zenoh alike (default {','.join(GROUPS)})")
    ap.add_argument("--zenoh-seeds", type=int, default=0,
                    help="run the groups as processes over Zenoh (iea up), ev_equipped_unseen over N seeds each; "
                         "the corridor figures are then these runs' (runs_mode zenoh)")
    ap.add_argument("--zenoh-first-seed", type=int, default=1, help="the Zenoh runs' first seed (default 1)")
    ap.add_argument("--runs-dir", default=str(ROOT / "runs"), help="where the Zenoh runs' folders go")
    args = ap.parse_args(argv)
    for name in ("seeds", "attack_seeds", "codec_n", "zenoh_seeds"):
        if getattr(args, name) < (1 if name == "codec_n" else 0):
            ap.error(f"--{name.replace('_', '-')} must be >= {1 if name == 'codec_n' else 0}")
    only = tuple(g for g in args.groups.split(",") if g)
    bad = sorted(set(only) - set(GROUPS))
    if bad:
        ap.error(f"unknown group(s) {bad}; expected some of {list(GROUPS)}")

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
    attack_seeds = list(range(1, args.attack_seeds + 1))
    if not args.skip_runs:
        lockstep = run_figures(list(range(1, args.seeds + 1)), attack_seeds, say, only)
        if args.zenoh_seeds:
            lockstep = {f"lockstep_{k}": v for k, v in lockstep.items()}
        figures.update(lockstep)
    if args.zenoh_seeds:
        first = args.zenoh_first_seed
        figures.update(zenoh_figures(list(range(first, first + args.zenoh_seeds)), attack_seeds, say,
                                     Path(args.runs_dir), only))
    if args.json:
        print(json.dumps(figures))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
