"""A test rig: an overhead pinhole camera rendered with plain OpenCV, independent of
camera_service.render (the service must not be checked against its own renderer).

The camera sits about 3 m above the floor, tilted a few degrees in a random direction, with a
focal length that gives about 3 mm of floor per pixel at 1280x960. Every marker is a square on a
horizontal plane (floor markers at z = 0, robots' markers at their height) and is drawn by
``cv2.warpPerspective`` through that plane's homography ``K [r1 r2 (z r3 + t)]`` at twice the
resolution, then area-averaged down; then uneven light (a smooth gradient and a vignette),
optical blur, sensor noise, and optionally lens distortion (a remap through
``cv2.undistortPoints``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

SIZE = (1280, 960)  # [px]
SS = 2  # supersampling per axis
QUIET = 1  # [modules] white margin around a marker
DICT = cv2.aruco.DICT_4X4_50


@dataclass
class Rig:
    K: np.ndarray
    R: np.ndarray  # world -> camera
    t: np.ndarray
    centre: np.ndarray  # camera centre, world [m]
    dist: np.ndarray | None = None

    def plane_h(self, z: float) -> np.ndarray:
        """Plane z (x, y, 1) -> pixel."""
        r = self.R
        return self.K @ np.c_[r[:, 0], r[:, 1], z * r[:, 2] + self.t]

    def project(self, pts: np.ndarray) -> np.ndarray:
        cam = pts @ self.R.T + self.t
        uv = cam @ self.K.T
        return uv[:, :2] / uv[:, 2:]


def make_rig(rng: np.random.Generator, look_at=(1.9, 1.4), height: float = 3.0,
             tilt_deg: tuple[float, float] = (8.0, 14.0), dist: np.ndarray | None = None) -> Rig:
    f = height / 0.003  # [px] about 3 mm per pixel at the nadir
    w, h = SIZE
    k = np.array([[f, 0, (w - 1) / 2 + rng.uniform(-8, 8)], [0, f, (h - 1) / 2 + rng.uniform(-8, 8)],
                  [0, 0, 1.0]])
    base = np.array([[1.0, 0, 0], [0, -1.0, 0], [0, 0, -1.0]])  # looking straight down
    tilt = math.radians(rng.uniform(*tilt_deg))
    axis_angle = rng.uniform(0, 2 * math.pi)
    rvec = tilt * np.array([math.cos(axis_angle), math.sin(axis_angle), 0.0])
    r = cv2.Rodrigues(rvec)[0] @ base
    axis = r.T @ np.array([0, 0, 1.0])  # optical axis in the world
    d = height / -axis[2]
    c = np.array([look_at[0], look_at[1], 0.0]) - d * axis
    return Rig(k, r, -r @ c, c, dist)


def _marker(marker_id: int) -> np.ndarray:
    d = cv2.aruco.getPredefinedDictionary(DICT)
    n = d.markerSize + 2
    core = cv2.aruco.generateImageMarker(d, marker_id, n, borderBits=1)
    return cv2.copyMakeBorder(core, QUIET, QUIET, QUIET, QUIET, cv2.BORDER_CONSTANT, value=255)


def _warp(canvas: np.ndarray, src: np.ndarray, m: np.ndarray) -> None:
    """Draw ``src`` into ``canvas`` through ``m`` (src pixel -> canvas pixel), nearest sample."""
    hh, ww = src.shape[:2]
    box = cv2.perspectiveTransform(
        np.array([[[-0.5, -0.5]], [[ww - 0.5, -0.5]], [[ww - 0.5, hh - 0.5]], [[-0.5, hh - 0.5]]]),
        m).reshape(4, 2)
    u0, v0 = np.floor(box.min(axis=0)).astype(int) - 2
    u1, v1 = np.ceil(box.max(axis=0)).astype(int) + 2
    u0, v0 = max(u0, 0), max(v0, 0)
    u1, v1 = min(u1, canvas.shape[1]), min(v1, canvas.shape[0])
    if u1 <= u0 or v1 <= v0:
        return
    shift = np.array([[1, 0, -u0], [0, 1, -v0], [0, 0, 1.0]]) @ m
    size = (u1 - u0, v1 - v0)
    img = cv2.warpPerspective(src, shift, size, flags=cv2.INTER_NEAREST,
                              borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    mask = cv2.warpPerspective(np.full_like(src, 255), shift, size, flags=cv2.INTER_NEAREST,
                               borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    roi = canvas[v0:v1, u0:u1]
    np.copyto(roi, img, where=mask > 0)


def _to_canvas(rig: Rig, z: float) -> np.ndarray:
    """Plane z (x, y, 1) -> supersampled canvas pixel (pixel centres kept)."""
    ss = np.array([[SS, 0, (SS - 1) / 2], [0, SS, (SS - 1) / 2], [0, 0, 1.0]])
    return ss @ rig.plane_h(z)


def draw_square_marker(canvas: np.ndarray, rig: Rig, marker_id: int, x: float, y: float,
                       theta: float, side: float, z: float) -> None:
    """Marker ``marker_id`` (black square ``side`` m) centred at (x, y, z), its x axis along
    ``theta``."""
    img = _marker(marker_id)
    n = img.shape[0]
    outer = side * n / (n - 2 * QUIET)
    m = outer / n
    a = np.array([[m, 0, m / 2 - outer / 2], [0, -m, outer / 2 - m / 2], [0, 0, 1.0]])
    c, s = math.cos(theta), math.sin(theta)
    pose = np.array([[c, -s, x], [s, c, y], [0, 0, 1.0]])
    _warp(canvas, img, _to_canvas(rig, z) @ pose @ a)


def draw_disc(canvas: np.ndarray, rig: Rig, x: float, y: float, r: float, z: float,
              grey: int) -> None:
    ang = np.linspace(0, 2 * math.pi, 48, endpoint=False)
    ring = np.c_[x + r * np.cos(ang), y + r * np.sin(ang), np.ones(48)]
    px = ring @ _to_canvas(rig, z).T
    px = px[:, :2] / px[:, 2:]
    cv2.fillPoly(canvas, [np.round(px * 16).astype(np.int32)], grey, cv2.LINE_AA, shift=4)


def finish(canvas: np.ndarray, rig: Rig, rng: np.random.Generator, blur: float = 0.8,
           noise: float = 3.0, light: float = 0.35) -> np.ndarray:
    """Downsample, uneven light, blur, noise, distortion; a BGR frame."""
    img = cv2.resize(canvas, SIZE, interpolation=cv2.INTER_AREA).astype(np.float32)
    w, h = SIZE
    uu, vv = np.meshgrid(np.linspace(-1, 1, w), np.linspace(-1, 1, h))
    ang = rng.uniform(0, 2 * math.pi)
    gain = 1.0 - light / 2 + light / 2 * (math.cos(ang) * uu + math.sin(ang) * vv)
    gain *= 1.0 - 0.2 * (uu ** 2 + vv ** 2) / 2
    img = img * gain.astype(np.float32)
    if blur > 0:
        img = cv2.GaussianBlur(img, (0, 0), blur)
    img = img + rng.normal(0, noise, img.shape).astype(np.float32)
    img = np.clip(img + 0.5, 0, 255).astype(np.uint8)
    if rig.dist is not None:
        img = distort(img, rig)
    return cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)


_DISTORT_MAPS: dict = {}


def distort(img: np.ndarray, rig: Rig) -> np.ndarray:
    key = (rig.K.tobytes(), rig.dist.tobytes())
    if key not in _DISTORT_MAPS:
        w, h = SIZE
        grid = np.stack(np.meshgrid(np.arange(w, dtype=np.float64),
                                    np.arange(h, dtype=np.float64)), -1).reshape(-1, 1, 2)
        und = cv2.undistortPoints(grid, rig.K, rig.dist, P=rig.K).reshape(h, w, 2)
        _DISTORT_MAPS[key] = und.astype(np.float32)
    m = _DISTORT_MAPS[key]
    return cv2.remap(img, m[:, :, 0], m[:, :, 1], cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_REPLICATE)


def blank() -> np.ndarray:
    w, h = SIZE
    return np.full((h * SS, w * SS), 170, dtype=np.uint8)
