"""The camera service: frames in, one pose per robot out.

:class:`CameraService` holds a frozen :class:`CameraConfig` (marker dictionary, robot -> marker id
or hue, the calibration, the mode) and turns each frame into :class:`PoseObservation` s with
:meth:`CameraService.process`. Frame sources (:func:`open_source`): a camera index (``"0"``), a
stream URL or a video file through ``cv2.VideoCapture``, or any iterable / callable of frames (the
simulated world renders them). Nothing here touches Zenoh: the networking wrapper calls
``process`` and publishes what it returns, stamping frames with its own clock.

Headings: in ``aruco`` mode every observation carries the marker's heading. In ``blobs`` mode a
blob has none; the service reports the direction of travel (:func:`camera_service.blobs.
motion_heading`: updated each time the robot has moved ``motion_step`` since the last update,
held in between, NaN until the robot first moves). A consumer must treat a NaN heading as unknown.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import NamedTuple

import cv2
import numpy as np

from camera_service.blobs import (
    HUE_TOLERANCE,
    MIN_AREA,
    MIN_SATURATION,
    MIN_VALUE,
    MOTION_STEP,
    check_hues,
    detect_blobs,
    motion_heading,
)
from camera_service.calibration import Calibration
from camera_service.markers import (
    DEFAULT_DICTIONARY,
    aruco_dictionary,
    check_marker_ids,
    detect_markers,
    make_detector,
)

logger = logging.getLogger(__name__)

MODES = ("aruco", "blobs")


class PoseObservation(NamedTuple):
    """One robot's pose as the camera saw it in one frame."""

    robot_id: str
    x: float  # [m]
    y: float  # [m]
    theta: float  # [rad] in (-pi, pi]; NaN when unknown (a blob that has not moved yet)
    stamp: float  # [s] the frame's stamp, as given to process()


