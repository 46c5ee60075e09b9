"""Colour-blob localisation, the thesis's method (section 6.1.3): one colour per robot.

Each robot carries one saturated coloured disc; its identity is its hue. A frame is thresholded in
HSV (saturated and bright enough: the floor, the grey obstacles and the dark robot bodies are not),
split into connected blobs, and each blob whose mean hue lies within ``hue_tolerance`` of a
robot's hue becomes that robot's observation (the largest such blob when there are several).

Position: the blob's centroid on the floor, computed from its pixels mapped through the homography
and weighted by the floor area each pixel covers (``|det H| / w^3``), so a perspective tilt does
not bias it the way mapping the image centroid would.

Heading: a blob has none, so :func:`detect_blobs` reports ``theta = nan``. A caller that needs a
heading can take the direction of travel with :func:`motion_heading` (what
``CameraService`` does in blob mode): it holds the last heading until the robot has moved
``min_step`` since the previous estimate, and is ``nan`` until the robot first moves. It is the
direction of travel, so it is wrong for a robot reversing and stale for one turning on the spot.

Hues are OpenCV's, 0..179 (half degrees). Robots' hues must lie at least ``2 * hue_tolerance``
apart on that circle, which limits a frame to ``180 // (2 * hue_tolerance)`` robots (11 at the
default tolerance): one reason the product prefers ArUco markers.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping
from dataclasses import dataclass

import cv2
import numpy as np

from camera_service.calibration import Calibration, apply_homography
from camera_service.markers import Pose, check_frame

logger = logging.getLogger(__name__)

HUE_TOLERANCE = 8  # [OpenCV hue units, half degrees] accepted distance from a robot's hue
MIN_SATURATION = 100  # HSV saturation (0..255) a blob pixel needs
MIN_VALUE = 60  # HSV value (0..255) a blob pixel needs
MIN_AREA = 12  # [px] smallest blob taken for a robot
MOTION_STEP = 0.02  # [m] travel needed before motion_heading updates the heading


@dataclass(frozen=True)
class BlobDetection:
    """Poses of the robots whose colour was found (``theta`` is nan), and the blobs not used.

    ``unmatched`` counts blobs of at least ``min_area`` pixels whose hue is no robot's;
    ``extra`` counts smaller or second blobs of a robot's hue that were passed over.
    """

    poses: dict[str, Pose]
    unmatched: int = 0
    extra: int = 0


def check_hues(hues: Mapping[str, int], hue_tolerance: int = HUE_TOLERANCE) -> dict[str, int]:
    """Validate ``{robot_id: hue}``: ints in 0..179, pairwise at least 2 tolerances apart."""
    if not isinstance(hues, Mapping):
        raise ValueError(f"hues: expected a mapping robot_id -> hue, got {type(hues).__name__}")
    if not (isinstance(hue_tolerance, int | float) and 0 < hue_tolerance < 45):
        raise ValueError(f"hue_tolerance: must be in (0, 45) hue units, got {hue_tolerance!r}")
    out: dict[str, int] = {}
    for robot, hue in hues.items():
        if not isinstance(robot, str) or not robot:
            raise ValueError(f"hues: robot ids must be non-empty strings, got {robot!r}")
        if isinstance(hue, bool) or not isinstance(hue, int | np.integer) or not 0 <= hue < 180:
            raise ValueError(f"hues: hue of {robot!r} must be an int in 0..179, got {hue!r}")
        for other, other_hue in out.items():
            if _hue_distance(float(hue), float(other_hue)) < 2 * hue_tolerance:
                raise ValueError(
                    f"hues: {robot!r} ({hue}) and {other!r} ({other_hue}) are less than "
                    f"2 * hue_tolerance = {2 * hue_tolerance} apart"
                )
        out[robot] = int(hue)
    return out


def _hue_distance(a: float, b: float) -> float:
    """Distance on the 180-unit hue circle."""
    d = abs(a - b) % 180.0
    return min(d, 180.0 - d)


def _mean_hue(hue: np.ndarray) -> float:
    """Circular mean of OpenCV hues (so red blobs at 178 and 2 average to 0, not 90)."""
    angle = hue.astype(np.float64) * (2.0 * math.pi / 180.0)
    mean = math.atan2(float(np.sin(angle).sum()), float(np.cos(angle).sum()))
    return (mean * 180.0 / (2.0 * math.pi)) % 180.0


def floor_centroid(calibration: Calibration, us: np.ndarray, vs: np.ndarray) -> tuple[float, float]:
    """Area-weighted floor centroid of a set of pixels (pixel centres ``us``, ``vs``)."""
    h = calibration.floor_from_pixel
    pixels = np.c_[us.astype(np.float64), vs.astype(np.float64)]
    w = pixels @ h[2, :2] + h[2, 2]
    weight = 1.0 / np.abs(w) ** 3  # floor area of a pixel, up to the constant |det H|
    floor = apply_homography(h, pixels)
    x, y = (weight[:, None] * floor).sum(axis=0) / weight.sum()
    return float(x), float(y)


def detect_blobs(
    frame: np.ndarray,
    calibration: Calibration,
    hues: Mapping[str, int],
    *,
    hue_tolerance: int = HUE_TOLERANCE,
    min_saturation: int = MIN_SATURATION,
    min_value: int = MIN_VALUE,
    min_area: int = MIN_AREA,
) -> BlobDetection:
    """Find each robot's coloured disc in a BGR ``frame``; poses have ``theta = nan``."""
    image = check_frame(frame)
    if image.size == 0:
        return BlobDetection({})
    _check_blob_frame(image, calibration, min_area)
    checked = check_hues(hues, hue_tolerance)
    bgr = image if image.shape[2] == 3 else cv2.cvtColor(image, cv2.COLOR_BGRA2BGR)
    hsv = cv2.cvtColor(bgr, cv2.COLOR_BGR2HSV)
    mask = np.asarray(cv2.inRange(hsv, (0, min_saturation, min_value), (179, 255, 255)), dtype=np.uint8)
    # Outer contours find the blobs far faster than labelling the whole frame; each blob's
    # pixels are then its filled contour intersected with the mask (so holes stay out).
    contours, _hierarchy = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    best: dict[str, tuple[int, np.ndarray, np.ndarray]] = {}  # robot -> (area, us, vs)
    unmatched = extra = 0
    for contour in contours:
        pixels = _blob_pixels(contour, mask, min_area)
        if pixels is None:
            continue
        us, vs = pixels
        robot = _matching_robot(_mean_hue(hsv[vs, us, 0]), checked, hue_tolerance)
        if robot is None:
            unmatched += 1
            continue
        if robot in best:
            extra += 1
            if best[robot][0] >= len(us):
                continue
        best[robot] = (len(us), us, vs)
    poses: dict[str, Pose] = {}
    for robot, (_area, us, vs) in best.items():
        x, y = floor_centroid(calibration, us, vs)
        poses[robot] = (x, y, math.nan)
    if unmatched or extra:
        logger.debug("blobs: %d of no robot's hue, %d extra", unmatched, extra)
    return BlobDetection(poses, unmatched, extra)


