"""EV identification benchmark on simulator renders (issue 5): recall, false alerts, lights-on -> alert.

    python bench/ev_bench.py [--quick] [--json] [--detector motion|onnx] [--seeds 301 302] [--scenarios ...]

Lockstep: for each scenario and (held-out) seed the sim ``World`` is stepped at the cameras' 15 fps,
every RSU's view is rendered with ``SimCamera.render`` and run through the RSU's own pipeline
(detector -> SORT -> ``TrackEvClassifier`` -> localiser) and ``EvAlertManager``, exactly as
``RsuService`` wires them. The pipeline sees pixels only; ground truth (``Renderer.labels`` of the
snapshot, the scenario's lights-on time) is used here to *score*:

- an **EV track** is one EV with its lights on as seen by one RSU camera, visible (labelled class ev)
  *within that RSU's zone of responsibility* (``max_range_m`` of the corridor file from its mast: the
  RSU reports nothing farther, the next RSU covers it) for at least ``--min-visible-s``; it is **found** if an ``active`` alert is raised for a track that
  overlaps it (IoU >= 0.3, or the track's majority match) while its lights are on.
  ``track_recall`` = found / EV tracks;
- a **false alert** is an alert id whose track matches anything but an EV with lights on (or nothing);
- **lights-on -> alert**: per scenario run with an EV, first ``active`` alert on the EV (any RSU) minus
  the later of the scenario's lights-on time and the first frame the lit EV is visible to a camera
  within its zone;
  ``lights_on_to_alert_median_s`` is the median over runs.

Seeds: ``EvidenceConfig``/``measure_lamps`` defaults were tuned on seeds 1-4 and then looked at on 101 and
102, the held-out seeds of the figures below; after that much use 1-4 and 101/102 are all tuning seeds.
Seeds 301/302 were drawn once for issue 17 and then used to set the steady-bar lamp-core test, so they are
tuning seeds too. Seeds 1142/1527 were drawn for the second session of issue 17; its false alerts on 1142 were
traced (the car beside the EV, the decoy-lamp car), so they are tuning seeds now. Seeds 5441/6538 were drawn at
random (2026-11-25, fourth session), held out, and run once for the figures below (fifth session): tuning seeds
now. Seeds 31372/91468 were drawn at random for the fifth session and tuned on (its false alerts traced): tuning
seeds. Seeds 50857/21674 were drawn at random once (2026-11-25, fifth session), held out, and run once (sixth
session, 2026-11-27, no change to the EV path since they were drawn): track recall 0.958 (23/24; rsu1 missed ev1 of
``ev_two_lanes_dense`` 21674), 1 false alert (rsu3, vehicle d4 of ``ev_lights_never_on`` 50857), median 0.23 s;
tuning seeds from now on. Seventh session (2026-11-27), on those tuning seeds: the light-bar flash cue counts only
lamp-lit runs (``EvidenceConfig.bar_flash_min_peak``: the false alert of 50857 was red paint, brightest channel
0.71-0.85); 50857/21674/31372/91468, all four scenarios: 0 false alerts, and the 21674 miss remains (removing the
strong bar flash's size bound found it but raised a false alert on 31372: kept). Seeds 80442/44077 were drawn at
random (sixth session), held out, and run once after that change (``python bench/ev_bench.py --json``, 362 s): track
recall 1.0 (24/24), **2 false alerts** (``ev_two_lanes_dense``: rsu4 vehicle v1 of 80442, rsu2 vehicle v4 of 44077;
traced after the run: the EV's own flashes, red and blue, seen in the neighbouring vehicle's lamp band),
median lights-on -> alert 0.37 s (max 0.60 s), 18 flasher/turn-signal cars seen; tuning seeds from now on. The
held-out seeds 90289/76285 were drawn at random once (2026-11-27, seventh session) and run once in the ninth
(2026-11-27, after the changes below: ``python bench/ev_bench.py --seeds 90289 76285 --json``, 287 s): track recall
0.958 (23/24: rsu1 missed ev1 of ``ev_two_lanes_dense`` 76285), 1 false alert (rsu4, vehicle v9 of
``ev_two_lanes_dense`` 90289, a box of 289 x 318 px), median lights-on -> alert 0.47 s (max 3.93 s), 9
flasher/turn-signal cars seen, 0 false alerts on them; not traced: they are tuning seeds from now on. Ninth session,
on tuning seeds 80442/44077 (all four scenarios): false alerts 4 -> 2, recall 1.0 (24/24), median 0.37 s. Traced:
(1) a hidden EV's light bar glowed through the bus in front of it (rsu4, 80442): a renderer artefact, mended (a
lamp hidden behind a nearer vehicle throws no halo, ``sim.render.effects.hidden_lamps``); (2) the EV's strobe on
the roof of the bus just behind it (rsu2, 44077), confirmed in the one frame where SORT had dropped the EV's
confirmed track: a confirmed EV lost within the hand-over time, or a vehicle just ahead too small to measure,
now holds back a flash-alone confirmation (``TrackEvClassifier._ev_ahead``). Left: (3) a car whose box, 2x
its height, took in the red turn signal of the van ahead (rsu1, 80442: the 288x512 detector's box); (4) the AV's
track switched onto the EV overtaking it and alerted on the EV's box (IoU 0.86 with the EV; rsu4, 44077 of
``rellis_ev_yield``), counted false because the track was mostly the AV. Held-out seeds 30023/41751, drawn at
random once (ninth session), were run once in the tenth (2026-11-27, with the zone-window detector at scale 0.5 and
the retrained EV-body classifier; ``python bench/ev_bench.py --seeds 30023 41751 --json``, 297 s): track recall
0.958 (23/24: rsu1 missed ev1 of ``ev_two_lanes_dense`` 41751, as it did on 21674 and 76285; traced after the
run: the EV drives away from rsu1, lit from 25 m, measurable to 61 m; its red bar flashes regularly at 3 Hz but
fills 14-42 % of the band, over the strong flash's size bound ``steady_max_fraction``; blue never shows from
behind; the body classifier scores its rear 0.1-0.35), 0 false alerts,
median lights-on -> alert 0.40 s (max 4.07 s), 7 flasher/turn-signal cars seen, 0 false alerts on them; they are
tuning seeds from now on (80442/44077 at the same code: recall 1.0, 0 false alerts, median 0.37 s). Held-out seeds
30788/36737, drawn at random once (tenth session), were run once in the sixteenth (2026-11-28, no change to the EV
path since they were drawn; ``python bench/ev_bench.py --seeds 30788 36737 --json``, 224 s): track recall 1.0
(24/24), 0 false alerts, median lights-on -> alert 0.27 s (max 0.47 s), 9 flasher/turn-signal cars seen (6 hazard
flashers, 3 turn signals), 0 false alerts on them; tuning seeds from now on. Held-out 65805/97823, drawn at random
once (sixteenth session), were run once in the seventeenth (2026-11-28; the EV path's outputs unchanged since they
were drawn; ``python bench/ev_bench.py --seeds 65805 97823 --json``, 281 s): track recall 1.0 (24/24), 0 false
alerts, median lights-on -> alert 0.20 s (max 0.60 s), 7 flasher/turn-signal cars seen (2 hazard flashers, 5 turn
signals), 0 false alerts on them; tuning seeds from now on. Held-out 51100/68157, drawn at random once (seventeenth
session), were run once in the eighteenth (2026-11-28; the EV path unchanged since they were drawn; ``python
bench/ev_bench.py --seeds 51100 68157 --json``, 252 s): track recall 1.0 (24/24), median lights-on -> alert 0.23 s
(max 0.60 s), 17 flasher/turn-signal cars seen (7 hazard flashers, 10 turn signals), and **2 false alerts, both on
one of them**: ``night_ev`` 51100, vehicle v0, on rsu1 (track 50, 9.13 s) and rsu2 (track 19,
10.4 s, IoU with the EV 0.34 and 0.04): issue 17's 0 false alerts is not met on this pair; tuning seeds from now
on. Traced there: the EV's restarted track, not yet confirmed, beside the truck behind it (rsu2), and a box over the EV
and the truck's top taking over the EV's lost track (rsu1); mended in ``rsu.classify.ev`` (a farther track flashing on
its own may own the flashes; a box holding most of a nearer vehicle's box takes over nothing): tuning seeds
51100/68157/65805/97823, recall 1.0 (48/48), 0 false alerts, median 0.20 s. Held-out 36545/16790, drawn at random
once (eighteenth session), were run once after that change (``python bench/ev_bench.py --seeds 36545 16790 --json``,
299 s): track recall 1.0 (24/24), **3 false alerts**, none on a flasher or turn-signal car (``rellis_ev_yield`` 16790:
rsu4 vehicle v0 twice, tracks 22 and 44; ``ev_two_lanes_dense`` 36545: rsu3 vehicle d0), median lights-on -> alert
0.33 s (max 0.93 s), 19 flasher/turn-signal cars seen; the code before the change raises the same three (those two
scenarios, same seeds): issue 17's 0 false alerts is not met on this pair; not traced; tuning seeds from now on. The
held-out seeds are now ``HELD_OUT_SEEDS`` = 57097, 72786, drawn at random once (eighteenth session) and not run: do
not tune on them.
With ``--json`` the last line is one JSON object of the figures.

Fifth session (2026-11-25), lamps counted for one vehicle only (``rsu.classify.ev``, ``rsu.classify.temporal``):
on tuning seeds 31372/91468 the figures were recall 1.0 (24/24), 8 false alerts, median 0.20 s. Causes traced:
(1) a sunlit red truck cab (paint R 228-243, core share 0.1-0.34) taken for a steady bar with a body score ~0.6
(3): a steady bar now needs a clipped brightest pixel (``steady_min_peak`` 250/255); (2) a truck or bus behind
a car or the EV took in the tail lights or the light bar of the vehicle ahead through its upward-grown band (4):
a farther vehicle's box is left out of the band above the box top (``band_exclusions``), of the light-bar band
altogether (``farther_boxes``), and the lamp-bright band reaches only 0.1 box heights above the box
(``bright_above_fraction``: an EV half hidden behind a bus, not detected); (3) the EV's red glow on the roof of the
bus just behind it, flashing in step (1): a track with a confirmed EV just ahead confirms on flashes only with a
confident body. After: recall 1.0 (24/24), 0 false alerts, median 0.17 s (max 1.27 s); tuning seeds
1142/1527/301/302: recall 1.0 (47/47), false alerts 2 -> 0, median 0.27 s both. Held-out 5441/6538, run once
after (``python bench/ev_bench.py --json --seeds 5441 6538``): track recall 0.957 (22/23: one EV track missed in
ev_two_lanes_dense 5441, not traced: held out), false alerts 0 (3 before), median lights-on -> alert 0.20 s
(max 3.80 s), 11 decoy-lamp vehicles seen, 0 false alerts on them. The real-data figures of
``bench/ev_real_bench.py`` are unchanged (clips alerted 5/6, traffic false alerts 0, photos and split).

Decoy lamps (issue 17): the traffic holds ordinary vehicles with amber hazard flashers at their four
corners or one red rear turn signal, blinking at 1-2 Hz (``sim.lamps``; ``hazard_flasher_fraction`` and
``turn_signal_fraction`` of the scenario's traffic, 0.08 each by default). ``decoy_lamp_vehicles`` counts
those a camera saw (labelled in a frame) with their lamps lit, per run, summed over runs;
``false_alerts_on_decoy_lamps`` the false alerts whose track matched one. On 301/302 the four scenarios start
with 17 of them (rellis_ev_yield and night_ev 301: none). The figures below predate them and the new seeds.

Measured (held-out 101/102, all four scenarios, 20 s, motion detector, defaults; a 2-core machine shared
with other jobs, so ms/frame is not a latency figure): track recall 1.0 (24/24), false alerts 0, median
lights-on -> alert 1.20 s (max 2.47 s): rellis_ev_yield 0.27/0.13 s, night_ev 2.13/0.13 s,
ev_two_lanes_dense 2.33/2.47 s. The slow cases are EVs that the motion detector merges with a
neighbour or inflates with their own glow when the lights go on (the lamp fraction of the box's top
band then stays below ``lamp_on_fraction``); a lower ``lamp_on_fraction`` (0.012-0.015) confirms those
sooner on tuning seeds but raised 2 false alerts on held-out ev_two_lanes_dense 101, so it is not
the default. The code before this rule (single transitions counted as blinks) measured recall 1.0,
15 false alerts, median 1.6 s on the same held-out runs (before the zone-of-responsibility filter of
the localiser landed on main, which now drops far blobs too).

Lamp threshold, 2026-11-24: ``lamp_on_fraction`` is now 0.015 (was 0.025). Tracing rellis_ev_yield
seed 8 frame by frame showed rsu1's tight box of the EV, seen from the front at 30-60 m, with a clean
red/blue alternation at 1.5-2.3 % of the band: below 0.025, so the EV confirmed only 1.6 s after lights
on, once it came closer (0.33 s at 0.015; seed 3: 0.53 -> 0.20 s; seed 1 stays 0.80 s: its blue half is
barely visible from rsu1, so it waits for a second red flash). Same held-out command as below: recall 1.0
(24/24), 0 false alerts, median 0.30 s, max 0.67 s (226 s); tuning seeds 1/3/8 of rellis_ev_yield,
ev_two_lanes_dense and ev_lights_never_on: 0 false alerts. The 2 false alerts at 0.015 noted above were
the motion detector's loose boxes. ``--keep-fraction 0.6`` emulates an RSU that keeps ~9 of 15 fps.

With the project detector (``--detector project``, now the default: the RSUs of the demo and the
lockstep corridor run it), same held-out runs, unloaded machine: track recall 0.958 (23/24: rsu2 missed
the EV in ev_two_lanes_dense 101), false alerts 0, median lights-on -> alert 0.30 s (max 0.67 s),
6.6-7.6 ms/frame. Tight boxes keep the light bar in the measured band, so the evidence confirms within
a flash or two.

The miss was track fragmentation, not the detector: rsu2 sees that EV drive away from the mast, its
box turning from wide (side and back) to narrow (back) within 1.5 s; SORT's aspect ratio lags that
(reference noise settings), the track's box drifts off the detections until IoU < 0.3, the track is
dropped (max_age 1) and its successor is reported 3 hits later (6.4 -> 6.67 s). Each id saw one or
two red flashes (the bar's white-hot core and V ~ 235 halo are missed on some flashes), and the second
id was confirmable only after 7.27 s, when the box shrank below ``min_box_px`` (40 px) and was no
longer measured. Since ``TrackEvClassifier`` hands a lost track's evidence to the new id that overlaps
its moved-on box (rsu.classify.ev, module docstring), the EV confirms at 7.0 s. Same command, same
held-out runs (``python bench/ev_bench.py --json``, 2-core machine shared with other jobs): track recall
1.0 (24/24), false alerts 0, median lights-on -> alert 0.30 s (max 0.67 s).

Twentieth session (2026-11-29): the three false alerts of 36545/16790 (tuning seeds since the eighteenth) were
traced there: an ordinary vehicle just behind the EV, nearer the camera, whose crop (grown above its box for the
roof bar) held the EV, so that the body classifier scored the EV in it; and on 16790 a truck that took over the
ambulance's lost track by position, with its body scores. Three changes in ``rsu.classify``: a track with a flashing
vehicle just ahead takes no body score; a crop is body-scored with the farther vehicles' boxes blanked where
they rise above its box's top (``ownership.above_top``, ``blank_rects``; blanking them whole, the first version, run on
57097/72786 below, would erase the roof and upper body of an EV in front of a bus); body scores handed over to a new
track id count again only once its own box is scored.
Tuning seeds 16790/36545: 0 false alerts (3 before), recall 1.0, median 0.33 s; 51100/68157/65805/97823: unchanged
(recall 1.0, 0 false alerts, median 0.20 s). Then held-out 57097/72786, run once (``python bench/ev_bench.py
--json``, 196 s): track recall 1.0 (24/24), 0 false alerts, median lights-on -> alert 0.50 s (the mean of the middle
two of six runs, 0.33 and 0.67 s; max 1.20 s), 15 flasher/turn-signal cars seen with 0 false alerts on them. They are
tuning seeds now. The blanking then changed to the part above the box's top (the change above); on tuning seeds
16790/36545: 0 false alerts, recall 1.0, median 0.33 s; 51100/68157/65805/97823/57097/72786: recall 1.0 (72/72),
0 false alerts, median 0.23 s (57097/72786 the same run by run as with whole-box blanking). Then held-out
21376/45884, run once (``python bench/ev_bench.py --json``, 2026-11-29): track recall 0.958 (23/24: rsu1 missed ev1
of ``ev_two_lanes_dense`` 21376, the fourth held-out pair with that miss), 2 false alerts (``ev_two_lanes_dense``:
rsu1 vehicle v6 of 21376, a 312 x 294 px box, and rsu3 vehicle v1 of 45884, both on a flash alone, body 0.03-0.40),
median 0.27 s (max 5.13 s), 13 flasher/turn-signal cars seen with 0 false alerts on them: issue 17's recall and
false-alert targets **not met** on this pair. The code before this session's changes (26f3d8e) gives the same miss
and the same two false alerts on those runs. Not traced further; tuning seeds now. The next held-out pair is
93492/82788, drawn at random.

Twenty-first session (2026-12-01): the rsu1 miss of ``ev_two_lanes_dense`` (held-out 21674, 76285, 41751 and 21376)
traced on 21376: a police car just ahead of a bus (nearer the camera), its bar inside the bus's crop grown
above the bus's box; the police car's band left out the bus's whole crop, so it lost every flash to it and was never
confirmed. Now a nearer vehicle's crop above its box yields to this box's rows nearer this box's top
(``ownership.band_exclusions``), and a steady bar alone no longer makes a track one that may own the flashes around it
(``TrackEvidence.last_flash_cue_s``; with the band change alone the Japanese clip's ambulance lost its body scores
to a van just ahead with a steady-bar cue). Tuning seeds 21376/21674/76285/41751/45884/30023: recall 1.0 (72/72;
the four rsu1 misses found), 1 false alert (the bus of 21376, rsu1, on a flash alone: a merged box over the bus and
the police car before the car had a box of its own; not mended: the bus's body scored 0.03-0.28, but sim EVs score
as low as 0.01, 31 of 92 EV alerts on four tuning seeds with a body mean under 0.11, so a body veto would cost
recall); 51100/68157/65805/97823/57097/72786: recall 1.0
(72/72), 0 false alerts, median 0.23 s (unchanged); 21376/21674/36545/16790: 64 of 64. Then held-out 93492/82788,
run once (``python bench/ev_bench.py --json``, 198 s): track recall **1.0** (24/24), **0 false alerts**, median
lights-on -> alert **0.37 s** (max 0.60 s), 22 flasher/turn-signal cars seen (12 hazard, 10 turn signals) with 0
false alerts on them: issue 17's simulator figures met on this pair. Tuning seeds now; the next held-out pair is
52609/82241, drawn at random.

Twenty-third session (2026-12-01): held-out 52609/82241, run once after the renderer's noise change (issue 19;
``python bench/ev_bench.py --json``, 226 s): track recall **0.958** (23/24: rsu4 missed ev1 of ``ev_two_lanes_dense``
52609), **1 false alert** (the same run, rsu4, t 17.87 s: a 214 x 232 px box scored as vehicle v0), median
lights-on -> alert 0.23 s (max 0.60 s), 13 flasher/turn-signal cars seen (7 turn signals, 6 hazard) with 0 false
alerts on them: issue 17's simulator figures **not met** on this pair. The renderer before this session's changes
(``bb3046f``) gives the same miss and the same false alert, run by run (207 s), so the renderer's change did not
cause them. Not traced; tuning seeds now. The next held-out pair is 47390/38696, drawn at random.

Twenty-sixth session (2026-12-01): held-out 47390/38696, run once after the EV classifier came to read the tracks
SORT holds back (``rsu.pipeline``; ``python bench/ev_bench.py --json``, 127 s): track recall **1.0** (23/23),
**0 false alerts**, median lights-on -> alert **0.40 s** (max 0.87 s: ``night_ev`` 38696), 11 flasher/turn-signal
cars seen with 0 false alerts on them: issue 17's simulator figures met on this pair. Before that run the change
gave the same figures as the code before it on the tuning pairs 52609/82241 and 93492/82788, run by run. Tuning
seeds now; the next held-out pair is 90535/51550, drawn at random. Then the false alert of 52609 (rsu4: the truck
behind the EV, confirmed on the EV's bar while the EV drove on hidden behind it) was traced and removed
(``TrackEvClassifier.occluded_hold_s``), the other tuning pairs unchanged run by run. Held-out 90535/51550, run
once on that code (125 s): track recall **0.958** (23/24: rsu1 missed ev1 of ``ev_two_lanes_dense`` 51550, first
alert of that run 4.13 s after lights on), **0 false alerts**, median **0.27 s**, 14 flasher/turn-signal cars with
0 false alerts on them: recall short of issue 17's 0.99 on this pair; the code at this session's start (5dc91d3)
misses the same EV. Not traced; tuning seeds now. The next held-out pair is 29407/89771, drawn at random.
"""

