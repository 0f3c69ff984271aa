"""Security benchmark: signature cost per message, its effect on end-to-end latency, fuzzing.

    python bench/security_bench.py [--json] [--quick] [--commands 200] [--fuzz-n 100000 | --fuzz-from FILE]

1. ``sign_us`` / ``verify_us``: one Ed25519 signature over the canonical encoding (``Signer.sign_message``)
   and its check (``Verifier.check``), best-of-5 mean, for a ``PathSwitchCommand`` of 150 waypoints (a
   DDM pull-over path at 1 m steps; ``sign_us``/``verify_us`` are its figures) and for an ``EvAlert``
   (``*_alert``). Also the whole in-process path, encode+decode vs sign+encode+decode+verify.
2. End to end, measured in the same run with and without signing: this process publishes commands over
   real Zenoh (peer mode, loopback) to a separate ``iea-vehicle run`` process whose corridor trusts the
   bench's DDM key with ``--no-require-signed``, so signed and unsigned commands meet the very same
   vehicle; they alternate (A/B interleaved). Latency = publish (signing included) -> the vehicle's
   ``accepted`` ack received here: two Zenoh hops, the vehicle's queue-until-next-100-Hz-step wait
   (0-10 ms, the dominant term) and its checks (verification included for signed ones).
3. ``fuzz_inputs`` / ``fuzz_crashes``: ``bench/fuzz_bench.py`` run here (``--fuzz-n`` per target), or the
   figures of an earlier full run (``--fuzz-from`` a file whose last line is its ``--json`` output).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import threading
import time
import uuid
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey  # noqa: E402

from deploy.procs import stop_process  # noqa: E402
from protocol import keys  # noqa: E402
from protocol.codec import decode, encode  # noqa: E402
from protocol.enums import Manoeuvre  # noqa: E402
from protocol.examples import example_messages  # noqa: E402
from protocol.messages import EvAlert, PathSwitchCommand  # noqa: E402
from protocol.security import Signer, TrustList, Verifier, public_key_b64  # noqa: E402
from vehicle.failsafe import FailsafeConfig  # noqa: E402


def _command(n_waypoints: int = 150, now: float = 100.0, seq: int = 1, manoeuvre=Manoeuvre.PULL_OVER,
             vehicle_id: str = "av1") -> PathSwitchCommand:
    wp = [(100.0 + i, 5.55 - 3.7 * min(i, 40) / 40) for i in range(n_waypoints)]
    return PathSwitchCommand(
        src="ddm", stamp=now, command_id=f"ddm-{vehicle_id}-{seq}", command_seq=seq, vehicle_id=vehicle_id,
        manoeuvre=manoeuvre, reason="EV approaching from behind in lane 1", target_lane=0, waypoints=wp,
        speed_profile_mps=[max(0.0, 13.4 - 0.1 * i) for i in range(n_waypoints)], target_speed_mps=13.4,
        stop_point=(100.0 + n_waypoints - 12, 1.85) if manoeuvre != Manoeuvre.RESUME else None,
        issued_at=now, valid_until=now + 30.0)


def _best_mean_us(fn, repeat: int) -> float:
    best = float("inf")
    for _ in range(5):
        t0 = time.perf_counter()
        for _ in range(repeat):
            fn()
        best = min(best, (time.perf_counter() - t0) / repeat * 1e6)
    return best


def crypto_costs(repeat: int) -> dict[str, float]:
    private = Ed25519PrivateKey.generate()
    signer = Signer("ddm-bench", private)
    rsu_private = Ed25519PrivateKey.generate()
    rsu_signer = Signer("rsu1-bench", rsu_private)
    trust = TrustList.from_entries([
        {"key_id": "ddm-bench", "role": "ddm", "public_key": public_key_b64(private.public_key())},
        {"key_id": "rsu1-bench", "role": "rsu", "rsu_id": "rsu1", "public_key": public_key_b64(rsu_private.public_key())}])
    verifier = Verifier(trust)
    out: dict[str, float] = {}
    blob, public = b"x" * 400, private.public_key()
    raw_sig = private.sign(blob)
    out["raw_ed25519_sign_us"] = _best_mean_us(lambda: private.sign(blob), repeat)
    out["raw_ed25519_verify_us"] = _best_mean_us(lambda: public.verify(raw_sig, blob), repeat)
    cmd, cmd_key = _command(), keys.vehicle_key("bench", "av1", "cmd")
    alert = next(m for _, m in example_messages("bench", stamp=100.0) if isinstance(m, EvAlert))
    alert_key = keys.rsu_key("bench", "rsu1", "ev")
    for name, msg, key, s in (("", cmd, cmd_key, signer), ("_alert", alert, alert_key, rsu_signer)):
        signed = s.sign_message(key, msg)
        verifier.check(key, signed, 100.5)
        out[f"sign_us{name}"] = _best_mean_us(lambda m=msg, k=key, s=s: s.sign_message(k, m), repeat)
        out[f"verify_us{name}"] = _best_mean_us(lambda m=signed, k=key: verifier.check(k, m, 100.5), repeat)
        kind = type(msg)
        out[f"plain_path_us{name}"] = _best_mean_us(lambda m=msg, t=kind: decode(encode(m), t), repeat)
        out[f"signed_path_us{name}"] = _best_mean_us(
            lambda m=msg, k=key, t=kind, s=s: verifier.check(k, decode(encode(s.sign_message(k, m)), t), 100.5), repeat)
        out[f"bytes{name}"] = len(encode(msg))
        out[f"signed_bytes{name}"] = len(encode(signed))
    return out


# ----------------------------------------------------------------------------- end to end over Zenoh
def end_to_end(n_commands: int, timeout_s: float = 120.0) -> dict[str, float]:
    from protocol.corridor import DEFAULT_CORRIDOR
    from protocol.zenoh_transport import ZenohTransport

    cid = f"secb{uuid.uuid4().hex[:8]}"
    private = Ed25519PrivateKey.generate()
    signer = Signer("ddm-bench", private)
    with tempfile.TemporaryDirectory(prefix="iea-secbench-") as tmp:
        corridor_file = Path(tmp) / "corridor.toml"
        corridor_file.write_text(DEFAULT_CORRIDOR.read_text() + "\n[[trust]]\n"
                                 f'key_id = "ddm-bench"\nrole = "ddm"\nvehicles = ["av1"]\n'
                                 f'public_key = "{public_key_b64(private.public_key())}"\n')
        env = dict(os.environ, PYTHONPATH=str(ROOT), PYTHONUNBUFFERED="1")
        # no DDM heartbeat here: the vehicle's link watchdog waits as long as its config allows (link_timeout_s
        # up to link_lost_s) before it degrades, longer than the bench is ever silent (its commands count)
        proc = subprocess.Popen([sys.executable, "-m", "vehicle", "run", "--corridor", str(corridor_file),
                                 "--corridor-id", cid, "--no-require-signed",
                                 "--link-timeout", str(FailsafeConfig().link_lost_s),
                                 "--duration", str(timeout_s)], cwd=ROOT, env=env,
                                stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        transport = ZenohTransport()
        acks: dict[str, float] = {}
        ready = threading.Event()
        cond = threading.Condition()

        def on_ack(_k, ack) -> None:
            if ack.status.value in ("accepted", "rejected"):
                with cond:
                    acks.setdefault(ack.command_id, time.perf_counter())
                    if ack.status.value == "rejected":
                        acks[ack.command_id + "#rejected"] = 0.0
                    cond.notify_all()

        transport.subscribe(keys.vehicle_key(cid, "av1", "ack"), on_ack)
        transport.subscribe(keys.vehicle_key(cid, "av1", "state"), lambda _k, _m: ready.set())
        cmd_key = keys.vehicle_key(cid, "av1", "cmd")
        lat: dict[str, list[float]] = {"signed": [], "unsigned": []}
        lost = 0
        try:
            deadline = time.monotonic() + 60.0
            while not ready.wait(0.2):
                if proc.poll() is not None or time.monotonic() > deadline:
                    raise RuntimeError("the vehicle process did not come up: "
                                       + (proc.stderr.read() if proc.poll() is not None else "no state in 60 s"))
            time.sleep(1.0)  # discovery settles
            seq = int(time.time() * 1000)
            for i in range(2 * n_commands + 4):
                mode = "signed" if i % 2 else "unsigned"
                seq += 1
                now = time.time()
                cmd = _command(150, now, seq, Manoeuvre.RESUME)  # a resume: accepted wherever the car is
                t0 = time.perf_counter()
                msg = signer.sign_message(cmd_key, cmd) if mode == "signed" else cmd
                transport.publish(cmd_key, msg)
                with cond:
                    cond.wait_for(lambda c=cmd.command_id: c in acks, timeout=2.0)
                    t1 = acks.get(cmd.command_id)
                if t1 is None or (cmd.command_id + "#rejected") in acks:
                    lost += 1
                elif i >= 4:  # the first two of each: warm-up
                    lat[mode].append((t1 - t0) * 1e3)
                time.sleep(0.013)  # not in phase with the vehicle's 100 Hz loop
        finally:
            transport.close()
            stop_process(proc)
    out: dict[str, float] = {"e2e_commands_per_mode": float(min(len(v) for v in lat.values())), "e2e_lost": float(lost)}
    for mode, v in lat.items():
        if v:
            v.sort()
            out[f"e2e_{mode}_ms_mean"] = statistics.fmean(v)
            out[f"e2e_{mode}_ms_p50"] = v[len(v) // 2]
            out[f"e2e_{mode}_ms_p90"] = v[int(0.9 * (len(v) - 1))]
    if lat["signed"] and lat["unsigned"]:
        out["e2e_signing_delta_ms_mean"] = out["e2e_signed_ms_mean"] - out["e2e_unsigned_ms_mean"]
        se = (statistics.pvariance(lat["signed"]) / len(lat["signed"])
              + statistics.pvariance(lat["unsigned"]) / len(lat["unsigned"])) ** 0.5
        out["e2e_signing_delta_ms_se"] = se
        out["e2e_signed_over_unsigned"] = out["e2e_signed_ms_mean"] / out["e2e_unsigned_ms_mean"]
    return out


def fuzz_figures(n: int | None, from_file: str | None) -> dict[str, float]:
    if from_file:
        last = Path(from_file).read_text().strip().splitlines()[-1]
        d = json.loads(last)
        return {k: d[k] for k in ("fuzz_inputs", "fuzz_crashes", "fuzz_inputs_per_target", "fuzz_targets",
                                  "fuzz_max_rss_growth_kb") if k in d} | {"fuzz_source": from_file}
    from bench import fuzz_bench

    d = fuzz_bench.run(n or 0, say=lambda s: print("  " + s))
    return {k: d[k] for k in ("fuzz_inputs", "fuzz_crashes", "fuzz_inputs_per_target", "fuzz_targets",
                              "fuzz_max_rss_growth_kb", "fuzz_seconds")}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--json", action="store_true", help="last line: one JSON object of the figures")
    ap.add_argument("--quick", action="store_true", help="short run: 30 commands per mode, 50 fuzz inputs per target")
    ap.add_argument("--commands", type=int, default=200, help="end-to-end commands per mode (default 200)")
    ap.add_argument("--fuzz-n", type=int, default=100_000, help="fuzz inputs per target (default 100,000)")
    ap.add_argument("--fuzz-from", metavar="FILE", default=None,
                    help="take fuzz_inputs/fuzz_crashes from a saved `fuzz_bench.py --json` output instead")
    ap.add_argument("--no-e2e", action="store_true", help="skip the Zenoh end-to-end part")
    args = ap.parse_args(argv)
    repeat = 100 if args.quick else 2000
    n_cmd = 30 if args.quick else args.commands
    fuzz_n = 50 if args.quick else args.fuzz_n

    out: dict[str, float | str] = {}
    out.update(crypto_costs(repeat))
    print(f"Ed25519 alone (cryptography/OpenSSL, 400 B): sign {out['raw_ed25519_sign_us']:.1f} us, "
          f"verify {out['raw_ed25519_verify_us']:.1f} us")
    print(f"PathSwitchCommand (150 waypoints, {out['bytes']} B, {out['signed_bytes']} B signed): "
          f"sign {out['sign_us']:.1f} us, verify {out['verify_us']:.1f} us; encode+decode {out['plain_path_us']:.1f} us "
          f"-> sign+encode+decode+verify {out['signed_path_us']:.1f} us "
          f"(x{out['signed_path_us'] / out['plain_path_us']:.2f})")
    print(f"EvAlert ({out['bytes_alert']} B, {out['signed_bytes_alert']} B signed): sign {out['sign_us_alert']:.1f} us, "
          f"verify {out['verify_us_alert']:.1f} us; encode+decode {out['plain_path_us_alert']:.1f} us -> "
          f"{out['signed_path_us_alert']:.1f} us (x{out['signed_path_us_alert'] / out['plain_path_us_alert']:.2f})")
    if not args.no_e2e:
        e2e = end_to_end(n_cmd)
        out.update(e2e)
        if "e2e_signing_delta_ms_mean" in e2e:
            print(f"end to end over Zenoh (command publish -> vehicle 'accepted' ack, {int(e2e['e2e_commands_per_mode'])} "
                  f"per mode, interleaved): unsigned mean {e2e['e2e_unsigned_ms_mean']:.2f} ms "
                  f"(p50 {e2e['e2e_unsigned_ms_p50']:.2f}), signed mean {e2e['e2e_signed_ms_mean']:.2f} ms "
                  f"(p50 {e2e['e2e_signed_ms_p50']:.2f}); signing adds {e2e['e2e_signing_delta_ms_mean']:+.2f} "
                  f"+- {e2e['e2e_signing_delta_ms_se']:.2f} ms (ratio {e2e['e2e_signed_over_unsigned']:.3f}); "
                  f"lost {int(e2e['e2e_lost'])}")
    print(f"fuzzing ({'from ' + args.fuzz_from if args.fuzz_from else f'{fuzz_n} inputs per target'}):")
    out.update(fuzz_figures(fuzz_n, args.fuzz_from))
    print(f"fuzz: {out['fuzz_inputs']} inputs, {out['fuzz_crashes']} crashes")
    if args.json:
        print(json.dumps({k: (round(v, 3) if isinstance(v, float) else v) for k, v in out.items()}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
