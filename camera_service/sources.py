"""Frame sources of the camera process: each yields ``(frame, capture stamp)``.

``source`` of ``CONFIG.yaml`` (or ``--source``) picks one (:func:`make_source`):

* ``0``, ``1``, ...: a camera index; ``rtsp://...``, ``http(s)://...``: a stream; both through
  ``cv2.VideoCapture``, stamped with the wall clock when the frame is read. A read that fails
  (unplugged camera, dropped stream) releases the capture and reopens it with back-off (0.25 s
  doubling to 4 s), each attempt counted ``reconnects``; the process never stops for it.
* a video file: ``cv2.VideoCapture``, frame ``k`` stamped ``start + k / fps`` (the file's own
  rate, else the config's), paced to that clock; the source ends with the file.
* a glob of image files (``frames/*.png``, sorted by name): frame ``k`` stamped
  ``start + k / fps``, paced to that clock; an unreadable file is counted and skipped.
* ``zenoh:KEY``: encoded frames (:mod:`wire.frames`) published on ``KEY``; the stamp is the one
  the frame carries. Decoding happens on the caller's thread; while it works on one frame, only
  the newest of the frames arriving waits (:data:`QUEUE`), older ones are dropped and counted
  ``skipped``: a late frame is worth less than the next one.

The first open of a source that does not exist (no such file, no image matching the glob, a
camera or stream that does not open) is a :class:`SourceError` naming it: exit 2 at start.
"""

from __future__ import annotations

import glob as globlib
import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
import zenoh

from wire.frames import decode_frame
from wire.payloads import DecodeError

logger = logging.getLogger(__name__)

BACKOFF_START_S = 0.25  # [s] first wait before reopening a failed capture
BACKOFF_MAX_S = 4.0  # [s] longest wait between two attempts
QUEUE = 1  # frames a zenoh source keeps waiting (an older one is dropped: the newest matters)
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp")
READ_TIMEOUT_S = 0.2  # [s] longest a read() blocks before returning to check for a stop

Item = tuple[np.ndarray | None, float]  # a frame (None: undecodable, counted) and its stamp


class SourceError(ValueError):
    """A source that cannot be opened at all."""


class EndOfSource(Exception):
    """A finite source (video file, image glob) has no more frames."""


class Source:
    """Base class: ``read()`` returns an item, ``None`` when nothing came in time, or raises
    :class:`EndOfSource`; counters in :attr:`counts`."""

    def __init__(self) -> None:
        self.counts = {"reconnects": 0, "read_failures": 0, "undecodable": 0, "skipped": 0}

    def read(self) -> Item | None:
        raise NotImplementedError

    def close(self) -> None:
        pass


def _sleep_until(t: float, stop: Callable[[], bool]) -> bool:
    """Sleep until ``time.time()`` reaches ``t``; False if ``stop()`` became true first."""
    while not stop():
        left = t - time.time()
        if left <= 0:
            return True
        time.sleep(min(left, 0.05))
    return False


def open_capture(target: int | str) -> cv2.VideoCapture:
    """``cv2.VideoCapture`` of a camera index or a stream URL (typed: one call per overload)."""
    if isinstance(target, int):
        return cv2.VideoCapture(target)
    return cv2.VideoCapture(target)


class CaptureSource(Source):
    """A camera index or a stream URL: live, reconnecting (see the module docstring)."""

    def __init__(self, target: int | str, stop: Callable[[], bool],
                 opener: Callable[[int | str], cv2.VideoCapture] = open_capture) -> None:
        super().__init__()
        self.target = target
        self.stop = stop
        self.opener = opener
        cap = opener(target)
        if not cap.isOpened():
            cap.release()
            raise SourceError(f"source: cannot open {target!r}")
        self.cap: cv2.VideoCapture | None = cap
        self.backoff = BACKOFF_START_S

    def read(self) -> Item | None:
        if self.cap is not None:
            ok, frame = self.cap.read()
            stamp = time.time()
            if ok and frame is not None:
                self.backoff = BACKOFF_START_S
                return frame, stamp
            self.counts["read_failures"] += 1
            logger.warning("source %r: read failed; reconnecting", self.target)
            self.cap.release()
            self.cap = None
        # reconnect with back-off
        if not _sleep_until(time.time() + self.backoff, self.stop):
            return None
        self.counts["reconnects"] += 1
        self.backoff = min(self.backoff * 2.0, BACKOFF_MAX_S)
        cap = self.opener(self.target)
        if cap.isOpened():
            logger.info("source %r: reopened", self.target)
            self.cap = cap
        else:
            cap.release()
        return None

    def close(self) -> None:
        if self.cap is not None:
            self.cap.release()
            self.cap = None


