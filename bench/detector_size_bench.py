"""The project detector's accuracy and cost against its input size.

    python bench/detector_size_bench.py [--quick] [--json] [--scales 0.5 0.45 0.4 0.35 0.3 0.25] [--model PATH]

``models/iea_det_tiny.onnx`` is fully convolutional (its shapes come from ``Shape`` nodes) but saved with a fixed
input: trained at [1, 3, 384, 640] (the 1280x720 frame letterboxed at scale 0.5); shipped at any input size, each RSU
searching its zone of responsibility at scale 0.5 (``rsu.detect_roi``; at 288x512, scale 0.4, it misses falling
debris in ``bench/hazard_bench.py``). For each scale s the same weights are saved with the input
ceil(1280 s / 32) 32 x ceil(720 s / 32) 32 (strides 8/16/32 need multiples of 32) and its anchor count, in a
temporary folder (``models.resize_detector.resized_model``: the ``onnx`` package edits the graph's declared shapes;
nothing else changes), and run exactly as an RSU runs the shipped model (``rsu.build``: Framework B, score threshold
0.3, one thread). Per size:

- ``mota`` / ``idf1``: the whole pipeline (detector -> ``FrameworkTracker('B')``) on held-out simulator renders with
  the simulator's labels as truth, as ``bench/rsu_bench.py`` scores it (``bench.rsu_sim_clips.sim_mot``:
  ``rellis_ev_yield`` seed 900003, every camera, 20 s at 15 fps, the first 2 s not scored, vehicles >= 30 % visible
  within the RSU's 100 m zone counted, the rest ignored);
- ``map50``: VOC mAP@0.5 of every vehicle (Framework B) within 100 m on ``models/evaluate_detector.py``'s held-out
  renders (seeds 900001 and 900002, every 0.7 s, 4 cameras), detections down to score 0.01;
- ``loc_err_60m_median_m``: median distance between the position the RSU publishes for a track (ray-plane
  back-projection of its box) and the vehicle's centre, for vehicles 55-65 m from the camera (``sim_mot``): MOTA and
  mAP count a box as right at IoU 0.5 and do not see a box that sits a little off, which the DDM's gap checks do
  (the detector's model card);
- ``cpu_ms``: CPU time (process time: what other processes on a shared machine do does not count) per frame of
  ``OnnxDetector.detect`` (letterbox + inference + decode + NMS) on one thread, mean over the first 60 held-out
  frames.

``chosen_input``: the smallest input whose MOTA is >= ``--mota-min`` (0.9); ``--write PATH`` saves that model;
``cpu_ms_saved_vs_trained``: its CPU per frame against the training size, 384x640. ``--quick``: rsu1 only, 6 s, mAP on
40 frames, scales 0.5 and 0.25 (unless ``--scales`` says otherwise).
With ``--json`` the last line is one JSON object of the figures. Needs the ``onnx`` package (dev extra).
"""

from __future__ import annotations

from bench._setup import ROOT  # noqa: F401  first: one thread per numeric library, before numpy loads

# isort: split
import argparse  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import cv2  # noqa: E402

from bench.rsu_sim_clips import render_sim_clip, sim_mot  # noqa: E402
from models.evaluate_detector import ZONE_M, cpu_latency, evaluate, render_held_out, restrict  # noqa: E402
from models.resize_detector import RSU_INPUT_HW, anchors, input_hw, resized_model  # noqa: E402, F401
from protocol.corridor import load_corridor  # noqa: E402
from rsu.build import PipelineConfig  # noqa: E402
from rsu.detect import PROJECT_MODEL  # noqa: E402

