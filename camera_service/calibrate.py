"""``formation calibrate``: the floor homography and the camera's position from one image.

Input: an overhead image of ArUco markers lying on the floor with their centres at surveyed
points (``FLOOR.yaml``: dictionary, printed side, id -> floor x, y), and optionally the lens's
intrinsics and distortion (``--intrinsics``, from a ChArUco calibration); the image is then
undistorted first, like every frame of the camera service, and the homography is in undistorted
pixels.

Fit (:func:`calibrate_image`):

1. detect the floor markers; the pixel centre of each is the intersection of its diagonals
   (a homography keeps it, so it is exactly the image of the surveyed centre);
2. a first homography from the centres;
3. each marker's orientation on the floor is read through that homography (the survey gives
   centres only); with it every corner gets a floor position (centre plus half the printed side
   along the marker's axes), and the homography is fitted again on all corners: 4 points per
   marker instead of 1 average out corner noise, and the printed size constrains the scale;
4. outliers: while a marker's centre error is over ``max_error`` and more than 4 markers are
   left, the worst one is set aside (reported) and the fit repeated: a marker moved since the
   survey, or a typo in FLOOR.yaml, does not spoil the rest;
5. refusals (:class:`CalibrationError`, exit 2): fewer than 4 markers, a near-collinear layout
   (the smaller principal spread of the centres under :data:`MIN_SPREAD` of the larger), or a
   marker still over ``max_error``.

Camera position (for the marker-height parallax, :func:`camera_service.calibration.
correct_parallax`): ``cv2.solvePnP`` (IPPE, planar) on the corners gives the camera's pose, and
its centre in floor coordinates is ``-R^T t``. Without ``--intrinsics`` the focal length is
recovered from the homography itself (square pixels, principal point at the image centre: the
two constraints of the rotation's first two columns being orthogonal and of equal length, solved
together in least squares). That fails for a camera looking almost straight down (the
constraints vanish); ``--camera-height H`` then places the camera ``H`` above the floor point
seen at the image centre.

Measured residual (tests/overhead_rig.py: an independent pinhole renderer, 1280x960 at about
3 mm per pixel, camera 3 m up tilted 6 to 12 deg in a random direction, principal point up to
8 px off centre, blur, noise, uneven light; 6 robots' markers 0.19 m up, 5 random cameras,
36 poses each; ``python3 benchmarks/camera_accuracy.py 0 5``): with ``--intrinsics`` the camera centre
comes out within 0.7 to 2.8 mm and the robots' positions within 0.16 to 0.26 mm median (p95
0.27 to 0.54 mm); with the focal length recovered from the homography the camera centre is
10 to 200 mm off (the principal point is assumed at the image centre) and the robots 0.2 to
3.2 mm median (p95 0.4 to 5.7 mm); without the parallax correction the same robots are 41 to
70 mm off (median), up to 100 mm at p95.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import yaml

from camera_service.calibration import Calibration, apply_homography
from camera_service.config import ConfigError, FloorMarkers
from camera_service.markers import check_frame, make_detector, to_grey

logger = logging.getLogger(__name__)

MIN_MARKERS = 4
MIN_SPREAD = 0.1  # smaller / larger principal spread of the marker centres; below: collinear
MAX_ERROR_M = 0.02  # [m] default: largest accepted centre error of one marker
MIN_TILT_CONSTRAINT = 1e-3  # below this relative size the focal length is unobservable


class CalibrationError(ValueError):
    """The image cannot give a trustworthy calibration; the message says why."""


@dataclass(frozen=True)
class CalibrationReport:
    calibration: Calibration
    errors_m: dict[int, float]  # marker id -> centre error of the fit [m] (used markers)
    rejected: dict[int, float] = field(default_factory=dict)  # set-aside outliers -> error [m]
    missing: tuple[int, ...] = ()  # surveyed markers not found in the image
    focal_px: float | None = None  # [px] focal length used for the camera position
    focal_source: str = ""  # "intrinsics", "homography" or "camera-height"

    @property
    def max_error_m(self) -> float:
        return max(self.errors_m.values())


def load_intrinsics(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """``camera_matrix`` (3x3) and ``dist_coeffs`` from a YAML file: plain YAML with those two
    keys (``image_size`` allowed), or OpenCV's FileStorage YAML (``camera_matrix`` and
    ``distortion_coefficients`` or ``dist_coeffs``) as OpenCV's calibration samples write it."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read intrinsics: {exc.strerror or exc}") from None
    k, d = _filestorage_intrinsics(path) if text.startswith("%YAML") else _yaml_intrinsics(path, text)
    if k is None or d is None:
        raise ConfigError(f"{path}: intrinsics need camera_matrix and dist_coeffs")
    try:
        matrix = np.array(k, dtype=np.float64).reshape(3, 3)
        coeffs = np.array(d, dtype=np.float64).ravel()
        Calibration(np.eye(3), (16, 16), camera_matrix=matrix, dist_coeffs=coeffs)  # the same checks
    except ValueError as exc:
        raise ConfigError(f"{path}: {exc}") from None
    return matrix, coeffs


