"""A route for a formation's footprint in (x, y, heading): lattice A*.

The centroid route of :mod:`geometry.route` inflates every shape by the formation's largest
radius: a long or uneven formation then finds no way through an aisle it fits lengthwise. This
planner moves the footprint itself, the rigid body of :mod:`agent.body` (eq. 4.12'): each member
a point at its slot that keeps a thing's safe distance Ds (eq. 3.4 for a circle, eq. 4.5 for a
wall or shelf) and the load's outline, which keeps the things' physical outlines (a circle's Ds
less the robot radius), each with :data:`PLAN_MARGIN` to spare.

* Two clearance fields on a fine grid (spacing h / 2, h the lattice's): F(p), the smallest
  distance of p from a thing less its Ds, and G(p), the smallest distance from a thing's physical
  outline. Both are 1-Lipschitz.
* A pose (c, theta) is scored by the smallest value of F - margin at the member slots and of
  G - margin at points spaced along (and inside) the load's outline, each read at the fine-grid
  point nearest it (error at most h / (2 sqrt 2)). One array per heading: K headings x the
  lattice, by array slices.
* A* over (cell, heading) (cells of 0.05 m in a scene up to 250 m^2, else 0.1 m): the 8
  neighbouring cells at one heading (a pose may move if it scores at least
  :attr:`Search.move_need` h, so every point between two cells, and on a shortcut, keeps the
  margin), or one heading step in place (at least rho dtheta / 2 + :attr:`Search.fine_error` h,
  rho the largest radius of the footprint). Cost: the distance moved, and the outermost point's
  arc for a turn; heuristic: the octile distance and that arc, times :attr:`Search.greedy`.
* A footprint that looks the same at every heading (a robot alone) is planned on one heading:
  turning changes nothing for it.
* Near the start and the goal a pose no worse than the end's own is allowed (a formation may
  start or park closer to a wall than the margin).
* A straight way to the goal, turning as it goes (as the rigid motion does), that scores
  everywhere is the route: the goal alone.
* The lattice path becomes waypoints (x, y, theta): straight runs at one heading, shortcut where
  the straight line between two of its poses scores; every turn in place is a waypoint at the
  old heading and one at the new. Then waypoints that a straight move turning as it goes (as
  the rigid motion does) joins are left out. The last waypoint is the goal pose itself.

* Where the lattice finds no way, the narrow pass (:func:`plan_narrow`): a passage the
  footprint fits by what the formation keeps (epsilon, the look-ahead offset) plus
  :attr:`Narrow.clearance` a side is shut on the lattice by its own margins (PLAN_MARGIN and
  about 2.4 cells); a loose search finds the way, and its tight stretches are searched again on
  a fine lattice in a window round each, its headings along the passage. A goal no way reaches
  (a closed room) stays without a route: the loose lattice shuts it too.

theta is the rotation of the footprint from its start frame (:class:`agent.body.Pose`). No
route: :class:`FootprintPlan` with ``route`` empty and the reason.
"""

from __future__ import annotations

import functools
import heapq
import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import NamedTuple

import numpy as np

from .angles import LEFT_BIAS, wrap_angle, wrap_left
from .shapes import Shape, shape_distance

Point = tuple[float, float]
Pose3 = tuple[float, float, float]  # (x [m], y [m], theta [rad])
Circle = tuple[float, float, float]  # (x, y, Ds [m]) a round thing, Ds from a robot's centre

PLAN_MARGIN = 0.05  # [m] the footprint's clearance beyond Ds (members) and outlines (load)
_CAP = 1.0  # [m] the fields need no larger value
_BLOCKED = -1e9


@dataclass(frozen=True)
class Grid:
    """The lattice the search runs on (:func:`lattice_for`, :func:`plan_footprint`)."""

    spacing: float = 0.1  # [m] the cell (finer: narrower gaps found, a slower search)
    fine_spacing: float = 0.05  # [m] the cell in a small scene (finer: tighter slots, more cells)
    fine_cells: int = 100_000  # a scene of at most this many fine cells (250 m^2) is planned on them
    fallback_cells: int = 400_000  # up to this many (1,000 m^2): fine again where ``spacing`` fails
    headings: int = 32  # headings on the lattice, every 11.25 degrees (more: finer turns, slower)
    coarse: int = 4  # the heuristic's grid is this much coarser (more: a cheaper, weaker heuristic)
    pad: float = 1.5  # [m] planned beyond the footprint round everything (more: wider detours, more cells)


@dataclass(frozen=True)
class Search:
    """The A* over the lattice (:func:`plan_footprint`)."""

    greedy: float = 1.5  # the heuristic's weight (>1: fewer poses expanded, a route up to this longer)
    max_expansions: int = 400_000  # poses expanded before "no route" (more: harder routes, slower no)
    end_radius: float = 0.5  # [m] round the ends, no worse than they are (larger: starts nearer walls)
    # [h] a straight move's points lie within 0.96 h of a checked cell, plus fine_error (lower:
    # gaps found narrower than the margin keeps)
    move_need: float = 1.35
    fine_error: float = 0.36  # [h] a point's distance from the fine-grid point it is read at (h / 2 / sqrt 2)


@dataclass(frozen=True)
class Waypoints:
    """How a lattice path becomes waypoints, and the load's sample points."""

    # a turn this near half a turn goes left, as the rigid motion turns (geometry.angles.wrap_left)
    direct_left: float = LEFT_BIAS
    merge_turn: float = math.radians(80.0)  # turns in place up to this are one waypoint (more: fewer)
    interior: float = 0.3  # [m] the load's inside points this apart (less: smaller things seen, slower)


@dataclass(frozen=True)
class Narrow:
    """The narrow-passage search (:func:`plan_narrow`), run where the lattice finds no way."""

    clearance: float = 0.02  # [m] beyond Ds and the formation's own keep: a passage this roomy is found
    spacing: float = 0.008  # [m] a window's cell (at most clearance / slack: the search's error fits)
    # [h] a lattice's own error: the nearest cell h / sqrt 2 off a passage's middle, read within
    # Search.fine_error h, and a move's Search.move_need h
    slack: float = 2.42
    pad: float = 0.3  # [m] beyond rho round a tight stretch: its window (more: room to turn, slower)
    max_cells: int = 250_000  # a window of more cells is not searched (its stretch stays shut)
    tries: int = 3  # tight stretches shut in turn before "no way" (more: slower no, other ways tried)
    # a loose step where the strict flags forbid a move costs this many times its length (more:
    # shorter tight stretches, so smaller windows; a longer way round to avoid them)
    tight_cost: float = 1.5


