"""On-board learned steering of the Clemson comparison (Clemson hazard navigation report ch. 3).

The car's own pipeline, from its dashboard camera (66 x 200 BGR, ``studies.clemson.dashcam``) and its radar:

1. hazard segmentation: a small fully convolutional net (``models/driving_seg.onnx``) gives a debris mask;
2. threat value T_f: case 2 from the radar's (lx, ly) by eq. 2-3, case 3 from the mask by eq. 4
   (``ddm.threat``: the same equations the DDM uses), case 1 none;
3. the fused image of eq. 1, I = (1 - T_f) I_original + T_f I_segmented, with I_segmented the mask drawn in
   ``SEGMENTED_BGR`` on black (so T_f also dims the rest of the image: the net sees how threatening it is);
4. the DAVE-2-like net of the case (``models/driving_case{1,2,3}.onnx``: normalisation inside, five
   convolutions, dense layers, one output) gives the steering angle normalised by eq. 5 over
   [-STEER_LIMIT_RAD, +STEER_LIMIT_RAD]; ``denormalise_steer`` turns it back into a road-wheel angle.

``LearnedVehicle`` is the simulated car with that steering: while the thesis core is in DRIVING it applies
the learned angle; in any other mode (a commanded manoeuvre, a stop, the fail-safe's minimal-risk stop) or
when no finite learned angle is there, the core's own command. Runtime needs onnxruntime only.
"""

from __future__ import annotations

import logging
import math
from pathlib import Path

import numpy as np

from ddm.threat import LX_MAX_M, LY_MAX_M, fuse_image, image_threat, threat_value
from protocol.enums import VehicleMode
from vehicle.core import ControlOutput
from vehicle.simulated import SimulatedVehicle

CASES = (1, 2, 3)
STEER_LIMIT_RAD = 0.2
"""Eq. 5's theta_max (= -theta_min): road-wheel angles beyond it are clipped (the teacher stays under 0.1)."""
SEGMENTED_BGR = (255, 0, 255)
MODELS_DIR = Path(__file__).resolve().parents[2] / "models"
log = logging.getLogger("studies.clemson.learned_steering")
INPUT_SHAPE = (66, 200, 3)


def normalise_steer(steer_rad):
    """Eq. 5: theta_n = -0.5 + clip((theta - theta_min) / (theta_max - theta_min), 0, 1), in [-0.5, 0.5]."""
    th = np.asarray(steer_rad, dtype=float)
    return -0.5 + np.clip((th + STEER_LIMIT_RAD) / (2.0 * STEER_LIMIT_RAD), 0.0, 1.0)


def denormalise_steer(steer_n):
    """Inverse of eq. 5 inside the limits (rad)."""
    return (np.asarray(steer_n, dtype=float) + 0.5) * (2.0 * STEER_LIMIT_RAD) - STEER_LIMIT_RAD


def segmented_image(mask: np.ndarray) -> np.ndarray:
    """I_segmented of eq. 1: the hazard pixels of ``mask`` in SEGMENTED_BGR on black (uint8, h x w x 3)."""
    m = np.asarray(mask).astype(bool)
    out = np.zeros((*m.shape, 3), np.uint8)
    out[m] = SEGMENTED_BGR
    return out


def radar_threat(radar: tuple[float, float] | None) -> float:
    """Eq. 2-3 on the radar's (lx, ly) with the report's limits (60 m, one lane 3.7 m); 0 without a target."""
    return 0.0 if radar is None else float(threat_value(radar[0], radar[1], LX_MAX_M, LY_MAX_M))


