"""The camera service: frames in, one pose per robot out.

:class:`CameraService` holds a frozen :class:`CameraConfig` (marker dictionary, robot -> marker id
or hue, the calibration, the mode) and turns each frame into :class:`PoseObservation` s with
:meth:`CameraService.process`. Frame sources (:func:`open_source`): a camera index (``"0"``), a
stream URL or a video file through ``cv2.VideoCapture``, or any iterable / callable of frames (the
simulated world renders them). Nothing here touches Zenoh: the networking wrapper calls
``process`` and publishes what it returns.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass, field
from typing import NamedTuple

import cv2
import numpy as np

from camera_service.blobs import detect_blobs
from camera_service.calibration import Calibration
from camera_service.markers import DEFAULT_DICTIONARY, check_marker_ids, detect_markers, make_detector

logger = logging.getLogger(__name__)

MODES = ("aruco", "blobs")
MIN_HEADING_STEP = 0.01  # [m] blobs: motion needed between frames to infer a heading


class PoseObservation(NamedTuple):
    robot_id: str
    x: float  # [m]
    y: float  # [m]
    theta: float  # [rad]; NaN when unknown (a blob that has not moved yet)
    stamp: float  # [s] the frame's stamp


@dataclass(frozen=True)
class CameraConfig:
    calibration: Calibration
    marker_ids: Mapping[str, int] = field(default_factory=dict)  # aruco: robot -> marker id
    hues: Mapping[str, int] = field(default_factory=dict)  # blobs: robot -> OpenCV hue 0..179
    mode: str = "aruco"
    dictionary: str = DEFAULT_DICTIONARY

    def __post_init__(self) -> None:
        if self.mode not in MODES:
            raise ValueError(f"mode: {self.mode!r} is not one of {MODES}")
        if self.mode == "aruco":
            object.__setattr__(self, "marker_ids", check_marker_ids(self.marker_ids, self.dictionary))
            if not self.marker_ids:
                raise ValueError("marker_ids: aruco mode needs at least one robot's marker id")
        else:
            if not self.hues:
                raise ValueError("hues: blob mode needs at least one robot's hue")
            for robot, hue in self.hues.items():
                if isinstance(hue, bool) or not isinstance(hue, int) or not 0 <= hue < 180:
                    raise ValueError(f"hues: hue of {robot!r} must be an int in 0..179, got {hue!r}")


class CameraService:
    """Frames -> poses, with counters (frames, detections, missing robots, unknown markers)."""

    def __init__(self, config: CameraConfig) -> None:
        self.config = config
        self._detector = make_detector(config.dictionary) if config.mode == "aruco" else None
        self._last: dict[str, tuple[float, float, float]] = {}
        self.frames = 0
        self.detections = 0
        self.missing = 0
        self.unknown_markers = 0

    @property
    def robots(self) -> tuple[str, ...]:
        c = self.config
        return tuple(c.marker_ids if c.mode == "aruco" else c.hues)

    def process(self, frame: np.ndarray, stamp: float) -> list[PoseObservation]:
        """Every robot seen in ``frame``, in the configuration's robot order."""
        if not math.isfinite(stamp):
            raise ValueError(f"stamp: must be finite, got {stamp!r}")
        c = self.config
        if c.mode == "aruco":
            found = detect_markers(frame, self._detector, c.calibration, c.marker_ids)
            poses = found.poses
            self.unknown_markers += len(found.unknown_ids)
        else:
            blobs = detect_blobs(frame, c.calibration, c.hues)
            poses = {r: self._blob_heading(r, p) for r, p in blobs.items()}
        self.frames += 1
        self.detections += len(poses)
        self.missing += len(self.robots) - len(poses)
        out = []
        for robot in self.robots:
            if robot in poses:
                x, y, th = poses[robot]
                out.append(PoseObservation(robot, x, y, th, stamp))
                self._last[robot] = (x, y, th)
        return out

    def _blob_heading(self, robot: str, pose: tuple[float, float, float]):
        """A blob has no heading: take the direction of its motion since the last frame, or keep
        the last known heading when it barely moved."""
        x, y, _ = pose
        last = self._last.get(robot)
        if last is None:
            return (x, y, math.nan)
        dx, dy = x - last[0], y - last[1]
        if math.hypot(dx, dy) >= MIN_HEADING_STEP:
            return (x, y, math.atan2(dy, dx))
        return (x, y, last[2])

    def stats(self) -> dict[str, int]:
        return {"frames": self.frames, "detections": self.detections, "missing": self.missing,
                "unknown_markers": self.unknown_markers}


FrameSource = str | int | Iterable[np.ndarray] | Callable[[], np.ndarray | None]


def open_source(spec: FrameSource) -> Iterator[np.ndarray]:
    """Frames from a camera index (``0`` or ``"0"``), a stream URL or video file path, an
    iterable of frames, or a callable returning the next frame (None ends the stream)."""
    if callable(spec):
        return _from_callable(spec)
    if isinstance(spec, int) or (isinstance(spec, str) and spec.isdigit()):
        return _from_capture(_open_capture(int(spec), str(spec)))
    if isinstance(spec, str):
        if not spec:
            raise ValueError("source: empty source")
        return _from_capture(_open_capture(spec, spec))
    if isinstance(spec, Iterable):
        return iter(spec)
    raise ValueError(f"source: expected a camera index, URL, file path, iterable or callable, got {spec!r}")


def _from_callable(fn: Callable[[], np.ndarray | None]) -> Iterator[np.ndarray]:
    while True:
        frame = fn()
        if frame is None:
            return
        yield frame


def _open_capture(target: int | str, name: str) -> cv2.VideoCapture:
    """Open now, so a bad source fails here rather than at the first frame."""
    cap = cv2.VideoCapture(target)
    if not cap.isOpened():
        cap.release()
        raise ValueError(f"source: cannot open {name!r}")
    return cap


def _from_capture(cap: cv2.VideoCapture) -> Iterator[np.ndarray]:
    try:
        while True:
            ok, frame = cap.read()
            if not ok:
                return
            yield frame
    finally:
        cap.release()
