"""Frame sources for the RSU: video files, cameras and streams (OpenCV), image folders, arrays.

Every source yields :class:`Frame` objects (BGR image, capture time, frame number, source id) through
``read(timeout_s)`` and iteration, and follows the :class:`FrameSource` protocol, so the simulator's
camera (``sim``) plugs in the same way. A source that ends returns ``None`` from ``read``; a source
that stalls (no frame within the timeout, e.g. a dead RTSP stream or a camera that never opens)
raises :class:`SourceStalled` instead of blocking the caller.

``VideoSource`` reads in a small background thread into a bounded queue (1-2 frames): a slow
consumer of a live source gets the newest frames and the older ones are dropped and counted; a file
is read at the consumer's pace with no drops. Timestamps come from the container
(``CAP_PROP_POS_MSEC``) when it gives them, else from frame number / fps; live input (camera, URL)
is stamped with the wall clock (UNIX seconds) when the frame is grabbed. A reader thread blocked
inside a dead stream cannot be interrupted by OpenCV: ``close`` then leaves it (a daemon thread).
"""

from __future__ import annotations

import os
import queue
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff", ".webp", ".ppm", ".pgm")


class SourceError(RuntimeError):
    """A source that cannot be opened or read at all (bad path, unsupported format)."""


class SourceStalled(TimeoutError):
    """No frame arrived within the read timeout: the source is alive but silent, or never opened."""


@dataclass(frozen=True)
class Frame:
    image: np.ndarray
    """H x W x 3 uint8, BGR (OpenCV order)."""
    timestamp_s: float
    """Capture time in seconds: media time for files and folders, UNIX time for live input."""
    frame_number: int
    """0-based index of the frame in its source (counts dropped frames too)."""
    source_id: str

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) in pixels."""
        return int(self.image.shape[1]), int(self.image.shape[0])


class FrameSource:
    """What the RSU service needs from a camera: frames, and what it reports about them. Every source derives
    from it and overrides what applies to it; the service reads these attributes and nothing else."""

    source_id: str = "source"
    fps: float | None = None
    """Frames per second, None when unknown."""
    drops: int = 0
    """Frames dropped because the consumer was slow (a live source keeps the newest)."""
    stamps_capture_time: bool = False
    """Are frames stamped with the wall-clock capture time? Then the RSU reports each frame's age at publication."""
    last_render_times_s: tuple[float, float] | None = None
    """A simulated camera rendering in the RSU's process: (wall, CPU) seconds the last frame took to render."""

    def read(self, timeout_s: float | None = None) -> Frame | None:
        """Next frame; ``None`` once the source has ended; raises SourceStalled after ``timeout_s``."""
        raise NotImplementedError

    def close(self) -> None:
        """Release the camera or file."""

    def __iter__(self) -> Iterator[Frame]:
        while True:
            frame = self.read()
            if frame is None:
                return
            yield frame

    def __enter__(self):
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


_END = object()


def _parse_uri(uri: str | int | os.PathLike) -> tuple[str | int, bool]:
    """(argument for cv2.VideoCapture, is_live). Camera index or URL -> live; an existing file -> not."""
    if isinstance(uri, int):
        return uri, True
    text = os.fspath(uri)
    if text.isdigit():
        return int(text), True
    if "://" in text:
        return text, not text.startswith("file://")
    if not Path(text).exists():
        raise SourceError(f"video source {text!r}: no such file (give a file, a camera index or an rtsp/http URL)")
    return text, False


