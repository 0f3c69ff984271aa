"""``python -m studies.clemson export``: the driving data set of the Clemson comparison (report ch. 4).

The teacher (``studies.clemson.driving``: the thesis controller under the DDM's hazard rule with perfect knowledge)
drives seeded hazard episodes; every ``stride_s`` the three dashboard cameras (``studies.clemson.dashcam``: centre,
left, right) are rendered at the car's true pose, each with its label mask of the debris, the radar's
(lx, ly) and threat value (eq. 2-3) as seen from that camera's place, the image threat value (eq. 4 on the
label mask) and the steering angle. The side cameras' angle is the teacher's plus the correction that
brings a car offset by ``SIDE_CAMERA_OFFSET_M`` back to the path over ``RECOVERY_M`` (pure pursuit:
delta = atan(2 L e / Ld^2)), DAVE-2's recovery views.

Augmentation (report 4.3: random rotation, random brightness, horizontal flip; the data set doubled): train
and validation frames get one augmented copy each, rotated by U(-3, 3) deg, brightness scaled by
U(0.7, 1.3) and, with probability 1/2, flipped left-right with the angle negated (and the mask flipped).
Test frames are not augmented.

Split by episode seed: ``train`` seeds 0.., ``val`` 1000.., ``test`` 2000.. (the bench's held-out
scenarios); a quarter of the train and val episodes have no debris (lane keeping only, as most of the
report's frames). Output: ``{out}/{train,val,test}.npz`` and ``{out}/meta.json``.
"""

from __future__ import annotations

import json
import math
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import cv2
import numpy as np

from ddm.threat import image_threat
from studies.clemson.dashcam import SIDE_CAMERA_OFFSET_M, DashCamera, hazard_mask
from studies.clemson.driving import make_scenario, run, simulated_radar
from studies.clemson.learned_steering import normalise_steer, radar_threat
from vehicle.plant import VehicleParams

RECOVERY_M = 12.0
SPLIT_SEED_BASE = {"train": 0, "val": 1000, "test": 2000}
MAX_ROTATION_DEG, BRIGHTNESS = 3.0, (0.7, 1.3)


@dataclass(frozen=True)
class DrivingExportConfig:
    out: str
    train_episodes: int = 24
    val_episodes: int = 6
    test_episodes: int = 8
    stride_s: float = 0.2
    seed: int = 0
    """Seed of the augmentation and of the sensors' noise."""
    episode_offset: int = 0
    """Train seeds start at this (val at 1000 + it): a second export with other roads."""
    late_triggers_m: tuple[float, ...] = ()
    """Train/val debris episodes cycle through the DDM's trigger and these late ones (``studies.clemson.driving.run``'s
    ``late_trigger_m``): demonstrations of avoiding debris seen late."""

    def __post_init__(self) -> None:
        for name in ("train_episodes", "val_episodes", "test_episodes"):
            if getattr(self, name) < 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)}")
        if self.train_episodes + self.val_episodes + self.test_episodes == 0:
            raise ValueError("nothing to export: give at least one episode")
        if not 0 <= self.episode_offset < 1000 - max(self.train_episodes, self.val_episodes):
            raise ValueError(f"episode_offset must keep train and val seeds under 1000 and 2000 (the test seeds), "
                             f"got {self.episode_offset}")
        if any(not 5.0 <= t <= 60.0 for t in self.late_triggers_m):
            raise ValueError(f"late_triggers_m must be in [5, 60] m, got {self.late_triggers_m}")
        if not 0.1 <= self.stride_s <= 5.0 or abs(self.stride_s / 0.1 - round(self.stride_s / 0.1)) > 1e-6:
            raise ValueError(f"stride_s must be a multiple of 0.1 s in [0.1, 5], got {self.stride_s}")


def side_correction_rad(offset_m: float, params: VehicleParams = VehicleParams()) -> float:
    """Steering that brings a car ``offset_m`` left of the path (> 0: left) back over RECOVERY_M (rad)."""
    return -math.atan(2.0 * params.wheelbase_m * offset_m / RECOVERY_M ** 2)


