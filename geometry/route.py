"""A formation's route around walls and shelves, and the rule that walks it.

The barriers keep every robot safe but cannot see past a shelf: a goal straight behind one is a
local minimum of the CBF-QP (the nominal command of eq. 4.2 points into the shelf, the barrier
cancels it). The leader therefore plans a route for its formation's centroid:

* every wall and shelf is inflated by the formation's radius (the largest distance of a member
  from the centroid in the goal shape), its safe distance Ds and :data:`ROUTE_MARGIN`;
* the candidate waypoints are the vertices of an octagon circumscribing each inflated shape
  (each octagon edge is tangent to the rounded outline, so a path along it keeps the
  clearance), keeping those clear of every other inflated shape;
* a straight leg between two points is usable when it keeps every shape's inflated clearance,
  or, for a leg starting or ending closer than that (a formation starting or parking next to a
  wall), no less than its ends already have;
* A* over that visibility graph, legs checked lazily, Euclidean length as cost and heuristic.

Circles are left to the barriers (they may move), so a scenario without walls and boxes gets the
one-waypoint route (the goal) and behaves as before. No route found: the goal alone.

Tracking (:func:`advance`): the formation heads for waypoint k; once its centroid is within
:data:`ADVANCE_RADIUS` of it, for waypoint k + 1; the last waypoint is the goal. Each member's
target is the current waypoint plus its offset in the goal shape (:func:`member_target`).
"""

from __future__ import annotations

import heapq
import math
from collections.abc import Sequence

from .shapes import Shape, path_clearance, shape_distance

Point = tuple[float, float]

ROUTE_MARGIN = 0.15  # [m] clearance of the centroid's route beyond formation radius and Ds
ADVANCE_RADIUS = 0.15  # [m] the centroid this close to a waypoint moves on to the next
_TAN_8 = math.tan(math.pi / 8.0)
_VERTEX_GROW = 1.02  # octagon vertices sit this much beyond the inflated outline


def formation_radius(offsets: Sequence[Point]) -> float:
    """Largest distance of a member from the centroid [m] (whatever the heading)."""
    return max((math.hypot(x, y) for x, y in offsets), default=0.0)


def plan_route(start: Point, goal: Point, shapes: Sequence[Shape], radius: float,
               margin: float = ROUTE_MARGIN) -> tuple[Point, ...]:
    """The centroid's waypoints from ``start`` to ``goal`` (``goal`` last, ``start`` not
    included) around ``shapes`` inflated by ``radius`` + Ds + ``margin``."""
    goal = (float(goal[0]), float(goal[1]))
    if not shapes:
        return (goal,)
    legs = _Legs((float(start[0]), float(start[1])), goal, shapes, radius + margin)
    path = _astar(legs.nodes, legs.usable)
    return tuple(legs.nodes[k] for k in path) if path else (goal,)


class _Legs:
    """The visibility graph: node 0 the start, node 1 the goal, then the octagon vertices clear
    of every inflated shape; :meth:`usable` checks a leg lazily."""

    def __init__(self, start: Point, goal: Point, shapes: Sequence[Shape], grow: float) -> None:
        self.shapes = shapes
        self.need = [sh.ds + grow for sh in shapes]
        self.frames = [(math.cos(sh.yaw), math.sin(sh.yaw)) for sh in shapes]
        self.nodes: list[Point] = [start, goal]
        for j, sh in enumerate(shapes):
            r = self.need[j] * _VERTEX_GROW
            for su, sv in ((sh.hx + r, sh.hy + r * _TAN_8), (sh.hx + r * _TAN_8, sh.hy + r)):
                for cu, cv in ((1, 1), (-1, 1), (-1, -1), (1, -1)):
                    p = sh.local_to_world(cu * su, cv * sv)
                    if all(self.gap(p, k) >= self.need[k] for k in range(len(shapes))):
                        self.nodes.append(p)
        self.end_gap = [[self.gap(p, j) for j in range(len(shapes))] for p in self.nodes[:2]]

    def gap(self, p: Point, j: int) -> float:
        return max(0.0, shape_distance(p[0], p[1], self.shapes[j])[0])

    def usable(self, a: int, b: int) -> bool:
        """Whether the leg between nodes a and b keeps every shape's clearance (a leg from the
        start or to the goal: no less than that end already has)."""
        pa, pb = self.nodes[a], self.nodes[b]
        for j, sh in enumerate(self.shapes):
            want = self.need[j]
            for end in (a, b):
                if end < 2:
                    want = min(want, self.end_gap[end][j])
            # quick accept: the leg misses the shape's rectangle grown by the clearance wanted
            if hits_grown_box(pa, pb, sh, self.frames[j], want) and \
                    path_clearance(pa, pb, sh) < want - 1e-9:
                return False
        return True


