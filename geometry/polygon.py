"""Convex polygons: a formation's load against points, disks, walls, shelves and other
loads.

A polygon is a sequence of vertices (x, y), counter-clockwise; two vertices make a segment and
one a point (the degenerate loads of two- and one-robot formations). Distances are signed:
positive is the gap between the two sets, negative is the depth of overlap (the shortest
translation that separates them, by the separating axis theorem over the edge normals and
directions of both: exact for convex sets).

Pure functions; :func:`points_distance` is vectorised (numpy) because the safety monitor calls it
for every robot on every tick.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from .angles import wrap_angle
from .shapes import segment_distance

Point = tuple[float, float]


def convex_hull(points: Sequence[Point]) -> tuple[Point, ...]:
    """The convex hull, counter-clockwise, without collinear or repeated vertices (Andrew's
    monotone chain); two distinct points give a segment, one a point."""
    pts = sorted(set((float(p[0]), float(p[1])) for p in points))
    if len(pts) <= 2:
        return tuple(pts)

    def half(seq: Sequence[Point]) -> list[Point]:
        out: list[Point] = []
        for p in seq:
            while len(out) >= 2 and cross(out[-2], out[-1], p) <= 0.0:
                out.pop()
            out.append(p)
        return out

    lower, upper = half(pts), half(pts[::-1])
    hull = lower[:-1] + upper[:-1]
    return tuple(hull) if len(hull) >= 2 else (pts[0], pts[-1])


def cross(o: Point, a: Point, b: Point) -> float:
    """z of (a - o) x (b - o): positive when o, a, b turn counter-clockwise."""
    return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])


def area(poly: Sequence[Point]) -> float:
    """Signed area (shoelace): positive for counter-clockwise vertices."""
    n = len(poly)
    return 0.5 * sum(poly[k][0] * poly[(k + 1) % n][1] - poly[(k + 1) % n][0] * poly[k][1]
                     for k in range(n))


def is_convex(poly: Sequence[Point]) -> bool:
    """Whether ``poly`` (3 or more vertices, in order) is a strictly convex polygon, in either
    direction: every turn has the same sign and none is straight, and it winds once."""
    n = len(poly)
    turns = [cross(poly[k], poly[(k + 1) % n], poly[(k + 2) % n]) for k in range(n)]
    if not (all(t > 0.0 for t in turns) or all(t < 0.0 for t in turns)):
        return False
    winding = 0.0
    for k in range(n):
        a = math.atan2(poly[(k + 1) % n][1] - poly[k][1], poly[(k + 1) % n][0] - poly[k][0])
        b = math.atan2(poly[(k + 2) % n][1] - poly[(k + 1) % n][1],
                       poly[(k + 2) % n][0] - poly[(k + 1) % n][0])
        winding += wrap_angle(b - a)
    return abs(abs(winding) - 2.0 * math.pi) < 1e-6


def counter_clockwise(poly: Sequence[Point]) -> tuple[Point, ...]:
    return tuple(poly) if area(poly) >= 0.0 else tuple(poly[::-1])


def points_distance(points: np.ndarray, poly: Sequence[Point]) -> np.ndarray:
    """Signed distance from each of ``points`` (m, 2) to the convex counter-clockwise polygon
    (negative inside: minus the distance to the outline); a segment or point has no inside."""
    p = np.asarray(points, dtype=float).reshape(-1, 2)
    v = np.asarray(poly, dtype=float).reshape(-1, 2)
    if len(v) == 1:
        return np.sqrt(np.sum((p - v[0]) ** 2, axis=1))
    a = v if len(v) > 2 else v[:1]
    b = np.roll(v, -1, axis=0) if len(v) > 2 else v[1:]
    e = b - a  # (k, 2) edges
    w = p[:, None, :] - a[None, :, :]  # (m, k, 2)
    ee = np.maximum(np.sum(e * e, axis=1), 1e-300)
    t = np.clip(np.sum(w * e[None, :, :], axis=2) / ee[None, :], 0.0, 1.0)
    d = w - t[:, :, None] * e[None, :, :]
    dist = np.min(np.sqrt(np.sum(d * d, axis=2)), axis=1)
    if len(v) > 2:
        side = e[None, :, 0] * w[:, :, 1] - e[None, :, 1] * w[:, :, 0]  # > 0: left of edge
        inside = np.all(side >= 0.0, axis=1)
        dist = np.where(inside, -dist, dist)
    return dist


def _axes(poly: Sequence[Point]) -> list[Point]:
    """Unit edge directions and normals of ``poly`` (the candidate separating axes)."""
    out: list[Point] = []
    n = len(poly)
    for k in range(n if n > 2 else n - 1):
        dx, dy = poly[(k + 1) % n][0] - poly[k][0], poly[(k + 1) % n][1] - poly[k][1]
        length = math.hypot(dx, dy)
        if length > 0.0:
            out.append((dx / length, dy / length))
            out.append((-dy / length, dx / length))
    return out


def _gap(p: Sequence[Point], q: Sequence[Point], axis: Point) -> float:
    """The gap between the projections of ``p`` and ``q`` on ``axis`` (negative: overlap)."""
    sp = [x * axis[0] + y * axis[1] for x, y in p]
    sq = [x * axis[0] + y * axis[1] for x, y in q]
    return max(min(sq) - max(sp), min(sp) - max(sq))


def separation_floor(p: Sequence[Point], q: Sequence[Point]) -> float:
    """A lower bound of :func:`polygon_distance` where it is positive: the widest gap between
    the projections of ``p`` and ``q`` on ``q``'s edge directions and normals (a projection
    brings no two points closer). Cheaper than the distance when ``q`` has few edges."""
    return max((_gap(p, q, ax) for ax in _axes(q)), default=-math.inf)


def polygon_distance(p: Sequence[Point], q: Sequence[Point]) -> float:
    """Signed distance between two convex polygons (segments and points allowed): the gap
    when apart, minus the separating depth when they overlap (see the module docstring)."""
    axes = _axes(p) + _axes(q)
    gaps = [_gap(p, q, ax) for ax in axes]
    if axes and max(gaps) <= 0.0:
        return max(gaps)  # overlap: the least depth over the axes (SAT)
    return min(_outline_distance(q, p), _outline_distance(p, q))


def _outline_distance(points: Sequence[Point], poly: Sequence[Point]) -> float:
    """The smallest distance from ``points`` to the outline of ``poly`` (pure Python: the
    polygons here have a few corners, where numpy's per-call cost dominates)."""
    n = len(poly)
    if n == 1:
        return min(math.dist(v, poly[0]) for v in points)
    edges = [(poly[k], poly[(k + 1) % n]) for k in range(n if n > 2 else 1)]
    return min(segment_distance(v[0], v[1], a[0], a[1], b[0], b[1])[0]
               for v in points for a, b in edges)


def bounding_circle(poly: Sequence[Point]) -> tuple[Point, float]:
    """A circle around every vertex: the vertices' mean and the largest distance to it."""
    n = len(poly)
    cx = sum(v[0] for v in poly) / n
    cy = sum(v[1] for v in poly) / n
    return (cx, cy), max(math.hypot(v[0] - cx, v[1] - cy) for v in poly)


def closest_point(poly: Sequence[Point], p: Point) -> Point:
    """The point of the convex counter-clockwise polygon (or segment, or point) nearest to
    ``p``: ``p`` itself when inside."""
    if len(poly) > 2 and points_distance(np.array([p]), poly)[0] <= 0.0:
        return (float(p[0]), float(p[1]))
    best, best_d = (float(poly[0][0]), float(poly[0][1])), math.inf
    n = len(poly)
    for k in range(n if n > 2 else n - 1):
        a, b = poly[k], poly[(k + 1) % n]
        ex, ey = b[0] - a[0], b[1] - a[1]
        ee = ex * ex + ey * ey
        t = 0.0 if ee == 0.0 else min(1.0, max(0.0, ((p[0] - a[0]) * ex + (p[1] - a[1]) * ey) / ee))
        q = (a[0] + t * ex, a[1] + t * ey)
        d = math.dist(q, p)
        if d < best_d:
            best, best_d = (float(q[0]), float(q[1])), d
    return best
