"""Dataset export (thesis 2.1): rendered RSU frames with ground truth, for training and evaluation.

Writes under ``out``:
- ``det/images/{train,val}/*.jpg`` and ``det/labels/{train,val}/*.txt``: a detection set in
  Darknet/YOLO form, one line ``class x_centre y_centre width height`` per vehicle, relative to the
  image size; classes (``det/obj.names``) 0 = vehicle, 1 = ev. Class ``ev`` is an emergency vehicle
  whose light bar is switched on (an active EV, the thing the corridor must react to); an EV with its
  lights off is labelled ``vehicle``, like its lookalikes. Boxes are the visible part of each vehicle as
  rendered (occluded parts cut off); vehicles less than ``min_visible_fraction`` visible are left out.
  ``det/train.txt``, ``det/val.txt`` list the images, ``det/data.yaml`` describes the set.
- ``cls/{train,val}/{ev,non_ev}/*.png``: crops of well-visible vehicles like RAVEV, positives = EV
  with lights on, negatives = every other vehicle (including red/white vans, red and blue cars, brake
  lights and EVs with lights off).
- ``mot/{train,val}/{sequence}/gt/gt.txt`` + ``seqinfo.ini``: per-sequence (episode x RSU) ground
  truth in MOTChallenge form ``frame,id,left,top,width,height,consider,class,visibility`` with
  class = 1 vehicle / 2 ev, consider = 0 for vehicles below the visible fraction; ``frames.txt`` maps
  frame numbers to the detection images.
The split is by episode (no frame of a val episode is in train). Export is seeded (same arguments,
same bytes of labels and the same images) and resumable (frames already on disk are not rendered
again; ``info.json`` holds the arguments and a mismatch is refused).
"""

from __future__ import annotations

import json
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import cv2

from sim.render.labels import CLASS_EV, CLASS_NAMES, MIN_VISIBLE_FRACTION, Label
from sim.render.renderer import Renderer
from sim.scenario import Scenario, load_scenario
from sim.world import World


def yolo_line(label: Label, width_px: int, height_px: int) -> str:
    """Darknet/YOLO label line ``class x_centre y_centre w h`` relative to the image (thesis 2.1)."""
    x1, y1, x2, y2 = label.bbox_px
    return (f"{label.class_id} {(x1 + x2) / 2 / width_px:.6f} {(y1 + y2) / 2 / height_px:.6f} "
            f"{(x2 - x1) / width_px:.6f} {(y2 - y1) / height_px:.6f}")


WORLD_DT_S = 0.05
LIGHTING_CYCLE = ("day", "dusk", "night")


@dataclass
class ExportConfig:
    out: str
    frames: int
    scenarios: list[str] = field(default_factory=lambda: ["rellis_ev_yield", "ev_two_lanes_dense", "hazard_in_lane",
                                                          "ev_lights_never_on", "night_ev"])
    seed: int = 0
    stride_s: float = 0.35
    """Sim time between a camera's exported frames. 0.35 s does not alias with 1-4 Hz light bars (0.5 s
    would show a 2 Hz bar in the same phase in every frame)."""
    val_every: int = 5
    """Every val_every-th episode goes to the validation split."""
    vary_lighting: bool = True
    min_visible_fraction: float = MIN_VISIBLE_FRACTION
    crop_min_visible: float = 0.6
    crop_min_px: int = 24
    jpeg_quality: int = 92
    rsus: list[str] = field(default_factory=list)
    """Cameras to export (empty: all of the corridor's)."""


class ExportError(ValueError):
    pass


class _Progress:
    def __init__(self, total: int, enabled: bool) -> None:
        self.total, self.enabled, self.t0, self.done, self.rendered = total, enabled, time.perf_counter(), 0, 0

    def update(self, rendered: bool) -> None:
        self.done += 1
        self.rendered += int(rendered)
        if not self.enabled or (self.done % 5 and self.done != self.total):
            return
        el = time.perf_counter() - self.t0
        rate = self.done / max(el, 1e-6)
        eta = (self.total - self.done) / max(rate, 1e-6)
        n = int(30 * self.done / max(1, self.total))
        sys.stderr.write(f"\r[{'#' * n}{'.' * (30 - n)}] {self.done}/{self.total} frames "
                         f"({self.rendered} rendered, {self.done - self.rendered} resumed) {rate:.1f}/s eta {eta:.0f}s")
        if self.done == self.total:
            sys.stderr.write("\n")
        sys.stderr.flush()