def _filestorage_intrinsics(path: Path) -> tuple[np.ndarray | None, np.ndarray | None]:
    """``camera_matrix`` and the distortion coefficients of OpenCV's FileStorage YAML (None: absent)."""
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    k = fs.getNode("camera_matrix").mat()
    d = fs.getNode("distortion_coefficients").mat()
    if d is None:
        d = fs.getNode("dist_coeffs").mat()
    fs.release()
    return k, d


def _yaml_intrinsics(path: Path, text: str) -> tuple[object, object]:
    """``camera_matrix`` and ``dist_coeffs`` of plain YAML (None: absent); unknown keys refused."""
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError:
        raise ConfigError(f"{path}: intrinsics are not valid YAML") from None
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: intrinsics: expected a mapping")
    unknown = sorted(set(map(str, data)) - {"camera_matrix", "dist_coeffs", "image_size"})
    if unknown:
        raise ConfigError(f"{path}: {unknown[0]}: unknown key in intrinsics")
    return data.get("camera_matrix"), data.get("dist_coeffs")


def _marker_centre(quad: np.ndarray) -> np.ndarray:
    """Pixel intersection of the diagonals of a quadrilateral (corners in order)."""
    p0, p1, p2, p3 = quad
    d1, d2 = p2 - p0, p3 - p1
    a = np.array([d1, -d2]).T
    if abs(np.linalg.det(a)) < 1e-12:
        return quad.mean(axis=0)
    s = np.linalg.solve(a, p1 - p0)[0]
    return p0 + s * d1


def _corner_targets(h: np.ndarray, quad: np.ndarray, centre: tuple[float, float],
                    side: float) -> np.ndarray:
    """Floor positions of a marker's four corners: its surveyed centre, the printed side, and
    its orientation as ``h`` (pixels -> floor) shows it."""
    q = apply_homography(h, quad)
    x_axis = (q[1] - q[0]) + (q[2] - q[3])
    y_axis = (q[0] - q[3]) + (q[1] - q[2])
    d = x_axis + np.array([y_axis[1], -y_axis[0]])
    theta = math.atan2(d[1], d[0])
    c, s = math.cos(theta), math.sin(theta)
    half = side / 2.0
    local = np.array([[-half, half], [half, half], [half, -half], [-half, -half]])
    return local @ np.array([[c, s], [-s, c]]) + np.asarray(centre)


def _fit(quads: dict[int, np.ndarray], floor: FloorMarkers) -> tuple[np.ndarray, dict]:
    """Homography (pixels -> floor) from the markers ``quads``; centre error of each [m]."""
    ids = sorted(quads)
    px = np.array([_marker_centre(quads[i]) for i in ids])
    fl = np.array([floor.markers[i] for i in ids])
    h, _ = cv2.findHomography(px, fl, 0)
    if h is None:
        raise CalibrationError("calibrate: no homography fits the floor markers (degenerate)")
    for _ in range(2):
        pix = np.vstack([quads[i] for i in ids])
        tgt = np.vstack([_corner_targets(h, quads[i], floor.markers[i], floor.size_m)
                         for i in ids])
        h2, _ = cv2.findHomography(pix, tgt, 0)
        if h2 is None:
            break
        h = h2 / h2[2, 2]
    errors = {i: float(np.linalg.norm(apply_homography(h, px[k:k + 1])[0] - fl[k]))
              for k, i in enumerate(ids)}
    return h, errors


