"""Control-barrier-function rows for one robot (thesis chapter 4.2 and appendix A).

Each function returns the barrier value(s) and QP rows ``(ax, ay, b)`` meaning
``ax * ux + ay * uy <= b``, normalised to |a| = 1 (see :mod:`agent.qp`). Every row is the
time-varying CBF condition  dh/dp . u + dh/dt >= -gamma h  for the robot's control point p,
with dh/dt from the other party's velocity (a neighbour, an obstacle, another formation's
centroid and orientation). Pure functions over floats; no numpy on this hot path.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple

from geometry import speed_polygon
from geometry.circle import circle_h
from geometry.ellipse import ellipse_terms
from geometry.shapes import Shape, distance_floor, shape_distance

from .qp import Row, normalized_row


class Neighbour(NamedTuple):
    """A graph neighbour as its ``state`` message gives it: control point and velocity."""

    x: float
    y: float
    vx: float
    vy: float
    df: float  # [m] desired distance Df_ij
    theta: float | None = None  # [rad] its heading (unicycles), from its ``state``


class Partner(NamedTuple):
    """A robot this one could touch, as its ``state`` message gives it (separation rows)."""

    x: float  # [m] control point (the body centre, or a unicycle's look-ahead point)
    y: float
    vx: float  # [m/s] its last certified control-point velocity
    vy: float
    theta: float = 0.0  # [rad] heading (used for unicycles only)


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


def formation_rows(px: float, py: float, n: Neighbour, eps: float, gamma: float,
                   narrow: float = 0.0):
    """Rows for one edge: lower bound (appendix A.2, eq. 8) and upper bound (eq. 12), each with
    the neighbour-velocity term dh/dp_j . p_j'. ``narrow`` [m] shrinks the band on both sides
    (unicycles: :func:`heading_narrowing`). Returns (h_g, h_l, row_g, row_l)."""
    dx, dy = px - n.x, py - n.y
    hg, hl = formation_h(px, py, n.x, n.y, n.df, eps - narrow)
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


def clearance(px: float, py: float, obstacles: Sequence[Obstacle], shapes: Sequence[Shape],
              grow: float, below: float = 0.0) -> float:
    """[m] How far the point p lies beyond the nearest circle's or shape's Ds grown by ``grow``
    (negative: inside), as the obstacle and shape rows measure it; distances at or above
    ``below`` come back as ``below`` (a caller that only acts nearer asks for no more)."""
    near = below
    for o in obstacles:
        near = min(near, math.hypot(px - o.x, py - o.y) - o.ds - grow)
    for sh in shapes:
        if distance_floor(px, py, sh) - sh.ds - grow < near:
            near = min(near, shape_distance(px, py, sh)[0] - sh.ds - grow)
    return near


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


# ------------------------------------------------------------- separation (bodies), hard


# [1] |e_i - e_j| is smoothed as sqrt(|e_i - e_j|^2 + this^2): it keeps the barrier's curvature
# where the headings agree low enough for a first-order step (0.02 let two TurtleBots turning
# towards each other at 2 rad/s overlap by 4 mm), and adds l * this (1 cm) to the separation.
HEADING_SMOOTH = 0.2


def separation_terms(
    pi: tuple[float, float], ti: float, pj: tuple[float, float], tj: float,
    dsep: float, lookahead: float,
) -> tuple[float, tuple[float, float], tuple[float, float]]:
    """The pair barrier that keeps two BODIES dsep apart, in terms of the control points p:
    (h, g_i, g_j) with  h' = g_i . u_i + g_j . u_j  (u the control-point velocities).

    Single integrator (lookahead 0): h = |p_i - p_j|^2 - dsep^2 (eq. 3.5's form), g = +-2 d.
    Unicycle: the body sits at b = p - l e(theta), so |b_i - b_j| >= |d| - l |e_i - e_j|, and
    h = |d|^2 - D^2 with D = dsep + l n, n = sqrt(|e_i - e_j|^2 + HEADING_SMOOTH^2) >= |e_i - e_j|:
    h >= 0 keeps the bodies dsep apart whatever the headings, with the headings from the
    neighbours' ``state`` (wire version 2). Under eq. 6.2 omega = e_perp . u / l, so
    D' = (q . e_i_perp / n)(e_i_perp . u_i) - (q . e_j_perp / n)(e_j_perp . u_j), q = e_i - e_j,
    and h' = 2 d . (u_i - u_j) - 2 D D' is linear in both commands; a pair facing the same
    way gets D = dsep + l HEADING_SMOOTH (1 cm for a TurtleBot), the single integrator's row
    with that margin, which covers the second-order terms a sampled step leaves."""
    dx, dy = pi[0] - pj[0], pi[1] - pj[1]
    if lookahead <= 0.0:
        return dx * dx + dy * dy - dsep * dsep, (2.0 * dx, 2.0 * dy), (-2.0 * dx, -2.0 * dy)
    ci, si, cj, sj = math.cos(ti), math.sin(ti), math.cos(tj), math.sin(tj)
    qx, qy = ci - cj, si - sj
    n = math.sqrt(qx * qx + qy * qy + HEADING_SMOOTH * HEADING_SMOOTH)
    big_d = dsep + lookahead * n
    h = dx * dx + dy * dy - big_d * big_d
    ki = 2.0 * big_d * (-qx * si + qy * ci) / n  # 2 D (q . e_i_perp) / n, e_perp = (-s, c)
    kj = 2.0 * big_d * (-qx * sj + qy * cj) / n
    gi = (2.0 * dx + ki * si, 2.0 * dy - ki * ci)
    gj = (-2.0 * dx - kj * sj, -2.0 * dy + kj * cj)
    return h, gi, gj


def separation_row(
    h: float, gi: tuple[float, float], vi: tuple[float, float],
    gj: tuple[float, float], vj: tuple[float, float], gamma: float,
) -> Row:
    """Robot i's share of the pair condition  g_i . u_i + g_j . u_j >= -gamma h  (hard).

    Each robot knows both last velocities v_i, v_j (its own, and the neighbour's from its
    ``state``) and the same positions and headings, so both compute the same slack of the pair
    condition at (v_i, v_j),

        c = gamma h + g_i . v_i + g_j . v_j,

    and split it with the same weights, lambda_i = |g_i|^2 / (|g_i|^2 + |g_j|^2) (one half
    each for single integrators). Robot i takes the row  g_i . (u_i - v_i) >= -lambda_i c,
    robot j the mirror row. Adding the two rows gives the pair condition for ANY u_i, u_j the
    two QPs return at the same time: neither robot counts on the other keeping its velocity
    (A.2's neighbour term does, and two robots acting at once can then both cross), each only
    on the other meeting its own row. This is the reciprocal (ORCA-style) split in CBF form:
    with c >= 0 (the pair is safe at its current velocities) u_i = v_i is allowed, so robots
    moving together are not slowed; only a change towards each other is shared out. When
    c < 0 (data out of step) both must move apart; an infeasible row is a fallback, counted.

    Sampled time, single integrators: d_k+1 = d_k + dt (u_i - u_j), so
    h_k+1 = h_k + dt 2 d . (u_i - u_j) + dt^2 |u_i - u_j|^2 >= (1 - gamma dt) h_k >= 0
    whenever gamma dt <= 1: the rate condition holds exactly between samples (the square term
    only helps). Unicycles: second-order terms in dt remain (the heading's arc).

    Returns the row normalised (a zero gradient is kept as 0 <= b)."""
    gvi = gi[0] * vi[0] + gi[1] * vi[1]
    c = gamma * h + gvi + gj[0] * vj[0] + gj[1] * vj[1]
    ni, nj = gi[0] * gi[0] + gi[1] * gi[1], gj[0] * gj[0] + gj[1] * gj[1]
    lam = ni / (ni + nj) if ni + nj > 1e-18 else 0.5
    # g_i . u >= g_i . v_i - lambda c   <=>   -g_i . u <= lambda c - g_i . v_i
    return normalized_row(-gi[0], -gi[1], lam * c - gvi)


# -------------------------------------------------------------------------- speed limits


#: |u| <= vmax as a regular polygon inscribed in the disk, one vertex along the nominal direction
#: (:func:`geometry.speed_polygon.rows`): the speed limit rows.
speed_rows = speed_polygon.rows