def _episode(cfg: ExportConfig, scenarios: list[Scenario], e: int) -> Scenario:
    base = scenarios[e % len(scenarios)]
    lighting = base.lighting
    if cfg.vary_lighting:  # each pass over the scenarios moves on by one lighting
        lighting = LIGHTING_CYCLE[(LIGHTING_CYCLE.index(base.lighting) + e // len(scenarios)) % len(LIGHTING_CYCLE)]
    return base.with_overrides(seed=cfg.seed * 100_003 + e * 7919 + base.seed, lighting=lighting)


def export_dataset(cfg: ExportConfig, progress: bool = True) -> dict:
    """Export ``cfg.frames`` frames; returns counts. Raises ExportError on bad arguments."""
    if cfg.frames < 1:
        raise ExportError(f"frames must be >= 1, got {cfg.frames}")
    if not WORLD_DT_S <= cfg.stride_s <= 60:
        raise ExportError(f"stride_s must be in [{WORLD_DT_S}, 60], got {cfg.stride_s}")
    steps = int(round(cfg.stride_s / WORLD_DT_S))
    aliased = [f for f in (1.0, 2.0, 3.0, 4.0) if abs(steps * WORLD_DT_S * f - round(steps * WORLD_DT_S * f)) < 1e-9]
    if aliased and progress:
        sys.stderr.write(f"warning: stride {steps * WORLD_DT_S:g} s is a multiple of the period of {aliased} Hz "
                         f"light bars: every frame of an episode shows them in the same phase\n")
    out = Path(cfg.out)
    out.mkdir(parents=True, exist_ok=True)
    info_path = out / "info.json"
    info = {"format": 1, "config": {k: v for k, v in asdict(cfg).items() if k not in ("out", "frames")}}
    if info_path.exists():
        old = json.loads(info_path.read_text())
        if old.get("config") != info["config"]:
            raise ExportError(f"{out} holds an export made with other settings ({old.get('config')}); "
                              f"use another --out or the same settings to resume")
    info_path.write_text(json.dumps(info, indent=1))
    scenarios = [load_scenario(s) for s in cfg.scenarios]
    if not scenarios:
        raise ExportError("no scenarios given")
    det = out / "det"
    for split in ("train", "val"):
        (det / "images" / split).mkdir(parents=True, exist_ok=True)
        (det / "labels" / split).mkdir(parents=True, exist_ok=True)
        for c in ("ev", "non_ev"):
            (out / "cls" / split / c).mkdir(parents=True, exist_ok=True)
    (det / "obj.names").write_text("\n".join(CLASS_NAMES) + "\n")
    lists: dict[str, list[str]] = {"train": [], "val": []}
    counts = {"frames": 0, "rendered": 0, "labels": 0, "ev_labels": 0, "crops_ev": 0, "crops_non_ev": 0}
    bar = _Progress(cfg.frames, progress)
    stride_steps = max(1, int(round(cfg.stride_s / WORLD_DT_S)))
    e = 0
    while counts["frames"] < cfg.frames:
        sc = _episode(cfg, scenarios, e)
        split = "val" if cfg.val_every > 0 and e % cfg.val_every == cfg.val_every - 1 else "train"
        rsus = [r for r in sc.corridor.rsus if not cfg.rsus or r.rsu_id in cfg.rsus]
        if not rsus:
            raise ExportError(f"none of the cameras {cfg.rsus} is in corridor {sc.corridor.corridor_id}")
        renderers = {r.rsu_id: Renderer(r.camera, sc.corridor.road, seed=sc.seed) for r in rsus}
        world = World(sc)
        track_ids = {v.vehicle_id: i + 1 for i, v in enumerate(world.vehicles())}
        mot: dict[str, list[str]] = {r.rsu_id: [] for r in rsus}
        mot_frames: dict[str, list[str]] = {r.rsu_id: [] for r in rsus}
        n_steps = int(sc.duration_s / WORLD_DT_S)
        k = 0
        for step in range(1, n_steps + 1):
            world.step(WORLD_DT_S)
            if step % stride_steps or counts["frames"] >= cfg.frames:
                continue
            k += 1
            snap = world.snapshot()
            for rsu in rsus:
                if counts["frames"] >= cfg.frames:
                    break
                r = renderers[rsu.rsu_id]
                stem = f"e{e:04d}_{sc.name}_{rsu.rsu_id}_{k:05d}"
                img_path = det / "images" / split / f"{stem}.jpg"
                lab_path = det / "labels" / split / f"{stem}.txt"
                labels = r.labels(snap, cfg.min_visible_fraction, include_dropped=True)
                kept = [lb for lb in labels if lb.visible_fraction >= cfg.min_visible_fraction]
                img = None
                rendered = False
                if not (img_path.exists() and lab_path.exists()):
                    img = r.render(snap, frame_index=int(round(snap.sim_time_s * rsu.camera.fps)))
                    cv2.imwrite(str(img_path), img, [cv2.IMWRITE_JPEG_QUALITY, cfg.jpeg_quality])
                    lab_path.write_text("".join(yolo_line(lb, r.w, r.h) + "\n" for lb in kept))
                    rendered = True
                lists[split].append(str(img_path.relative_to(out)))
                counts["labels"] += len(kept)
                counts["ev_labels"] += sum(lb.class_id == CLASS_EV for lb in kept)
                for lb in labels:
                    if lb.visible_fraction <= 0:
                        continue
                    x1, y1, x2, y2 = lb.bbox_px
                    consider = int(lb.visible_fraction >= cfg.min_visible_fraction)
                    mot[rsu.rsu_id].append(f"{k},{track_ids.get(lb.actor_id, 0)},{x1:.1f},{y1:.1f},{x2 - x1:.1f},"
                                           f"{y2 - y1:.1f},{consider},{lb.class_id + 1},{lb.visible_fraction:.3f}")
                mot_frames[rsu.rsu_id].append(f"{k} {img_path.relative_to(out)}")
                for lb in kept:
                    x1, y1, x2, y2 = lb.bbox_px
                    if lb.visible_fraction < cfg.crop_min_visible or min(x2 - x1, y2 - y1) < cfg.crop_min_px:
                        continue
                    cname = "ev" if lb.class_id == CLASS_EV else "non_ev"
                    crop_path = out / "cls" / split / cname / f"{stem}_{lb.actor_id}.png"
                    counts[f"crops_{cname}"] += 1
                    if crop_path.exists():
                        continue
                    if img is None:
                        img = cv2.imread(str(img_path))
                    mx, my = 0.08 * (x2 - x1), 0.08 * (y2 - y1)
                    cx1, cy1 = max(0, int(x1 - mx)), max(0, int(y1 - my))
                    cx2, cy2 = min(r.w, int(x2 + mx) + 1), min(r.h, int(y2 + my) + 1)
                    cv2.imwrite(str(crop_path), img[cy1:cy2, cx1:cx2])
                counts["frames"] += 1
                counts["rendered"] += int(rendered)
                bar.update(rendered)
        for rsu in rsus:
            if not mot_frames[rsu.rsu_id]:
                continue
            seq = out / "mot" / split / f"e{e:04d}_{sc.name}_{rsu.rsu_id}"
            (seq / "gt").mkdir(parents=True, exist_ok=True)
            (seq / "gt" / "gt.txt").write_text("".join(line + "\n" for line in mot[rsu.rsu_id]))
            (seq / "frames.txt").write_text("".join(line + "\n" for line in mot_frames[rsu.rsu_id]))
            (seq / "seqinfo.ini").write_text(
                f"[Sequence]\nname={seq.name}\nimDir=../../../det/images/{split}\nframeRate={1.0 / (stride_steps * WORLD_DT_S):g}\n"
                f"seqLength={len(mot_frames[rsu.rsu_id])}\nimWidth={renderers[rsu.rsu_id].w}\n"
                f"imHeight={renderers[rsu.rsu_id].h}\nimExt=.jpg\n")
        e += 1
    for split, items in lists.items():
        (det / f"{split}.txt").write_text("".join(p + "\n" for p in items))
    (det / "data.yaml").write_text(f"path: {out.resolve()}\ntrain: det/images/train\nval: det/images/val\n"
                                   f"nc: {len(CLASS_NAMES)}\nnames: {list(CLASS_NAMES)}\n")
    counts["episodes"] = e
    (out / "counts.json").write_text(json.dumps(counts, indent=1))
    return counts


def render_views(scenario: str, t_s: float, out: str | Path, *, rsus: list[str] = (), seed: int | None = None,
                 lighting: str | None = None, boxes: bool = False) -> list[Path]:
    """``iea-sim render``: one PNG per RSU camera (``rsus``: only these) of scenario ``scenario`` at sim time
    ``t_s``, in folder ``out``; ``boxes`` draws the ground-truth label boxes. The paths written."""
    sc = load_scenario(scenario).with_overrides(seed=seed, lighting=lighting)
    world = World(sc)
    world.run_until(t_s)
    snap = world.snapshot()
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for rsu in sc.corridor.rsus:
        if rsus and rsu.rsu_id not in rsus:
            continue
        r = Renderer(rsu.camera, sc.corridor.road, seed=world.seed)
        img = r.render(snap)
        if boxes:
            for lb in r.labels(snap):
                x1, y1, x2, y2 = (int(round(v)) for v in lb.bbox_px)
                cv2.rectangle(img, (x1, y1), (x2, y2), (0, 255, 255) if lb.class_id else (0, 255, 0), 1)
        path = out / f"{sc.name}_{rsu.rsu_id}_t{t_s:06.2f}.png"
        cv2.imwrite(str(path), img)
        written.append(path)
    return written
