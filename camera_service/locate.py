"""One frame -> floor poses of every configured marker (pure apart from OpenCV).

:class:`Locator` undistorts the frame when the calibration holds the lens (``camera_matrix``,
``dist_coeffs``: one ``cv2.remap`` through maps built once), detects the ArUco markers
(:func:`camera_service.markers.make_detector`), maps each marker's corners to the floor through
the homography, corrects the marker height's parallax
(:func:`camera_service.calibration.correct_parallax`) and checks the mapped square's side
against the printed one: a square more than :data:`SIZE_TOLERANCE` off is not a marker the
config describes (a misread, or a marker of another size lying around) and is dropped, counted
``implausible``. An id seen twice in one frame is ambiguous: both are dropped (``duplicates``);
an id nobody owns is counted (``unknown``), except the calibration's floor markers, which are
always in view.

Heading convention (:mod:`camera_service.markers`): a robot's heading is its marker's ``x`` axis,
from the printed marker's left edge to its right edge.
"""

from __future__ import annotations

import math
from collections.abc import Collection, Mapping
from dataclasses import dataclass, field

import cv2
import numpy as np

from camera_service.calibration import Calibration, apply_homography, correct_parallax
from camera_service.markers import check_frame, make_detector, to_grey

SIZE_TOLERANCE = 0.3  # a mapped marker side more than 30 % off the printed one is dropped

Pose = tuple[float, float, float]  # x [m], y [m], theta [rad]


@dataclass(frozen=True)
class Located:
    """What one frame showed: marker id -> floor pose, and what was dropped."""

    poses: dict[int, Pose]
    unknown: tuple[int, ...] = ()
    duplicates: tuple[int, ...] = ()
    implausible: tuple[int, ...] = ()
    markers_seen: int = 0  # every decoded marker, before any was dropped
    sides: dict[int, float] = field(default_factory=dict)  # [m] mapped side of each pose's marker


def pose_from_floor_corners(q: np.ndarray) -> tuple[Pose, float]:
    """Pose and mean side [m] of a square from its four floor corners (ArUco order)."""
    x, y = q.mean(axis=0)
    x_axis = (q[1] - q[0]) + (q[2] - q[3])
    y_axis = (q[0] - q[3]) + (q[1] - q[2])
    d = x_axis + np.array([y_axis[1], -y_axis[0]])  # y turned by -90 deg lies along x
    side = float(np.mean(np.linalg.norm(q - np.roll(q, 1, axis=0), axis=1)))
    return (float(x), float(y), math.atan2(d[1], d[0])), side


class Locator:
    """Frames of one calibrated camera -> marker poses at ``height`` [m] above the floor."""

    def __init__(self, calibration: Calibration, dictionary: str, marker_size: float,
                 height: float = 0.0, wanted: Collection[int] | None = None,
                 overrides: Mapping[int, tuple[float, float]] | None = None) -> None:
        """``overrides`` maps a marker id to its own ``(size, height)`` [m]; the calibration's
        floor markers are ignored (not counted unknown)."""
        self.overrides = dict(overrides or {})
        heights = [height, *(h for _s, h in self.overrides.values())]
        if max(heights) > 0.0 and calibration.camera_position is None:
            raise ValueError("height: parallax correction needs the calibration's camera_position")
        self.calibration = calibration
        self.height = float(height)
        self.marker_size = float(marker_size)
        self.wanted = None if wanted is None else frozenset(int(i) for i in wanted)
        self.detector = make_detector(dictionary)
        self._maps = None
        if calibration.camera_matrix is not None:
            k, d = calibration.camera_matrix, calibration.dist_coeffs
            self._maps = cv2.initUndistortRectifyMap(k, d, None, k, calibration.image_size,
                                                     cv2.CV_16SC2)

    def undistort(self, grey: np.ndarray) -> np.ndarray:
        """The frame as a pinhole camera with the same matrix would see it."""
        if self._maps is None:
            return grey
        return cv2.remap(grey, self._maps[0], self._maps[1], cv2.INTER_LINEAR)

    def locate(self, frame: np.ndarray) -> Located:
        """Every wanted marker in ``frame``; ValueError naming ``frame`` for a bad image or one
        of another size than the calibration's."""
        image = check_frame(frame)
        height, width = image.shape[:2]
        if (width, height) != self.calibration.image_size:
            w, h = self.calibration.image_size
            raise ValueError(f"frame: size {width}x{height} does not match the calibration's "
                             f"{w}x{h}")
        grey = self.undistort(to_grey(image))
        corners, ids, _rejected = self.detector.detectMarkers(grey)
        if ids is None or len(ids) == 0:
            return Located({})
        seen = [int(i) for i in np.asarray(ids).ravel()]
        counts: dict[int, int] = {}
        for mid in seen:
            counts[mid] = counts.get(mid, 0) + 1
        poses: dict[int, Pose] = {}
        sides: dict[int, float] = {}
        unknown, implausible = [], []
        for mid, quad in zip(seen, corners, strict=True):
            if self.wanted is not None and mid not in self.wanted:
                if mid not in self.calibration.floor_markers:
                    unknown.append(mid)
                continue
            if counts[mid] > 1:
                continue
            q = apply_homography(self.calibration.floor_from_pixel,
                                 np.asarray(quad, dtype=np.float64).reshape(4, 2))
            size, lift = self.overrides.get(mid, (self.marker_size, self.height))
            q = self._lifted(q, lift)
            pose, side = pose_from_floor_corners(q)
            if abs(side - size) > SIZE_TOLERANCE * size:
                implausible.append(mid)
                continue
            poses[mid] = pose
            sides[mid] = side
        duplicates = tuple(sorted(m for m, n in counts.items() if n > 1
                                  and (self.wanted is None or m in self.wanted)))
        return Located(poses, tuple(sorted(unknown)), duplicates, tuple(sorted(implausible)),
                       len(seen), sides)

    def _lifted(self, q: np.ndarray, lift: float) -> np.ndarray:
        """Floor corners ``q`` of a marker ``lift`` metres above the floor, parallax-corrected."""
        if lift <= 0.0:
            return q
        camera = self.calibration.camera_position
        if camera is None:  # __init__ refuses a height without a camera position
            raise ValueError("height: parallax correction needs the calibration's camera_position")
        return correct_parallax(q, camera, lift)