def _check_blob_frame(image: np.ndarray, calibration: Calibration, min_area: int) -> None:
    """A BGR or BGRA image of the calibration's size, and a whole ``min_area`` >= 1 pixel."""
    if image.ndim != 3 or image.shape[2] not in (3, 4):
        raise ValueError(f"frame: blob mode needs a BGR or BGRA image, got shape {image.shape}")
    height, width = image.shape[:2]
    if (width, height) != calibration.image_size:
        raise ValueError(
            f"frame: size {width}x{height} does not match the calibration's "
            f"{calibration.image_size[0]}x{calibration.image_size[1]}"
        )
    if not (isinstance(min_area, int) and min_area >= 1):
        raise ValueError(f"min_area: must be an int >= 1 pixel, got {min_area!r}")


def _blob_pixels(contour: np.ndarray, mask: np.ndarray,
                 min_area: int) -> tuple[np.ndarray, np.ndarray] | None:
    """Image columns and rows of the mask's pixels inside ``contour`` (its filled outline);
    None for a blob of fewer than ``min_area`` pixels."""
    x0, y0, w, h = cv2.boundingRect(contour)
    if w * h < min_area:
        return None
    inside = np.zeros((h, w), dtype=np.uint8)
    cv2.drawContours(inside, [contour], -1, 255, thickness=cv2.FILLED, offset=(-x0, -y0))
    inside &= mask[y0 : y0 + h, x0 : x0 + w]
    vs, us = np.nonzero(inside)
    if len(us) < min_area:
        return None
    return us + x0, vs + y0


def _matching_robot(hue: float, hues: Mapping[str, int], tolerance: int) -> str | None:
    """The robot whose hue is nearest ``hue``, if within ``tolerance``; else None."""
    robot = min(hues, key=lambda r: _hue_distance(hue, hues[r]), default=None)
    if robot is None or _hue_distance(hue, hues[robot]) > tolerance:
        return None
    return robot


def motion_heading(
    anchor: tuple[float, float] | None,
    heading: float,
    position: tuple[float, float],
    min_step: float = MOTION_STEP,
) -> tuple[tuple[float, float], float]:
    """Direction of travel as a heading: returns the new ``(anchor, heading)``.

    ``anchor`` is where the last heading was taken (None at first sight). Once ``position`` is
    ``min_step`` [m] or more from it, the heading becomes the direction anchor -> position and the
    anchor moves there; otherwise both are kept (``heading`` stays nan until the first move).
    """
    if not (math.isfinite(min_step) and min_step > 0.0):
        raise ValueError(f"min_step: must be a positive distance, got {min_step!r}")
    if anchor is None:
        return (position[0], position[1]), heading
    dx, dy = position[0] - anchor[0], position[1] - anchor[1]
    if math.hypot(dx, dy) < min_step:
        return anchor, heading
    return (position[0], position[1]), math.atan2(dy, dx)
