"""Static obstacle shapes of a warehouse: walls (segments) and shelves (boxes with a yaw).

The barrier of a shape is eq. 4.5 generalised from a disk's centre to the shape itself:

    h(p) = d(p) - Ds

where ``d`` is the distance from the robot's control point p to the nearest point of the
segment, or of the box's outline (signed: negative inside the box). ``dh/dp`` is the unit
vector from that nearest point to p: along a face it is the face's outward normal, near a
corner or a segment's end (the nearest point is a vertex) it is the radial direction from the
vertex, and inside a box it is the outward normal of the nearest face, so h keeps decreasing
the deeper p goes. The gradient is continuous outside the shape; inside a box it switches
between faces on the diagonals (the set where two faces are equally near), where h is still
continuous.

Pure functions over floats; the hot path of every robot's tick calls :func:`shape_distance`.
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

SEGMENT = "segment"
BOX = "box"


class Shape(NamedTuple):
    """A static obstacle shape, as one record for both kinds.

    A segment from (ax, ay) to (bx, by) is stored as the degenerate box around it: centre
    (cx, cy), half length ``hx``, half width ``hy = 0`` and ``yaw`` the segment's direction.
    A box has centre (cx, cy), half sizes (hx, hy) and yaw [rad]. ``ds`` is the safe distance
    from the shape to a robot's centre [m]."""

    name: str
    kind: str  # SEGMENT or BOX
    cx: float
    cy: float
    hx: float
    hy: float
    yaw: float
    ds: float

    @property
    def cos_yaw(self) -> float:
        return math.cos(self.yaw)

    @property
    def sin_yaw(self) -> float:
        return math.sin(self.yaw)

    def corners(self) -> list[tuple[float, float]]:
        """The outline's vertices (2 for a segment, 4 for a box), counter-clockwise."""
        return list(_corners(self))

    def local_to_world(self, u: float, v: float) -> tuple[float, float]:
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        return (self.cx + c * u - s * v, self.cy + s * u + c * v)


@functools.lru_cache(maxsize=4096)
def _corners(sh: Shape) -> tuple[tuple[float, float], ...]:
    """:meth:`Shape.corners`, worked out once per shape (every robot's tick asks for them)."""
    if sh.kind == SEGMENT:
        return (sh.local_to_world(-sh.hx, 0.0), sh.local_to_world(sh.hx, 0.0))
    return tuple(sh.local_to_world(sx * sh.hx, sy * sh.hy)
                 for sx, sy in ((1, 1), (-1, 1), (-1, -1), (1, -1)))


def segment(name: str, a: tuple[float, float], b: tuple[float, float], ds: float) -> Shape:
    """The wall from ``a`` to ``b`` (a zero-length segment is a point)."""
    dx, dy = b[0] - a[0], b[1] - a[1]
    length = math.hypot(dx, dy)
    yaw = math.atan2(dy, dx) if length > 0.0 else 0.0
    return Shape(name, SEGMENT, 0.5 * (a[0] + b[0]), 0.5 * (a[1] + b[1]), 0.5 * length, 0.0,
                 yaw, ds)


def box(name: str, center: tuple[float, float], size: tuple[float, float], yaw: float,
        ds: float) -> Shape:
    """The shelf of full ``size`` (length along ``yaw``, depth across it) centred at ``center``."""
    return Shape(name, BOX, center[0], center[1], 0.5 * size[0], 0.5 * size[1], yaw, ds)


def segment_distance(px: float, py: float, ax: float, ay: float, bx: float, by: float):
    """(d, dd/dpx, dd/dpy): distance from p to the segment a-b and its gradient.

    On the segment itself (d = 0) the gradient is the segment's left normal (any unit vector
    is a subgradient there; a robot's centre on a wall is a collision anyway)."""
    ex, ey = bx - ax, by - ay
    ee = ex * ex + ey * ey
    wx, wy = px - ax, py - ay
    t = 0.0 if ee == 0.0 else min(1.0, max(0.0, (wx * ex + wy * ey) / ee))
    dx, dy = wx - t * ex, wy - t * ey
    d = math.hypot(dx, dy)
    if d > 0.0:
        return d, dx / d, dy / d
    n = math.sqrt(ee)
    return 0.0, (-ey / n if n else 1.0), (ex / n if n else 0.0)


