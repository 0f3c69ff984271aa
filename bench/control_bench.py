"""Vehicle control benchmark: the field test (report Figs. 12-16) over a grid of speeds, localisation
noise and latency, the stability margin of the gain schedule, and the controller's cost per step.

    python bench/control_bench.py            # full grid
    python bench/control_bench.py --quick    # a few cells (smoke)
    python bench/control_bench.py --json     # last line: one JSON object of the reference-case figures

Reference case: 13.4 m/s, left lane, change one lane right (3.7 m) and stop; GNSS
sigma 0.2 m at 10 Hz with 100 ms latency. Baseline measured in the same run: the plain thesis
controller (eqs. 4.13-4.15 with the curvature at the car, no preview, no sideslip or acceleration
term).

Settled error split (13.4 and 25 m/s, straight and R = 200 m): RMS and max over the settled
window, its mean (bias) and standard deviation, the estimator's share (RMS of true minus
estimated lateral error), the same run without GNSS noise (the controller's share) and, on the
curve, the constant-speed feedforward of eq. 4.13 as the baseline; plus the EKF's own lateral
standard deviation over the window and the analytic floor of a GNSS + gyro estimate.
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from vehicle.lateral import LateralController, LateralGains, closed_loop_eigenvalues, stability_margin  # noqa: E402
from vehicle.localisation import lateral_error_floor_m  # noqa: E402
from vehicle.lockstep import field_test_scenario, run_scenario  # noqa: E402
from vehicle.longitudinal import LongitudinalController  # noqa: E402
from vehicle.plant import VehicleParams  # noqa: E402
from vehicle.reference import ReferencePath, lane_change_waypoints  # noqa: E402


def controller_step_us(iterations: int = 20000) -> float:
    """Median cost of one control step (curve fit + lateral + longitudinal), microseconds."""
    sc = field_test_scenario()
    road = sc.road
    wp = lane_change_waypoints(road, 60.0, 1, 0, 40.0, 200.0, lead_m=10.0)
    path = ReferencePath(wp, stop_point=tuple(wp[-20]))
    lat, lon = LateralController(), LongitudinalController()
    xs = np.linspace(55.0, 200.0, iterations)
    ys = np.interp(xs, wp[:, 0], wp[:, 1]) + 0.05
    samples = []
    for chunk in range(5):
        lat.reset()
        t0 = time.perf_counter()
        for i in range(chunk, iterations, 5):
            out = lat.step(path, float(xs[i]), float(ys[i]), -0.02, 13.4, 0.0, 0.01)
            lon.step(13.4, 13.4, path.stop_s_m - out.s_m)
        samples.append((time.perf_counter() - t0) / len(range(chunk, iterations, 5)) * 1e6)
    return statistics.median(samples)


def settling_split(seeds: int) -> dict:
    """Settled-window figures per case (see the module docstring); returns the JSON figures."""
    print(f"Settled lateral error split (sigma 0.2 m, 10 Hz, 100 ms; {seeds} seed(s); metres; 'worst' over seeds)")
    head = (f"{'road':>6} {'v m/s':>6} {'rms':>6} {'rms.w':>6} {'max':>6} {'max.w':>6} {'|bias|w':>7} {'std.w':>6} "
            f"{'est.rms':>7} {'EKF sd':>6} {'floor':>6} | {'clean rms':>9} {'clean max':>9} | {'eq4.13 rms':>10} "
            f"{'eq4.13 max':>10}")
    print(head)
    print("-" * len(head))
    out = {}
    for radius, v in ((None, 13.4), (None, 25.0), (200.0, 13.4), (200.0, 25.0)):
        ms, sds = [], []
        for seed in range(seeds):
            lat_sd: list[tuple[float, float]] = []

            def ekf_sd(sim, now, lat_sd=lat_sd):
                est = sim.core.estimator
                n = np.array([-math.sin(est.x[2]), math.cos(est.x[2])])
                lat_sd.append((now, float(math.sqrt(n @ est.P[:2, :2] @ n))))

            m = run_scenario(field_test_scenario(v, radius_m=radius, seed=seed), ekf_sd).metrics
            ms.append(m)
            sds.append(float(np.mean([sd for t, sd in lat_sd if t >= m["settled_from_s"]])))
        clean = run_scenario(field_test_scenario(v, 0.0, 0.1, radius_m=radius)).metrics

        def constant_speed_ff(sim, now):
            sim.core.lateral.accel_feedforward = False

        base = run_scenario(field_test_scenario(v, 0.0, 0.1, radius_m=radius), constant_speed_ff).metrics \
            if radius else None
        worst = {k: max(abs(m[k]) for m in ms) for k in ("settled_lateral_error_m", "settled_lateral_max_m",
                                                          "settled_lateral_mean_m", "settled_lateral_std_m")}
        est = float(np.mean([m["settled_estimate_error_m"] for m in ms]))
        floor = lateral_error_floor_m(v)
        name = "line" if radius is None else f"R{radius:g}"
        print(f"{name:>6} {v:6.1f} {ms[0]['settled_lateral_error_m']:6.3f} {worst['settled_lateral_error_m']:6.3f} "
              f"{ms[0]['settled_lateral_max_m']:6.3f} {worst['settled_lateral_max_m']:6.3f} "
              f"{worst['settled_lateral_mean_m']:7.3f} {worst['settled_lateral_std_m']:6.3f} {est:7.3f} "
              f"{float(np.mean(sds)):6.3f} {floor:6.3f} | {clean['settled_lateral_error_m']:9.3f} "
              f"{clean['settled_lateral_max_m']:9.3f} | {fmt(base and base['settled_lateral_error_m']):>10} "
              f"{fmt(base and base['settled_lateral_max_m']):>10}", flush=True)
        tag = f"{name.lower()}_{format(v, 'g').replace('.', 'p')}mps"
        out[f"{tag}_settled_lateral_error_m"] = round(ms[0]["settled_lateral_error_m"], 4)
        out[f"{tag}_settled_lateral_max_m"] = round(ms[0]["settled_lateral_max_m"], 4)
        out[f"{tag}_settled_lateral_error_worst_m"] = round(worst["settled_lateral_error_m"], 4)
        out[f"{tag}_settled_lateral_max_worst_m"] = round(worst["settled_lateral_max_m"], 4)
        out[f"{tag}_settled_estimate_error_m"] = round(est, 4)
        out[f"{tag}_clean_settled_lateral_max_m"] = round(clean["settled_lateral_max_m"], 4)
    print("('rms'/'max': seed 0; '.w': worst seed; 'est.rms': RMS of true - estimated lateral error in the window; "
          "'EKF sd': the filter's own lateral sd there;\n 'floor': steady sd of any GNSS + gyro estimate "
          "(vehicle.localisation.lateral_error_floor_m); 'clean': sigma 0, the controller's share; 'eq4.13': clean, constant-speed "
          "feedforward)\n")
    return out


def fmt(v) -> str:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "   -  "
    return f"{v:6.3f}"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="a few grid cells only")
    ap.add_argument("--json", action="store_true", help="print the reference-case figures as JSON last")
    ap.add_argument("--seeds", type=int, default=2, help="seeds per grid cell (worst case is shown)")
    args = ap.parse_args(argv)
    seeds = 1 if args.quick else args.seeds

    params, gains = VehicleParams(), LateralGains()
    print("Stability of the speed-scheduled gains (closed-loop eigenvalues: bicycle error model + eq. 4.14 "
          "+ steering lag)")
    print(f"{'v m/s':>6} {'k_e':>8} {'k_theta':>8} {'k_omega':>8} {'max Re(lambda)':>15} {'min zeta':>9}")
    for v in (5.0, 10.0, 13.4, 20.0, 25.0, 30.0):
        ev = closed_loop_eigenvalues(params, gains, v)
        k = gains.at_wheelbase(v, params.wheelbase_m)
        zeta = float(np.min(-ev.real / np.abs(ev)))
        print(f"{v:6.1f} {k[0]:8.4f} {k[1]:8.4f} {k[2]:8.4f} {float(ev.real.max()):15.3f} {zeta:9.3f}")
    worst_re, worst_zeta = stability_margin(params, gains)
    print(f"worst over 5..30 m/s (0.5 m/s steps): max Re = {worst_re:.3f} 1/s, min damping = {worst_zeta:.3f}\n")

    speeds = (13.4, 25.0) if args.quick else (8.0, 13.4, 25.0)
    noises = (0.2,) if args.quick else (0.0, 0.2, 0.5)
    latencies = (0.1,) if args.quick else (0.0, 0.1, 0.3)
    roads = (None,) if args.quick else (None, 200.0)
    print(f"Field test grid (worst of {seeds} seed(s) per cell; errors of the TRUE pose against the commanded path)")
    head = (f"{'road':>6} {'v m/s':>6} {'sigma':>6} {'lat s':>6} {'max|e|':>7} {'settl':>7} {'settl.max':>9} "
            f"{'|yaw|':>7} {'|dyaw|':>7} {'stop':>7} {'decel':>6} {'ok':>3}")
    print(head)
    print("-" * len(head))
    t_grid = time.perf_counter()
    for radius, v, sigma, latency in itertools.product(roads, speeds, noises, latencies):
        ms = [run_scenario(field_test_scenario(v, sigma, latency, 10.0, radius, seed)).metrics for seed in range(seeds)]

        def worst(key: str, ms=ms) -> float:
            return max(m[key] for m in ms)

        ok = all(m["stopped"] and m["completed"] for m in ms)
        print(f"{'R' + format(radius, 'g') if radius else 'line':>6} {v:6.1f} {sigma:6.2f} {latency:6.2f} "
              f"{fmt(worst('max_lateral_error_m')):>7} {fmt(worst('settled_lateral_error_m')):>7} "
              f"{fmt(worst('settled_lateral_max_m')):>9} {fmt(worst('max_yaw_error_rad')):>7} "
              f"{fmt(worst('max_yaw_rate_error_rps')):>7} {fmt(worst('stop_error_m')):>7} "
              f"{fmt(worst('max_decel_mps2')):>6} {'yes' if ok else 'NO':>3}", flush=True)
    print(f"(grid: {time.perf_counter() - t_grid:.1f} s; 'settl' = RMS of |e| from 1 s after the lane change to "
          f"the stop, 'stop' = distance to the stop point)\n")

    split = settling_split(seeds)

    print("Localisation from the RSU track of the car (sigma 0.3 m, 15 Hz, 200 ms latency, 5% dropouts):")
    rsu = run_scenario(field_test_scenario(13.4, 0.3, 0.2, 15.0, None, 0, source="rsu", dropout_prob=0.05)).metrics
    print(f"  max|e| {rsu['max_lateral_error_m']:.3f} m, settled {rsu['settled_lateral_error_m']:.3f} m, "
          f"yaw {rsu['max_yaw_error_rad']:.3f} rad, stop {rsu['stop_error_m']:.3f} m\n")

    ref_runs = [run_scenario(field_test_scenario(seed=s)) for s in range(seeds)]
    ref = ref_runs[0].metrics

    def plain(sim, now):  # the thesis controller as printed: no preview, sideslip or acceleration term
        sim.core.lateral.preview_s = 0.0
        sim.core.lateral.sideslip_compensation = False
        sim.core.lateral.accel_feedforward = False

    base = run_scenario(field_test_scenario(seed=0), plain).metrics
    step_us = controller_step_us(4000 if args.quick else 20000)
    print("Reference case (13.4 m/s, sigma 0.2 m, 10 Hz, 100 ms), seed 0:")
    for key in ("max_lateral_error_m", "settled_lateral_error_m", "settled_lateral_max_m", "max_yaw_error_rad",
                "max_yaw_rate_error_rps", "stop_error_m", "max_decel_mps2"):
        print(f"  {key:26s} {ref[key]:.4f}   (plain thesis controller: {base[key]:.4f})")
    ratio = base["max_lateral_error_m"] / ref["max_lateral_error_m"]
    print(f"  max lateral error, plain / this controller: {ratio:.2f}x   (field test: 0.55 m)")
    print(f"  controller cost per step (fit + lateral + longitudinal): {step_us:.1f} us; "
          f"whole simulated step (plant + EKF + controller): {ref['sim_step_us']:.1f} us")
    if args.json:
        print(json.dumps({
            "max_lateral_error_m": round(ref["max_lateral_error_m"], 4),
            "settled_lateral_error_m": round(ref["settled_lateral_error_m"], 4),
            "max_yaw_error_rad": round(ref["max_yaw_error_rad"], 4),
            "stop_error_m": round(ref["stop_error_m"], 4),
            "controller_step_us": round(step_us, 2),
            "max_yaw_rate_error_rps": round(ref["max_yaw_rate_error_rps"], 4),
            "settled_lateral_max_m": round(ref["settled_lateral_max_m"], 4),
            "baseline_max_lateral_error_m": round(base["max_lateral_error_m"], 4),
            "baseline_ratio": round(ratio, 3),
            "stability_max_real_part": round(worst_re, 4),
            "stability_min_damping": round(worst_zeta, 4),
            "sim_step_us": round(ref["sim_step_us"], 2),
            **split,
        }))
    return 0


if __name__ == "__main__":
    sys.exit(main())
