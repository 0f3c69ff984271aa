"""One RSU assembled in one place: which detector, the SORT tracker's settings, the EV classifier,
the hazard detector and the localiser, from one :class:`PipelineConfig`.

``iea-rsu`` (:func:`run_rsu`), ``iea-rsu scan``, the lockstep corridor (``scenario/lockstep.py``), the benches
and the tests build their RSUs here, so an RSU measured by a bench is the RSU a corridor runs. The defaults are
the RSU's (thesis 2.3, Framework B): the project's detector, SORT with ``max_age`` 1, ``min_hits`` 3, IoU 0.3,
ray-plane localisation, the per-track lamp evidence with the EV-body classifier.
"""

from __future__ import annotations

import logging
import signal
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2

from protocol.corridor import Corridor, load_corridor
from protocol.security import TrustList, load_signer
from protocol.zenoh_transport import ZenohSettings, ZenohTransport
from rsu.classify.body import load_body_classifier
from rsu.classify.box_gate import SingleVehicleGate
from rsu.classify.classifiers import load_classifier
from rsu.classify.ev import TrackEvClassifier
from rsu.classify.lamp_state import DEFAULT_LAMP_STATE_MODEL, LampStateModel
from rsu.detect import PROJECT_MODEL, Detector, MotionDetector, vehicle_detector
from rsu.detect_roi import ROI_MARGIN_M, detection_roi, zone_box_px
from rsu.frames import FrameSource, ImageFolderSource, VideoSource
from rsu.hazard import HazardConfig, HazardDetector
from rsu.localize import INTERPOLATIONS, METHODS, Localizer
from rsu.pipeline import RsuPipeline
from rsu.service import RsuService
from rsu.sim_source import SimSource
from rsu.track.frameworks import FrameworkTracker

log = logging.getLogger(__name__)

MOTION = "motion"
PROJECT = "project"


@dataclass(frozen=True)
class PipelineConfig:
    """How one RSU's pipeline is built; every field is checked at construction."""

    detector: str = PROJECT
    """``project`` (models/iea_det_tiny.onnx), ``motion`` (MOG2 background subtraction, no model) or the path of
    a YOLOX-layout ONNX model (e.g. the COCO YOLOX-Nano of ../shared/data/real)."""
    score_threshold: float = 0.3
    """An ONNX detector's box score threshold."""
    motion_min_area_px: float = 150.0
    """The motion detector's smallest box (pixels of the full frame)."""
    providers: tuple[str, ...] | str | None = None
    """onnxruntime providers of an ONNX detector: None (CPU), ``auto`` or a tuple of names."""
    threads: int | None = 1
    """CPU threads of the ONNX detector and the EV classifiers (None: onnxruntime's default, all cores, for the
    detector; one for the classifiers)."""
    framework: str = "B"
    """``B``: one class, every vehicle tracked alike (thesis 2.3); ``A``: a tracker per class (thesis 2.2)."""
    max_age: int = 1
    min_hits: int = 3
    iou_threshold: float = 0.3
    localization: str = "transform"
    """``transform``: ray-plane back-projection; ``reference``: interpolate the calibration pairs."""
    interpolation: str = "homography+rbf"
    detect_roi: bool = True
    """An ONNX detector of any input size searches only the part of the frame where the RSU's zone of
    responsibility (``max_range_m`` + ``rsu.detect_roi.ROI_MARGIN_M``) lies (needs the camera's calibration)."""
    ev_classifier: bool = True
    """Per-track lamp evidence (:class:`~rsu.classify.ev.TrackEvClassifier`) and EV alerts."""
    ev_body: str | None = "default"
    """EV-body classifier: ``default`` (models/ev_body.onnx), ``none`` / None, or a path."""
    ev_lamp_state: str | None = "default"
    """Lamp-state model (p(warning lamps lit) of the lamp band): ``default`` (models/lamp_state.onnx), ``none`` /
    None, or a path."""
    ev_crop_classifier: str = "none"
    """Per-crop EV probability fused into the evidence: ``none``, ``cnn``, ``hsv8-gb`` or PATH.onnx[:FEATURE]."""
    ev_box_gate: bool = False
    """No lamp measurement on boxes wider than one vehicle at their range (needs the camera's calibration)."""
    classifier_tuning: dict[str, Any] = field(default_factory=dict)
    """Further keyword arguments of ``TrackEvClassifier`` (ablations in ``bench/ev_bench.py``)."""
    hazards: bool = False
    """Static objects that appear in a lane reported as hazards (:class:`~rsu.hazard.HazardDetector`)."""
    hazard_background: str | None = None
    """A frame of the empty road from this camera: the hazard detector starts from it."""

    def __post_init__(self) -> None:
        if self.threads is not None and self.threads < 1:
            raise ValueError(f"threads must be >= 1 (or None: all cores), got {self.threads}")
        if self.framework not in ("A", "B"):
            raise ValueError(f"framework must be 'A' or 'B', got {self.framework!r}")
        if self.localization not in METHODS:
            raise ValueError(f"localization must be one of {METHODS}, got {self.localization!r}")
        if self.interpolation not in INTERPOLATIONS:
            raise ValueError(f"interpolation must be one of {INTERPOLATIONS}, got {self.interpolation!r}")