def box_distance(px: float, py: float, cx: float, cy: float, hx: float, hy: float,
                 c: float, s: float):
    """(d, dd/dpx, dd/dpy): signed distance from p to the outline of the box centred at
    (cx, cy) with half sizes (hx, hy) and yaw given as c = cos(yaw), s = sin(yaw); negative
    inside. Outside, the nearest point is on a face (gradient: its outward normal) or a corner
    (gradient: radial from the corner); inside, the nearest face decides (its outward normal)."""
    dx, dy = px - cx, py - cy
    u = c * dx + s * dy  # box frame
    v = -s * dx + c * dy
    su = 1.0 if u >= 0.0 else -1.0
    sv = 1.0 if v >= 0.0 else -1.0
    qu, qv = abs(u) - hx, abs(v) - hy
    if qu > 0.0 or qv > 0.0:
        ou, ov = max(qu, 0.0), max(qv, 0.0)
        d = math.hypot(ou, ov)
        gu, gv = su * ou / d, sv * ov / d
    elif qu > qv:
        d, gu, gv = qu, su, 0.0
    else:
        d, gu, gv = qv, 0.0, sv
    return d, c * gu - s * gv, s * gu + c * gv


def shape_distance(px: float, py: float, sh: Shape):
    """(d, dd/dpx, dd/dpy) for either kind (a segment is the box of half width 0: its outline
    distance is the segment distance; it has no inside)."""
    if sh.kind == SEGMENT:
        c, s = math.cos(sh.yaw), math.sin(sh.yaw)
        return segment_distance(px, py, sh.cx - c * sh.hx, sh.cy - s * sh.hx,
                                sh.cx + c * sh.hx, sh.cy + s * sh.hx)
    return box_distance(px, py, sh.cx, sh.cy, sh.hx, sh.hy, math.cos(sh.yaw), math.sin(sh.yaw))


def distance_floor(px: float, py: float, sh: Shape) -> float:
    """A lower bound on the distance from p to the shape, from its bounding circle (centre to
    a corner; 1 nm less for rounding): a cheap test before :func:`shape_distance`. Negative
    inside the circle."""
    return math.hypot(px - sh.cx, py - sh.cy) - math.hypot(sh.hx, sh.hy) - 1e-9


def shape_h(px: float, py: float, sh: Shape, grow: float = 0.0) -> float:
    """h = d(p) - (Ds + grow): eq. 4.5 generalised to the shape (see the module docstring)."""
    return shape_distance(px, py, sh)[0] - sh.ds - grow


def contains(sh: Shape, px: float, py: float) -> bool:
    """Whether p lies inside the box (on or inside its outline); never for a segment."""
    return sh.kind == BOX and shape_distance(px, py, sh)[0] <= 0.0


# ------------------------------------------------------------------ segment against shape


def segment_segment_distance(p0: tuple[float, float], p1: tuple[float, float],
                             q0: tuple[float, float], q1: tuple[float, float]) -> float:
    """Smallest distance between the segments p0-p1 and q0-q1 (0 when they cross)."""
    if _segments_cross(p0, p1, q0, q1):
        return 0.0
    return min(
        segment_distance(*p0, *q0, *q1)[0], segment_distance(*p1, *q0, *q1)[0],
        segment_distance(*q0, *p0, *p1)[0], segment_distance(*q1, *p0, *p1)[0],
    )


def path_clearance(p0: tuple[float, float], p1: tuple[float, float], sh: Shape) -> float:
    """Smallest distance from any point of the straight path p0-p1 to the shape (0 when the
    path touches or enters it)."""
    if sh.kind == BOX and (contains(sh, *p0) or contains(sh, *p1)):
        return 0.0
    pts = sh.corners()
    if sh.kind == SEGMENT:
        return segment_segment_distance(p0, p1, pts[0], pts[1])
    return min(segment_segment_distance(p0, p1, pts[k], pts[(k + 1) % 4]) for k in range(4))


def _cross(ox: float, oy: float, ax: float, ay: float, bx: float, by: float) -> float:
    return (ax - ox) * (by - oy) - (ay - oy) * (bx - ox)


def _segments_cross(p0, p1, q0, q1) -> bool:
    d1 = _cross(*q0, *q1, *p0)
    d2 = _cross(*q0, *q1, *p1)
    d3 = _cross(*p0, *p1, *q0)
    d4 = _cross(*p0, *p1, *q1)
    return ((d1 > 0.0) != (d2 > 0.0) and d1 != 0.0 and d2 != 0.0
            and (d3 > 0.0) != (d4 > 0.0) and d3 != 0.0 and d4 != 0.0)