GRID = Grid()
SEARCH = Search()
WAYPOINTS = Waypoints()
NARROW = Narrow()
NO_WAY = "no way for the footprint from its start to the goal"
GOAL_SHUT = "the footprint does not fit at the goal"


@dataclass(frozen=True)
class Body:
    """The footprint in its start frame (origin: the centroid; :class:`agent.body.Footprint`)."""

    slots: tuple[Point, ...]  # each member's point (its control point at the start)
    load: tuple[Point, ...] = ()  # the load's convex outline; () = the members' hull
    radius: float = 0.0  # [m] a robot's body radius (a circle's physical size is Ds less it)
    margin: float = PLAN_MARGIN

    @property
    def rho(self) -> float:
        """[m] the largest distance of a footprint point from the centroid."""
        return max([0.01] + [math.hypot(x, y) for x, y in self.slots + self.load])

    @property
    def turn_free(self) -> bool:
        """Whether the footprint looks the same at every heading (one point at the centroid,
        no load: a robot alone): turning changes nothing, so it is planned on one heading."""
        return not self.load and all(x == 0.0 and y == 0.0 for x, y in self.slots)

    def headings(self, wanted: int) -> int:
        """The lattice's headings for this footprint: ``wanted``, one where it is round."""
        return 1 if self.turn_free else wanted

    @functools.cached_property
    def width(self) -> float:
        """[m] the footprint's smaller extent (across its least-width direction, bodies included;
        worked out once)."""
        pts = self.slots + self.load
        best = math.inf
        for k in range(36):
            a = math.pi * k / 36
            c, s = math.cos(a), math.sin(a)
            proj = [c * x + s * y for x, y in pts]
            best = min(best, max(proj) - min(proj))
        return best + 2.0 * self.radius


class FootprintPlan(NamedTuple):
    route: tuple[Pose3, ...]  # waypoints, the goal pose last; () when none
    reason: str = ""  # why there is no route ("" when there is one)
    expanded: int = 0  # poses the search expanded


@dataclass(frozen=True)
class Lattice:
    """The planned area: ``nx`` x ``ny`` cells of ``h`` from (x0, y0); the fine grid is twice as dense."""

    x0: float
    y0: float
    h: float
    nx: int
    ny: int
    headings: int
    turn0: float = 0.0  # [rad] heading 0's theta (a narrow window's: its passage's axis)

    def cell(self, x: float, y: float) -> tuple[int, int]:
        return (min(self.nx - 2, max(1, round((x - self.x0) / self.h))),
                min(self.ny - 2, max(1, round((y - self.y0) / self.h))))

    def point(self, i: int, j: int) -> Point:
        return (self.x0 + i * self.h, self.y0 + j * self.h)

    def heading(self, theta: float) -> int:
        return round((theta - self.turn0) / (2.0 * math.pi / self.headings)) % self.headings

    def theta(self, k: int) -> float:
        if self.turn0:
            return wrap_angle(self.turn0 + 2.0 * math.pi * k / self.headings)
        a = 2.0 * math.pi * k / self.headings
        return a - 2.0 * math.pi if a > math.pi else a


def lattice_for(start: Pose3, goal: Pose3, shapes: Sequence[Shape], circles: Sequence[Circle],
                rho: float, h: float = GRID.spacing, headings: int = GRID.headings) -> Lattice:
    """The area holding the start, the goal and every thing, with rho + GRID.pad around it."""
    xs = [start[0], goal[0]] + [c[0] for c in circles]
    ys = [start[1], goal[1]] + [c[1] for c in circles]
    for sh in shapes:
        for x, y in sh.corners():
            xs.append(x)
            ys.append(y)
    pad = rho + GRID.pad
    x0, y0 = min(xs) - pad, min(ys) - pad
    nx = int(math.ceil((max(xs) + pad - x0) / h)) + 1
    ny = int(math.ceil((max(ys) + pad - y0) / h)) + 1
    return Lattice(x0, y0, h, nx, ny, headings)


# --------------------------------------------------------------------------- the fields


def _box_field(xs: np.ndarray, ys: np.ndarray, sh: Shape) -> np.ndarray:
    """Signed distance to the shape's outline on the grid xs x ys (a segment: a box of width 0)."""
    c, s = math.cos(sh.yaw), math.sin(sh.yaw)
    dx, dy = xs[:, None] - sh.cx, ys[None, :] - sh.cy
    u, v = np.abs(c * dx + s * dy) - sh.hx, np.abs(-s * dx + c * dy) - sh.hy
    out = np.hypot(np.maximum(u, 0.0), np.maximum(v, 0.0))
    return np.where((u > 0.0) | (v > 0.0), out, np.maximum(u, v))


def fields(lat: Lattice, shapes: Sequence[Shape], circles: Sequence[Circle], radius: float
           ) -> tuple[np.ndarray, np.ndarray]:
    """(F, G) on the fine grid (module docstring), capped at _CAP; each thing only where it is
    nearer than that."""
    f = lat.h / 2.0
    nfx, nfy = 2 * lat.nx - 1, 2 * lat.ny - 1
    big_f = np.full((nfx, nfy), _CAP, dtype=np.float32)
    big_g = np.full((nfx, nfy), _CAP, dtype=np.float32)
    for sh in shapes:
        corners = sh.corners()
        win = _window(lat, [p[0] for p in corners], [p[1] for p in corners], sh.ds + _CAP)
        if win is None:
            continue
        (a, b), (c, d) = win
        dist = _box_field(lat.x0 + f * np.arange(a, b), lat.y0 + f * np.arange(c, d), sh)
        big_f[a:b, c:d] = np.minimum(big_f[a:b, c:d], dist - sh.ds)
        big_g[a:b, c:d] = np.minimum(big_g[a:b, c:d], dist)
    for ox, oy, ds in circles:
        win = _window(lat, [ox], [oy], ds + _CAP)
        if win is None:
            continue
        (a, b), (c, d) = win
        xs, ys = lat.x0 + f * np.arange(a, b), lat.y0 + f * np.arange(c, d)
        dist = np.hypot(xs[:, None] - ox, ys[None, :] - oy)
        big_f[a:b, c:d] = np.minimum(big_f[a:b, c:d], dist - ds)
        big_g[a:b, c:d] = np.minimum(big_g[a:b, c:d], dist - max(0.0, ds - radius))
    return big_f, big_g