def _astar(nodes: Sequence[Point], usable) -> list[int] | None:
    """Shortest path from node 0 to node 1 (Euclidean cost and heuristic), legs checked lazily
    with ``usable(a, b)``: the node indices after the start, or None."""
    goal = nodes[1]
    best = {0: 0.0}
    parent: dict[int, int] = {}
    done: set[int] = set()
    heap = [(math.dist(nodes[0], goal), 0.0, 0)]
    while heap:
        _, g, a = heapq.heappop(heap)
        if a in done:
            continue
        done.add(a)
        if a == 1:
            path = [1]
            while path[-1] != 0:
                path.append(parent[path[-1]])
            return list(reversed(path[:-1]))
        for b in range(1, len(nodes)):
            if b in done:
                continue
            ng = g + math.dist(nodes[a], nodes[b])
            if ng >= best.get(b, math.inf) or not usable(a, b):
                continue
            best[b] = ng
            parent[b] = a
            heapq.heappush(heap, (ng + math.dist(nodes[b], goal), ng, b))
    return None


def hits_grown_box(p0: Point, p1: Point, sh: Shape, frame: tuple[float, float], grow: float) -> bool:
    """Whether the leg p0-p1 meets the shape's rectangle grown by ``grow`` on every side
    (Liang-Barsky clipping in the shape's frame). False means the leg keeps at least ``grow``
    from the shape; True says nothing (the grown rectangle's corners are square)."""
    c, s = frame
    x0, y0 = p0[0] - sh.cx, p0[1] - sh.cy
    x1, y1 = p1[0] - sh.cx, p1[1] - sh.cy
    u0, v0 = c * x0 + s * y0, -s * x0 + c * y0
    du, dv = c * (x1 - x0) + s * (y1 - y0), -s * (x1 - x0) + c * (y1 - y0)
    hu, hv = sh.hx + grow, sh.hy + grow
    lo, hi = 0.0, 1.0
    for d, q0, h in ((du, u0, hu), (dv, v0, hv)):
        if d == 0.0:
            if abs(q0) > h:
                return False
            continue
        t0, t1 = (-h - q0) / d, (h - q0) / d
        if t0 > t1:
            t0, t1 = t1, t0
        lo, hi = max(lo, t0), min(hi, t1)
        if lo > hi:
            return False
    return True


def advance(route: Sequence[Point], index: int, cx: float, cy: float,
            radius: float = ADVANCE_RADIUS) -> int:
    """The waypoint to head for, given the formation centroid (cx, cy): past every waypoint
    the centroid is already within ``radius`` of, never past the last (the goal)."""
    while index < len(route) - 1 and math.hypot(route[index][0] - cx, route[index][1] - cy) <= radius:
        index += 1
    return index


def member_target(route: Sequence[Point], index: int, goal: Point, offset: Point,
                  turned: float = 0.0) -> Point:
    """A member's target: its own goal on the last leg, else the waypoint plus its offset (its
    goal's from the goal centroid) turned by ``turned`` [rad]: a waypoint with a heading is the
    formation's pose there, so a member's target is its slot at that pose (the goal shape's
    offset at the goal's heading would park a formation that must still turn at the waypoint: a
    pentagon stood short of a waypoint's heading with every member near its unturned target)."""
    if index >= len(route) - 1:
        return goal
    wx, wy = route[index]
    c, s = math.cos(turned), math.sin(turned)
    return (wx + c * offset[0] - s * offset[1], wy + s * offset[0] + c * offset[1])


def route_length(start: Point, route: Sequence[Point]) -> float:
    """Length of the polyline start -> route[0] -> ... [m]."""
    total, p = 0.0, start
    for w in route:
        total += math.dist(p, w)
        p = w
    return total
