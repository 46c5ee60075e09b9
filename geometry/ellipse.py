"""The formation ellipse a leader publishes (thesis section 4.2, eq. 4.6 and 4.7).

Pure functions over numbers: no clock, no network. Shared by the leader (which estimates and
publishes it), the agent (whose barrier rows keep out of it), the scenario checks and the
simulator.

* :func:`reference_shape` fixes a formation's reference offsets and the orientation of its
  principal axis from the start configuration.
* :func:`derive_axes` picks semi-axes (a, b) so that the ellipse, in the principal frame,
  contains a disk of a given clearance around every member: another robot's control point that
  stays outside the ellipse then stays at least that far from every member.
* :func:`estimate` turns the members' current positions and velocities into the ellipse
  (centroid eq. 4.7, orientation by a least-squares rotation of the reference shape onto the
  current one, centroid velocity and orientation rate from the members' velocities).
* :func:`ellipse_terms` is h of eq. 4.6 with its derivatives; :func:`ellipse_value` is h alone.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from .angles import wrap_angle

Point = tuple[float, float]

_ASPECTS = np.linspace(0.25, 1.0, 61)  # b/a ratios tried by derive_axes
_DISK_SAMPLES = 90  # boundary samples per member disk in derive_axes
_SAMPLE_SLACK = 1.0 / math.cos(math.pi / _DISK_SAMPLES)  # covers the chord between samples


class Ellipse(NamedTuple):
    """Centroid [m], orientation alpha [rad], semi-axes a >= b [m] and their rates."""

    cx: float
    cy: float
    alpha: float
    a: float
    b: float
    vx: float = 0.0  # [m/s] centroid velocity
    vy: float = 0.0  # [m/s]
    alpha_rate: float = 0.0  # [rad/s]
    # [m] the members' control points it was estimated from (:func:`estimate`; none from a
    # leader that predates them): what other formations keep out of their own ellipses
    points: tuple[Point, ...] = ()
    # [rad] the members' body headings, in the order of ``points`` (unicycle formations; none
    # otherwise): every member then knows how far each one is from facing the formation's motion
    headings: tuple[float, ...] = ()


class ReferenceShape(NamedTuple):
    """Members' offsets from their centroid at the reference pose, in world axes."""

    offsets: tuple[Point, ...]
    alpha0: float  # [rad] orientation of the principal (major) axis at the reference pose


def centroid(points: Sequence[Point]) -> Point:
    """eq. 4.7."""
    if not points:
        raise ValueError("points: at least one point is needed")
    n = len(points)
    return (sum([p[0] for p in points]) / n, sum([p[1] for p in points]) / n)


def reference_shape(points: Sequence[Point]) -> ReferenceShape:
    """Centred offsets of ``points`` and the angle of their principal axis."""
    cx, cy = centroid(points)
    offsets = tuple((p[0] - cx, p[1] - cy) for p in points)
    sxx = sum(o[0] * o[0] for o in offsets)
    syy = sum(o[1] * o[1] for o in offsets)
    sxy = sum(o[0] * o[1] for o in offsets)
    alpha0 = 0.5 * math.atan2(2.0 * sxy, sxx - syy) if (sxx or syy or sxy) else 0.0
    return ReferenceShape(offsets, alpha0)


def derive_axes(shape: ReferenceShape, clearance: float) -> tuple[float, float]:
    """Semi-axes (a, b) of the smallest-area ellipse, aligned with the principal axis, that
    contains a disk of radius ``clearance`` [m] around every member."""
    if not (clearance > 0.0 and math.isfinite(clearance)):
        raise ValueError(f"clearance: must be a positive number, got {clearance!r}")
    c, s = math.cos(shape.alpha0), math.sin(shape.alpha0)
    pts = np.array([(c * x + s * y, -s * x + c * y) for x, y in shape.offsets])  # principal frame
    phi = np.linspace(0.0, 2.0 * math.pi, _DISK_SAMPLES, endpoint=False)
    ring = clearance * _SAMPLE_SLACK * np.stack([np.cos(phi), np.sin(phi)], axis=1)
    samples = (pts[:, None, :] + ring[None, :, :]).reshape(-1, 2)
    x2, y2 = samples[:, 0] ** 2, samples[:, 1] ** 2
    # For aspect k = b/a, a point is inside iff x^2 + y^2/k^2 <= a^2: the smallest a is exact.
    a = np.sqrt(np.max(x2[None, :] + y2[None, :] / _ASPECTS[:, None] ** 2, axis=1))
    area = _ASPECTS * a * a
    best = int(np.argmin(area))
    return float(a[best]), float(_ASPECTS[best] * a[best])


