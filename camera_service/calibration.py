"""Floor <-> pixel homography of the overhead camera.

A camera looking down at a flat floor sees it through a plane-to-plane projective map, a 3x3
homography ``H`` with ``[x, y, 1] ~ H [u, v, 1]``. Four or more correspondences between pixels and
measured floor points fix it (``cv2.findHomography``); after that every pixel maps to the floor
and back without a camera model.

Frames and units:

- floor: metres, right-handed, ``x`` and ``y`` on the floor, ``z`` up towards the camera; a
  heading ``theta`` is measured counter-clockwise from ``+x`` in radians.
- image: pixels, ``u`` to the right, ``v`` down, integer coordinates at pixel centres (OpenCV's
  convention, so the image spans ``[-0.5, width - 0.5]``).

The homography is exact for one plane only. Markers ride on the robots' top plates, 0.19 m
above the floor on a TurtleBot3 burger: with a camera 3 m up, such a marker mapped through the
floor homography lands about 7 % of its distance from the camera's nadir too far out (30 mm at
0.5 m from the nadir). Parallax correction (:func:`correct_parallax`): the floor homography maps
a pixel to the point where its ray meets the floor; the marker lies on that ray, at height ``h``.
With the camera's centre ``C = (cx, cy, cz)`` in floor coordinates (``camera_position``, found by
``formation calibrate``), the marker's floor position is ``C_xy + (q - C_xy) (1 - h / cz)``: a
scaling about the nadir, so headings are unchanged. This holds for any camera orientation.
A calibration may also hold the lens's ``camera_matrix`` and ``dist_coeffs``; the homography is
then in the pixels of the undistorted image (the frames are undistorted before detection).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import cast

import cv2
import numpy as np
import yaml

logger = logging.getLogger(__name__)

CALIBRATION_VERSION = 1  # version of the YAML layout written by save_calibration
DEFAULT_IMAGE_SIZE = (1280, 960)  # [px] width, height of the synthetic camera
DEFAULT_ARENA = (0.0, 0.0, 4.0, 3.0)  # [m] x_min, y_min, x_max, y_max seen by the synthetic camera
DEFAULT_MARGIN = 16  # [px] border left around the arena in the synthetic image
MAX_TILT = 0.5  # largest accepted perspective tilt (fraction the far edge shrinks)
_HORIZON_EPS = 1e-12  # |w| below this: the point maps to infinity

_YAML_KEYS = {"version", "image_size", "floor_from_pixel", "units", "camera_position",
              "camera_matrix", "dist_coeffs", "residual_m", "floor_markers"}


@dataclass(frozen=True, eq=False)
class Calibration:
    """A floor <-> pixel homography for one camera image size.

    ``floor_from_pixel`` maps homogeneous pixels ``[u, v, 1]`` to homogeneous floor points
    ``[x, y, 1]`` (metres), normalised so that its bottom-right entry is 1.
    """

    floor_from_pixel: np.ndarray  # 3x3, pixels -> metres
    image_size: tuple[int, int]  # [px] width, height
    camera_position: tuple[float, float, float] | None = None  # [m] camera centre on the floor frame
    camera_matrix: np.ndarray | None = None  # 3x3 intrinsics (frames are undistorted with them)
    dist_coeffs: np.ndarray | None = None  # OpenCV distortion coefficients
    floor_markers: tuple[int, ...] = ()  # ids of the floor markers calibrated on (not robots)
    pixel_from_floor: np.ndarray = field(init=False, repr=False)  # 3x3, metres -> pixels

    def __post_init__(self) -> None:
        h, inverse = _checked_homography(self.floor_from_pixel)
        size = _checked_image_size(self.image_size)
        object.__setattr__(self, "floor_from_pixel", h)
        object.__setattr__(self, "image_size", size)
        object.__setattr__(self, "pixel_from_floor", inverse)
        if self.camera_position is not None:
            object.__setattr__(self, "camera_position", _checked_camera_position(self.camera_position))
        object.__setattr__(self, "floor_markers", _checked_marker_ids(self.floor_markers))
        if (self.camera_matrix is None) != (self.dist_coeffs is None):
            raise ValueError("camera_matrix: camera_matrix and dist_coeffs go together")
        if self.camera_matrix is not None and self.dist_coeffs is not None:
            k, d = _checked_intrinsics(self.camera_matrix, self.dist_coeffs)
            object.__setattr__(self, "camera_matrix", k)
            object.__setattr__(self, "dist_coeffs", d)


def _checked_homography(matrix: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``floor_from_pixel`` normalised (bottom-right 1) and its inverse, both read-only."""
    h = np.array(matrix, dtype=np.float64)
    if h.shape != (3, 3) or not np.all(np.isfinite(h)):
        raise ValueError(f"floor_from_pixel: expected a finite 3x3 matrix, got {h.shape}")
    if abs(np.linalg.det(h)) < 1e-300 or abs(h[2, 2]) < 1e-15:
        raise ValueError("floor_from_pixel: singular homography")
    h = h / h[2, 2]
    h.setflags(write=False)
    inverse = np.linalg.inv(h)
    inverse = inverse / inverse[2, 2]
    inverse.setflags(write=False)
    return h, inverse