def _spread_ratio(points: np.ndarray) -> float:
    centred = points - points.mean(axis=0)
    s = np.linalg.svd(centred, compute_uv=False)
    return float(s[-1] / s[0]) if s[0] > 0 else 0.0


def focal_from_homography(pixel_from_floor: np.ndarray, image_size: tuple[int, int]
                          ) -> float | None:
    """Focal length [px] of a camera with square pixels and its principal point at the image
    centre that sees the floor through ``pixel_from_floor``; None when unobservable."""
    w, h = image_size
    scale = float(max(w, h))  # work in image-size units, so the test below has no dimension
    shift = np.array([[1.0 / scale, 0.0, -(w - 1) / 2.0 / scale],
                      [0.0, 1.0 / scale, -(h - 1) / 2.0 / scale], [0.0, 0.0, 1.0]])
    m = shift @ pixel_from_floor
    m = m / np.linalg.norm(m[:, 0])
    (h11, h12, _), (h21, h22, _), (h31, h32, _) = m
    # with w = 1/f^2: a1 w + b1 = 0 (r1 . r2 = 0) and a2 w + b2 = 0 (|r1| = |r2|)
    a1, b1 = h11 * h12 + h21 * h22, h31 * h32
    a2, b2 = h11 ** 2 + h21 ** 2 - h12 ** 2 - h22 ** 2, h31 ** 2 - h32 ** 2
    if math.hypot(b1, b2) < MIN_TILT_CONSTRAINT:
        return None  # looking straight down: the perspective terms that fix f vanish
    denom = a1 * a1 + a2 * a2
    if denom <= 0.0:
        return None
    inv_f2 = -(a1 * b1 + a2 * b2) / denom
    if not inv_f2 > 0.0:
        return None
    f = scale / math.sqrt(inv_f2)
    return f if 0.1 * scale < f < 100.0 * scale else None


def camera_centre(quads: dict[int, np.ndarray], floor: FloorMarkers, floor_from_pixel: np.ndarray,
                  camera_matrix: np.ndarray) -> tuple[float, float, float]:
    """The camera's centre in floor coordinates from the markers' corners (solvePnP, IPPE)."""
    ids = sorted(quads)
    pix = np.vstack([quads[i] for i in ids]).astype(np.float64)
    tgt = np.vstack([_corner_targets(floor_from_pixel, quads[i], floor.markers[i], floor.size_m)
                     for i in ids])
    obj = np.c_[tgt, np.zeros(len(tgt))]
    ok, rvec, tvec = cv2.solvePnP(obj, pix, camera_matrix, None, flags=cv2.SOLVEPNP_IPPE)
    if not ok:
        raise CalibrationError("calibrate: cannot recover the camera's pose from the markers")
    rot, _ = cv2.Rodrigues(rvec)
    c = (-rot.T @ tvec).ravel()
    if c[2] <= 0.0:
        raise CalibrationError("calibrate: the floor coordinates look mirrored (the camera "
                               "comes out below the floor): check the x and y of FLOOR.yaml")
    return float(c[0]), float(c[1]), float(c[2])