def build_detector(config: PipelineConfig, corridor: Corridor | None = None, rsu_id: str | None = None) -> Detector:
    """The configured detector; an ONNX model runs as an RSU runs it (:func:`rsu.detect.vehicle_detector`:
    in Framework B a project-layout model scores its two classes as one). Given the corridor and the RSU, a model
    of any input size searches only where the RSU's zone of responsibility lies in its frame (``detect_roi``,
    :mod:`rsu.detect_roi`). Raises FileNotFoundError for a missing model."""
    if config.detector == MOTION:
        return MotionDetector(min_area_px=config.motion_min_area_px)
    providers = config.providers
    if isinstance(providers, tuple):
        providers = list(providers)
    model = PROJECT_MODEL if config.detector == PROJECT else Path(config.detector)
    det = vehicle_detector(model, framework=config.framework, score_threshold=config.score_threshold,
                           providers=providers, intra_op_threads=config.threads)
    if config.detect_roi and corridor is not None and rsu_id is not None and det.any_input_size:
        rsu = corridor.rsu(rsu_id)
        if rsu.max_range_m is not None:
            cam = rsu.camera
            box = zone_box_px(cam, corridor.road, rsu.position, rsu.max_range_m + ROI_MARGIN_M)
            scale = min(det.input_hw[0] / cam.height_px, det.input_hw[1] / cam.width_px)
            det.search_window(*detection_roi(box, (cam.width_px, cam.height_px), scale))
    return det


def build_tracker(config: PipelineConfig) -> FrameworkTracker:
    return FrameworkTracker(config.framework, config.max_age, config.min_hits, config.iou_threshold)


def build_classifier(config: PipelineConfig, corridor: Corridor | None = None,
                     rsu_id: str | None = None) -> TrackEvClassifier | None:
    """The per-track EV classifier, or None when ``config.ev_classifier`` is off. ``ev_box_gate`` needs the
    corridor and the RSU (its camera)."""
    if not config.ev_classifier:
        return None
    threads = config.threads or 1
    kw = dict(config.classifier_tuning)
    if config.ev_crop_classifier != "none":
        kw["crop_score"] = load_classifier(config.ev_crop_classifier, threads=threads)
    if config.ev_box_gate:
        if corridor is None or rsu_id is None:
            raise ValueError("ev_box_gate needs the corridor and the RSU id (its camera calibration)")
        kw["box_gate"] = SingleVehicleGate(corridor.rsu(rsu_id).camera, corridor.road)
    if config.ev_lamp_state not in (None, "none"):
        kw.setdefault("lamp_state", LampStateModel(DEFAULT_LAMP_STATE_MODEL if config.ev_lamp_state == "default"
                                                   else config.ev_lamp_state))
    return TrackEvClassifier(body=load_body_classifier(config.ev_body, threads=threads), **kw)


def build_hazards(config: PipelineConfig, corridor: Corridor, rsu_id: str,
                  localizer: Localizer) -> HazardDetector | None:
    """The hazard detector on the localiser's ground mapping, primed with ``hazard_background`` when given
    (ValueError when that is not a frame of this camera's size)."""
    if not config.hazards:
        return None
    camera = corridor.rsu(rsu_id).camera
    # the corridor's RSUs look in turn (HazardConfig.phase_s)
    config_h = HazardConfig(phase_s=(corridor.rsu_index(rsu_id) % 4) * HazardConfig().period_s / 4)
    hazards = HazardDetector(corridor.road, localizer.mapper.to_ground, config_h, camera=camera)
    if config.hazard_background:
        empty = cv2.imread(config.hazard_background, cv2.IMREAD_COLOR)
        if empty is None or empty.shape[:2] != (camera.height_px, camera.width_px):
            raise ValueError(f"hazard background {config.hazard_background!r}: not a "
                             f"{camera.width_px}x{camera.height_px} image")
        hazards.prime(empty)
    return hazards