class VideoFileSource(Source):
    """A video file, paced to its frame rate."""

    def __init__(self, path: str, fps: float, stop: Callable[[], bool]) -> None:
        super().__init__()
        if not Path(path).is_file():
            raise SourceError(f"source: no such file {path!r}")
        self.cap = cv2.VideoCapture(path)
        if not self.cap.isOpened():
            self.cap.release()
            raise SourceError(f"source: cannot read video {path!r}")
        own = self.cap.get(cv2.CAP_PROP_FPS)
        self.fps = own if own and 0 < own < 1000 else fps
        self.stop = stop
        self.k = 0
        self.start = time.time()

    def read(self) -> Item | None:
        stamp = self.start + self.k / self.fps
        if not _sleep_until(stamp, self.stop):
            return None
        ok, frame = self.cap.read()
        if not ok:
            raise EndOfSource
        self.k += 1
        return frame, stamp

    def close(self) -> None:
        self.cap.release()


class GlobSource(Source):
    """Image files matching a glob, sorted, paced at ``fps``."""

    def __init__(self, pattern: str, fps: float, stop: Callable[[], bool]) -> None:
        super().__init__()
        self.files = sorted(globlib.glob(pattern))
        if not self.files:
            raise SourceError(f"source: no image file matches {pattern!r}")
        self.fps = fps
        self.stop = stop
        self.k = 0
        self.start = time.time()

    def read(self) -> Item | None:
        if self.k >= len(self.files):
            raise EndOfSource
        stamp = self.start + self.k / self.fps
        if not _sleep_until(stamp, self.stop):
            return None
        path = self.files[self.k]
        self.k += 1
        frame = cv2.imread(path, cv2.IMREAD_COLOR)
        if frame is None:
            self.counts["undecodable"] += 1
            logger.warning("source: cannot read image %s", path)
        return frame, stamp


class ZenohSource(Source):
    """Encoded frames on a Zenoh key (see :mod:`wire.frames`)."""

    def __init__(self, session: zenoh.Session, key: str) -> None:
        super().__init__()
        self.key = key
        self._cond = threading.Condition()
        self._queue: deque[bytes] = deque()
        self._sub = session.declare_subscriber(key, self._callback)

    def _callback(self, sample: zenoh.Sample) -> None:
        data = sample.payload.to_bytes()
        with self._cond:
            if len(self._queue) >= QUEUE:
                self._queue.popleft()
                self.counts["skipped"] += 1
            self._queue.append(data)
            self._cond.notify()

    def read(self) -> Item | None:
        with self._cond:
            if not self._queue:
                self._cond.wait(READ_TIMEOUT_S)
            if not self._queue:
                return None
            data = self._queue.popleft()
        try:
            frame = decode_frame(data)
        except DecodeError as exc:
            self.counts["undecodable"] += 1
            logger.warning("source %s: dropped a frame: %s", self.key, exc)
            return None
        # grey at once: detection needs no colour, and a JPEG decodes faster without chroma
        image = cv2.imdecode(np.frombuffer(frame.image, dtype=np.uint8), cv2.IMREAD_GRAYSCALE)
        if image is None:
            self.counts["undecodable"] += 1
            logger.warning("source %s: dropped a frame: its %s image does not decode",
                           self.key, frame.encoding)
        return image, frame.stamp

    def close(self) -> None:
        try:
            self._sub.undeclare()
        except Exception:  # noqa: BLE001 - the session may be closing already
            pass


def source_kind(spec: str) -> str:
    """``"zenoh"``, ``"camera"``, ``"stream"``, ``"glob"`` or ``"file"``."""
    if spec.startswith("zenoh:"):
        return "zenoh"
    if spec.strip().isdigit():
        return "camera"
    if "://" in spec:
        return "stream"
    if any(ch in spec for ch in "*?[") or Path(spec).suffix.lower() in IMAGE_SUFFIXES:
        return "glob"
    return "file"


def make_source(spec: str, fps: float, stop: Callable[[], bool],
                session: zenoh.Session | None = None) -> Source:
    """The source ``spec`` names (see the module docstring); :class:`SourceError` naming it."""
    kind = source_kind(spec)
    if kind == "zenoh":
        key = spec[len("zenoh:"):]
        if not key or any(ch in key for ch in "*$#?") or key.startswith("/") or key.endswith("/"):
            raise SourceError(f"source: {spec!r} needs one exact key after 'zenoh:'")
        if session is None:
            raise SourceError("source: a zenoh source needs a session")
        return ZenohSource(session, key)
    if kind == "camera":
        return CaptureSource(int(spec), stop)
    if kind == "stream":
        if spec.split("://", 1)[0] not in ("rtsp", "http", "https", "rtmp", "udp", "tcp"):
            raise SourceError(f"source: unsupported stream {spec!r} (rtsp://, http://, ...)")
        return CaptureSource(spec, stop)
    if kind == "glob":
        return GlobSource(spec, fps, stop)
    return VideoFileSource(spec, fps, stop)