from __future__ import annotations

from bench._setup import REAL, ROOT  # noqa: F401  first: one thread per numeric library, before numpy loads

# isort: split
import argparse  # noqa: E402
import dataclasses  # noqa: E402
import json  # noqa: E402
import os
import statistics  # noqa: E402
import time  # noqa: E402
from collections import Counter, defaultdict  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from protocol.enums import AlertState
from rsu.build import MOTION, PROJECT, PipelineConfig, build_pipeline  # noqa: E402
from rsu.classify.evidence_config import EvidenceConfig  # noqa: E402
from rsu.classify.lamps import LAMP_BRIGHT  # noqa: E402
from rsu.frames import Frame  # noqa: E402
from rsu.track.assoc import iou_matrix  # noqa: E402
from sim.camera_source import SimCamera  # noqa: E402
from sim.lamps import signal_on, style_signal  # noqa: E402
from sim.scenario import load_scenario  # noqa: E402
from sim.warmup import warmup_frames  # noqa: E402
from sim.world import World  # noqa: E402

cv2.setNumThreads(1)
SCENARIOS = ("rellis_ev_yield", "ev_two_lanes_dense", "night_ev", "ev_lights_never_on")
YOLOX = REAL / "yolox_nano" / "yolox_nano.onnx"
HELD_OUT_SEEDS = (29407, 89771)
"""Drawn at random once (2026-12-01, twenty-sixth session), not run yet; 1-4, 101/102, 301/302, 1142/1527, 5441/6538,
31372/91468, 50857/21674, 80442/44077, 90289/76285, 30023/41751, 30788/36737, 65805/97823, 51100/68157,
36545/16790, 57097/72786, 21376/45884, 93492/82788, 52609/82241, 47390/38696 and 90535/51550 are tuning seeds
(module docstring)."""
DEBUG = bool(os.environ.get("EV_BENCH_DEBUG"))