def case_input(case: int, image: np.ndarray, mask: np.ndarray | None,
               radar: tuple[float, float] | None) -> tuple[np.ndarray, float]:
    """The driving net's input image for ``case`` (1: the camera image; 2: eq. 1 with the radar's T_f;
    3: eq. 1 with the image's T_f, eq. 4) and the T_f used."""
    if case not in CASES:
        raise ValueError(f"case must be one of {CASES}, got {case!r}")
    if image.shape != INPUT_SHAPE or image.dtype != np.uint8:
        raise ValueError(f"the dashcam image must be uint8 {INPUT_SHAPE}, got {image.dtype} {image.shape}")
    if case == 1:
        return image, 0.0
    if mask is None:
        raise ValueError(f"case {case} needs the hazard mask")
    tf = radar_threat(radar) if case == 2 else image_threat(mask)
    return fuse_image(image, segmented_image(mask), tf), tf


def _session(path: Path):
    import onnxruntime as ort

    if not path.is_file():
        raise FileNotFoundError(f"{path} not found: train it with '/tmp/trainenv/bin/python models/train_driving.py' "
                                "(see models/driving.md)")
    opts = ort.SessionOptions()
    opts.intra_op_num_threads, opts.inter_op_num_threads = 1, 1
    return ort.InferenceSession(str(path), opts, providers=["CPUExecutionProvider"])


def _batch(image: np.ndarray) -> np.ndarray:
    """uint8 BGR (h, w, 3) -> float32 (1, 3, h, w), 0-255 (the nets normalise inside: the report's lambda layer)."""
    return np.ascontiguousarray(image.transpose(2, 0, 1)[None].astype(np.float32))


class HazardSegmenter:
    """The on-board debris segmentation (``driving_seg.onnx``): image -> boolean mask."""

    def __init__(self, path: Path | str = MODELS_DIR / "driving_seg.onnx", threshold: float = 0.5) -> None:
        self.session = _session(Path(path))
        self.threshold = threshold

    def __call__(self, image: np.ndarray) -> np.ndarray:
        logits = self.session.run(None, {"image": _batch(image)})[0][0, 0]
        return logits > math.log(self.threshold / (1.0 - self.threshold))


class LearnedSteering:
    """Steering of one case from a dashcam image and the radar: ``__call__`` -> (road-wheel angle rad, T_f)."""

    def __init__(self, case: int, models_dir: Path | str = MODELS_DIR) -> None:
        if case not in CASES:
            raise ValueError(f"case must be one of {CASES}, got {case!r}")
        self.case = case
        d = Path(models_dir)
        self.net = _session(d / f"driving_case{case}.onnx")
        self.segmenter = HazardSegmenter(d / "driving_seg.onnx") if case != 1 else None

    def __call__(self, image: np.ndarray, radar: tuple[float, float] | None) -> tuple[float, float]:
        mask = self.segmenter(image) if self.segmenter is not None else None
        x, tf = case_input(self.case, image, mask, radar)
        steer_n = float(self.net.run(None, {"image": _batch(x)})[0].reshape(-1)[0])
        return float(denormalise_steer(steer_n)), tf


class LearnedVehicle(SimulatedVehicle):
    """``SimulatedVehicle`` steered by ``learned_steer_rad`` (set by the camera loop) while the core is in
    DRIVING; the core's command otherwise. ``applied_steer_rad``: what went to the plant last step."""

    learned_steer_rad: float | None = None
    applied_steer_rad: float = 0.0
    learned_steps: int = 0
    """Control steps steered by the learned angle."""

    @classmethod
    def adopt(cls, sim: SimulatedVehicle) -> LearnedVehicle:
        """Turn a running ``SimulatedVehicle`` (a service's) into a learned one, state kept."""
        sim.__class__ = cls
        return sim  # type: ignore[return-value]

    def plant_steer_rad(self, out: ControlOutput) -> float:
        """The learned angle while the core is DRIVING (clipped to the steering limit), the core's otherwise."""
        steer = out.steer_cmd_rad
        learned = self.learned_steer_rad
        if out.mode == VehicleMode.DRIVING and learned is not None and math.isfinite(learned):
            steer = float(np.clip(learned, -STEER_LIMIT_RAD, STEER_LIMIT_RAD))
            self.learned_steps += 1
        self.applied_steer_rad = steer
        return steer


