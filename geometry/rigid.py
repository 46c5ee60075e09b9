"""The least-squares rigid motion of a point set (2-D Kabsch), and placing a body by it.

A formation's load moves with its members as one rigid body: each tick it is placed
by the proper rotation R(theta) and translation t that map the members' start positions a_i
onto their current ones b_i best in the least-squares sense:

    min over theta, t of  sum_i |R(theta) a_i + t - b_i|^2

With the centred points a_i' = a_i - mean(a) and b_i' = b_i - mean(b) the minimiser is
theta = atan2(sum a_i' x b_i', sum a_i' . b_i') (the 2-D case of Kabsch's SVD solution, which
is a proper rotation by construction: no reflection) and t = mean(b) - R(theta) mean(a).
The same rotation as the formation ellipse's orientation estimate (:func:`geometry.ellipse.estimate`).

Pure functions over floats and sequences of points.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple

Point = tuple[float, float]


class RigidMotion(NamedTuple):
    """p -> R(theta) p + (tx, ty)."""

    theta: float  # [rad]
    tx: float  # [m]
    ty: float  # [m]

    def apply(self, p: Point) -> Point:
        c, s = math.cos(self.theta), math.sin(self.theta)
        return (c * p[0] - s * p[1] + self.tx, s * p[0] + c * p[1] + self.ty)

    def apply_all(self, points: Sequence[Point]) -> tuple[Point, ...]:
        return tuple(self.apply(p) for p in points)


class FitSums(NamedTuple):
    """What the fit's rotation is made of: the centroid (bx, by) of the current points, and
    sum a_i' x b_i' and sum a_i' . b_i' (module docstring); theta = atan2(cross, dot)."""

    bx: float
    by: float
    cross: float
    dot: float


def fit_sums(offsets: Sequence[Point], now: Sequence[Point]) -> FitSums:
    """:class:`FitSums` of the start points' ``offsets`` about their centroid (a_i') and the
    current points ``now`` (b_i, member order)."""
    n = len(now)
    sx = sy = 0.0  # summed in order, as sum() does
    for qx, qy in now:
        sx += qx
        sy += qy
    bx, by = sx / n, sy / n
    cross = dot = 0.0
    for (ux, uy), (qx, qy) in zip(offsets, now, strict=True):
        vx, vy = qx - bx, qy - by
        cross += ux * vy - uy * vx
        dot += ux * vx + uy * vy
    return FitSums(bx, by, cross, dot)


def rigid_fit(start: Sequence[Point], now: Sequence[Point]) -> RigidMotion:
    """The least-squares proper rigid motion mapping ``start[i]`` onto ``now[i]`` (see the
    module docstring). One point: a pure translation; points all at their centroid: no rotation."""
    n = len(start)
    if n == 0 or len(now) != n:
        raise ValueError(f"start/now: need the same positive number of points, got {n}, {len(now)}")
    ax = sum(p[0] for p in start) / n
    ay = sum(p[1] for p in start) / n
    bx, by, cross, dot = fit_sums([(px - ax, py - ay) for px, py in start], now)
    theta = math.atan2(cross, dot) if (cross or dot) else 0.0
    c, s = math.cos(theta), math.sin(theta)
    return RigidMotion(theta, bx - (c * ax - s * ay), by - (s * ax + c * ay))