def _window(lat: Lattice, xs: Sequence[float], ys: Sequence[float], reach: float):
    """The fine-grid index ranges within ``reach`` of the points' bounding box (clipped), or None."""
    f = lat.h / 2.0
    a = max(0, int(math.floor((min(xs) - reach - lat.x0) / f)))
    b = min(2 * lat.nx - 1, int(math.ceil((max(xs) + reach - lat.x0) / f)) + 1)
    c = max(0, int(math.floor((min(ys) - reach - lat.y0) / f)))
    d = min(2 * lat.ny - 1, int(math.ceil((max(ys) + reach - lat.y0) / f)) + 1)
    return None if a >= b or c >= d else ((a, b), (c, d))


# -------------------------------------------------------------------------- the footprint


def load_outline(body: Body) -> tuple[Point, ...]:
    """The load's outline: the declared one, else the members' hull (a segment for two)."""
    if len(body.load) >= 2:
        return body.load
    return _hull(body.slots) if len(body.slots) >= 2 else ()


def _hull(pts: Sequence[Point]) -> tuple[Point, ...]:
    """Convex hull, counter-clockwise (monotone chain)."""
    p = sorted(set(pts))
    if len(p) <= 2:
        return tuple(p)

    def half(seq: Sequence[Point]) -> list[Point]:
        out: list[Point] = []
        for q in seq:
            while len(out) >= 2 and ((out[-1][0] - out[-2][0]) * (q[1] - out[-2][1])
                                     - (out[-1][1] - out[-2][1]) * (q[0] - out[-2][0])) <= 0.0:
                out.pop()
            out.append(q)
        return out

    lower, upper = half(p), half(list(reversed(p)))
    return tuple(lower[:-1] + upper[:-1])


def load_samples(outline: Sequence[Point], spacing: float) -> list[Point]:
    """Points along the outline at most ``spacing`` apart, and inside it every WAYPOINTS.interior."""
    n = len(outline)
    if n == 0:  # a formation of one carries nothing
        return []
    pts: list[Point] = []
    for k in range(n if n > 2 else 1):
        (ax, ay), (bx, by) = outline[k], outline[(k + 1) % n]
        steps = max(1, int(math.ceil(math.hypot(bx - ax, by - ay) / spacing)))
        pts += [(ax + (bx - ax) * t / steps, ay + (by - ay) * t / steps) for t in range(steps)]
    if n <= 2:
        return pts + [outline[-1]]
    xs, ys = [p[0] for p in outline], [p[1] for p in outline]
    x = min(xs) + WAYPOINTS.interior / 2
    while x < max(xs):
        y = min(ys) + WAYPOINTS.interior / 2
        while y < max(ys):
            if _inside(outline, x, y):
                pts.append((x, y))
            y += WAYPOINTS.interior
        x += WAYPOINTS.interior
    return pts


def _inside(poly: Sequence[Point], x: float, y: float) -> bool:
    """Whether (x, y) is inside the counter-clockwise convex polygon."""
    n = len(poly)
    return all((poly[(k + 1) % n][0] - poly[k][0]) * (y - poly[k][1])
               - (poly[(k + 1) % n][1] - poly[k][1]) * (x - poly[k][0]) >= 0.0 for k in range(n))