def augment(image: np.ndarray, mask: np.ndarray, steer_rad: float, rng: np.random.Generator
            ) -> tuple[np.ndarray, np.ndarray, float, bool]:
    """Report 4.3: random rotation and brightness, and a flip with the angle negated (returns flipped?)."""
    h, w = mask.shape
    rot = cv2.getRotationMatrix2D((w / 2.0, h / 2.0), float(rng.uniform(-MAX_ROTATION_DEG, MAX_ROTATION_DEG)), 1.0)
    img = cv2.warpAffine(image, rot, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    msk = cv2.warpAffine(mask, rot, (w, h), flags=cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT)
    img = np.clip(img.astype(np.float32) * float(rng.uniform(*BRIGHTNESS)), 0, 255).astype(np.uint8)
    flip = bool(rng.uniform() < 0.5)
    if flip:
        img, msk, steer_rad = img[:, ::-1].copy(), msk[:, ::-1].copy(), -steer_rad
    return img, msk, steer_rad, flip


def episode_frames(seed: int, with_debris: bool, stride_s: float, rng: np.random.Generator,
                   late_trigger_m: float | None = None) -> list[dict]:
    """The three cameras' frames of one teacher episode."""
    sc = make_scenario(seed, with_debris)
    trace = run(sc, "teacher", seed=seed, late_trigger_m=late_trigger_m).arrays()
    cam, actors = DashCamera(sc.road, seed=sc.seed), sc.actors()
    every = int(round(stride_s / 0.1))
    out = []
    for i in range(0, len(trace["t_s"]), every):
        x, y, yaw, t = (float(trace[k][i]) for k in ("x_m", "y_m", "yaw_rad", "t_s"))
        for cam_index, off in ((-1, -SIDE_CAMERA_OFFSET_M), (0, 0.0), (1, SIDE_CAMERA_OFFSET_M)):
            img = cam.render(x, y, yaw, actors, t, off, frame_index=int(round(t * 10)))
            mask = hazard_mask(x, y, yaw, actors, off)
            cx, cy = x - off * math.sin(yaw), y + off * math.cos(yaw)
            radar = simulated_radar(cx, cy, yaw, actors, rng)
            out.append(dict(image=img, mask=mask, steer=float(trace["steer_cmd_rad"][i]) + side_correction_rad(off),
                            radar_lx=math.nan if radar is None else radar[0],
                            radar_ly=math.nan if radar is None else radar[1], radar_tf=radar_threat(radar),
                            seed=seed, t_s=t, camera=cam_index, augmented=False, flipped=False))
    return out


def _pack(frames: list[dict]) -> dict[str, np.ndarray]:
    if not frames:
        return {}
    steer = np.array([f["steer"] for f in frames], np.float32)
    return dict(images=np.stack([f["image"] for f in frames]), masks=np.stack([f["mask"] for f in frames]),
                steer_rad=steer, steer_n=normalise_steer(steer).astype(np.float32),
                radar_lx=np.array([f["radar_lx"] for f in frames], np.float32),
                radar_ly=np.array([f["radar_ly"] for f in frames], np.float32),
                radar_tf=np.array([f["radar_tf"] for f in frames], np.float32),
                image_tf=np.array([image_threat(f["mask"]) for f in frames], np.float32),
                seed=np.array([f["seed"] for f in frames], np.int32), t_s=np.array([f["t_s"] for f in frames]),
                camera=np.array([f["camera"] for f in frames], np.int8),
                augmented=np.array([f["augmented"] for f in frames]), flipped=np.array([f["flipped"] for f in frames]))


def export_driving(cfg: DrivingExportConfig, progress: bool = True) -> dict[str, int]:
    """Write the three splits; returns the frame count of each."""
    out = Path(cfg.out)
    out.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng([23, cfg.seed])
    counts: dict[str, int] = {}
    n_total = cfg.train_episodes + cfg.val_episodes + cfg.test_episodes
    done, t0 = 0, time.perf_counter()
    for split, n in (("train", cfg.train_episodes), ("val", cfg.val_episodes), ("test", cfg.test_episodes)):
        frames: list[dict] = []
        for k in range(n):
            seed = SPLIT_SEED_BASE[split] + k + (cfg.episode_offset if split != "test" else 0)
            with_debris = split == "test" or k % 4 != 3
            triggers = (None, *cfg.late_triggers_m) if split != "test" else (None,)
            ep = episode_frames(seed, with_debris, cfg.stride_s, rng, triggers[k % len(triggers)])
            if split != "test":
                for f in list(ep):
                    img, msk, steer, flip = augment(f["image"], f["mask"], f["steer"], rng)
                    ep.append({**f, "image": img, "mask": msk, "steer": steer, "augmented": True, "flipped": flip})
            frames += ep
            done += 1
            if progress:
                el = time.perf_counter() - t0
                print(f"\r{split} episode {k + 1}/{n} ({len(frames)} frames), {el:.0f} s, "
                      f"~{el / done * (n_total - done):.0f} s left", end="", file=sys.stderr, flush=True)
        if frames:
            np.savez_compressed(out / f"{split}.npz", **_pack(frames))
        counts[split] = len(frames)
    if progress:
        print(file=sys.stderr)
    (out / "meta.json").write_text(json.dumps({"config": asdict(cfg), "counts": counts,
                                               "seed_base": SPLIT_SEED_BASE}, indent=1))
    return counts
