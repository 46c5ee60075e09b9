"""Render the overhead camera's frame of a simulated world (pure functions).

Everything is drawn on the floor plane and projected through the calibration's homography, so the
frames carry the same perspective as the synthetic camera
(:func:`camera_service.calibration.synthetic_camera`). Drawing order: floor, obstacles (grey
discs), robot bodies (dark discs), then per robot either its ArUco marker (``render_aruco_frame``)
or its coloured disc (``render_blob_frame``, the thesis's colour-blob localisation).

Marker convention (see :mod:`camera_service.markers`): the marker lies face up, centred on the
robot, its ``x`` axis (top edge, left to right) along the robot's heading ``theta``.

Markers are drawn with area-averaged anti-aliasing, the way a camera integrates light over a
pixel: each marker is point-sampled on a grid ``SUPERSAMPLE`` times finer than the image, then
box-averaged down, so its edges land at their sub-pixel positions.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from functools import lru_cache

import cv2
import numpy as np

from camera_service.calibration import Calibration, floor_to_pixel
from camera_service.markers import (
    DEFAULT_DICTIONARY,
    MARKER_BORDER_BITS,
    aruco_dictionary,
    check_marker_ids,
)
from geometry.limits import BURGER_RADIUS

MARKER_SIDE = 0.08  # [m] side of the marker's black square on the floor
QUIET_ZONE = 1  # [modules] white border around the marker's black square
ROBOT_RADIUS = BURGER_RADIUS  # [m] TurtleBot3 burger body radius
BLOB_RADIUS = 0.05  # [m] radius of a robot's coloured disc in blob mode
SUPERSAMPLE = 4  # marker sub-pixel samples per image pixel, per axis
CIRCLE_VERTICES = 72  # polygon vertices of a projected disc
FLOOR_GREY = 185  # grey level of the floor (light grey)
OBSTACLE_BGR = (120, 120, 120)  # mid grey obstacle discs
ROBOT_BGR = (45, 45, 45)  # dark robot bodies
BLOB_SATURATION = 255  # HSV saturation of blob colours (0..255)
BLOB_VALUE = 230  # HSV value of blob colours (0..255)
_SHIFT = 4  # fractional bits of fillPoly vertex coordinates (1/16 px)

PoseLike = tuple[float, float, float]


def _check_poses(poses: Mapping[str, PoseLike]) -> dict[str, tuple[float, float, float]]:
    if not isinstance(poses, Mapping):
        raise ValueError(f"poses: expected a mapping robot_id -> (x, y, theta), got {poses!r}")
    out = {}
    for robot, pose in poses.items():
        try:
            x, y, theta = (float(v) for v in pose)
        except (TypeError, ValueError):
            raise ValueError(f"poses: {robot!r} needs (x, y, theta), got {pose!r}") from None
        if not all(math.isfinite(v) for v in (x, y, theta)):
            raise ValueError(f"poses: {robot!r} has a non-finite pose {pose!r}")
        out[robot] = (x, y, theta)
    return out


def _check_obstacles(obstacles: Iterable[tuple[float, float, float]]) -> list[tuple[float, float, float]]:
    out: list[tuple[float, float, float]] = []
    for obstacle in obstacles:
        try:
            x, y, r = (float(v) for v in obstacle)
        except (TypeError, ValueError):
            raise ValueError(f"obstacles: expected (x, y, radius), got {obstacle!r}") from None
        if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(r) and r > 0.0):
            raise ValueError(f"obstacles: need finite x, y and radius > 0, got {obstacle!r}")
        out.append((x, y, r))
    return out


def _check_positive(value: float, name: str) -> float:
    if not (isinstance(value, int | float) and math.isfinite(value) and value > 0.0):
        raise ValueError(f"{name}: must be a positive number, got {value!r}")
    return float(value)


def _check_robot_radius(robot_radius: float) -> None:
    if not (math.isfinite(robot_radius) and robot_radius >= 0.0):
        raise ValueError(f"robot_radius: must be >= 0, got {robot_radius!r}")


def _blank(calibration: Calibration) -> np.ndarray:
    width, height = calibration.image_size
    return np.full((height, width, 3), FLOOR_GREY, dtype=np.uint8)


def _draw_disc(
    frame: np.ndarray,
    calibration: Calibration,
    centre: tuple[float, float],
    radius: float,
    colour: tuple[int, int, int],
) -> None:
    """Fill the image of a floor disc (a projected polygon, anti-aliased, sub-pixel vertices)."""
    angles = np.linspace(0.0, 2.0 * math.pi, CIRCLE_VERTICES, endpoint=False)
    ring = np.c_[centre[0] + radius * np.cos(angles), centre[1] + radius * np.sin(angles)]
    px = floor_to_pixel(calibration, ring)
    pts = np.round(px * (1 << _SHIFT)).astype(np.int32).reshape(-1, 1, 2)
    cv2.fillPoly(frame, [pts], colour, lineType=cv2.LINE_AA, shift=_SHIFT)


def _draw_scene(
    calibration: Calibration,
    poses: dict[str, tuple[float, float, float]],
    obstacles: list[tuple[float, float, float]],
    robot_radius: float,
) -> np.ndarray:
    frame = _blank(calibration)
    for x, y, r in obstacles:
        _draw_disc(frame, calibration, (x, y), r, OBSTACLE_BGR)
    if robot_radius > 0.0:
        for x, y, _theta in poses.values():
            _draw_disc(frame, calibration, (x, y), robot_radius, ROBOT_BGR)
    return frame


@lru_cache(maxsize=256)
def _marker_image(dictionary: str, marker_id: int, quiet_modules: int) -> np.ndarray:
    """The marker with its quiet zone, one pixel per module (to be point-sampled)."""
    d = aruco_dictionary(dictionary)
    modules = d.markerSize + 2 * MARKER_BORDER_BITS
    core = cv2.aruco.generateImageMarker(d, marker_id, modules, borderBits=MARKER_BORDER_BITS)
    image = cv2.copyMakeBorder(
        core, quiet_modules, quiet_modules, quiet_modules, quiet_modules,
        cv2.BORDER_CONSTANT, value=255,
    )
    image.setflags(write=False)
    return image


def _paste_marker(
    frame: np.ndarray,
    calibration: Calibration,
    pose: tuple[float, float, float],
    image: np.ndarray,
    side: float,
) -> None:
    """Project the marker ``image`` (a square ``side`` metres wide) to ``pose`` and blend it in."""
    x, y, theta = pose
    n = image.shape[0]
    c, s = math.cos(theta), math.sin(theta)
    # Corners of the square in the marker frame (x forward, y left), then on the floor.
    half = side / 2.0
    local = np.array([[-half, half], [half, half], [half, -half], [-half, -half]])
    floor = local @ np.array([[c, s], [-s, c]]) + np.array([x, y])
    corners = floor_to_pixel(calibration, floor)
    height, width = frame.shape[:2]
    u0 = max(int(math.floor(corners[:, 0].min())) - 1, 0)
    v0 = max(int(math.floor(corners[:, 1].min())) - 1, 0)
    u1 = min(int(math.ceil(corners[:, 0].max())) + 2, width)
    v1 = min(int(math.ceil(corners[:, 1].max())) + 2, height)
    if u1 <= u0 or v1 <= v0:
        return  # entirely outside the image
    k = SUPERSAMPLE
    # marker image pixel (col, row), centres at integers -> marker frame metres
    m = side / n
    img_to_marker = np.array([[m, 0.0, m / 2 - half], [0.0, -m, half - m / 2], [0.0, 0.0, 1.0]])
    marker_to_floor = np.array([[c, -s, x], [s, c, y], [0.0, 0.0, 1.0]])
    # image pixel (u, v) -> supersampled ROI pixel: i = k (u - u0 + 1/2) - 1/2
    to_roi = np.array(
        [[k, 0.0, k * (0.5 - u0) - 0.5], [0.0, k, k * (0.5 - v0) - 0.5], [0.0, 0.0, 1.0]]
    )
    transform = to_roi @ calibration.pixel_from_floor @ marker_to_floor @ img_to_marker
    size = (k * (u1 - u0), k * (v1 - v0))
    # Point-sample the ideal marker (nearest module) at every sub-pixel, then box-average.
    fine = cv2.warpPerspective(
        image, transform, size, flags=cv2.INTER_NEAREST,
        borderMode=cv2.BORDER_CONSTANT, borderValue=0,
    )
    cover = cv2.warpPerspective(
        np.full_like(image, 255), transform, size, flags=cv2.INTER_NEAREST,
        borderMode=cv2.BORDER_CONSTANT, borderValue=0,
    )
    roi_size = (u1 - u0, v1 - v0)
    grey = cv2.resize(fine, roi_size, interpolation=cv2.INTER_AREA).astype(np.float32)
    alpha = cv2.resize(cover, roi_size, interpolation=cv2.INTER_AREA).astype(np.float32) / 255.0
    roi = frame[v0:v1, u0:u1].astype(np.float32)
    # ``grey`` is already premultiplied by coverage (black outside the marker).
    blended = roi * (1.0 - alpha)[:, :, None] + grey[:, :, None]
    frame[v0:v1, u0:u1] = np.clip(blended + 0.5, 0, 255).astype(np.uint8)


def _finish(
    frame: np.ndarray,
    noise_std: float,
    blur_sigma: float,
    rng: np.random.Generator | None,
) -> np.ndarray:
    """Optical blur, then sensor noise (Gaussian, rounded to whole grey levels).

    The noise comes from OpenCV's thread-local generator, seeded from ``rng`` (from a fixed seed
    when ``rng`` is None), so the frame is a function of the arguments; cv2.randn is about four
    times faster than numpy's normal generator for a full frame.
    """
    if not (math.isfinite(blur_sigma) and blur_sigma >= 0.0):
        raise ValueError(f"blur_sigma: must be >= 0 pixels, got {blur_sigma!r}")
    if not (math.isfinite(noise_std) and noise_std >= 0.0):
        raise ValueError(f"noise_std: must be >= 0 grey levels, got {noise_std!r}")
    if blur_sigma > 0.0:
        frame = cv2.GaussianBlur(frame, (0, 0), blur_sigma)
    if noise_std > 0.0:
        generator = rng if rng is not None else np.random.default_rng(0)
        cv2.setRNGSeed(int(generator.integers(2**31 - 1)))
        # One channel: cv2.randn's scalar std would otherwise reach the first channel only.
        noise = np.empty((frame.shape[0], frame.size // frame.shape[0]), dtype=np.int16)
        # OpenCV takes scalars for mean and stddev (a cv::Scalar); its stub admits arrays only.
        cv2.randn(noise, 0.0, noise_std)  # type: ignore[call-overload]
        frame = cv2.add(frame, noise.reshape(frame.shape), dtype=cv2.CV_8U)  # saturates
    return frame


@dataclass(frozen=True)
class MarkerPrint:
    """How every robot's marker is printed: its ArUco ``dictionary`` and the white
    ``quiet_zone`` [modules] around its black square."""

    dictionary: str = DEFAULT_DICTIONARY
    quiet_zone: int = QUIET_ZONE


def render_aruco_frame(
    poses: Mapping[str, PoseLike],
    calibration: Calibration,
    marker_ids: Mapping[str, int],
    obstacles: Iterable[tuple[float, float, float]] = (),
    *,
    printed: MarkerPrint = MarkerPrint(),
    marker_side: float = MARKER_SIDE,
    robot_radius: float = ROBOT_RADIUS,
    noise_std: float = 0.0,
    blur_sigma: float = 0.0,
    rng: np.random.Generator | None = None,
) -> np.ndarray:
    """An overhead BGR frame (uint8) with one ArUco marker per robot.

    ``poses`` maps robot id -> ``(x, y, theta)`` [m, m, rad]; every posed robot needs an entry in
    ``marker_ids`` (robot id -> marker id of ``printed.dictionary``). ``obstacles`` are
    ``(x, y, radius)`` [m] drawn as grey discs. ``marker_side`` [m] is the black square's side;
    ``printed.quiet_zone``
    [modules] the white margin around it. ``noise_std`` [grey levels] adds Gaussian sensor noise
    drawn from ``rng`` (a fixed seed when omitted, so the function stays deterministic);
    ``blur_sigma`` [px] a Gaussian optical blur. Set ``robot_radius`` to 0 to leave bodies out.
    """
    checked = _check_poses(poses)
    dictionary, quiet_zone = printed.dictionary, printed.quiet_zone
    ids = check_marker_ids(marker_ids, dictionary)
    missing = sorted(set(checked) - set(ids))
    if missing:
        raise ValueError(f"marker_ids: no marker id for robot {missing[0]!r}")
    side = _check_positive(marker_side, "marker_side")
    if not (isinstance(quiet_zone, int) and 0 <= quiet_zone <= 4):
        raise ValueError(f"quiet_zone: must be an int number of modules in 0..4, got {quiet_zone}")
    _check_robot_radius(robot_radius)
    frame = _draw_scene(calibration, checked, _check_obstacles(obstacles), robot_radius)
    modules = aruco_dictionary(dictionary).markerSize + 2 * MARKER_BORDER_BITS
    outer = side * (modules + 2 * quiet_zone) / modules  # [m] side with the quiet zone
    for robot, pose in checked.items():
        image = _marker_image(dictionary, ids[robot], quiet_zone)
        _paste_marker(frame, calibration, pose, image, outer)
    return _finish(frame, noise_std, blur_sigma, rng)


def default_hues(robot_ids: Iterable[str]) -> dict[str, int]:
    """Evenly spaced OpenCV hues (0..179) for the robots, in sorted id order (first one red)."""
    robots = sorted(set(robot_ids))
    if not robots:
        return {}
    step = 180.0 / len(robots)
    return {robot: int(round(i * step)) % 180 for i, robot in enumerate(robots)}


def hue_to_bgr(hue: int) -> tuple[int, int, int]:
    """The saturated BGR colour of an OpenCV hue (0..179)."""
    if isinstance(hue, bool) or not isinstance(hue, int | np.integer) or not 0 <= hue < 180:
        raise ValueError(f"hue: must be an int in 0..179, got {hue!r}")
    hsv = np.array([[[hue, BLOB_SATURATION, BLOB_VALUE]]], dtype=np.uint8)
    b, g, r = cv2.cvtColor(hsv, cv2.COLOR_HSV2BGR)[0, 0]
    return int(b), int(g), int(r)


def render_blob_frame(
    poses: Mapping[str, PoseLike],
    calibration: Calibration,
    hues: Mapping[str, int],
    obstacles: Iterable[tuple[float, float, float]] = (),
    *,
    blob_radius: float = BLOB_RADIUS,
    robot_radius: float = ROBOT_RADIUS,
    noise_std: float = 0.0,
    blur_sigma: float = 0.0,
    rng: np.random.Generator | None = None,
) -> np.ndarray:
    """An overhead BGR frame (uint8) with one coloured disc per robot (no heading shown).

    ``hues`` maps robot id -> OpenCV hue 0..179 (see :func:`default_hues`); the disc of radius
    ``blob_radius`` [m] sits centred on the robot. Other arguments as in
    :func:`render_aruco_frame`.
    """
    checked = _check_poses(poses)
    if not isinstance(hues, Mapping):
        raise ValueError(f"hues: expected a mapping robot_id -> hue, got {hues!r}")
    missing = sorted(set(checked) - set(hues))
    if missing:
        raise ValueError(f"hues: no hue for robot {missing[0]!r}")
    colours = {robot: hue_to_bgr(hues[robot]) for robot in checked}
    radius = _check_positive(blob_radius, "blob_radius")
    _check_robot_radius(robot_radius)
    frame = _draw_scene(calibration, checked, _check_obstacles(obstacles), robot_radius)
    for robot, (x, y, _theta) in checked.items():
        _draw_disc(frame, calibration, (x, y), radius, colours[robot])
    return _finish(frame, noise_std, blur_sigma, rng)