def pipeline_config(detector: str, *, ev_body: str = "default", box_gate: bool = False, crop_classifier: str = "none",
                    classifier_kwargs: dict | None = None) -> PipelineConfig:
    """``detector``: ``project``: the project's detector (what the RSUs of the demo and the lockstep corridor
    run), every vehicle one class; ``onnx``: the COCO YOLOX-nano (score threshold 0.25); ``motion``: MOG2."""
    model = {"project": PROJECT, "onnx": str(YOLOX), "motion": MOTION}[detector]
    return PipelineConfig(detector=model, score_threshold=0.25 if detector == "onnx" else 0.3, threads=1,
                          ev_body=ev_body, ev_box_gate=box_gate, ev_crop_classifier=crop_classifier,
                          classifier_tuning=dict(classifier_kwargs or {}))


def run_one(scenario_name: str, seed: int, detector: str, duration_s: float | None, min_visible_s: float,
            label_stride: int = 1, classifier_kwargs: dict | None = None, box_gate: bool = False,
            crop_classifier: str = "none", keep_fraction: float = 1.0, ev_body: str = "default") -> dict:
    sc = load_scenario(scenario_name).with_overrides(seed=seed)
    world = World(sc, seed=seed)
    corridor = sc.corridor
    fps = corridor.rsus[0].camera.fps
    dt = 1.0 / fps
    end_s = min(sc.duration_s, duration_s) if duration_s else sc.duration_s
    rsus = []
    for r in corridor.rsus:
        cam = SimCamera(corridor, r.rsu_id, seed=seed)
        config = pipeline_config(detector, ev_body=ev_body, box_gate=box_gate, crop_classifier=crop_classifier,
                                 classifier_kwargs=classifier_kwargs)
        pipe = build_pipeline(config, corridor, r.rsu_id)
        if pipe.learns_the_road:  # an RSU that has been running: MOG2 learnt the road from its own frames
            for _rid, image in warmup_frames(sc, {r.rsu_id: cam}):
                pipe.learn_road(image)
        rsus.append((r.rsu_id, cam, pipe, pipe.classifier))
    zone = {r.rsu_id: (r.position, r.max_range_m) for r in corridor.rsus}
    lights_on_at = sc.ev.lights_on_at_s if sc.ev is not None else None
    ev_visible = defaultdict(float)           # (rsu, actor) -> seconds visible with lights on
    first_lit_visible: dict[str, float] = {}  # actor -> first time a camera sees it lit
    votes = defaultdict(Counter)              # (rsu, track) -> Counter(actor id)
    alert_match: dict[tuple, tuple] = {}      # (rsu, track) -> (actor or None, ok, t)
    found: set[tuple] = set()
    first_alert_ev: dict[str, float] = {}
    decoys = {a.actor_id: style_signal(a.style).mode for a in world.snapshot().actors if style_signal(a.style)}
    decoys_seen: set[str] = set()             # decoy lamp vehicles a camera saw with their lamps lit
    frames = 0
    t_pipe = 0.0
    k = 0
    skip_rng = np.random.default_rng(seed)
    while world.t_s < end_s - 1e-9:
        world.step(dt)
        k += 1
        snap = world.snapshot()
        for rsu_id, cam, pipe, clf in rsus:
            if keep_fraction < 1.0 and skip_rng.random() >= keep_fraction:
                continue  # this RSU is still busy with an earlier frame: it never sees this one
            f = cam.render(snap)
            frame = Frame(f.image, f.timestamp_s, f.frame_number, rsu_id)
            t0 = time.perf_counter()
            result = pipe.process(frame)
            events = result.alerts
            t_pipe += time.perf_counter() - t0
            frames += 1
            need_labels = bool(events) or k % label_stride == 0
            if not need_labels:
                continue
            labels = cam.renderer.labels(snap)
            lit = {lb.actor_id for lb in labels if lb.class_id == 1}
            if decoys:
                styles = {a.actor_id: a.style for a in snap.actors if a.actor_id in decoys}
                decoys_seen.update(lb.actor_id for lb in labels
                                   if lb.actor_id in styles and signal_on(styles[lb.actor_id], snap.sim_time_s))
            (cx, cy), max_range = zone[rsu_id]
            in_zone = {a.actor_id for a in snap.actors if max_range is None
                       or np.hypot(a.pos_x_m - cx, a.pos_y_m - cy) <= max_range}
            for aid in lit & in_zone:
                ev_visible[(rsu_id, aid)] += dt * label_stride
                first_lit_visible.setdefault(aid, snap.sim_time_s)
            if len(result.tracks) and labels:
                iou = iou_matrix(np.asarray(result.tracks.boxes, float),
                                 np.array([lb.bbox_px for lb in labels], float))
                for i, tid in enumerate(result.tracks.track_ids):
                    j = int(np.argmax(iou[i]))
                    if iou[i, j] >= 0.3:
                        votes[(rsu_id, int(tid))][labels[j].actor_id] += 1
            for e in events:
                key = (rsu_id, e.track_id)
                if e.state != AlertState.ACTIVE or key in alert_match:
                    continue
                v = votes.get(key)
                actor = v.most_common(1)[0][0] if v else None
                ok = actor in lit
                box = np.asarray(e.row.boxes, float).reshape(1, 4)
                evl = [lb for lb in labels if lb.class_id == 1]
                ev_iou = float(iou_matrix(box, np.array([lb.bbox_px for lb in evl], float)).max()) if evl else 0.0
                alert_match[key] = (actor, ok, snap.sim_time_s, round(ev_iou, 2),
                                    tuple(int(v) for v in e.row.boxes[0]))
                if DEBUG and not ok:
                    evd = clf.tracks[e.track_id].evidence
                    print("  FALSE", rsu_id, e.track_id, actor, round(snap.sim_time_s, 2), "cues",
                          [c.value for c in evd.cues], "body", np.round(list(evd.body_scores), 2))
                    for name, series in evd._signals.items():
                        print(f"    {name:18s}", np.round(list(series)[-int(os.environ.get("EV_BENCH_DEBUG_N", "20")):], 3))
                if ok:
                    found.add((rsu_id, actor))
                    first_alert_ev.setdefault(actor, snap.sim_time_s)
            # a later alert refresh can still find an EV the first association missed
            for e in events:
                key = (rsu_id, e.track_id)
                if e.state == AlertState.ACTIVE and key in alert_match and not alert_match[key][1]:
                    v = votes.get(key)
                    actor = v.most_common(1)[0][0] if v else None
                    if actor in lit:
                        found.add((rsu_id, actor))
                        first_alert_ev.setdefault(actor, snap.sim_time_s)
    ev_tracks = {key for key, s in ev_visible.items() if s >= min_visible_s}
    false = [(k_, m) for k_, m in alert_match.items() if not m[1]]
    latency = None
    if first_alert_ev and lights_on_at is not None:
        aid, t_alert = min(first_alert_ev.items(), key=lambda kv: kv[1])
        t_on = max(lights_on_at, first_lit_visible.get(aid, lights_on_at))
        latency = t_alert - t_on
    seen_modes = Counter("hazard" if decoys[a] == "hazard" else "turn_signal" for a in decoys_seen)
    return dict(scenario=scenario_name, seed=seed, ev_tracks=len(ev_tracks),
                found=len(ev_tracks & found), missed=sorted(map(list, ev_tracks - found)),
                false_alerts=len(false), false_detail=[[*k_, m[0], round(m[2], 2), *m[3:]] for k_, m in false],
                lights_on_to_alert_s=latency, frames=frames, pipeline_ms_per_frame=1000 * t_pipe / max(frames, 1),
                decoy_lamp_vehicles=len(decoys_seen), decoy_lamp_modes=dict(seen_modes),
                false_alerts_on_decoy_lamps=sum(1 for _k, m in false if m[0] in decoys))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenarios", nargs="+", default=list(SCENARIOS))
    ap.add_argument("--seeds", nargs="+", type=int, default=list(HELD_OUT_SEEDS),
                    help="held-out seeds (default: HELD_OUT_SEEDS, 29407 89771; the module docstring lists the tuning seeds)")
    ap.add_argument("--detector", choices=["project", "motion", "onnx"], default="project",
                    help="project: the RSUs' default (models/iea_det_tiny.onnx); motion: MOG2; onnx: COCO YOLOX-nano")
    ap.add_argument("--duration-s", type=float, default=20.0, help="simulated seconds per run (scenario cap)")
    ap.add_argument("--min-visible-s", type=float, default=1.0,
                    help="an EV counts as a track for a camera when seen lit at least this long")
    ap.add_argument("--label-stride", type=int, default=1, help="ground-truth labels every Nth frame")
    ap.add_argument("--lamp-min-value", type=int, default=None, help="override measure_lamps min_value")
    ap.add_argument("--set", nargs="*", default=[], metavar="FIELD=VALUE",
                    help="override EvidenceConfig fields (tuning only), e.g. --set lamp_on_fraction=0.02")
    ap.add_argument("--box-gate", action="store_true",
                    help="skip lamp measurements on boxes wider than one vehicle (rsu.classify.box_gate.SingleVehicleGate)")
    ap.add_argument("--ev-body", default="default",
                    help="EV-body classifier fused with the lamps, as the RSU runs it: default (models/ev_body.onnx), "
                         "none or PATH.onnx")
    ap.add_argument("--crop-classifier", default="none", help="none, cnn or hsv8-gb: per-crop score fused per track")
    ap.add_argument("--keep-fraction", type=float, default=1.0,
                    help="each RSU processes a frame with this probability (0.6: an RSU that keeps up with ~9 of "
                         "15 fps, as co-located RSUs on 2 cores do); default 1")
    ap.add_argument("--quick", action="store_true", help="rellis_ev_yield only, 1 seed, 8 s (a smoke run)")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    if not 0.0 < args.keep_fraction <= 1.0:
        ap.error(f"--keep-fraction must be in (0, 1], got {args.keep_fraction}")
    if args.quick:
        args.scenarios, args.seeds, args.duration_s = ["rellis_ev_yield"], args.seeds[:1], 8.0
    t0 = time.perf_counter()
    runs = []
    kwargs: dict = {} if args.lamp_min_value is None else {
        "colours": dataclasses.replace(LAMP_BRIGHT, min_value=args.lamp_min_value)}
    if args.set:
        over = {k: float(v) if "." in v else int(v) for k, v in (item.split("=", 1) for item in args.set)}
        kwargs["config"] = dataclasses.replace(EvidenceConfig(), **over)
    for name in args.scenarios:
        for seed in args.seeds:
            r = run_one(name, seed, args.detector, args.duration_s, args.min_visible_s, args.label_stride,
                        kwargs, args.box_gate, args.crop_classifier, args.keep_fraction, args.ev_body)
            runs.append(r)
            lat = r["lights_on_to_alert_s"]
            print(f"{name:22s} seed {seed:4d}: EV tracks found {r['found']}/{r['ev_tracks']}  false alerts "
                  f"{r['false_alerts']}  lights-on->alert {'-' if lat is None else f'{lat:.2f} s'}  "
                  f"decoy lamp vehicles {r['decoy_lamp_vehicles']}  "
                  f"({r['frames']} frames, {r['pipeline_ms_per_frame']:.1f} ms/frame)"
                  + (f"  missed {r['missed']}" if r["missed"] else "")
                  + (f"  false {r['false_detail']}" if r["false_detail"] else ""), flush=True)
    n_tracks = sum(r["ev_tracks"] for r in runs)
    lats = [r["lights_on_to_alert_s"] for r in runs if r["lights_on_to_alert_s"] is not None]
    figures = dict(
        track_recall=(sum(r["found"] for r in runs) / n_tracks) if n_tracks else None,
        ev_tracks=n_tracks, false_alerts=sum(r["false_alerts"] for r in runs),
        lights_on_to_alert_median_s=statistics.median(lats) if lats else None,
        lights_on_to_alert_max_s=max(lats) if lats else None,
        decoy_lamp_vehicles=sum(r["decoy_lamp_vehicles"] for r in runs),
        decoy_lamp_modes=dict(sum((Counter(r["decoy_lamp_modes"]) for r in runs), Counter())),
        false_alerts_on_decoy_lamps=sum(r["false_alerts_on_decoy_lamps"] for r in runs),
        detector=args.detector, box_gate=args.box_gate, crop_classifier=args.crop_classifier, ev_body=args.ev_body, seeds=args.seeds, scenarios=args.scenarios, duration_s=args.duration_s,
        fps=15.0, keep_fraction=args.keep_fraction, runtime_s=time.perf_counter() - t0)
    print(f"track recall {figures['track_recall']}  false alerts {figures['false_alerts']}  "
          f"median lights-on->alert {figures['lights_on_to_alert_median_s']}  decoy lamp vehicles seen "
          f"{figures['decoy_lamp_vehicles']} (false alerts on them {figures['false_alerts_on_decoy_lamps']})  "
          f"({figures['runtime_s']:.0f} s)")
    if args.json:
        print(json.dumps(figures))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
