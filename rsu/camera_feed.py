"""An RSU's annotated camera frames on the corridor, for Foxglove and Lichtblick (and recordings).

At most ``rate_hz`` frames a second (the clock is the service's: simulated time in a lockstep run), the
annotated frame (the corridor overlay and the tracked boxes, as ``--annotate`` writes them) is JPEG
encoded (``quality``) and published (scaled to ``max_width_px``) on ``iea/<c>/rsu/<rsu>/camera/jpeg`` as ``foxglove.CompressedImage``
JSON (``protocol.foxglove_msgs``; its ``frame_id`` is the RSU id). Frames are large (tens of kB), so an
operator chooses the rate: ``default_rate_hz`` gives a few a second from a simulated camera and none
from a real one unless asked.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from typing import Any

from protocol.foxglove_msgs import compressed_image
from protocol.keys import rsu_camera_key

DEFAULT_SIM_RATE_HZ = 2.0
MAX_RATE_HZ = 30.0
DEFAULT_QUALITY = 70
DEFAULT_MAX_WIDTH_PX = 640
"""Frames wider than this are scaled down (aspect kept) before encoding: a 1280x720 frame is ~125 kB as
JPEG at quality 70, ~35 kB at 640x360."""


def default_rate_hz(source: Any, asked_hz: float | None) -> float:
    """The frame rate to publish: what the operator asked, else ``DEFAULT_SIM_RATE_HZ`` for a simulated
    camera (a source that renders: ``last_render_times_s``) and 0 (off) for a real one."""
    if asked_hz is not None:
        return validate_rate_hz(asked_hz)
    return DEFAULT_SIM_RATE_HZ if hasattr(source, "last_render_times_s") else 0.0


def validate_rate_hz(rate_hz: float) -> float:
    if not (0.0 <= rate_hz <= MAX_RATE_HZ):
        raise ValueError(f"camera frame rate {rate_hz} Hz is outside 0..{MAX_RATE_HZ:g} (0: off)")
    return float(rate_hz)


def encode_frame(image_bgr: Any, t_s: float, frame_id: str, quality: int = DEFAULT_QUALITY,
                 max_width_px: int = DEFAULT_MAX_WIDTH_PX) -> bytes:
    """One frame (scaled to at most ``max_width_px`` wide) as ``foxglove.CompressedImage`` JSON bytes."""
    import cv2

    h, w = image_bgr.shape[:2]
    if w > max_width_px:
        image_bgr = cv2.resize(image_bgr, (max_width_px, max(1, round(h * max_width_px / w))),
                               interpolation=cv2.INTER_AREA)
    ok, jpeg = cv2.imencode(".jpg", image_bgr, [int(cv2.IMWRITE_JPEG_QUALITY), int(quality)])
    if not ok:
        raise ValueError("JPEG encoding failed")
    return json.dumps(compressed_image(t_s, frame_id, jpeg.tobytes()), separators=(",", ":")).encode()


class CameraFeed:
    """Publishes an RSU's annotated frames at ``rate_hz`` on ``transport`` (``publish_bytes``)."""

    def __init__(self, transport: Any, corridor_id: str, rsu_id: str, rate_hz: float,
                 quality: int = DEFAULT_QUALITY, max_width_px: int = DEFAULT_MAX_WIDTH_PX) -> None:
        if not 1 <= quality <= 100:
            raise ValueError(f"JPEG quality {quality} is outside 1..100")
        self.transport = transport
        self.key = rsu_camera_key(corridor_id, rsu_id)
        self.rsu_id = rsu_id
        self.rate_hz = validate_rate_hz(rate_hz)
        self.quality = quality
        self.max_width_px = max_width_px
        self._next_s: float | None = None
        self.published = 0
        self.bytes_published = 0
        self.unwatched = 0
        """Frames due while no subscriber matched the key (not encoded: Zenoh would send them nowhere)."""

    def due(self, now_s: float) -> bool:
        """True when a frame is due at ``now_s`` (then the next is due a period later, missed ones skipped)."""
        if self.rate_hz <= 0.0:
            return False
        if self._next_s is not None and now_s + 1e-9 < self._next_s:
            return False
        period = 1.0 / self.rate_hz
        nxt = now_s if self._next_s is None else self._next_s
        while nxt <= now_s + 1e-9:
            nxt += period
        self._next_s = nxt
        return True

    def offer(self, now_s: float, make_image: Callable[[], Any]) -> bool:
        """Publish ``make_image()`` (BGR) if a frame is due and someone subscribes to the key; the image is made
        only then."""
        if not self.due(now_s):
            return False
        if not self.transport.wait_for_subscribers(self.key, 0.0):  # nobody watches: no JPEG to encode
            self.unwatched += 1
            return False
        payload = encode_frame(make_image(), now_s, self.rsu_id, self.quality, self.max_width_px)
        self.transport.publish_bytes(self.key, payload)
        self.published += 1
        self.bytes_published += len(payload)
        return True