class CameraLoop:
    """The vehicle process's learned steering (``python -m studies.clemson vehicle --case CASE``): the simulator's
    world snapshots (``iea/{c}/sim/world``) give the scene; every ``period_s`` the dashcam is rendered at
    the car's true pose (``studies.clemson.dashcam``: the camera is on the car), the radar measures the debris
    (``studies.clemson.driving.simulated_radar``), and ``steering`` sets ``vehicle.learned_steer_rad``. Without a
    snapshot newer than ``stale_s`` the learned angle is withdrawn and the thesis controller steers."""

    def __init__(self, vehicle: LearnedVehicle, road, steering, vehicle_id: str, period_s: float = 0.1,
                 stale_s: float = 0.5, seed: int = 0) -> None:
        from studies.clemson.dashcam import DashCamera

        self.vehicle, self.steering, self.vehicle_id = vehicle, steering, vehicle_id
        self.camera = DashCamera(road, seed=seed)
        self.period_s, self.stale_s = period_s, stale_s
        self.rng = np.random.default_rng(seed)
        self.snapshot = None
        self.snapshot_at_s = -math.inf
        self.frames = 0
        self.last_threat = 0.0
        self.engaged = False

    def on_world(self, snapshot, now_s: float) -> None:
        self.snapshot, self.snapshot_at_s = snapshot, now_s

    def tick(self, now_s: float) -> float | None:
        """One camera frame: the learned angle set (rad), or None when the world is stale."""
        from protocol.enums import ActorKind
        from studies.clemson.driving import simulated_radar

        snap = self.snapshot
        if snap is None or now_s - self.snapshot_at_s > self.stale_s:
            self.vehicle.learned_steer_rad = None
            if self.engaged:
                log.warning("learned steering withdrawn: no world snapshot for %.1f s", now_s - self.snapshot_at_s)
                self.engaged = False
            return None
        st = self.vehicle.truth
        actors = [a for a in snap.actors if a.actor_id != self.vehicle_id]
        img = self.camera.render(st.x_m, st.y_m, st.yaw_rad, actors, snap.sim_time_s, frame_index=self.frames)
        debris = [a for a in actors if a.kind == ActorKind.DEBRIS]
        radar = simulated_radar(st.x_m, st.y_m, st.yaw_rad, debris, self.rng, self.vehicle.core.config.params.length_m)
        steer, self.last_threat = self.steering(img, radar)
        self.vehicle.learned_steer_rad = steer
        self.frames += 1
        if not self.engaged:
            log.info("learned steering engaged: first dashcam frame, %.4f rad", steer)
            self.engaged = True
        return steer


def attach_camera(service, transport, case: int, models_dir: Path | str = MODELS_DIR) -> CameraLoop:
    """Give a ``vehicle.service.VehicleService`` the learned steering of ``case``: its car becomes a
    ``LearnedVehicle``, a ``CameraLoop`` listens to the simulator's world and runs in a daemon thread."""
    import threading

    from protocol.keys import sim_world_key

    steering = LearnedSteering(case, models_dir)
    vehicle = LearnedVehicle.adopt(service.sim)
    loop = CameraLoop(vehicle, service.corridor.road, steering, service.vehicle_id)
    clock = service.clock
    sub = transport.subscribe(sim_world_key(service.corridor.corridor_id), lambda _k, msg: loop.on_world(msg, clock.now()))
    service._subs.append(sub)  # closed with the service

    def run() -> None:
        while not service._stop.is_set():
            t0 = clock.now()
            loop.tick(t0)
            clock.sleep(max(0.0, loop.period_s - (clock.now() - t0)))
        vehicle.learned_steer_rad = None

    threading.Thread(target=run, name="learned-steering", daemon=True).start()
    return loop