class VideoSource(FrameSource):
    """A video file, a camera index or an RTSP/HTTP URL through ``cv2.VideoCapture``.

    ``read_timeout_s`` bounds every ``read``; ``open_timeout_s`` bounds opening (done in the reader
    thread, so a URL that never answers cannot hang the caller). ``live`` (default: camera or URL)
    makes the queue drop its oldest frame when the consumer is slow; ``drops`` counts them.
    ``realtime`` plays a file at its own frame rate as a live source (for demos and service tests).
    ``capture_factory`` replaces ``cv2.VideoCapture`` (tests).
    """

    @property
    def stamps_capture_time(self) -> bool:
        """Are frames stamped with the wall-clock capture time (live input, not a file played in real time)? Then
        the RSU reports each frame's age at publication (``RsuService``)."""
        return self.live and not self.realtime

    def __init__(self, uri: str | int | os.PathLike, *, source_id: str | None = None,
                 read_timeout_s: float = 5.0, open_timeout_s: float = 10.0, queue_size: int = 2,
                 live: bool | None = None, realtime: bool = False,
                 capture_factory: Callable[[Any], Any] | None = None) -> None:
        if not 1 <= queue_size <= 64:
            raise ValueError(f"queue_size must be in [1, 64], got {queue_size}")
        self._arg, auto_live = _parse_uri(uri)
        self.live = auto_live if live is None else live
        self.realtime = realtime
        if realtime:  # a file played at its own rate behaves like a camera: late frames are dropped
            self.live = True
        self.source_id = source_id or (f"camera{self._arg}" if isinstance(self._arg, int) else Path(str(self._arg)).name)
        self.read_timeout_s = read_timeout_s
        self._factory = capture_factory or cv2.VideoCapture
        self._queue: queue.Queue = queue.Queue(maxsize=queue_size)
        self._stop = threading.Event()
        self._opened = threading.Event()
        self._error: BaseException | None = None
        self._ended = False
        self._cap: Any = None
        self.fps: float | None = None
        self.frame_size: tuple[int, int] | None = None
        self.frames_read = 0
        self.drops = 0
        self.stalls = 0
        self._thread = threading.Thread(target=self._run, name=f"VideoSource[{self.source_id}]", daemon=True)
        self._thread.start()
        if not self._opened.wait(open_timeout_s):
            self._stop.set()
            raise SourceStalled(f"video source {self.source_id!r}: not open after {open_timeout_s:.1f} s")
        if self._error is not None:
            self.close()
            raise SourceError(f"video source {self.source_id!r}: {self._error}") from self._error

    # ------------------------------------------------------------------ reader thread
    def _run(self) -> None:
        try:
            cap = self._factory(self._arg)
            if not cap.isOpened():
                raise SourceError("cannot open (missing codec, bad URL or no camera)")
            self._cap = cap
            fps = float(cap.get(cv2.CAP_PROP_FPS) or 0.0)
            self.fps = fps if 0.0 < fps < 1000.0 else None
            w, h = int(cap.get(cv2.CAP_PROP_FRAME_WIDTH) or 0), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT) or 0)
            self.frame_size = (w, h) if w > 0 and h > 0 else None
        except BaseException as exc:  # reported to the caller by __init__
            self._error = exc
            self._opened.set()
            return
        self._opened.set()
        number = 0
        wall_start = time.monotonic()
        last_media_s = -1.0
        try:
            while not self._stop.is_set():
                ok, image = cap.read()
                if not ok or image is None:
                    break
                media_s = float(cap.get(cv2.CAP_PROP_POS_MSEC) or 0.0) / 1000.0
                from_file = not self.live or self.realtime
                if media_s > last_media_s and (media_s > 0.0 or number == 0) and from_file:
                    stamp = media_s
                elif self.fps and from_file:
                    stamp = number / self.fps
                else:
                    stamp = time.time()  # live input: wall-clock capture time (UNIX s)
                last_media_s = max(last_media_s, media_s)
                if self.realtime:  # pace on media time
                    wait = stamp - (time.monotonic() - wall_start)
                    if wait > 0 and self._stop.wait(wait):
                        break
                if image.ndim == 2:
                    image = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
                self._put(Frame(image, stamp, number, self.source_id))
                number += 1
        except BaseException as exc:  # a read error ends the source; read() raises it
            self._error = exc
        finally:
            self._put(_END)

    def _put(self, item: object) -> None:
        """Queue a frame: a live source replaces the oldest queued frame at once (counted in
        ``drops``); a file, and the end marker, wait for the consumer (until ``close``)."""
        while not self._stop.is_set():
            if self.live and item is not _END:
                try:
                    self._queue.put_nowait(item)
                    return
                except queue.Full:
                    try:
                        old = self._queue.get_nowait()
                        if old is not _END:
                            self.drops += 1
                    except queue.Empty:
                        pass
            else:
                try:
                    self._queue.put(item, timeout=0.05)
                    return
                except queue.Full:
                    pass

    # ------------------------------------------------------------------ consumer side
    def read(self, timeout_s: float | None = None) -> Frame | None:
        if self._ended:
            return None
        timeout = self.read_timeout_s if timeout_s is None else timeout_s
        try:
            item = self._queue.get(timeout=timeout)
        except queue.Empty:
            self.stalls += 1
            raise SourceStalled(f"video source {self.source_id!r}: no frame for {timeout:.2f} s") from None
        if item is _END:
            self._ended = True
            if self._error is not None:
                raise SourceError(f"video source {self.source_id!r}: {self._error}") from self._error
            return None
        self.frames_read += 1
        return item

    @property
    def ended(self) -> bool:
        return self._ended

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=1.0)
        if self._cap is not None and not self._thread.is_alive():
            self._cap.release()
        self._ended = True


class ImageFolderSource(FrameSource):
    """Image files of a folder in name order, stamped ``index / fps``; unreadable files are counted and skipped."""

    def __init__(self, folder: str | os.PathLike, fps: float = 15.0, *, source_id: str | None = None) -> None:
        path = Path(folder)
        if not path.is_dir():
            raise SourceError(f"image folder {str(path)!r} does not exist")
        if not fps > 0:
            raise ValueError(f"fps must be > 0, got {fps}")
        self.files = sorted(p for p in path.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
        if not self.files:
            raise SourceError(f"image folder {str(path)!r} has no images ({', '.join(IMAGE_SUFFIXES)})")
        self.fps = fps
        self.source_id = source_id or path.name
        self.unreadable = 0
        self._next = 0

    def read(self, timeout_s: float | None = None) -> Frame | None:
        while self._next < len(self.files):
            index = self._next
            self._next += 1
            image = cv2.imread(str(self.files[index]), cv2.IMREAD_COLOR)
            if image is None:
                self.unreadable += 1
                continue
            return Frame(image, index / self.fps, index, self.source_id)
        return None

    def close(self) -> None:
        self._next = len(self.files)


class ArraySource(FrameSource):
    """Frames from memory (an iterable of BGR images), stamped ``index / fps``; for tests and adapters."""

    def __init__(self, images: Iterable[np.ndarray], fps: float = 15.0, source_id: str = "array") -> None:
        if not fps > 0:
            raise ValueError(f"fps must be > 0, got {fps}")
        self._it = iter(images)
        self.fps = fps
        self.source_id = source_id
        self._n = 0

    def read(self, timeout_s: float | None = None) -> Frame | None:
        try:
            image = next(self._it)
        except StopIteration:
            return None
        frame = Frame(np.asarray(image), self._n / self.fps, self._n, self.source_id)
        self._n += 1
        return frame

    def close(self) -> None:
        self._it = iter(())


def open_source(spec: str | int, *, fps: float = 15.0, **video_kwargs: Any) -> FrameSource:
    """A folder -> ImageFolderSource; anything else (file, camera index, URL) -> VideoSource."""
    if isinstance(spec, str) and Path(spec).is_dir():
        return ImageFolderSource(spec, fps)
    return VideoSource(spec, **video_kwargs)