def calibrate_image(image: np.ndarray, floor: FloorMarkers,
                    intrinsics: tuple[np.ndarray, np.ndarray] | None = None,
                    camera_height: float | None = None,
                    max_error: float = MAX_ERROR_M) -> CalibrationReport:
    """See the module docstring; :class:`CalibrationError` for a refusal."""
    frame = check_frame(image)
    height, width = frame.shape[:2]
    quads = _floor_quads(frame, floor, intrinsics)
    missing = tuple(sorted(set(floor.markers) - set(quads)))
    if len(quads) < MIN_MARKERS:
        raise CalibrationError(
            f"calibrate: found {len(quads)} of the floor markers "
            f"({', '.join(map(str, sorted(quads))) or 'none'}); need at least {MIN_MARKERS}"
            + (f" (not found: {', '.join(map(str, missing))})" if missing else ""))
    spread = _spread_ratio(np.array([floor.markers[i] for i in quads]))
    if spread < MIN_SPREAD:
        raise CalibrationError(f"calibrate: the floor markers found lie nearly on one line "
                               f"(spread ratio {spread:.3f} < {MIN_SPREAD}); lay them out in a "
                               "rectangle around the area")
    quads, h, errors, rejected = _fit_without_outliers(quads, floor, max_error)
    worst = max(errors, key=errors.__getitem__)
    if errors[worst] > max_error:
        raise CalibrationError(f"calibrate: marker {worst} is {errors[worst] * 1e3:.1f} mm off "
                               f"its surveyed position (limit {max_error * 1e3:.0f} mm); check "
                               "FLOOR.yaml and that the markers have not moved")
    size = (width, height)
    focal, how, k_used = _camera_matrix(np.linalg.inv(h), size, intrinsics)
    if k_used is not None:
        position = camera_centre(quads, floor, h, k_used)
    elif camera_height is not None:
        nadir = apply_homography(h, np.array([[(width - 1) / 2.0, (height - 1) / 2.0]]))[0]
        position, how = (float(nadir[0]), float(nadir[1]), float(camera_height)), "camera-height"
    else:
        raise CalibrationError("calibrate: the camera looks almost straight down, so its height "
                               "cannot be recovered from the floor markers: pass --intrinsics "
                               "or --camera-height METRES")
    calibration = Calibration(
        h, size, camera_position=position,
        camera_matrix=None if intrinsics is None else intrinsics[0],
        dist_coeffs=None if intrinsics is None else intrinsics[1],
        floor_markers=tuple(sorted(floor.markers)))
    return CalibrationReport(calibration, errors, rejected, missing, focal, how)


def _floor_quads(frame: np.ndarray, floor: FloorMarkers,
                 intrinsics: tuple[np.ndarray, np.ndarray] | None) -> dict[int, np.ndarray]:
    """Pixel corners (4 x 2) of each floor marker seen once in ``frame`` (undistorted first
    with ``intrinsics``)."""
    grey = to_grey(frame)
    if intrinsics is not None:
        k, d = intrinsics
        grey = cv2.undistort(grey, k, d, None, k)
    corners, ids, _ = make_detector(floor.dictionary).detectMarkers(grey)
    found = [] if ids is None else [int(i) for i in np.asarray(ids).ravel()]
    quads: dict[int, np.ndarray] = {}
    for mid, quad in zip(found, corners or (), strict=True):
        if mid in floor.markers and found.count(mid) == 1:
            quads[mid] = np.asarray(quad, dtype=np.float64).reshape(4, 2)
    return quads


def _fit_without_outliers(
    quads: dict[int, np.ndarray], floor: FloorMarkers, max_error: float,
) -> tuple[dict[int, np.ndarray], np.ndarray, dict[int, float], dict[int, float]]:
    """Fit, then set the worst marker aside and fit again while one is over ``max_error`` and
    enough well-spread markers remain: the markers kept, the homography, their errors [m] and
    the rejected markers' errors [m]."""
    rejected: dict[int, float] = {}
    h, errors = _fit(quads, floor)
    while max(errors.values()) > max_error and len(quads) > MIN_MARKERS:
        worst = max(errors, key=errors.__getitem__)
        trial = {i: q for i, q in quads.items() if i != worst}
        if _spread_ratio(np.array([floor.markers[i] for i in trial])) < MIN_SPREAD:
            break
        rejected[worst] = errors[worst]
        quads = trial
        h, errors = _fit(quads, floor)
    return quads, h, errors, rejected


def _camera_matrix(pixel_from_floor: np.ndarray, size: tuple[int, int],
                   intrinsics: tuple[np.ndarray, np.ndarray] | None,
                   ) -> tuple[float | None, str, np.ndarray | None]:
    """The focal length [px], where it came from and the camera matrix to place the camera
    with: the intrinsics', else one estimated from the homography (None: looking straight down)."""
    if intrinsics is not None:
        return float(intrinsics[0][0, 0]), "intrinsics", intrinsics[0]
    width, height = size
    focal = focal_from_homography(pixel_from_floor, size)
    if focal is None:
        return None, "homography", None
    return focal, "homography", np.array([[focal, 0.0, (width - 1) / 2.0],
                                          [0.0, focal, (height - 1) / 2.0], [0.0, 0.0, 1.0]])
