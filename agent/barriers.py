"""Control-barrier-function rows for one robot (thesis chapter 4.2 and appendix A).

Each function returns the barrier value(s) and QP rows ``(ax, ay, b)`` meaning
``ax * ux + ay * uy <= b``, normalised to |a| = 1 (see :mod:`agent.qp`). Every row is the
time-varying CBF condition  dh/dp . u + dh/dt >= -gamma h  for the robot's control point p,
with dh/dt from the other party's velocity (a neighbour, an obstacle, another formation's
centroid and orientation). Pure functions over floats; no numpy on this hot path.
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

from geometry.circle import circle_h
from geometry.ellipse import ellipse_terms
from geometry.shapes import Shape, shape_distance

from .qp import Row, normalized_row


class Neighbour(NamedTuple):
    """A graph neighbour as its ``state`` message gives it: control point and velocity."""

    x: float
    y: float
    vx: float
    vy: float
    df: float  # [m] desired distance Df_ij


class Obstacle(NamedTuple):
    x: float
    y: float
    vx: float
    vy: float
    ds: float  # [m] safe distance Ds for the control point


# ----------------------------------------------------------------- formation, eq. 4.3 / 4.4


def formation_h(px: float, py: float, qx: float, qy: float, df: float, eps: float):
    """(h_formg, h_forml) of eq. 4.3 and 4.4 for the edge (p, q)."""
    d2 = (px - qx) ** 2 + (py - qy) ** 2
    return d2 - (df - eps) ** 2, (df + eps) ** 2 - d2


def formation_rows(px: float, py: float, n: Neighbour, eps: float, gamma: float):
    """Rows for one edge: lower bound (appendix A.2, eq. 8) and upper bound (eq. 12), each with
    the neighbour-velocity term dh/dp_j . p_j'. Returns (h_g, h_l, row_g, row_l)."""
    dx, dy = px - n.x, py - n.y
    hg, hl = formation_h(px, py, n.x, n.y, n.df, eps)
    dv = 2.0 * (dx * n.vx + dy * n.vy)  # 2 (p_i - p_j) . p_j'
    row_g = normalized_row(-2.0 * dx, -2.0 * dy, gamma * hg - dv)  # A.2 (8)
    row_l = normalized_row(2.0 * dx, 2.0 * dy, gamma * hl + dv)  # A.2 (12)
    return hg, hl, row_g, row_l


# ------------------------------------------------------------------------ obstacle, eq. 4.5


def obstacle_h(px: float, py: float, o: Obstacle) -> float:
    """h_obs of eq. 4.5."""
    return circle_h(px, py, o.x, o.y, o.ds)


def obstacle_row(px: float, py: float, o: Obstacle, gamma: float) -> tuple[float, Row]:
    """Appendix A.1 (4): -2 (p - p_obs) . u <= gamma h - 2 (p - p_obs) . p_obs'."""
    dx, dy = px - o.x, py - o.y
    h = circle_h(px, py, o.x, o.y, o.ds)
    return h, normalized_row(-2.0 * dx, -2.0 * dy, gamma * h - 2.0 * (dx * o.vx + dy * o.vy))


def shape_row(px: float, py: float, sh: Shape, gamma: float, grow: float = 0.0) -> tuple[float, Row]:
    """A static wall or shelf (:mod:`geometry.shapes`): h = d(p) - (Ds + grow), eq. 4.5
    generalised to the distance from the shape; the row is -dd/dp . u <= gamma h (the shape
    does not move, so no dh/dt term; dd/dp is a unit vector, so the row is normalised)."""
    d, gx, gy = shape_distance(px, py, sh)
    h = d - sh.ds - grow
    return h, (-gx, -gy, gamma * h)


# ------------------------------------------------------------ other formations, eq. 4.6


def ellipse_class_k(h: float, gamma: float) -> float:
    """Extended class-K function for the ellipse barrier: gamma h (1 + max(h, 0)).

    Near the boundary it is the thesis's gamma h. Far away it grows faster than the rotation
    term dh/dalpha . alpha', which scales like h itself: with the linear gamma h, a formation
    turning at alpha' > ~gamma / 4 would make robots metres away infeasible or push them.
    """
    return gamma * h * (1.0 + h) if h > 0.0 else gamma * h


def ellipse_row(px: float, py: float, e, gamma: float) -> tuple[float, Row]:
    """Appendix A.3 (19): -dh/dp . u <= alpha(h) + dh/dc . c' + dh/dalpha . alpha', with
    alpha = :func:`ellipse_class_k`. ``e`` is a :class:`geometry.ellipse.Ellipse`."""
    h, gx, gy, ga = ellipse_terms(px, py, e.cx, e.cy, e.alpha, e.a, e.b)
    b = ellipse_class_k(h, gamma) - (gx * e.vx + gy * e.vy) + ga * e.alpha_rate
    return h, normalized_row(-gx, -gy, b)


# ----------------------------------------------------------- pairwise robots, eq. 3.5


def pairwise_row(px: float, py: float, n: Neighbour, d_af: float, gamma: float):
    """All-to-all baseline: keep |p_i - p_j| >= D_Af from a robot of another formation, as an
    obstacle moving with that robot's velocity (eq. 3.5 in the form of 4.5 / A.1)."""
    return obstacle_row(px, py, Obstacle(n.x, n.y, n.vx, n.vy, d_af), gamma)


# -------------------------------------------------------------------------- speed limits


SPEED_SIDES = 12  # sides of the polygon inscribed in the speed disk


def speed_rows(vmax: float, heading: float, sides: int = SPEED_SIDES) -> list[Row]:
    """|u| <= vmax as a regular polygon inscribed in the disk, one vertex along ``heading``
    (the nominal direction), so the clamped nominal command itself stays feasible."""
    face = vmax * math.cos(math.pi / sides)
    c0, s0 = math.cos(heading), math.sin(heading)
    return [(c0 * c - s0 * s, s0 * c + c0 * s, face) for c, s in _polygon_normals(sides)]


@functools.lru_cache(maxsize=8)
def _polygon_normals(sides: int) -> tuple[tuple[float, float], ...]:
    """Unit face normals of the polygon for heading 0: angles pi/sides + 2 pi k / sides."""
    return tuple(
        (math.cos(math.pi / sides + 2.0 * math.pi * k / sides),
         math.sin(math.pi / sides + 2.0 * math.pi * k / sides))
        for k in range(sides)
    )