def scores(lat: Lattice, body: Body, big_f: np.ndarray, big_g: np.ndarray, cover: float = 0.0
           ) -> np.ndarray:
    """For each heading, the footprint's score (smallest clearance beyond the margin) on the
    lattice (an array K x nx x ny); the lattice's border is blocked. A load point within
    ``cover`` of a slot is left out: G >= F + cover there (``cover`` at most the robot radius
    and every shape's Ds), so the slot's reading bounds it."""
    samples = [(p, 0) for p in body.slots]
    samples += [(p, 1) for p in load_samples(load_outline(body), lat.h)
                if all(math.dist(p, q) > cover for q in body.slots)]
    f = lat.h / 2.0
    reach = int(math.ceil(body.rho / f)) + 2
    # each field padded, then split by the parity of its fine indices: a lattice-strided read
    # of the fine grid is a plain slice of one part
    parts = []
    for a in (big_f, big_g):
        pad = np.pad(a, reach, constant_values=_BLOCKED)
        parts.append({(pi, pj): np.ascontiguousarray(pad[pi::2, pj::2]) for pi in (0, 1) for pj in (0, 1)})
    out = np.full((lat.headings, lat.nx, lat.ny), _CAP, dtype=np.float32)
    for k in range(lat.headings):
        th = lat.theta(k)
        c, s = math.cos(th), math.sin(th)
        score = out[k]
        for (px, py), which in samples:
            di = reach + round((c * px - s * py) / f)
            dj = reach + round((s * px + c * py) / f)
            sub = parts[which][(di % 2, dj % 2)]
            np.minimum(score, sub[di // 2:di // 2 + lat.nx, dj // 2:dj // 2 + lat.ny], out=score)
    out -= body.margin
    out[:, 0, :] = out[:, -1, :] = out[:, :, 0] = out[:, :, -1] = _BLOCKED
    return out


# ---------------------------------------------------------------------------- the search


class _Search(NamedTuple):
    lat: Lattice
    move: bytearray  # per state k * N + i * ny + j: may move to a neighbouring cell
    turn: bytearray  # may turn one heading step
    turn_cost: float  # [m] the outermost point's arc for one heading step
    to_goal: list[float]  # per coarse cell: its distance to the goal (coarse_distance)
    coarse_ny: int  # the coarse grid's row length
    dear: bytearray | None = None  # per state: a step into it costs Narrow.tight_cost times more


def coarse_distance(lat: Lattice, move: bytearray, goal: Point) -> tuple[list[float], int]:
    """The heuristic: per cell of a grid GRID.coarse times coarser than the lattice (row-major, the
    second number its row length), open where any of its cells may move at any heading, the
    length of the shortest 8-connected path to the goal's cell less the coarse cells' diagonal
    twice (so it underestimates the lattice's path); inf where the goal cannot be reached."""
    free = np.frombuffer(move, dtype=bool).reshape(lat.headings, lat.nx, lat.ny).any(axis=0)
    cx, cy = -(-lat.nx // GRID.coarse), -(-lat.ny // GRID.coarse)
    grid = np.zeros((cx * GRID.coarse, cy * GRID.coarse), dtype=bool)
    grid[:lat.nx, :lat.ny] = free
    opened = grid.reshape(cx, GRID.coarse, cy, GRID.coarse).any(axis=(1, 3)).ravel().tolist()
    gi, gj = lat.cell(*goal)
    dist = _dijkstra(opened, cx, cy, (gi // GRID.coarse) * cy + gj // GRID.coarse, GRID.coarse * lat.h)
    slack = 2.0 * math.sqrt(2.0) * GRID.coarse * lat.h
    return [max(0.0, d - slack) for d in dist], cy


def _dijkstra(opened: list[bool], cx: int, cy: int, goal: int, step: float) -> list[float]:
    """8-connected grid distances from ``goal`` over the open cells (row-major cx x cy)."""
    dist = [math.inf] * (cx * cy)
    dist[goal] = 0.0
    heap = [(0.0, goal)]
    d2 = step * math.sqrt(2.0)
    moves = ((-1, 0, step), (1, 0, step), (0, -1, step), (0, 1, step),
             (-1, -1, d2), (-1, 1, d2), (1, -1, d2), (1, 1, d2))
    while heap:
        d, c = heapq.heappop(heap)
        if d > dist[c]:
            continue
        i, j = divmod(c, cy)
        for di, dj, w in moves:
            a, b = i + di, j + dj
            if 0 <= a < cx and 0 <= b < cy and opened[a * cy + b] and d + w < dist[a * cy + b]:
                dist[a * cy + b] = d + w
                heapq.heappush(heap, (d + w, a * cy + b))
    return dist


def _allowed(lat: Lattice, sc: np.ndarray, ends: Sequence[Pose3], rho: float,
             need_move: float, need_turn: float) -> tuple[bytearray, bytearray]:
    """The move and turn flags of every state (module docstring), relaxed around the ends."""
    floor = np.zeros((lat.nx, lat.ny), dtype=np.float32)
    xs = lat.x0 + lat.h * np.arange(lat.nx)
    ys = lat.y0 + lat.h * np.arange(lat.ny)
    need = max(need_move, need_turn)
    for x, y, th in ends:
        i, j = lat.cell(x, y)
        own = float(sc[lat.heading(th), i, j])
        if own >= need:
            continue
        near = np.hypot(xs[:, None] - x, ys[None, :] - y) <= rho + SEARCH.end_radius
        floor = np.where(near, np.minimum(floor, own - need - 1e-6), floor).astype(np.float32)
    move = sc >= (floor + np.float32(need_move))[None, :, :]
    turn = sc >= (floor + np.float32(need_turn))[None, :, :]
    return bytearray(move.tobytes()), bytearray(turn.tobytes())


def _astar(sr: _Search, start: int, goal: int, limit: int) -> tuple[list[int] | None, int]:
    """Weighted A* from state ``start`` to ``goal``: (the states, or None; poses expanded)."""
    lat = sr.lat
    n, ny, kk = lat.nx * lat.ny, lat.ny, lat.headings
    gi, gk = goal % n, goal // n
    gx, gy = divmod(gi, ny)
    steps = _steps(lat)

    to_goal, cny = sr.to_goal, sr.coarse_ny
    greedy, coarse = SEARCH.greedy, GRID.coarse

    def heur(s: int) -> float:
        i, j = divmod(s % n, ny)
        a, b = abs(i - gx), abs(j - gy)
        dk = abs(s // n - gk)
        octile = lat.h * (max(a, b) + 0.41421356 * min(a, b))
        return greedy * (max(octile, to_goal[(i // coarse) * cny + j // coarse])
                         + sr.turn_cost * min(dk, kk - dk))

    best = {start: 0.0}
    parent: dict[int, int] = {}
    heap = [(heur(start), 0.0, start)]
    expanded = 0
    while heap and expanded < limit:
        _, g, s = heapq.heappop(heap)
        if g > best.get(s, math.inf):
            continue
        if s == goal:
            return _unwind(parent, start, goal), expanded
        expanded += 1
        for t, cost in _next(sr, s, n, kk, steps):
            ng = g + cost
            if ng < best.get(t, math.inf):
                est = heur(t)
                if est == math.inf:  # the goal cannot be reached from t at all
                    continue
                best[t] = ng
                parent[t] = s
                heapq.heappush(heap, (ng + est, ng, t))
    return None, expanded


def _next(sr: _Search, s: int, n: int, kk: int, steps: Sequence[tuple[int, float]]):
    """The states reachable from ``s`` in one move or one heading step, with their costs."""
    out = []
    if sr.move[s]:
        out = [(s + d, c) for d, c in steps if sr.move[s + d]]
    if sr.turn[s]:
        k, cell = divmod(s, n)
        for dk in (1, kk - 1):
            t = ((k + dk) % kk) * n + cell
            if sr.turn[t]:
                out.append((t, sr.turn_cost))
    if sr.dear is not None:
        dear = sr.dear
        return [(t, c * NARROW.tight_cost if dear[t] else c) for t, c in out]
    return out


def _unwind(parent: dict[int, int], start: int, goal: int) -> list[int]:
    path = [goal]
    while path[-1] != start:
        path.append(parent[path[-1]])
    path.reverse()
    return path


# ---------------------------------------------------------------------------- the route


def _poses(lat: Lattice, states: Sequence[int]) -> list[tuple[int, int, int]]:
    n = lat.nx * lat.ny
    return [(s // n, *divmod(s % n, lat.ny)) for s in states]


def _segment_clear(sr: _Search, k: int, a: tuple[int, int], b: tuple[int, int]) -> bool:
    """Whether the straight move from cell a to cell b at heading k scores everywhere (points
    every h / 2, each at its nearest cell)."""
    lat = sr.lat
    n = lat.nx * lat.ny
    steps = max(1, int(math.ceil(2.0 * math.hypot(b[0] - a[0], b[1] - a[1]))))
    for t in range(steps + 1):
        i = round(a[0] + (b[0] - a[0]) * t / steps)
        j = round(a[1] + (b[1] - a[1]) * t / steps)
        if not sr.move[k * n + i * lat.ny + j]:
            return False
    return True


def _runs(poses: list[tuple[int, int, int]]) -> list[list[tuple[int, int, int]]]:
    """The path split into runs at one heading (a turn in place ends one)."""
    runs = [[poses[0]]]
    for p in poses[1:]:
        if p[0] != runs[-1][-1][0]:
            runs.append([p])
        else:
            runs[-1].append(p)
    return runs


def _shortcut(sr: _Search, run: list[tuple[int, int, int]]) -> list[tuple[int, int, int]]:
    """The run's poses a straight move can join (greedy: the farthest clear one each time)."""
    out = [run[0]]
    a = 0
    while a < len(run) - 1:
        b = len(run) - 1
        while b > a + 1 and not _segment_clear(sr, run[a][0], run[a][1:], run[b][1:]):
            b -= 1
        out.append(run[b])
        a = b
    return out


def route_of(sr: _Search, states: Sequence[int], start: Pose3, goal: Pose3) -> tuple[Pose3, ...]:
    """The waypoints of a lattice path (module docstring): the goal pose last, the start left out."""
    lat = sr.lat
    pts: list[Pose3] = []
    turned = -1.0  # [rad] turned in place at the last point so far (< 0: it was reached moving)
    for run in _runs(_poses(lat, states)):
        for k, i, j in _shortcut(sr, run):
            x, y = lat.point(i, j)
            p = (x, y, lat.theta(k))
            if pts and p == pts[-1]:
                continue
            step = abs(wrap_angle(p[2] - pts[-1][2])) if pts and p[:2] == pts[-1][:2] else -1.0
            if step >= 0.0 and 0.0 <= turned < WAYPOINTS.merge_turn:
                pts[-1] = p  # one more heading step in place: one waypoint
                turned += step
            else:
                pts.append(p)
                turned = step
    while pts and math.dist(pts[0][:2], start[:2]) < lat.h and _same(pts[0][2], start[2], lat):
        pts.pop(0)
    while pts and math.dist(pts[-1][:2], goal[:2]) < lat.h and _same(pts[-1][2], goal[2], lat):
        pts.pop()
    return _smooth(sr, [start, *pts, goal])


def _smooth(sr: _Search, pts: list[Pose3]) -> tuple[Pose3, ...]:
    """The waypoints after the first that a straight move turning as it goes joins (greedy:
    the farthest :func:`direct_clear` one each time); the last is kept."""
    out: list[Pose3] = []
    a = 0
    while a < len(pts) - 1:
        b = len(pts) - 1
        while b > a + 1 and not direct_clear(sr, pts[a], pts[b]):
            b -= 1
        out.append(pts[b])
        a = b
    return tuple(out)


def _same(a: float, b: float, lat: Lattice) -> bool:
    return lat.heading(a) == lat.heading(b)


def plan_footprint(start: Pose3, goal: Pose3, body: Body, shapes: Sequence[Shape] = (),
                   circles: Sequence[Circle] = (), h: float | None = None, headings: int = GRID.headings,
                   limit: int = SEARCH.max_expansions, movable: Sequence[Circle] = ()) -> FootprintPlan:
    """The footprint's route from pose ``start`` to pose ``goal`` around ``shapes`` and
    ``circles`` (module docstring); cells of ``h`` [m], by default :attr:`Grid.fine_spacing` where
    the area holds at most :attr:`Grid.fine_cells` of them (a small scene: narrow slots), else
    :attr:`Grid.spacing`, and where that finds no route, the fine spacing again if the area holds
    at most :attr:`Grid.fallback_cells` of them: a move must score :attr:`Search.move_need` h, so a
    gap the footprint fits by less than about 0.14 m a side is shut on the coarse lattice (a
    hexagon of six robots between two shelves 1.68 m apart, in the warehouse) and open on the fine
    one. Where that finds no route either (and the footprint fits at the goal), and ``h`` is not
    given, :func:`plan_narrow` on the fine
    lattice (the coarse one beyond :attr:`Grid.fallback_cells`). ``movable``: those of
    ``circles`` that may move out of the way (other formations): where they alone shut the
    lattice's way there is no route (leader.routing gives way or waits, rather than sending the
    formation round by a narrow way), and the narrow pass squeezes past none of them."""
    if not shapes and not circles:  # an open floor: the straight move (what the search finds)
        return FootprintPlan((goal,))
    headings = body.headings(headings)
    plan = _plan_lattice(start, goal, body, shapes, circles, h, headings, limit)
    if h is not None or plan.route or plan.reason == GOAL_SHUT:
        return plan
    moving = set(movable)
    if moving and _plan_lattice(start, goal, body, shapes, [c for c in circles if c not in moving],
                                None, headings, limit).route:
        return plan  # the formations shut a way the lattice has: given way to, not gone round
    fine = lattice_for(start, goal, shapes, circles, body.rho, GRID.fine_spacing, headings)
    loose = fine if fine.nx * fine.ny <= GRID.fallback_cells else \
        lattice_for(start, goal, shapes, circles, body.rho, GRID.spacing, headings)
    narrow = plan_narrow(loose, start, goal, body, shapes, circles, limit, movable)
    return narrow._replace(expanded=plan.expanded + narrow.expanded)


def _plan_lattice(start: Pose3, goal: Pose3, body: Body, shapes: Sequence[Shape],
                  circles: Sequence[Circle], h: float | None, headings: int, limit: int) -> FootprintPlan:
    """:func:`plan_footprint` on the lattice alone (fine, else coarse then fine)."""
    fine = lattice_for(start, goal, shapes, circles, body.rho, h or GRID.fine_spacing, headings)
    if h is not None or fine.nx * fine.ny <= GRID.fine_cells:
        return _plan_on(fine, start, goal, body, shapes, circles, limit)
    coarse = _plan_on(lattice_for(start, goal, shapes, circles, body.rho, GRID.spacing, headings),
                      start, goal, body, shapes, circles, limit)
    if coarse.route or fine.nx * fine.ny > GRID.fallback_cells:
        return coarse
    again = _plan_on(fine, start, goal, body, shapes, circles, limit)
    return again._replace(expanded=coarse.expanded + again.expanded)


def _flags(lat: Lattice, body: Body, shapes: Sequence[Shape], circles: Sequence[Circle],
           ends: Sequence[Pose3]) -> tuple[bytearray, bytearray, float]:
    """The move and turn flags of every state of ``lat`` for the footprint (relaxed around
    ``ends``), and the cost of one heading step [m]."""
    rho, h = body.rho, lat.h
    big_f, big_g = fields(lat, shapes, circles, body.radius)
    cover = min([body.radius] + [sh.ds for sh in shapes])
    sc = scores(lat, body, big_f, big_g, cover)
    dth = 2.0 * math.pi / lat.headings
    move, turn = _allowed(lat, sc, ends, rho, SEARCH.move_need * h, 0.5 * rho * dth + SEARCH.fine_error * h)
    return move, turn, rho * dth


def _steps(lat: Lattice) -> list[tuple[int, float]]:
    """The eight moves to a neighbouring cell: (state offset, length [m])."""
    ny, d2 = lat.ny, math.sqrt(2.0) * lat.h
    return [(-ny, lat.h), (ny, lat.h), (-1, lat.h), (1, lat.h),
            (-ny - 1, d2), (-ny + 1, d2), (ny - 1, d2), (ny + 1, d2)]


def _plan_on(lat: Lattice, start: Pose3, goal: Pose3, body: Body, shapes: Sequence[Shape],
             circles: Sequence[Circle], limit: int) -> FootprintPlan:
    """:func:`plan_footprint` on the lattice ``lat``."""
    move, turn, turn_cost = _flags(lat, body, shapes, circles, (start, goal))
    sr = _Search(lat, move, turn, turn_cost, *coarse_distance(lat, move, goal[:2]))
    n = lat.nx * lat.ny
    s0 = lat.heading(start[2]) * n + _flat(lat, start)
    s1 = lat.heading(goal[2]) * n + _flat(lat, goal)
    if not move[s1] and not turn[s1]:
        return FootprintPlan((), GOAL_SHUT)
    if direct_clear(sr, start, goal):
        return FootprintPlan((goal,))
    states, expanded = _astar(sr, s0, s1, limit)
    if states is None:
        why = NO_WAY if expanded < limit else f"no route found in {limit} poses"
        return FootprintPlan((), why, expanded)
    return FootprintPlan(route_of(sr, states, start, goal), "", expanded)


# ------------------------------------------------------------------- the narrow passages


def plan_narrow(lat: Lattice, start: Pose3, goal: Pose3, body: Body, shapes: Sequence[Shape],
                circles: Sequence[Circle], limit: int = SEARCH.max_expansions,
                movable: Sequence[Circle] = ()) -> FootprintPlan:
    """The route through passages the footprint fits by :attr:`Narrow.clearance` beyond what it
    keeps (``body.margin`` less PLAN_MARGIN: epsilon and the look-ahead offset), which the
    lattice ``lat`` shuts by its own error (:attr:`Narrow.slack` h a side):

    * a loose search on ``lat`` whose margin is that keep plus the clearance, less the slack and
      less rho pi / headings (the most a footprint point moves as a heading rounds to the
      lattice's): every passage the footprint fits so, at any heading, is open on it;
    * each stretch of its path that the strict flags (the footprint's own margin) do not allow is
      searched again in a window round it (:attr:`Narrow.pad` beyond rho) on a lattice of
      :attr:`Narrow.spacing`, keeping the keep plus the clearance less that lattice's slack, so
      the route keeps at least what the formation keeps, and finds any passage it fits by the
      clearance at a lattice heading;
    * the rest of the path is :func:`route_of` on the strict flags; the loose search's steps
      into poses the strict flags forbid cost :attr:`Narrow.tight_cost` times more, so the tight
      stretches are short (and their windows small).

    A window with no way, or one that a circle of ``movable`` meets (a formation in the way is
    given way to, leader.routing, not squeezed past), is shut on the loose lattice (all but its
    start and goal cells: a tight last stretch into a slot, shut with the slot, left no other
    way to it) and the loose search runs again, up to :attr:`Narrow.tries` times.

    Chosen on the narrow-passage scenarios (tests/scenarios/narrow-*.yaml) and the warehouse
    draw's planning time (benchmarks/route_plan.py --draw): the pass runs only where the lattice
    finds no way, so a route the lattice finds, and its time, stay as they were; a whole-scene
    lattice of :attr:`Narrow.spacing` needs memory of the order of the scene's area over that
    cell squared, times the headings (gigabytes in a warehouse hall); sampling in SE(2) proves
    no "no way", which a closed room needs (the loose search shuts it as the lattice does)."""
    keep = max(0.0, body.margin - PLAN_MARGIN) + NARROW.clearance
    sc = _scored(lat, body, shapes, circles)
    strict = _search_of(lat, sc - np.float32(body.margin), body.rho, (start, goal))
    off = body.rho * math.pi / lat.headings  # a point's move as a heading rounds to the lattice's
    loose = _search_of(lat, sc - np.float32(keep - NARROW.slack * lat.h - off), body.rho, (start, goal))
    loose = loose._replace(dear=bytearray((~np.frombuffer(strict.move, dtype=bool)).tobytes()))
    n = lat.nx * lat.ny
    s0 = lat.heading(start[2]) * n + _flat(lat, start)
    s1 = lat.heading(goal[2]) * n + _flat(lat, goal)
    fine_body = replace(body, margin=keep - NARROW.slack * NARROW.spacing)
    if not connected(lat, loose.move, lat.cell(*start[:2]), lat.cell(*goal[:2])):
        return FootprintPlan((), NO_WAY)
    done = 0
    for _ in range(NARROW.tries):
        states, expanded = _astar(loose, s0, s1, limit)
        done += expanded
        if states is None:
            return FootprintPlan((), NO_WAY if expanded < limit else f"no route found in {limit} poses", done)
        way = _Way(lat, states, start, goal)
        route, shut, more = _through(strict, way, fine_body, (shapes, circles, movable), limit)
        done += more
        if route:
            return FootprintPlan(route, "", done)
        for s in states[max(shut[0], 1):min(shut[1] + 1, len(states) - 1)]:
            for k in range(lat.headings):
                loose.move[k * n + s % n] = loose.turn[k * n + s % n] = 0
    return FootprintPlan((), NO_WAY, done)


def connected(lat: Lattice, move: bytearray, a: tuple[int, int], b: tuple[int, int]) -> bool:
    """Whether cell ``b`` is reached from cell ``a`` through cells that may move at some heading
    (8-connected; a flood fill by whole-array steps). A path of the search is one such, so "no"
    is a proof of no way, found without the search (whose heuristic's coarser grid joins cells
    across a thin wall that a loose margin leaves open on both sides)."""
    free = np.asarray(np.frombuffer(move, dtype=bool).reshape(lat.headings, lat.nx, lat.ny).any(axis=0))
    reach = np.zeros_like(free)
    reach[a] = free[a]
    while not reach[b]:
        grown = reach.copy()
        grown[1:, :] |= reach[:-1, :]
        grown[:-1, :] |= reach[1:, :]
        grown[:, 1:] |= grown[:, :-1].copy()
        grown[:, :-1] |= grown[:, 1:].copy()
        grown &= free
        if np.array_equal(grown, reach):
            return False
        reach = grown
    return True


class _Way(NamedTuple):
    """A loose path: its states on ``lat`` and the real start and goal poses."""

    lat: Lattice
    states: list[int]
    start: Pose3
    goal: Pose3

    def pose(self, k: int) -> Pose3:
        """The path's k-th pose (the real start and goal at its ends)."""
        if k == 0:
            return self.start
        if k == len(self.states) - 1:
            return self.goal
        n = self.lat.nx * self.lat.ny
        s = self.states[k]
        i, j = divmod(s % n, self.lat.ny)
        return (*self.lat.point(i, j), self.lat.theta(s // n))


def _scored(lat: Lattice, body: Body, shapes: Sequence[Shape], circles: Sequence[Circle]) -> np.ndarray:
    """:func:`scores` with no margin taken off."""
    big_f, big_g = fields(lat, shapes, circles, body.radius)
    cover = min([body.radius] + [sh.ds for sh in shapes])
    return scores(lat, replace(body, margin=0.0), big_f, big_g, cover)


def _search_of(lat: Lattice, sc: np.ndarray, rho: float, ends: Sequence[Pose3]) -> _Search:
    """The search over scores ``sc`` (the margin taken off), relaxed round ``ends`` (the goal last)."""
    dth = 2.0 * math.pi / lat.headings
    move, turn = _allowed(lat, sc, ends, rho, SEARCH.move_need * lat.h,
                          0.5 * rho * dth + SEARCH.fine_error * lat.h)
    return _Search(lat, move, turn, rho * dth, *coarse_distance(lat, move, ends[-1][:2]))


def _tight(strict: _Search, states: Sequence[int]) -> list[bool]:
    """Per state of a path: whether a step into or out of it is one the strict flags forbid."""
    n = strict.lat.nx * strict.lat.ny
    flags = [False] * len(states)
    for k in range(len(states) - 1):
        a, b = states[k], states[k + 1]
        ok = strict.turn if a % n == b % n else strict.move
        if not (ok[a] and ok[b]):
            flags[k] = flags[k + 1] = True
    return flags


def _stretches(way: _Way, tight: Sequence[bool], grow: float) -> list[tuple[int, int]]:
    """The path's tight stretches as (entry, exit) indices, each a pose before and after it;
    stretches whose boxes (grown by ``grow``) meet are one."""
    last = len(tight) - 1
    out: list[tuple[int, int]] = []
    k = 0
    while k <= last:
        if not tight[k]:
            k += 1
            continue
        j = k
        while j < last and tight[j + 1]:
            j += 1
        a, b = max(0, k - 1), min(last, j + 1)
        if out and (a <= out[-1][1] or _meets(_box(way, *out[-1], grow), _box(way, a, b, grow))):
            a = out.pop()[0]
        out.append((a, b))
        k = j + 1
    return out


def _box(way: _Way, a: int, b: int, grow: float) -> tuple[float, float, float, float]:
    xs = [way.pose(k)[0] for k in range(a, b + 1)]
    ys = [way.pose(k)[1] for k in range(a, b + 1)]
    return (min(xs) - grow, min(ys) - grow, max(xs) + grow, max(ys) + grow)


def aligned_turn(body: Body, shapes: Sequence[Shape], at: Pose3, headings: int) -> float:
    """[rad] the lattice's heading 0 that holds the poses turning the footprint's narrowest side
    (the hull edge its width is across) along the axes of the shape nearest ``at``; 0 for none.
    A passage between shelves runs along their axes: at an unaligned heading a long footprint
    needs up to its length times sin(pi / headings) more room across it."""
    hull = _hull(body.slots + body.load)
    if len(hull) < 2 or not shapes:
        return 0.0
    edges = [(hull[k], hull[(k + 1) % len(hull)]) for k in range(len(hull))]

    def width(e: tuple[Point, Point]) -> float:
        (ax, ay), (bx, by) = e
        d = math.hypot(bx - ax, by - ay) or 1.0
        return max(abs((bx - ax) * (py - ay) - (by - ay) * (px - ax)) / d for px, py in hull)

    (ax, ay), (bx, by) = min(edges, key=width)
    near = min(shapes, key=lambda sh: shape_distance(at[0], at[1], sh)[0])
    step = 2.0 * math.pi / headings
    return (near.yaw - math.atan2(by - ay, bx - ax)) % step


def _meets(p: tuple[float, float, float, float], q: tuple[float, float, float, float]) -> bool:
    return p[0] <= q[2] and q[0] <= p[2] and p[1] <= q[3] and q[1] <= p[3]


def _through(strict: _Search, way: _Way, fine_body: Body,
             things: tuple[Sequence[Shape], Sequence[Circle], Sequence[Circle]], limit: int
             ) -> tuple[tuple[Pose3, ...], tuple[int, int], int]:
    """The route along a loose path: its tight stretches searched again in their windows, the
    rest on the strict flags; () and the stretch that has no way (or that a movable circle
    meets) where one has none; and the poses the windows expanded. ``things``: the shapes, the
    circles and the movable ones among them."""
    shapes, circles, movable = things
    grow = fine_body.rho + NARROW.pad
    route: list[Pose3] = []
    at, expanded = 0, 0
    for a, b in _stretches(way, _tight(strict, way.states), grow):
        if a > at:
            route += route_of(strict, way.states[at:a + 1], way.pose(at), way.pose(a))
        x0, y0, x1, y1 = _box(way, a, b, grow)
        if any(_meets((x0, y0, x1, y1), (x - r, y - r, x + r, y + r)) for x, y, r in movable):
            return (), (a, b), expanded
        h = NARROW.spacing
        mid = way.pose((a + b) // 2)
        win = Lattice(x0, y0, h, int(math.ceil((x1 - x0) / h)) + 1, int(math.ceil((y1 - y0) / h)) + 1,
                      strict.lat.headings, aligned_turn(fine_body, shapes, mid, strict.lat.headings))
        if win.nx * win.ny > NARROW.max_cells:
            return (), (a, b), expanded
        part = _plan_on(win, way.pose(a), way.pose(b), fine_body, shapes, circles, limit)
        expanded += part.expanded
        if not part.route:
            return (), (a, b), expanded
        route += part.route
        at = b
    if at < len(way.states) - 1:
        route += route_of(strict, way.states[at:], way.pose(at), way.goal)
    return tuple(route), (0, 0), expanded


def plan_aside(start: Pose3, body: Body, shapes: Sequence[Shape], circles: Sequence[Circle],
               way: Sequence[Point], clear: float, limit: int = SEARCH.max_expansions) -> FootprintPlan:
    """A formation giving way: the route to the nearest pose (by the lattice's path length)
    the footprint can reach from ``start`` around ``shapes`` and ``circles`` with its centroid
    at least ``clear`` from the polyline ``way`` (another formation's way), the pose last; no
    such pose: no route, and the reason. The lattice is :func:`plan_footprint`'s first (fine
    in a small scene, else GRID.spacing), over the things, the start and the way."""
    pts = [(x, y, 0.0) for x, y in way]
    extent = list(circles) + pts
    headings = body.headings(GRID.headings)
    lat = lattice_for(start, start, shapes, extent, body.rho, GRID.fine_spacing, headings)
    if lat.nx * lat.ny > GRID.fine_cells:
        lat = lattice_for(start, start, shapes, extent, body.rho, GRID.spacing, headings)
    move, turn, turn_cost = _flags(lat, body, shapes, circles, (start,))
    sr = _Search(lat, move, turn, turn_cost, [], 1)  # no heuristic: the nearest place wins
    away = _away(lat, way, clear)
    n, ny, kk = lat.nx * lat.ny, lat.ny, lat.headings
    steps = _steps(lat)
    s0 = lat.heading(start[2]) * n + _flat(lat, start)
    best = {s0: 0.0}
    parent: dict[int, int] = {}
    heap = [(0.0, s0)]
    expanded = 0
    while heap and expanded < limit:
        g, s = heapq.heappop(heap)
        if g > best.get(s, math.inf):
            continue
        if away[s % n] and move[s] and turn[s]:
            i, j = divmod(s % n, ny)
            x, y = lat.point(i, j)
            goal = (x, y, lat.theta(s // n))
            if s == s0:
                return FootprintPlan((start,), "", expanded)
            return FootprintPlan(route_of(sr, _unwind(parent, s0, s), start, goal), "", expanded)
        expanded += 1
        for t, cost in _next(sr, s, n, kk, steps):
            if g + cost < best.get(t, math.inf):
                best[t] = g + cost
                parent[t] = s
                heapq.heappush(heap, (g + cost, t))
    why = ("no place off the other's way for the footprint" if expanded < limit
           else f"no place found in {limit} poses")
    return FootprintPlan((), why, expanded)


def _away(lat: Lattice, way: Sequence[Point], clear: float) -> list[bool]:
    """Per lattice cell (row-major): whether its point lies at least ``clear`` from ``way``."""
    xs = (lat.x0 + lat.h * np.arange(lat.nx))[:, None]
    ys = (lat.y0 + lat.h * np.arange(lat.ny))[None, :]
    d = np.full((lat.nx, lat.ny), np.inf)
    pts = list(way) if len(way) > 1 else list(way) * 2
    for (ax, ay), (bx, by) in zip(pts[:-1], pts[1:], strict=True):
        ex, ey = bx - ax, by - ay
        ee = max(ex * ex + ey * ey, 1e-12)
        t = np.clip(((xs - ax) * ex + (ys - ay) * ey) / ee, 0.0, 1.0)
        d = np.minimum(d, np.hypot(xs - ax - t * ex, ys - ay - t * ey))
    return (d >= clear).ravel().tolist()


def direct_clear(sr: _Search, start: Pose3, goal: Pose3) -> bool:
    """Whether the footprint may go straight to the goal turning as it goes (the rigid motion
    does: the short way round, left within WAYPOINTS.direct_left of half a turn): every pose on the way,
    at most h / 2 and half a heading step apart, at a lattice state that may move and turn."""
    lat = sr.lat
    left = WAYPOINTS.direct_left
    turn = wrap_left(goal[2] - start[2], left)
    dth = 2.0 * math.pi / lat.headings
    steps = max(1, int(math.ceil(max(2.0 * math.dist(start[:2], goal[:2]) / lat.h,
                                     2.0 * abs(turn) / dth))))
    n = lat.nx * lat.ny
    for k in range(steps + 1):
        f = k / steps
        x, y = start[0] + f * (goal[0] - start[0]), start[1] + f * (goal[1] - start[1])
        s = lat.heading(start[2] + f * turn) * n + _flat(lat, (x, y))
        if not (sr.move[s] and sr.turn[s]):
            return False
    return True


def _flat(lat: Lattice, p: Sequence[float]) -> int:
    i, j = lat.cell(p[0], p[1])
    return i * lat.ny + j
