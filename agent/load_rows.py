"""Each member's own rows for its formation's load: the last safety filter
keeps the load, not only the member's body, off walls, shelves and circles.

The formation's twist QP (:mod:`agent.body`) plans the load clear of things with its footprint
rows. Where those cannot all hold (another formation's ellipse rows, with A.3's velocity term,
push the formation towards a shelf), the twist QP relaxes them by one common slack, and each
member's QP, which held only its own body's rows, let the members carry the load into the shelf
(the warehouse draw of ``formation montecarlo --draw warehouse``). So
each member's QP also holds these rows, as contact rows: never relaxed to reach a goal, kept
exact in a fallback (:func:`agent.qp.solve_cbf_qp`), where the other formation's margin rows give
way instead.

The load is where the safety monitor measures it (:func:`scenario.cargo.loads_now`): its start
outline placed by the least-squares rigid fit (:func:`geometry.rigid.rigid_fit`) of the members'
start body positions a_k (about their centroid) onto their current ones b_k, centroid c. The fit's
angle is theta = atan2(C, D), C = sum a_k x (b_k - c), D = sum a_k . (b_k - c); since sum a_k = 0,

    omega = theta' = sum_k w_k . b_k',   w_k = (D J a_k - C a_k) / (C^2 + D^2),

and a point P of the placed load moves at  P' = c' + omega J (P - c),  so with c' = mean b_k',

    P' = sum_k [ b_k' / n + J (P - c) (w_k . b_k') ]                                   (L.1)

linear in every member's body velocity. A barrier h on the load (eq. 4.5 on a distance) with
dh/dP = m then has h' = sum_k g_k . b_k' + dh/dq . q', g_k = m / n + (m . J (P - c)) w_k. For a
unicycle the body moves at e (e . u) under eq. 6.2 (u its look-ahead point's velocity, e its
heading), so its gradient in u is (g_k . e_k) e_k.

The condition  sum_k g_k . u_k >= -gamma h - dh/dq . q'  involves every member. Each takes an
equal share in speed, the reciprocal split of :func:`agent.barriers.separation_row` for n
robots: with v_k the members' last certified velocities (their ``state``), the slack at them is
c = gamma h + dh/dq . q' + sum_k g_k . v_k, and member i holds

    g_i/|g_i| . (u_i - v_i) >= -c / S,   S = sum_k |g_k|                                 (L.2)

Summed (times |g_k|) over the members, the rows give the condition for ANY commands the members
return at the same time; each counts only on the others meeting their own rows. With c >= 0
(safe at the current velocities) every member may keep its velocity; the split in speed (not
|g|^2 as for a pair) gives a member with little effect on the distance no tight row.

The rate. A carried load is one body with its members, and (L.2) is a row the members share,
as their band and separation rows are: near its edge (c near 0) it asks each member to keep its
last speed along g_i. A unicycle member moves its body only along its heading (its g_i is
(g_i . e_i) e_i) and turns before it drives, so members turning at a door's jamb cannot all
keep their last forward speeds: at an obstacle gamma of 0.05 the row asked a member to keep
driving against its formation's band, and the QP gave up the band or, with the separation rows,
took the least-risk command (two unicycle rectangles, the members' hull their load, through a
doorway: tests/scenarios/door-gamma005-pair-unicycle.yaml). So a unicycle member's load rows
keep at least the thesis's unicycle gamma, as its band and separation rows do
(:func:`agent.unicycle.member_gamma`; thesis Table 6.3 drives its unicycles past obstacles at
gamma 1). Any positive rate keeps the load's safe set invariant (with gamma dt <= 1 for the
sampled rows), so the floor sets how fast the load may close on a thing, not how near it comes;
the formation's twist still plans the load's approach at the scenario's gamma
(:mod:`agent.body`).

The features are those of :func:`agent.body._load_rows`: each shape corner and circle centre
against each load edge (the distance between two convex outlines is reached at a vertex of one of
them), and each vertex of a declared load against each shape (the default hull's vertices sit
where the members' bodies are, up to the fit's error, and their own rows keep them Ds away); a
circle's physical radius is its Ds less the robot radius, and the load keeps :data:`LOAD_CLEAR`
(plus the robot's margins) from each.

Pure functions over floats.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import NamedTuple

from geometry.rigid import fit_sums
from geometry.shapes import Shape, distance_floor, segment_distance, shape_distance

from .barriers import Obstacle, Partner
from .body import Footprint, outline_edges
from .qp import Row, normalized_row
from .unicycle import member_gamma

Point = tuple[float, float]

LOAD_CLEAR = 0.01  # [m] the load keeps this from a shape or circle in the members' own rows
_TINY = 1e-9


class PlacedLoad(NamedTuple):
    """The load now: its outline placed by the rigid fit, the members' centroid and (L.1)'s w_k."""

    outline: tuple[Point, ...]
    cx: float
    cy: float
    w: tuple[Point, ...]  # d omega / d b_k' per member
    radius: float  # [m] the outline's largest distance from (cx, cy)
    spread: float  # 1 + radius sum_k |w_k|: a bound of S = sum_k |g_k| for a unit m (L.2)


def place_load(start: Sequence[Point], outline: Sequence[Point],
               bodies: Sequence[Point]) -> PlacedLoad | None:
    """The load whose outline (``outline``, about the start bodies' centroid) the fit of the
    start body offsets ``start`` (about their centroid, member order) onto ``bodies`` places;
    None when the fit has no angle (every start offset zero, or the bodies all at one point)."""
    cx, cy, cross, dot = fit_sums(start, bodies)
    q = cross * cross + dot * dot
    if q < _TINY:
        return None
    th = math.atan2(cross, dot)
    c, s = math.cos(th), math.sin(th)
    pts: list[Point] = []
    radius = -math.inf
    for x, y in outline:
        px, py = cx + c * x - s * y, cy + s * x + c * y
        pts.append((px, py))
        radius = max(radius, math.hypot(px - cx, py - cy))
    w, wsum = _weights(start, cross, dot, q)
    return PlacedLoad(tuple(pts), cx, cy, w, radius, 1.0 + radius * wsum)


def _weights(start: Sequence[Point], cross: float, dot: float, q: float
             ) -> tuple[tuple[Point, ...], float]:
    """(L.1)'s w_k of the fit with sums ``cross``, ``dot`` (``q = cross^2 + dot^2``), and
    sum_k |w_k|."""
    w: list[Point] = []
    wsum = 0.0  # summed in order, as sum() does
    for ax, ay in start:
        wx, wy = (-dot * ay - cross * ax) / q, (dot * ax - cross * ay) / q
        w.append((wx, wy))
        wsum += math.hypot(wx, wy)
    return tuple(w), wsum


class LoadFit(NamedTuple):
    """What :func:`place_load` finds before it places the outline: the members' centroid and
    (L.1)'s w_k, to the bit, with upper bounds of the placed outline's radius and spread."""

    cx: float
    cy: float
    w: tuple[Point, ...]
    radius: float  # [m] at least :attr:`PlacedLoad.radius`
    spread: float  # at least :attr:`PlacedLoad.spread`


# A placed point's distance from the centroid is its outline point's (a rotation keeps lengths)
# up to the rounding of the placement: a few units in the last place of the coordinates, far
# below this share of them.
_ROUNDING = 1e-12


def fit_load(start: Sequence[Point], reach: float, bodies: Sequence[Point]) -> LoadFit | None:
    """:class:`LoadFit` of the load :func:`place_load` places from ``start`` onto ``bodies``,
    whose outline points lie at most ``reach`` [m] from the start centroid; None where
    :func:`place_load` gives None."""
    cx, cy, cross, dot = fit_sums(start, bodies)
    q = cross * cross + dot * dot
    if q < _TINY:
        return None
    w, wsum = _weights(start, cross, dot, q)
    big = reach * (1.0 + _ROUNDING) + _ROUNDING * (abs(cx) + abs(cy) + 1.0)
    return LoadFit(cx, cy, w, big, 1.0 + big * wsum)


def outline_reach(outline: Sequence[Point]) -> float:
    """The largest distance [m] of an outline point from the origin (its centroid frame)."""
    reach = 0.0
    for x, y in outline:
        reach = max(reach, math.hypot(x, y))
    return reach


def gradients(load: PlacedLoad, p: Point, m: Point,
              headings: Sequence[float] | None) -> list[Point]:
    """g_k of (L.1) for a barrier with dh/dP = ``m`` at the load point ``p``, per member, in
    its command (a unicycle's look-ahead point velocity where ``headings`` are given)."""
    n = len(load.w)
    k = m[0] * -(p[1] - load.cy) + m[1] * (p[0] - load.cx)  # m . J (P - c)
    return onto_headings([(m[0] / n + k * wx, m[1] / n + k * wy) for wx, wy in load.w], headings)


def spread_of(g: Sequence[Point]) -> float:
    """S = sum_k |g_k| of (L.2)."""
    return sum(math.hypot(a[0], a[1]) for a in g)


def share_row(g: Sequence[Point], v: Point, member: int, h: float, hdot: float,
              gamma: float, s: float | None = None) -> Row | None:
    """Member ``member``'s row (L.2) of the condition sum_k g_k . u_k >= -gamma h - dh/dq . q'
    (``hdot``: h' at the members' last commands v_k, sum_k g_k . v_k + dh/dq . q'; ``v`` this
    member's), normalised; None when its gradient is zero (it cannot change h). ``s``:
    :func:`spread_of` ``g``, where the caller has it already."""
    gx, gy = g[member]
    gi = math.hypot(gx, gy)
    if gi < _TINY:
        return None
    c = gamma * h + hdot
    if s is None:
        s = spread_of(g)
    # g_i . (u - v_i) >= -|g_i| c / S   <=>   -g_i . u <= |g_i| c / S - g_i . v_i
    return normalized_row(-gx, -gy, gi * c / s - (gx * v[0] + gy * v[1]))


class MemberLoad:
    """A member's formation's load as its QP sees it. Its outline is placed when first asked
    for (:attr:`placed`): :func:`load_rows` needs only :attr:`fit` to find that no barrier on
    it can be active, the common case away from shelves."""

    __slots__ = ("_placed", "_place", "_fit", "member", "velocities", "headings", "declared")

    def __init__(self, placed: PlacedLoad | Callable[[], PlacedLoad], member: int,
                 velocities: list[Point], headings: list[float] | None, declared: bool = True,
                 fit: LoadFit | None = None) -> None:
        """``placed``: the placed load, or what places it (then ``fit`` is its :class:`LoadFit`).
        ``member``: this member's index; ``velocities``: every member's last certified command;
        ``headings``: unicycles' every member's heading; ``declared``: a declared load's
        vertices get rows (the default hull's are the members)."""
        if isinstance(placed, PlacedLoad):
            self._placed: PlacedLoad | None = placed
            self._place: Callable[[], PlacedLoad] | None = None
        else:
            self._placed, self._place = None, placed
            if fit is None:
                raise ValueError("fit: a load placed later needs its fit")
        self._fit = fit
        self.member = member
        self.velocities = velocities
        self.headings = headings
        self.declared = declared

    @property
    def placed(self) -> PlacedLoad:
        """The load placed by the rigid fit (placed once, on the first call)."""
        if self._placed is None:
            assert self._place is not None
            self._placed = self._place()
        return self._placed

    @property
    def fit(self) -> LoadFit:
        """The fit's centroid and w_k, with bounds of the placed radius and spread."""
        if self._fit is None:
            p = self.placed
            self._fit = LoadFit(p.cx, p.cy, p.w, p.radius, p.spread)
        return self._fit


class LastPlaced:
    """The last load :func:`place_load` placed, by its inputs (a pure cache of one entry:
    (inputs, load) replaced whole)."""

    __slots__ = ("last",)

    def __init__(self) -> None:
        self.last: tuple[tuple, PlacedLoad | None] | None = None


PLACED = LastPlaced()  # :func:`member_load`'s


def member_load(fp: Footprint, pose: tuple[float, float, float], last_u: Point,
                partners: Sequence[Partner], offset: float, unicycle: bool) -> MemberLoad | None:
    """The load placed at the members' bodies now: this robot's ``pose`` and its formation's
    other members, the first of ``partners`` in member order (their control points, ``offset``
    ahead of their bodies, and headings from their ``state``); None without an outline or with
    members missing."""
    n = len(fp.fit0)
    if len(fp.outline0) < 2 or len(partners) < n - 1:
        return None
    mates = partners[:n - 1]
    me = fp.member
    # the members' bodies: this robot's pose, the mates' control points ``offset`` behind (a
    # single integrator's: the point itself)
    if offset:
        bodies = [(q.x - offset * math.cos(q.theta), q.y - offset * math.sin(q.theta))
                  for q in mates]
    else:
        bodies = [(q.x, q.y) for q in mates]
    bodies.insert(me, (pose[0], pose[1]))
    vel = [(q.vx, q.vy) for q in mates]
    vel.insert(me, last_u)
    fit = fit_load(fp.fit0, outline_reach(fp.outline0), bodies)
    if fit is None:  # and place_load's would be None
        return None
    heads = None
    if unicycle:
        heads = [q.theta for q in mates]
        heads.insert(me, pose[2])
    return MemberLoad(lambda: _placed(fp, bodies), me, vel, heads, bool(fp.load_points), fit)


def _placed(fp: Footprint, bodies: list[Point]) -> PlacedLoad:
    """:func:`place_load` of ``fp``'s load at ``bodies`` (through :data:`PLACED`: every member
    places the same load, single integrators to the bit), where :func:`fit_load` found one."""
    key = (fp.fit0, fp.outline0, tuple(bodies))
    last = PLACED.last
    if last is not None and last[0] == key:
        placed = last[1]
    else:
        placed = place_load(fp.fit0, fp.outline0, bodies)
        PLACED.last = (key, placed)
    assert placed is not None  # the same test as fit_load's
    return placed


class Feature(NamedTuple):
    """One barrier on the load: h, its gradient g_k in each member's command (L.1) and h' at
    the members' last commands (with the thing's part, dh/dq . q')."""

    h: float
    g: list[Point]
    hdot: float
    thing_speed: float


def onto_headings(vectors: Sequence[Point], headings: Sequence[float] | None) -> list[Point]:
    """Each vector's part along its member's heading, e (e . x) (unchanged without headings): a
    unicycle's body moves at e (e . u) under eq. 6.2, so this maps its command to its body's
    velocity, and a body-velocity gradient g to the one in its command, (g . e) e."""
    if headings is None:
        return list(vectors)
    out = []
    for (x, y), th in zip(vectors, headings, strict=True):
        ex, ey = math.cos(th), math.sin(th)
        s = ex * x + ey * y
        out.append((s * ex, s * ey))
    return out


class Candidate(NamedTuple):
    """A barrier of :func:`features` before the tests that depend on who asks: the thing it
    is against passed each of ``tests`` (h, h', S, v: an ``inactive`` call's arguments)
    before it was measured; then it counts towards the smallest h, and it is a feature unless
    inactive for its own h, h', S and v."""

    tests: tuple[tuple[float, float, float, float], ...]
    h: float
    hdot: float
    s: float  # the bound of S for this barrier
    speed: float  # [m/s] the thing's
    p: Point  # the load point and dh/dP (its gradients are worked out when first kept)
    m: Point


Inactive = Callable[[float, float, float, float], bool]


def candidates(load: MemberLoad, obstacles: Sequence[Obstacle], shapes: Sequence[Shape],
               radius: float, clear: float, inactive: Inactive) -> list[Candidate]:
    """Every barrier of the module docstring on the member's placed load against ``obstacles``
    (Ds for the body; physical radius Ds - ``radius``) and ``shapes``, each kept ``clear`` [m]
    off, whose thing passes the cheap tests of :func:`features` for ``inactive`` (a test at
    least as strict as the one they will be selected by: any ``inactive`` that says inactive
    only where this one does selects the same features from them as from all)."""
    placed, headings = load.placed, load.headings
    out: list[Candidate] = []
    pts = placed.outline
    cx, cy, big, spread = placed.cx, placed.cy, placed.radius, placed.spread
    wsum = (spread - 1.0) / big if big > 0.0 else 0.0
    vel = onto_headings(load.velocities, headings) if headings is not None \
        else load.velocities  # the bodies' velocities
    n = len(vel)
    svx = svy = om = 0.0  # summed in order, as sum() does
    for (vx, vy), (wx, wy) in zip(vel, placed.w, strict=True):
        svx += vx
        svy += vy
        om += wx * vx + wy * vy
    mvx, mvy = svx / n, svy / n
    fastest = math.hypot(mvx, mvy) + abs(om) * big

    def add(tests: tuple, p: Point, m: Point, h: float, q_term: float, speed: float) -> None:
        rx, ry = p[0] - cx, p[1] - cy
        hdot = q_term + m[0] * (mvx - om * ry) + m[1] * (mvy + om * rx)  # + m . P' (L.1)
        out.append(Candidate(tests, h, hdot, 1.0 + abs(m[1] * rx - m[0] * ry) * wsum, speed,
                             p, m))

    things, near_shapes = near_things(placed, fastest, obstacles, shapes, radius, clear, inactive)
    edges = outline_edges(pts) if things else ()
    for q, qv, r, speed, tests in things:  # a corner or circle against each edge
        for (ax, ay), (bx, by) in edges:
            d, nx, ny = segment_distance(q[0], q[1], ax, ay, bx, by)  # n: from the edge to q
            add(tests, (q[0] - d * nx, q[1] - d * ny), (-nx, -ny), d - r,
                nx * qv[0] + ny * qv[1], speed)
    for sh, tests in near_shapes if load.declared else ():  # each declared vertex, each shape
        for v in pts:
            d, gx, gy = shape_distance(v[0], v[1], sh)
            add(tests, v, (gx, gy), d - clear, 0.0, 0.0)
    return out


Thing = tuple[Point, Point, float, float, tuple]  # centre, velocity, radius, speed, its tests


def near_things(placed: PlacedLoad, fastest: float, obstacles: Sequence[Obstacle],
                shapes: Sequence[Shape], radius: float, clear: float, inactive: Inactive,
                ) -> tuple[list[Thing], list[tuple[Shape, tuple]]]:
    """The circles and shape corners that pass :func:`features`' cheap tests over the load's
    bounding circle (its points move at most ``fastest``), each with the tests it passed, and
    the shapes that pass them, with theirs."""
    cx, cy, big, spread = placed.cx, placed.cy, placed.radius, placed.spread
    things: list[Thing] = []
    for o in obstacles:
        speed = math.hypot(o.vx, o.vy)
        r = max(0.0, o.ds - radius) + clear
        test = (math.hypot(o.x - cx, o.y - cy) - big - r, -speed - fastest, spread, speed)
        if not inactive(*test):
            things.append(((o.x, o.y), (o.vx, o.vy), r, speed, (test,)))
    near_shapes = []
    for sh in shapes:  # first by the shape's own bounding circle (cheap)
        floor = (distance_floor(cx, cy, sh) - big - clear, -fastest, spread, 0.0)
        if inactive(*floor):
            continue
        exact = (shape_distance(cx, cy, sh)[0] - big - clear, -fastest, spread, 0.0)
        if not inactive(*exact):
            near_shapes.append((sh, (floor, exact)))
    for sh, tests in near_shapes:
        for q in sh.corners():
            corner = (math.hypot(q[0] - cx, q[1] - cy) - big - clear, -fastest, spread, 0.0)
            if not inactive(*corner):
                things.append((q, (0.0, 0.0), clear, 0.0, (*tests, corner)))
    return things, near_shapes


def select(load: MemberLoad, found: Sequence[Candidate], inactive: Inactive,
           gradients_of: Callable[[Candidate], list[Point]] | None = None,
           ) -> tuple[float, list[Feature]]:
    """The features of ``found`` (:func:`candidates`) for ``inactive``, and the smallest h of
    those measured: a candidate whose thing fails a test for ``inactive`` is not measured.
    ``gradients_of``: where the candidates' gradients are kept (default: worked out here)."""
    hmin = math.inf
    out: list[Feature] = []
    tried: tuple | None = None  # the tests last tried (one thing's candidates share them)
    ok = False
    for c in found:
        if c.tests is not tried:
            tried, ok = c.tests, not any(inactive(*t) for t in c.tests)
        if not ok:
            continue
        hmin = min(hmin, c.h)
        if inactive(c.h, c.hdot, c.s, c.speed):
            continue
        g = (gradients(load.placed, c.p, c.m, load.headings) if gradients_of is None
             else gradients_of(c))
        out.append(Feature(c.h, g, c.hdot, c.speed))
    return hmin, out


def select_linear(load: MemberLoad, found: Sequence[Candidate], gamma: float, floor: float,
                  gradients_of: Callable[[Candidate], list[Point]]) -> tuple[float, list[Feature]]:
    """:func:`select` for the test ``gamma h + h' >= S floor`` (:func:`load_rows`'), written
    out: the same features and smallest h, with no call per test."""
    hmin = math.inf
    out: list[Feature] = []
    tried: tuple | None = None
    ok = False
    for c in found:
        if c.tests is not tried:
            tried = c.tests
            ok = not any(gamma * h + hdot >= s * floor for h, hdot, s, _v in tried)
        if not ok:
            continue
        hmin = min(hmin, c.h)
        if gamma * c.h + c.hdot >= c.s * floor:
            continue
        out.append(Feature(c.h, gradients_of(c), c.hdot, c.speed))
    return hmin, out


def features(load: MemberLoad, obstacles: Sequence[Obstacle], shapes: Sequence[Shape],
             radius: float, clear: float, inactive: Inactive) -> tuple[float, list[Feature]]:
    """Every barrier of the module docstring on the member's placed load against ``obstacles``
    (Ds for the body; physical radius Ds - ``radius``) and ``shapes``, each kept ``clear`` [m]
    off, that can be active, and the smallest h of those measured. ``inactive(h, h', S, v)``
    says a barrier of value at least h, rate at least h' and S = sum_k |g_k| at most S, against
    a thing moving at v, has no active row. It culls things first by lower bounds over the
    load's bounding circle (h' >= -(the thing's speed + the fastest load point's),
    S <= ``spread``), then each barrier by its h and its h' at the members' last commands (L.1
    with those: m . P'), S <= 1 + |m . J (P - c)| sum_k |w_k|, before its gradients are
    worked out (:func:`candidates`, then :func:`select`)."""
    return select(load, candidates(load, obstacles, shapes, radius, clear, inactive), inactive)


def idle(load: MemberLoad, obstacles: Sequence[Obstacle], shapes: Sequence[Shape],
         radius: float, clear: float, loose: tuple[float, float]) -> bool:
    """Whether :func:`candidates` for the test ``gamma h + h' >= S floor`` (``loose`` = (gamma,
    floor)) finds none, told from :attr:`MemberLoad.fit` alone: :func:`near_things`' tests of
    each circle and each shape's bounding circle, with the fit's bounds of the radius and spread
    in place of the placed ones. With gamma and floor not negative each bound only lowers the
    left side or raises the right (in floats too: every step is monotone), so a thing ruled out
    here is ruled out there."""
    gamma, floor = loose
    if not (gamma >= 0.0 and floor >= 0.0):
        return False
    f = load.fit
    cx, cy, big, spread = f.cx, f.cy, f.radius, f.spread
    headings = load.headings
    vel = onto_headings(load.velocities, headings) if headings is not None \
        else load.velocities
    n = len(vel)
    svx = svy = om = 0.0  # as candidates() sums them
    for (vx, vy), (wx, wy) in zip(vel, f.w, strict=True):
        svx += vx
        svy += vy
        om += wx * vx + wy * vy
    fastest = math.hypot(svx / n, svy / n) + abs(om) * big
    right = spread * floor
    for o in obstacles:
        speed = math.hypot(o.vx, o.vy)
        r = max(0.0, o.ds - radius) + clear
        if not gamma * (math.hypot(o.x - cx, o.y - cy) - big - r) + (-speed - fastest) >= right:
            return False
    for sh in shapes:
        if not gamma * (distance_floor(cx, cy, sh) - big - clear) + -fastest >= right:
            return False
    return True


class LoadMemo:
    """The last :func:`candidates` worked out, with their gradients, by their inputs. Every
    member of a formation places the same load from the same ``state``s (single integrators:
    to the bit) and differs only in its own speed, which :func:`load_rows`'s test reads; so
    the candidates are found once with the loosest test any member can ask for (the fastest
    member's) and each member selects its own from them (:func:`select`: the same features
    and the same smallest h as finding them itself). A pure cache: a controller that serves
    every member in turn (the in-process simulator) finds them once a tick."""

    __slots__ = ("last",)

    def __init__(self) -> None:
        # (inputs, (candidates, their gradients)) as one pair, replaced whole
        self.last: tuple[tuple, tuple[list[Candidate], dict[int, tuple[list[Point], float]]]] | None = None

    def found(self, load: MemberLoad, obstacles: Sequence[Obstacle], shapes: Sequence[Shape],
              radius: float, clear: float, loose: tuple[float, float],
              ) -> tuple[list[Candidate], dict[int, tuple[list[Point], float]]]:
        """The candidates for the test ``gamma h + h' >= S floor`` with ``loose`` = (gamma,
        the largest floor of any member), and the gradients kept so far with their S (by
        candidate id)."""
        key = (load.placed, tuple(load.velocities), load.headings and tuple(load.headings),
               load.declared, tuple(obstacles), tuple(shapes), radius, clear, loose)
        last = self.last
        if last is not None and last[0] == key:
            return last[1]
        gamma, floor = loose
        kept: dict[int, tuple[list[Point], float]] = {}
        value = (candidates(load, obstacles, shapes, radius, clear,
                            lambda h, hdot, s, _v: gamma * h + hdot >= s * floor), kept)
        self.last = (key, value)
        return value


SHARED = LoadMemo()  # the memo :func:`load_rows` finds its barriers through by default


def load_rows(load: MemberLoad, obstacles: Sequence[Obstacle], shapes: Sequence[Shape],
              radius: float, clear: float, gamma: float, reach: float,
              memo: LoadMemo | None = None) -> tuple[float, list[Row]]:
    """The member's rows (L.2) of :func:`features`; rows with b >= ``reach`` (the largest
    command the limit rows allow: never active) are left out. Returns (the smallest h, the rows).

    A barrier is inactive when, with its slack c = gamma h + h' >= 0 and S at most its bound,
    b = c / S - g_i . v_i / |g_i| >= c / S - |v_i| >= reach. The barriers are found through
    ``memo`` (default: :data:`SHARED`), a pure cache, once :func:`idle` cannot rule them all
    out (without placing the outline). A unicycle member's rows (``load.headings`` given) keep
    at least the thesis's unicycle gamma (the module docstring's "The rate")."""
    rows: list[Row] = []
    if load.headings is not None:
        gamma = member_gamma(gamma)
    v = load.velocities[load.member]
    floor = reach + math.hypot(v[0], v[1])
    fastest = -math.inf
    for ux, uy in load.velocities:
        fastest = max(fastest, math.hypot(ux, uy))
    loose = reach + fastest
    if idle(load, obstacles, shapes, radius, clear, (gamma, loose)):
        return math.inf, rows
    found, kept = (memo or SHARED).found(load, obstacles, shapes, radius, clear, (gamma, loose))

    def gradients_of(c: Candidate) -> list[Point]:
        got = kept.get(id(c))
        if got is None:
            g = gradients(load.placed, c.p, c.m, load.headings)
            got = kept[id(c)] = (g, spread_of(g))
            spreads[id(g)] = got[1]
        return got[0]

    spreads: dict[int, float] = {id(g): total for g, total in kept.values()}
    hmin, feats = select_linear(load, found, gamma, floor, gradients_of)
    for f in feats:
        row = share_row(f.g, v, load.member, f.h, f.hdot, gamma, spreads[id(f.g)])
        if row is not None and row[2] < reach:
            rows.append(row)
    return hmin, rows