MOT_SCENARIO, MOT_SEED = "rellis_ev_yield", 900_003
"""As ``bench/rsu_bench.py``: held out (never used to train the detector)."""
SCALES = (0.5, 0.45, 0.4, 0.35, 0.3, 0.25)
QUICK_SCALES = (0.5, 0.25)
"""The training size and the smallest: a ``--quick`` run's."""
def measure(model: Path, clips, held_out, corridor, latency_frames: int) -> dict:
    mot = sim_mot(clips, PipelineConfig(detector=str(model), ev_classifier=False), corridor)
    ap = evaluate(model, restrict(held_out, max_range_m=ZONE_M))
    lat = cpu_latency(model, held_out.images[:latency_frames])
    loc = mot["loc_err_60m_median_m_transform"]  # NaN: no matched vehicle 55-65 m from the camera
    return {"mota": mot["mota"], "idf1": mot["idf1"], "fn": mot["fn"], "fp": mot["fp"], "idsw": mot["idsw"],
            "map50": ap["map50_all_vehicles"], "recall": ap["recall_all_vehicles"], "cpu_ms": lat["cpu_ms_mean"],
            "latency_ms_median": lat["latency_ms_median"],
            "loc_err_60m_median_m": None if math.isnan(loc) else round(loc, 3)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scales", type=float, nargs="+", default=None,
                    help="letterbox scales of the 1280x720 frame to measure (default 0.5 0.45 0.4 0.35 0.3 0.25; "
                         "0.5: 384x640, the training size)")
    ap.add_argument("--mota-min", type=float, default=0.9, help="MOTA the chosen input must keep")
    ap.add_argument("--quick", action="store_true", help="rsu1 only, 6 s, mAP on 40 frames, scales 0.5 and 0.25 (a smoke run)")
    ap.add_argument("--json", action="store_true", help="last line: one JSON object of the figures")
    ap.add_argument("--model", type=Path, default=PROJECT_MODEL, metavar="PATH",
                    help="the detector to measure (default: the shipped models/iea_det_tiny.onnx): a candidate is "
                         "judged on the same renders and figures")
    ap.add_argument("--write", type=Path, default=None, metavar="PATH",
                    help="also save the model resized to the chosen input here (to ship it)")
    args = ap.parse_args(argv)
    cv2.setNumThreads(1)
    corridor = load_corridor()
    scales = args.scales or (QUICK_SCALES if args.quick else SCALES)
    cams = ["rsu1"] if args.quick else [r.rsu_id for r in corridor.rsus]
    duration_s = 6.0 if args.quick else 20.0
    t0 = time.perf_counter()
    clips = [render_sim_clip(MOT_SCENARIO, c, seed=MOT_SEED, duration_s=duration_s) for c in cams]
    held_out = render_held_out(seeds=(900_001,) if args.quick else (900_001, 900_002),
                               stride_s=2.1 if args.quick else 0.7, max_frames=40 if args.quick else None)
    print(f"rendered {sum(len(c.frames) for c in clips)} MOT frames ({MOT_SCENARIO} seed {MOT_SEED}, {cams}, "
          f"{duration_s:g} s) and {len(held_out.images)} mAP frames in {time.perf_counter() - t0:.0f} s", flush=True)
    sizes: dict[str, dict] = {}
    with tempfile.TemporaryDirectory(prefix="iea_det_size_") as tmp:
        for scale in sorted(set(scales), reverse=True):
            hw = input_hw(scale)
            model = resized_model(args.model, hw, Path(tmp))
            r = measure(model, clips, held_out, corridor, 60)
            r.update(scale=scale, input_h=hw[0], input_w=hw[1])
            sizes[f"{hw[0]}x{hw[1]}"] = r
            loc = "none matched" if r["loc_err_60m_median_m"] is None else f"{r['loc_err_60m_median_m']:.2f} m"
            print(f"  input {hw[0]:3d}x{hw[1]:3d} (scale {scale:.2f}): MOTA {r['mota']:.3f}  IDF1 {r['idf1']:.3f}  "
                  f"mAP@0.5 {r['map50']:.3f} (recall {r['recall']:.3f})  localisation error at 55-65 m {loc}  "
                  f"{r['cpu_ms']:.2f} ms CPU per frame",
                  flush=True)
    ok = [(v["input_h"] * v["input_w"], k) for k, v in sizes.items() if v["mota"] >= args.mota_min]
    chosen = min(ok)[1] if ok else None
    shipped = f"{RSU_INPUT_HW[0]}x{RSU_INPUT_HW[1]}"
    figures: dict = {"model": str(args.model), "sizes": sizes, "mota_min": args.mota_min, "chosen_input": chosen,
                     "shipped_input": shipped,
                     "mot_source": f"{MOT_SCENARIO} seed {MOT_SEED}, cameras {cams}, {duration_s:g} s"}
    if chosen:
        figures["chosen_mota"] = sizes[chosen]["mota"]
        figures["chosen_cpu_ms"] = sizes[chosen]["cpu_ms"]
        trained = f"{input_hw(0.5)[0]}x{input_hw(0.5)[1]}"
        if trained in sizes:
            figures["cpu_ms_saved_vs_trained"] = sizes[trained]["cpu_ms"] - sizes[chosen]["cpu_ms"]
    print(f"smallest input with MOTA >= {args.mota_min:g}: {chosen or 'none'} (shipped: {shipped})")
    if chosen and args.write:
        with tempfile.TemporaryDirectory() as tmp:
            made = resized_model(args.model, (sizes[chosen]["input_h"], sizes[chosen]["input_w"]), Path(tmp))
            args.write.write_bytes(made.read_bytes())
        print(f"wrote {args.write}")
    if args.json:
        print(json.dumps(figures))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
