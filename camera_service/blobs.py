"""Colour-blob detection -> robot positions on the floor (the thesis's method, section 6.1.3).

Each robot carries one saturated coloured disc; a robot's hue is known (see
:func:`camera_service.render.default_hues`). Pixels within ``HUE_TOLERANCE`` of that hue and
saturated and bright enough form its mask; the centroid of the largest connected blob, mapped
through the homography, is the robot's floor position. A blob carries no heading: ``theta`` is
NaN, and :class:`camera_service.service.CameraService` fills it from the robot's previous
detected motion when it can (or leaves it NaN, which a consumer must treat as unknown).
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import cv2
import numpy as np

from camera_service.calibration import Calibration, pixel_to_floor
from camera_service.markers import check_frame

HUE_TOLERANCE = 6  # [OpenCV hue units, 0..179] half-width of a robot's hue band
MIN_SATURATION = 120  # 0..255: greys (floor, bodies, obstacles) stay below this
MIN_VALUE = 80  # 0..255
MIN_BLOB_PIXELS = 12  # [px] smaller blobs are noise


def detect_blobs(
    frame: np.ndarray, calibration: Calibration, hues: Mapping[str, int]
) -> dict[str, tuple[float, float, float]]:
    """``{robot_id: (x, y, nan)}`` for every robot whose coloured blob is visible."""
    image = check_frame(frame)
    if image.size == 0:
        return {}
    if image.ndim != 3 or image.shape[2] != 3:
        raise ValueError("frame: colour blobs need a BGR frame (H, W, 3)")
    hsv = cv2.cvtColor(image, cv2.COLOR_BGR2HSV)
    h, s, v = hsv[:, :, 0].astype(np.int16), hsv[:, :, 1], hsv[:, :, 2]
    coloured = (s >= MIN_SATURATION) & (v >= MIN_VALUE)
    out: dict[str, tuple[float, float, float]] = {}
    for robot, hue in hues.items():
        diff = np.abs(h - int(hue))
        diff = np.minimum(diff, 180 - diff)  # hue is circular
        mask = (coloured & (diff <= HUE_TOLERANCE)).astype(np.uint8)
        n, _labels, stats, centroids = cv2.connectedComponentsWithStats(mask, connectivity=8)
        if n <= 1:
            continue
        best = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
        if stats[best, cv2.CC_STAT_AREA] < MIN_BLOB_PIXELS:
            continue
        x, y = pixel_to_floor(calibration, centroids[best])
        out[robot] = (float(x), float(y), math.nan)
    return out