def _checked_image_size(image_size: tuple[int, int]) -> tuple[int, int]:
    size = tuple(int(s) for s in image_size)
    if len(size) != 2 or min(size) <= 0:
        raise ValueError(f"image_size: expected (width, height) > 0, got {image_size}")
    return size[0], size[1]


def _checked_camera_position(position: tuple[float, float, float]) -> tuple[float, float, float]:
    c = tuple(float(v) for v in position)
    if len(c) != 3 or not all(math.isfinite(v) for v in c) or c[2] <= 0.0:
        raise ValueError(f"camera_position: expected finite [x, y, z > 0], got {position!r}")
    return c[0], c[1], c[2]


def _checked_marker_ids(floor_markers: tuple[int, ...]) -> tuple[int, ...]:
    ids = tuple(floor_markers)
    if not all(isinstance(i, int | np.integer) and not isinstance(i, bool) and i >= 0 for i in ids):
        raise ValueError(f"floor_markers: expected marker ids, got {floor_markers!r}")
    return tuple(int(i) for i in ids)


def _checked_intrinsics(camera_matrix: np.ndarray, dist_coeffs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The camera matrix (3x3, fx, fy > 0) and distortion coefficients, read-only float64."""
    k = np.array(camera_matrix, dtype=np.float64)
    d = np.array(dist_coeffs, dtype=np.float64).ravel()
    if k.shape != (3, 3) or not np.all(np.isfinite(k)) or k[0, 0] <= 0 or k[1, 1] <= 0:
        raise ValueError("camera_matrix: expected a finite 3x3 matrix with fx, fy > 0")
    if d.size not in (4, 5, 8, 12, 14) or not np.all(np.isfinite(d)):
        raise ValueError("dist_coeffs: expected 4, 5, 8, 12 or 14 finite numbers")
    k.setflags(write=False)
    d.setflags(write=False)
    return k, d


def correct_parallax(points: np.ndarray, camera_position: tuple[float, float, float],
                     height: float) -> np.ndarray:
    """Floor points ``(N, 2)`` of rays through a plane ``height`` above the floor -> the points
    of that plane (their floor x, y). See the module docstring; exact for a pinhole camera."""
    cx, cy, cz = camera_position
    scale = 1.0 - height / cz
    centre = np.array([cx, cy])
    return centre + (np.asarray(points, dtype=np.float64) - centre) * scale


def _as_points(points: object, name: str) -> tuple[np.ndarray, bool]:
    """Points as an (N, 2) float array, and whether the caller gave a single (2,) point."""
    try:
        arr = np.asarray(points, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name}: not an array of numbers ({exc})") from None
    single = arr.shape == (2,)
    if single:
        arr = arr.reshape(1, 2)
    if arr.ndim != 2 or arr.shape[1] != 2:
        raise ValueError(f"{name}: expected shape (N, 2) or (2,), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name}: contains non-finite values")
    return arr, single


def apply_homography(matrix: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Map (N, 2) points through a 3x3 homography; raises ValueError on the horizon line."""
    w = points @ matrix[2, :2] + matrix[2, 2]
    if np.any(np.abs(w) < _HORIZON_EPS):
        raise ValueError("points: a point lies on the horizon line and maps to infinity")
    out = points @ matrix[:2, :2].T + matrix[:2, 2]
    return out / w[:, None]


def pixel_to_floor(calibration: Calibration, points: object) -> np.ndarray:
    """Pixels ``(u, v)`` -> floor metres ``(x, y)``; accepts one ``(2,)`` point or ``(N, 2)``."""
    arr, single = _as_points(points, "points")
    out = apply_homography(calibration.floor_from_pixel, arr)
    return out[0] if single else out


def floor_to_pixel(calibration: Calibration, points: object) -> np.ndarray:
    """Floor metres ``(x, y)`` -> pixels ``(u, v)``; accepts one ``(2,)`` point or ``(N, 2)``."""
    arr, single = _as_points(points, "points")
    out = apply_homography(calibration.pixel_from_floor, arr)
    return out[0] if single else out


def heading_to_floor(
    calibration: Calibration, pixel: object, angle: float, step: float = 1.0
) -> float:
    """Image direction ``angle`` at ``pixel`` -> floor heading [rad].

    ``angle`` is measured from ``+u`` towards ``+v`` (image convention, clockwise on screen). The
    direction is mapped as the chord from ``pixel`` to ``pixel + step * (cos, sin)``; ``step`` [px]
    should be small against the image but need not be tiny (a homography bends directions only
    slowly).
    """
    p0, _ = _as_points(pixel, "pixel")
    if not math.isfinite(angle):
        raise ValueError(f"angle: must be finite, got {angle}")
    if not (math.isfinite(step) and step > 0.0):
        raise ValueError(f"step: must be a positive number of pixels, got {step}")
    return _map_direction(calibration.floor_from_pixel, p0, angle, step)


def heading_to_pixel(
    calibration: Calibration, point: object, theta: float, step: float = 0.01
) -> float:
    """Floor heading ``theta`` at floor ``point`` -> image direction [rad] (from ``+u`` to ``+v``).

    The chord from ``point`` to ``point + step * (cos, sin)`` (``step`` in metres) is mapped.
    """
    p0, _ = _as_points(point, "point")
    if not math.isfinite(theta):
        raise ValueError(f"theta: must be finite, got {theta}")
    if not (math.isfinite(step) and step > 0.0):
        raise ValueError(f"step: must be a positive distance in metres, got {step}")
    return _map_direction(calibration.pixel_from_floor, p0, theta, step)


def _map_direction(matrix: np.ndarray, p0: np.ndarray, angle: float, step: float) -> float:
    """Direction [rad] of the chord from ``p0`` to ``p0 + step * (cos, sin)`` after ``matrix``."""
    p1 = p0 + step * np.array([[math.cos(angle), math.sin(angle)]])
    q = apply_homography(matrix, np.vstack([p0, p1]))
    d = q[1] - q[0]
    return math.atan2(d[1], d[0])


def fit_homography(
    pixel_points: object,
    floor_points: object,
    image_size: tuple[int, int],
    ransac_threshold: float | None = None,
) -> Calibration:
    """Fit the floor <-> pixel homography from N >= 4 correspondences.

    ``pixel_points[i]`` (pixels) is where the camera sees ``floor_points[i]`` (metres). With
    ``ransac_threshold`` (a reprojection error in metres) outliers are rejected by RANSAC;
    otherwise all points are used in a least-squares fit.
    """
    px, _ = _as_points(pixel_points, "pixel_points")
    fl, _ = _as_points(floor_points, "floor_points")
    if len(px) < 4:
        raise ValueError(f"pixel_points: need at least 4 correspondences, got {len(px)}")
    if len(fl) != len(px):
        raise ValueError(
            f"floor_points: {len(fl)} points do not match {len(px)} pixel_points"
        )
    if ransac_threshold is not None and not (
        math.isfinite(ransac_threshold) and ransac_threshold > 0.0
    ):
        raise ValueError(f"ransac_threshold: must be a positive distance, got {ransac_threshold}")
    # A degenerate configuration (three or more of four points collinear) has no unique answer.
    if np.linalg.matrix_rank(np.c_[px, np.ones(len(px))], tol=1e-6) < 3:
        raise ValueError("pixel_points: all points are collinear")
    if np.linalg.matrix_rank(np.c_[fl, np.ones(len(fl))], tol=1e-9) < 3:
        raise ValueError("floor_points: all points are collinear")
    if ransac_threshold is None:
        h, _mask = cv2.findHomography(px, fl, 0)
    else:
        h, _mask = cv2.findHomography(px, fl, cv2.RANSAC, ransac_threshold)
    if h is None or not np.all(np.isfinite(h)):
        raise ValueError("pixel_points: no homography fits these correspondences (degenerate)")
    calibration = Calibration(h, image_size)
    logger.debug(
        "fitted homography from %d points, rms error %.4f m",
        len(px),
        reprojection_error(calibration, px, fl),
    )
    return calibration


def reprojection_error(
    calibration: Calibration, pixel_points: object, floor_points: object
) -> float:
    """Root-mean-square floor distance [m] between mapped pixels and their floor points."""
    px, _ = _as_points(pixel_points, "pixel_points")
    fl, _ = _as_points(floor_points, "floor_points")
    if len(fl) != len(px):
        raise ValueError(
            f"floor_points: {len(fl)} points do not match {len(px)} pixel_points"
        )
    d = apply_homography(calibration.floor_from_pixel, px) - fl
    return float(np.sqrt(np.mean(np.sum(d * d, axis=1))))


def synthetic_camera(
    image_size: tuple[int, int] = DEFAULT_IMAGE_SIZE,
    arena: tuple[float, float, float, float] = DEFAULT_ARENA,
    margin: int = DEFAULT_MARGIN,
    tilt: float = 0.0,
) -> Calibration:
    """A plausible overhead camera that sees the floor rectangle ``arena``.

    ``arena = (x_min, y_min, x_max, y_max)`` [m] is fitted into the image, aspect kept, centred,
    ``margin`` pixels clear of the image border. Floor ``+x`` points right in the image and floor
    ``+y`` up (so the view is not mirrored). ``tilt`` in ``[0, 0.5)`` mimics a camera leaning back:
    the far edge (``y_max``) appears that fraction shorter than the near edge, with the projective
    foreshortening that goes with it.
    """
    try:
        width, height = (int(s) for s in image_size)
    except (TypeError, ValueError):
        raise ValueError(f"image_size: expected (width, height), got {image_size!r}") from None
    if width < 16 or height < 16:
        raise ValueError(f"image_size: at least 16x16 pixels, got {width}x{height}")
    try:
        x_min, y_min, x_max, y_max = (float(a) for a in arena)
    except (TypeError, ValueError):
        raise ValueError(f"arena: expected (x_min, y_min, x_max, y_max), got {arena!r}") from None
    if not all(math.isfinite(a) for a in (x_min, y_min, x_max, y_max)):
        raise ValueError(f"arena: must be finite, got {arena!r}")
    if not (x_max > x_min and y_max > y_min):
        raise ValueError(f"arena: needs x_max > x_min and y_max > y_min, got {arena!r}")
    if not (0 <= margin < min(width, height) / 2 - 4):
        raise ValueError(f"margin: must be in [0, {min(width, height) // 2 - 4}), got {margin}")
    if not (math.isfinite(tilt) and 0.0 <= tilt < MAX_TILT):
        raise ValueError(f"tilt: must be in [0, {MAX_TILT}), got {tilt}")
    span_x, span_y = x_max - x_min, y_max - y_min
    scale = min((width - 2 * margin) / span_x, (height - 2 * margin) / span_y)  # [px/m]
    cu, cv = (width - 1) / 2.0, (height - 1) / 2.0
    half_w, half_h = scale * span_x / 2.0, scale * span_y / 2.0
    far = half_w * (1.0 - tilt)  # half width of the far (top) edge
    pixels = np.array(
        [
            [cu - half_w, cv + half_h],  # (x_min, y_min), near left
            [cu + half_w, cv + half_h],  # (x_max, y_min), near right
            [cu + far, cv - half_h],  # (x_max, y_max), far right
            [cu - far, cv - half_h],  # (x_min, y_max), far left
        ],
    )
    floor = np.array([[x_min, y_min], [x_max, y_min], [x_max, y_max], [x_min, y_max]])
    h, _mask = cv2.findHomography(pixels, floor, 0)  # exact through four points, in float64
    return Calibration(h, (width, height))


def calibration_to_dict(calibration: Calibration) -> dict[str, object]:
    """A plain, YAML-friendly dictionary of the calibration."""
    out: dict[str, object] = {
        "version": CALIBRATION_VERSION,
        "units": "m",
        "image_size": [int(s) for s in calibration.image_size],
        "floor_from_pixel": [[float(v) for v in row] for row in calibration.floor_from_pixel],
    }
    if calibration.camera_position is not None:
        out["camera_position"] = [float(v) for v in calibration.camera_position]
    if calibration.floor_markers:
        out["floor_markers"] = list(calibration.floor_markers)
    if calibration.camera_matrix is not None and calibration.dist_coeffs is not None:  # both or neither
        out["camera_matrix"] = [[float(v) for v in row] for row in calibration.camera_matrix]
        out["dist_coeffs"] = [float(v) for v in calibration.dist_coeffs]
    return out


def calibration_from_dict(data: object) -> Calibration:
    """Inverse of ``calibration_to_dict``; unknown or missing keys are a ValueError naming them."""
    if not isinstance(data, dict):
        raise ValueError(f"calibration: expected a mapping, got {type(data).__name__}")
    _check_calibration_keys(data)
    size = data["image_size"]
    if not (isinstance(size, list | tuple) and len(size) == 2):
        raise ValueError(f"image_size: expected [width, height], got {size!r}")
    try:
        matrix = np.array(data["floor_from_pixel"], dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError("floor_from_pixel: expected a 3x3 list of numbers") from None
    position = _optional_numbers(data, "camera_position")
    return Calibration(matrix, (size[0], size[1]),
                       camera_position=None if position is None else _position_tuple(position),
                       camera_matrix=_optional_numbers(data, "camera_matrix"),
                       dist_coeffs=_optional_numbers(data, "dist_coeffs"),
                       floor_markers=_floor_markers(data))


def _check_calibration_keys(data: dict[object, object]) -> None:
    """No unknown key, the required ones present, the version and units this reader knows."""
    unknown = sorted(set(map(str, data)) - _YAML_KEYS)
    if unknown:
        raise ValueError(f"{unknown[0]}: unknown key in calibration")
    for key in ("version", "image_size", "floor_from_pixel"):
        if key not in data:
            raise ValueError(f"{key}: missing from calibration")
    if data["version"] != CALIBRATION_VERSION:
        raise ValueError(f"version: unsupported calibration version {data['version']!r}")
    if data.get("units", "m") != "m":
        raise ValueError(f"units: only metres ('m') are supported, got {data['units']!r}")


def _optional_numbers(data: dict[object, object], key: str) -> np.ndarray | None:
    """``data[key]`` as a float64 array; None when absent or null."""
    if data.get(key) is None:
        return None
    try:
        return np.array(data[key], dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{key}: expected numbers") from None


def _position_tuple(position: np.ndarray) -> tuple[float, float, float]:
    """The camera position's numbers as a tuple (Calibration checks there are three)."""
    return cast(tuple[float, float, float], tuple(position.ravel()))


def _floor_markers(data: dict[object, object]) -> tuple[int, ...]:
    markers = data.get("floor_markers")
    if markers is None:
        return ()
    if not isinstance(markers, list):
        raise ValueError(f"floor_markers: expected a list of ids, got {markers!r}")
    return tuple(markers)


def save_calibration(calibration: Calibration, path: str | Path) -> None:
    """Write the calibration as YAML (full float precision)."""
    text = yaml.safe_dump(calibration_to_dict(calibration), sort_keys=False)
    Path(path).write_text(text, encoding="utf-8")


def load_calibration(path: str | Path) -> Calibration:
    """Read a calibration written by ``save_calibration``."""
    try:
        data = yaml.safe_load(Path(path).read_text(encoding="utf-8"))
    except yaml.YAMLError as exc:
        raise ValueError(f"path: {path} is not valid YAML ({exc})") from None
    return calibration_from_dict(data)