def estimate(
    shape: ReferenceShape,
    axes: tuple[float, float],
    positions: Sequence[Point],
    velocities: Sequence[Point],
    headings: Sequence[float] = (),
) -> Ellipse:
    """The formation's ellipse now, from its members' positions and velocities.

    ``positions`` and ``velocities`` are in the same member order as ``shape.offsets``.
    Orientation: the rotation theta that best maps the reference offsets r_i onto the current
    offsets q_i (least squares, theta = atan2(sum r x q, sum r . q)), so alpha = alpha0 + theta.
    Rates: centroid velocity is the mean velocity; alpha_rate is the least-squares angular
    velocity sum(q x (v - v_c)) / sum |q|^2. ``points`` are the ``positions``, ``headings``
    the members' body headings (none, or one per member).
    """
    n = len(shape.offsets)
    if len(positions) != n or len(velocities) != n or len(headings) not in (0, n):
        raise ValueError(f"positions/velocities/headings: expected {n} members")
    cx, cy = centroid(positions)
    vx, vy = centroid(velocities)
    cross = dot = q2 = w = 0.0
    for (rx, ry), (px, py), (ux, uy) in zip(shape.offsets, positions, velocities, strict=True):
        qx, qy = px - cx, py - cy
        cross += rx * qy - ry * qx
        dot += rx * qx + ry * qy
        q2 += qx * qx + qy * qy
        w += qx * (uy - vy) - qy * (ux - vx)
    theta = math.atan2(cross, dot) if (cross or dot) else 0.0
    rate = w / q2 if q2 > 1e-12 else 0.0
    return Ellipse(cx, cy, wrap_angle(shape.alpha0 + theta), axes[0], axes[1], vx, vy, rate,
                   tuple(positions), tuple(headings))


def within_reach(own: Ellipse, cx: float, cy: float, a: float, reach: float) -> bool:
    """Whether a formation whose ellipse is centred at (``cx``, ``cy``) with semi-major axis
    ``a`` comes within ``reach`` [m] of ``own``: the centres' distance less both semi-major axes
    (a lower bound on the gap between the two ellipses) is at most ``reach``."""
    return math.hypot(cx - own.cx, cy - own.cy) - own.a - a <= reach


def ellipse_terms(px: float, py: float, cx: float, cy: float, alpha: float, a: float, b: float):
    """h of eq. 4.6 with its partial derivatives: (h, dh/dpx, dh/dpy, dh/dalpha).

    In the ellipse frame u = R(alpha)^T (p - c): h = u1^2/a^2 + u2^2/b^2 - 1, which expands to
    eq. 4.6; dh/dp matches appendix A.3 (14, 15), dh/dc = -dh/dp (16, 17) and dh/dalpha =
    2 u1 u2 (1/a^2 - 1/b^2) is (18) rewritten.
    """
    c, s = math.cos(alpha), math.sin(alpha)
    dx, dy = px - cx, py - cy
    u1 = c * dx + s * dy
    u2 = -s * dx + c * dy
    ia2, ib2 = 1.0 / (a * a), 1.0 / (b * b)
    h = u1 * u1 * ia2 + u2 * u2 * ib2 - 1.0
    g1, g2 = 2.0 * u1 * ia2, 2.0 * u2 * ib2
    return h, g1 * c - g2 * s, g1 * s + g2 * c, 2.0 * u1 * u2 * (ia2 - ib2)


def ellipse_value(e: Ellipse, x: float, y: float) -> float:
    """h of eq. 4.6 at (x, y): negative inside the ellipse, zero on it, positive outside."""
    return ellipse_terms(x, y, e.cx, e.cy, e.alpha, e.a, e.b)[0]