@dataclass(frozen=True)
class CameraConfig:
    """Everything the service needs; validated on construction (ValueError naming the field).

    ``marker_ids`` (aruco mode) maps robot id -> marker id in ``dictionary``; ``hues`` (blobs
    mode) maps robot id -> OpenCV hue 0..179. Both are stored read-only.
    """

    calibration: Calibration
    marker_ids: Mapping[str, int] = field(default_factory=dict)  # aruco: robot -> marker id
    hues: Mapping[str, int] = field(default_factory=dict)  # blobs: robot -> OpenCV hue 0..179
    mode: str = "aruco"
    dictionary: str = DEFAULT_DICTIONARY
    corner_refinement: str = "contour"  # aruco: see markers.make_detector
    hue_tolerance: int = HUE_TOLERANCE  # blobs: [hue units] accepted distance from a robot's hue
    min_saturation: int = MIN_SATURATION  # blobs: HSV saturation a blob pixel needs (0..255)
    min_value: int = MIN_VALUE  # blobs: HSV value a blob pixel needs (0..255)
    min_area: int = MIN_AREA  # blobs: [px] smallest blob taken for a robot
    motion_step: float = MOTION_STEP  # blobs: [m] travel before the heading is updated

    def __post_init__(self) -> None:
        if not isinstance(self.calibration, Calibration):
            raise ValueError(
                f"calibration: expected a Calibration, got {type(self.calibration).__name__}"
            )
        if self.mode not in MODES:
            raise ValueError(f"mode: {self.mode!r} is not one of {MODES}")
        aruco_dictionary(self.dictionary)  # ValueError naming `dictionary` if unknown
        marker_ids = check_marker_ids(self.marker_ids, self.dictionary)
        hues = check_hues(self.hues, self.hue_tolerance)
        if self.mode == "aruco" and not marker_ids:
            raise ValueError("marker_ids: aruco mode needs at least one robot's marker id")
        if self.mode == "blobs" and not hues:
            raise ValueError("hues: blob mode needs at least one robot's hue")
        for name in ("min_saturation", "min_value"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= 255:
                raise ValueError(f"{name}: must be an int in 0..255, got {value!r}")
        area = self.min_area
        if isinstance(area, bool) or not isinstance(area, int) or area < 1:
            raise ValueError(f"min_area: must be an int >= 1 pixel, got {self.min_area!r}")
        if not (math.isfinite(self.motion_step) and self.motion_step > 0.0):
            raise ValueError(f"motion_step: must be a positive distance, got {self.motion_step!r}")
        make_detector(self.dictionary, self.corner_refinement)  # validates corner_refinement
        object.__setattr__(self, "marker_ids", MappingProxyType(marker_ids))
        object.__setattr__(self, "hues", MappingProxyType(hues))

    @property
    def robots(self) -> tuple[str, ...]:
        """The robots this configuration looks for, in configuration order."""
        return tuple(self.marker_ids if self.mode == "aruco" else self.hues)


class CameraService:
    """Frames -> poses, with counters (see :meth:`stats`).

    Stateless in aruco mode apart from the counters; in blobs mode it remembers each robot's
    last heading anchor (see the module docstring).
    """

    def __init__(self, config: CameraConfig) -> None:
        self.config = config
        self._detector = (
            make_detector(config.dictionary, config.corner_refinement)
            if config.mode == "aruco"
            else None
        )
        self._anchors: dict[str, tuple[tuple[float, float], float]] = {}
        self._counts = {
            "frames": 0,
            "detections": 0,
            "missing": 0,
            "unknown_markers": 0,
            "duplicate_markers": 0,
            "unmatched_blobs": 0,
        }

    @property
    def robots(self) -> tuple[str, ...]:
        return self.config.robots

    def process(self, frame: np.ndarray, stamp: float) -> list[PoseObservation]:
        """Every configured robot seen in ``frame``, in configuration order.

        Robots not seen are left out (and counted as missing). Raises ValueError naming
        ``frame`` for anything but an 8-bit image of the calibration's size, and naming
        ``stamp`` for a non-finite stamp.
        """
        if isinstance(stamp, bool) or not isinstance(stamp, int | float) or not math.isfinite(
            stamp
        ):
            raise ValueError(f"stamp: must be a finite number of seconds, got {stamp!r}")
        c = self.config
        if self._detector is not None:  # mode "aruco"
            found = detect_markers(frame, self._detector, c.calibration, c.marker_ids)
            poses = found.poses
            self._counts["unknown_markers"] += len(found.unknown_ids)
            self._counts["duplicate_markers"] += len(found.duplicate_ids)
        else:
            blobs = detect_blobs(
                frame,
                c.calibration,
                c.hues,
                hue_tolerance=c.hue_tolerance,
                min_saturation=c.min_saturation,
                min_value=c.min_value,
                min_area=c.min_area,
            )
            self._counts["unmatched_blobs"] += blobs.unmatched
            poses = {r: self._with_motion_heading(r, p) for r, p in blobs.poses.items()}
        self._counts["frames"] += 1
        self._counts["detections"] += len(poses)
        self._counts["missing"] += len(c.robots) - len(poses)
        return [
            PoseObservation(robot, *poses[robot], float(stamp))
            for robot in c.robots
            if robot in poses
        ]

    def _with_motion_heading(
        self, robot: str, pose: tuple[float, float, float]
    ) -> tuple[float, float, float]:
        x, y, _nan = pose
        anchor, heading = self._anchors.get(robot, (None, math.nan))
        anchor, heading = motion_heading(anchor, heading, (x, y), self.config.motion_step)
        self._anchors[robot] = (anchor, heading)
        return x, y, heading

    def stats(self) -> dict[str, int]:
        """Counters since construction: frames, detections, missing (robot-frames not seen),
        unknown_markers, duplicate_markers (aruco) and unmatched_blobs (blobs)."""
        return dict(self._counts)


FrameSource = str | int | Iterable[np.ndarray] | Callable[[], np.ndarray | None]


def open_source(spec: FrameSource | cv2.VideoCapture) -> Iterator[np.ndarray]:
    """An iterator of frames (BGR uint8 for captures) from ``spec``.

    ``spec`` is a camera index (``0`` or ``"0"``), a stream URL (``"rtsp://..."``), a video file
    path, an opened ``cv2.VideoCapture``, an iterable of frames, or a callable returning the next
    frame (None ends the stream). Captures are opened here, so a bad source fails at once
    (ValueError naming ``spec``); they are released when the stream ends or the iterator is
    closed (``close()`` on the returned generator, or garbage collection).
    """
    if isinstance(spec, cv2.VideoCapture):
        if not spec.isOpened():
            raise ValueError("spec: the VideoCapture is not opened")
        return _from_capture(spec)
    if isinstance(spec, bool):
        raise ValueError(f"spec: expected a camera index, path, URL or frames, got {spec!r}")
    if isinstance(spec, int | str | Path):
        return _from_capture(_open_named(spec))
    if callable(spec):
        return _from_callable(spec)
    if isinstance(spec, Iterable):
        return iter(spec)
    raise ValueError(
        f"spec: expected a camera index, URL, file path, iterable or callable, got {spec!r}"
    )


def _from_callable(fn: Callable[[], np.ndarray | None]) -> Iterator[np.ndarray]:
    while True:
        frame = fn()
        if frame is None:
            return
        yield frame


def _open_named(spec: int | str | Path) -> cv2.VideoCapture:
    """The capture of a camera index (``0`` or ``"0"``), a stream URL or a video file path."""
    if isinstance(spec, int) or (isinstance(spec, str) and spec.strip().isdigit()):
        index = int(spec)
        if index < 0:
            raise ValueError(f"spec: camera index must be >= 0, got {index}")
        return _open_capture(index, f"camera {index}")
    text = str(spec)
    if not text:
        raise ValueError("spec: empty source")
    if "://" not in text and not Path(text).is_file():
        raise ValueError(f"spec: cannot open {text!r}: no such file")
    return _open_capture(text, repr(text))


def _open_capture(target: int | str, name: str) -> cv2.VideoCapture:
    """Open now, so a bad source fails here rather than at the first frame."""
    cap = cv2.VideoCapture(target)
    if not cap.isOpened():
        cap.release()
        raise ValueError(f"spec: cannot open {name}")
    logger.info("opened frame source %s", name)
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