def build_pipeline(config: PipelineConfig, corridor: Corridor | None = None, rsu_id: str | None = None, *,
                   localizer=None) -> RsuPipeline:
    """Detector -> tracker -> EV classifier -> localiser (-> hazards) of RSU ``rsu_id`` of ``corridor``.
    ``localizer``: another localiser (``rsu.scan.ImageOnlyLocalizer`` for a clip with no calibration); the
    corridor is then needed only for hazards and the box gate."""
    if localizer is None:
        if corridor is None or rsu_id is None:
            raise ValueError("build_pipeline needs the corridor and the RSU id, or a localizer")
        localizer = Localizer(corridor, rsu_id, method=config.localization, interpolation=config.interpolation)
    hazards = build_hazards(config, corridor, rsu_id, localizer) if config.hazards else None
    return RsuPipeline(build_detector(config, corridor, rsu_id), build_tracker(config), localizer,
                       build_classifier(config, corridor, rsu_id), hazards=hazards)


def open_source(spec: str, corridor: Corridor, rsu_id: str, transport_factory, *, corridor_id: str | None = None,
                sim_seed: int = 0, fps: float | None = None, realtime: bool = False, read_timeout_s: float = 5.0,
                queue_size: int = 2) -> FrameSource:
    """``sim`` (this RSU's view of the simulator's WorldSnapshot; needs the transport), a folder of images,
    or what OpenCV opens: a video file, a camera index, an rtsp:// or http:// URL."""
    if spec == "sim":
        return SimSource(corridor, rsu_id, transport_factory(), corridor_id=corridor_id, seed=sim_seed,
                         queue_size=queue_size)
    if Path(spec).is_dir():
        return ImageFolderSource(spec, fps or corridor.rsu(rsu_id).camera.fps, source_id=rsu_id)
    return VideoSource(spec, source_id=rsu_id, read_timeout_s=read_timeout_s, queue_size=queue_size,
                       realtime=realtime)


@dataclass(frozen=True)
class ServiceOptions:
    """The service around the pipeline: where frames come from, where it publishes, what it writes."""

    rsu_id: str
    source: str
    """See :func:`open_source`."""
    corridor_file: str | None = None
    corridor_id: str | None = None
    sim_seed: int = 0
    fps: float | None = None
    realtime: bool = False
    read_timeout_s: float = 5.0
    max_stall_s: float | None = None
    queue_size: int = 2
    max_frames: int | None = None
    annotate: str | None = None
    camera_hz: float | None = None
    """Annotated frames a second on the corridor (rsu.camera_feed; None: by source kind)."""
    uplink_bit_s: float | None = None
    """The uplink's rate: bulk is thinned to fit it (``rsu.uplink``); None: no budget."""
    key: str | None = None
    key_id: str | None = None
    zenoh: ZenohSettings = field(default_factory=ZenohSettings)


def run_rsu(options: ServiceOptions, config: PipelineConfig) -> int:
    """``iea-rsu``: build one RSU, run it over Zenoh until its source ends or SIGTERM/SIGINT; the service's exit
    code. Everything that can be wrong with the options (corridor, RSU id, models, source, key) raises before
    anything is published: CorridorError / KeyError / ValueError / FileNotFoundError / SourceError."""
    corridor = load_corridor(options.corridor_file)
    corridor.rsu(options.rsu_id)
    if config.threads is not None:
        cv2.setNumThreads(config.threads)
    signer = (load_signer(options.key, options.key_id, TrustList.from_corridor(corridor))
              if options.key else None)
    pipeline = build_pipeline(config, corridor, options.rsu_id)
    transport: ZenohTransport | None = None

    def open_transport() -> ZenohTransport:
        nonlocal transport
        transport = transport or ZenohTransport(options.zenoh)
        return transport

    source = open_source(options.source, corridor, options.rsu_id, open_transport, corridor_id=options.corridor_id,
                         sim_seed=options.sim_seed, fps=options.fps, realtime=options.realtime,
                         read_timeout_s=options.read_timeout_s, queue_size=options.queue_size)
    try:
        service = RsuService(corridor, options.rsu_id, source, pipeline, open_transport(),
                             corridor_id=options.corridor_id, annotate_path=options.annotate,
                             max_frames=options.max_frames, read_timeout_s=options.read_timeout_s,
                             max_stall_s=options.max_stall_s, signer=signer, camera_rate_hz=options.camera_hz,
                             uplink_bit_s=options.uplink_bit_s)
        signal.signal(signal.SIGTERM, lambda *_: service.stop())
        signal.signal(signal.SIGINT, lambda *_: service.stop())
        log.info("RSU %s: %s -> %s on %s", options.rsu_id, source.source_id,
                 getattr(pipeline.detector, "name", "detector"), service.objects_key)
        try:
            return service.run()
        finally:
            log.info("RSU %s stopped after %d frames (drops %s, stalls %d)", options.rsu_id, service.frames,
                     getattr(source, "drops", 0), service.stalls)
    finally:
        source.close()
        open_transport().close()
