"""The formation as one rigid body: a safety QP over its twist (``controller.method: rigid``).

The formation's pose is (c, theta): c its centroid and theta the rotation of its start shape, both
read from the ellipse its leader publishes (eq. 4.7 for c; ``alpha - alpha0`` for theta, the
least-squares rotation of :func:`geometry.ellipse.estimate`). Its motion is the twist
(vx, vy, omega) about c; a point P of the body then moves at

    P' = v + omega J (P - c),   J = [[0, -1], [1, 0]],

which is linear in the twist. Every barrier row of one robot's QP (eq. 4.12, rows a . u <= b on a
point's velocity u) therefore becomes a row on the twist by the substitution u = P' (a "footprint
row", :func:`point_row`), and the formation's QP is

    min |v - v_goal|^2 + rho^2 (omega - omega_goal)^2   s.t.  footprint rows, limits     (4.12')

with rho the largest slot radius (so both parts are speeds [m/s]). The footprint is every member's
slot (its start control point placed at the pose) and the load:

* circles (static and moving), appendix A.1 (4) on a slot:  -2 (P - o) . P' <= gamma h - 2 (P - o) . o',
  h = |P - o|^2 - Ds^2 (eq. 4.5; Ds grown by the look-ahead offset and the sampling margin as the
  member's own rows grow it, :attr:`agent.control.ControlParams.sampling_margin`);
* walls and shelves (:mod:`geometry.shapes`, eq. 4.5 on the distance to the shape):
  -grad d . P' <= gamma (d - Ds);
* other formations' ellipses, appendix A.3 (19) on a slot:
  -dh/dp . P' <= alpha(h) + dh/dc . c_e' + dh/dalpha . alpha_e' (alpha = the extended class-K of
  :func:`agent.barriers.ellipse_class_k`); for a formation that sends its member points, half of
  alpha and without the other ellipse's motion (below, "Two formations");
* the load's outline: each vertex as a point of the body against shapes and circles (physical
  size: the shape itself, a circle's Ds less the robot radius), and each edge against every shape
  corner and circle centre q: with P* the edge's point nearest q and n = (q - P*)/|q - P*|,
  d' = n . (q' - P*'), so  n . P*' <= gamma (d - D) + n . q'. The distance between two convex
  outlines is reached at a vertex of one of them, so vertices and corners cover every contact;
* every member's speed limit on its slot velocity, |v| + rho |omega| <= vmax (a 12-gon in v for each
  sign of omega, inscribed like :func:`agent.barriers.speed_rows`), and |omega| <= the turn limit;
* unicycle members, what they can follow (:func:`spread_rows`): a unicycle's body sits l e(theta)
  behind its look-ahead point (thesis section 6.2, s = p + l e(theta)), so members whose
  headings differ by delta hold their bodies up to 2 l sin(delta / 2) <= l delta off the rigid
  shape their points keep. Aligned with their slots' velocities v + omega J r_i, the members'
  headings spread by at most 2 asin(rho |omega| / |v|); the rotation the rows add beyond the
  goal's turn therefore keeps rho |omega - omega_goal| <= sin(delta_max / 2) (d . v), d the goal
  twist's direction of travel and delta_max = epsilon / l, so the bodies stay within epsilon of
  their shape while the formation turns aside; without the goal's travel it does not turn aside
  at all, it slows instead. These rows give way to the barrier rows (:func:`solve_twist`).

Two formations. Appendix A.3 keeps each formation's members out of the other's ellipse and
credits the other ellipse's motion: a formation whose ellipse moves away leaves room, one that
comes closer takes it. Nothing keeps a formation's own ellipse off the other's members, and an
ellipse reaches beyond its robots (it holds a clearance disk round each member), so a formation
could drive on while its ellipse swept over a smaller one, whose members then had to flee at
the pace it came: a chase (a pentagon boxed in by a shelf and a third formation in the warehouse
draw of ``formation montecarlo`` broke its band and never reached its goal). So
a leader sends its members' control points with its ellipse (wire ``ellipse`` and ``others``
version 2), and every formation keeps, besides its slots out of the other's ellipse, its own
ellipse off the other's points (:func:`mirror_rows`): for q such a point and h = h_own(q),
dh/dt = -dh/dq . v + dh/dalpha omega >= -alpha(h) / 2, q held still. Each side takes half of
alpha and credits nothing of the other's motion, as the separation rows split one barrier
between two robots; the two halves add to appendix A.3's condition on the pair, so the
barrier holds whatever each side does within its half. A formation that sends no points
(an older leader, or a stale ellipse the leader grew: :func:`agent.leader_step.inflate`) is
kept out of as before.

Facing the motion. A unicycle member drives only along its heading; asked to move its slot
elsewhere, it turns in place first (:func:`agent.unicycle.steer`), then drives while it turns the
rest. Each member picks its own way round, and members whose headings differ by a few degrees
can pick opposite ways: driving while they turn, their bodies sweep arcs on opposite sides and
the formation bends (the turn round when its motion reverses: tests/scenarios/
lab-unicycles-turn-round.yaml, rigid-doorway-four-unicycle.yaml). So a leader sends its members'
body headings with their points, and a formation of unicycles asks for :func:`pace`'s share of
its goal twist until every member faces its slot's motion: its members turn in place, bodies
still, whichever way each turns, and the formation drives once they face it.

Turning back. Where the goal twist would send a slot back against its motion now (more than
120 degrees from its velocity under the own ellipse's rates, while it moves faster than
``brake_from``), the formation keeps that motion, braked by ``brake_decel`` dt a tick, until it is
slow (:func:`brake_before_turning_back`): a new route that leads back (a blocked plan, a parked
thing gone or come) stops the body before it moves the other way, as a carried load would. An
escape (an ``intent``) is never braked.

Sampled time: over one period dt at a constant twist a body point leaves the straight line
P + dt P' by at most rho (omega dt)^2 / 2; every distance here is convex along a straight motion, so
the row with gamma dt <= 1 keeps h >= 0 at the next sample once the safe distance is grown by that
bound (:func:`arc_margin`) - the property the tests check for dt in [0.02, 0.1].

The QP has three variables and is solved exactly (:func:`solve_twist`): the incremental algorithm of
:func:`agent.qp.solve_exact` one dimension up - when a row is violated by the optimum so far, the new
optimum lies on that row's plane, a 2-D problem over the earlier rows that :func:`solve_exact`
solves. Where the barrier rows cannot all hold, they are relaxed by their smallest common slack
inside the limits (as :func:`agent.qp.solve_cbf_qp` does for a robot).

Who computes it: every member, from the snapshot its formation shares - the leader's ``others``
message (its own ellipse: the pose and its rates; the other formations' ellipses), the obstacles and
the walls and shelves. Lock-step, every member then computes the same twist; in real time they
differ only as much as their obstacle messages do. Chosen over a leader publishing the twist on a new
key because it needs no new key, payload or access right, no successor hand-over (a member that has
the leader's ellipse has everything) and adds no round trip; the cost is the small QP on every
member (reported by ``formation bench`` with the rest of the step).

Each member's nominal (:func:`member_nominal`) is its slot's velocity under the twist plus a band
correction towards its slot; the thesis's per-robot QP (every row as before, hard rows never relaxed
to reach a goal) stays the last safety filter.

Pure functions over floats; no numpy on this hot path.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import NamedTuple

from geometry import speed_polygon
from geometry.angles import wrap_angle, wrap_left
from geometry.ellipse import Ellipse, ellipse_terms, reference_shape
from geometry.shapes import Shape, distance_floor, segment_distance, shape_distance
from geometry.slack import smallest_slack
from scenario.routes import shape_turn

from .barriers import Obstacle, ellipse_class_k
from .qp import FEAS_TOL, solve_exact

Point = tuple[float, float]
Row3 = tuple[float, float, float, float]  # (a1, a2, a3, b): a . z <= b, z = (vx, vy, rho omega)
Twist = tuple[float, float, float]  # (vx [m/s], vy [m/s], omega [rad/s]) about the centroid



@dataclass(frozen=True, slots=True)
class BodyTuning:
    """The formation QP's tuning (the module docstring has each rule)."""

    arrive_range: float = 0.1  # [m] blend to eq. 4.2 within this: wider settles softer, holds less shape
    mirror_share: float = 0.5  # each formation's share of A.3's alpha: more for one, less for the other
    brake_from: float = 0.04  # [m/s] faster bodies brake before turning back: lower brakes crawls too
    brake_decel: float = 1.0  # [m/s^2] that braking: harder stops sooner, softer turns back later
    brake_cos: float = math.cos(math.radians(120.0))  # this far off a slot's motion is back: 0 brakes more
    pace_from: float = 0.02  # [m/s] slower slots need no facing: higher ignores more of the band's noise
    pace_moving: float = 0.1  # [m/s] a formation with no slot this fast does not wait: higher waits less
    pace_aligned: float = math.radians(30.0)  # facing within this: full pace; wider drives on while turning
    pace_sideways: float = math.radians(90.0)  # this far off the formation waits: narrower waits sooner
    pace_floor: float = 0.1  # least goal-twist share while waiting: higher drives unfaced slots on
    bisect_steps: int = 40  # halvings of the twist QP's slack search: tighter slack, one 3-D solve each
    min_rho: float = 0.01  # [m] least slot radius (weighs omega): a one-robot formation's turn still costs


BODY_TUNING = BodyTuning()


@dataclass(frozen=True)
class Footprint:
    """What every member knows of its formation's body, in the start frame (origin: the start
    centroid of the members' control points; the scenario's axes)."""

    slots: tuple[Point, ...]  # each member's control point at the start (reference offsets)
    alpha0: float  # [rad] the ellipse's orientation at the start (geometry.ellipse.reference_shape)
    member: int  # this member's slot (index into slots)
    goal_turn: float = 0.0  # [rad] rotation from the start shape to the goal shape
    load_points: tuple[Point, ...] = ()  # a declared load's vertices (the default hull's are slots)
    load_edges: tuple[tuple[Point, Point], ...] = ()  # the load's outline edges
    # the members' start body positions and the load's outline about their centroid (the
    # rigid fit the safety monitor places the load by: agent.load_rows)
    fit0: tuple[Point, ...] = ()
    outline0: tuple[Point, ...] = ()

    @functools.cached_property
    def shape(self) -> tuple:
        """What of the footprint the formation's twist depends on (every member's slot but its
        own index), one object per distinct shape in the process (:class:`TwistMemo`'s key)."""
        key = (self.slots, self.alpha0, self.goal_turn, self.load_points, self.load_edges)
        return _SHAPES.setdefault(key, key)

    @functools.cached_property
    def rho(self) -> float:
        """[m] the largest slot radius (at least 1 cm: it weighs omega in the QP)."""
        return max([BODY_TUNING.min_rho] + [math.hypot(x, y) for x, y in self.slots])


class BodyParams(NamedTuple):
    """The numbers the formation QP needs (from :class:`agent.control.ControlParams`)."""

    vmax: float  # [m/s] every member's speed limit
    omega_max: float  # [rad/s] the formation's turn limit (a unicycle's turn rate, or inf)
    gamma_obstacle: float
    gamma_formations: float
    kp: float  # eq. 4.2, on the centroid and on the orientation
    dt: float  # [s] control period
    grow: float = 0.0  # [m] a member's Ds grows by this (look-ahead offset, sampling margin)
    radius: float = 0.0  # [m] body radius: a circle's physical radius is Ds less this
    load_margin: float = 0.0  # [m] the load keeps this from things (members sit near, not on, slots)
    # ellipse rows with the linear class-K gamma_formations h, not ellipse_class_k's: a double
    # integrator's members close on an ellipse no faster (agent.double_integrator.twist_gamma)
    linear_ellipses: bool = False
    spread: float = math.inf  # [rad] the members' largest heading spread (:func:`spread_rows`)


class Pose(NamedTuple):
    cx: float
    cy: float
    theta: float  # [rad] rotation of the start shape


def pose_of(own: Ellipse, alpha0: float) -> Pose:
    """The formation's pose from its leader's ellipse (eq. 4.7 and the rotation estimate)."""
    return Pose(own.cx, own.cy, wrap_angle(own.alpha - alpha0))


def motion_of(own: Ellipse, rho: float) -> tuple[float, float, float]:
    """The formation's motion from its leader's ellipse's rates: the centroid's velocity [m/s]
    and its outermost member's speed of rotation rho |alpha'| [m/s]."""
    return (own.vx, own.vy, rho * abs(own.alpha_rate))


def place(pose: Pose, p: Point) -> Point:
    """A start-frame point placed at ``pose``: c + R(theta) p."""
    c, s = math.cos(pose.theta), math.sin(pose.theta)
    return (pose.cx + c * p[0] - s * p[1], pose.cy + s * p[0] + c * p[1])


def point_velocity(pose: Pose, twist: Twist, p: Point) -> Point:
    """P' = v + omega J (P - c) for the world point P = ``p`` of the body."""
    return (twist[0] - twist[2] * (p[1] - pose.cy), twist[1] + twist[2] * (p[0] - pose.cx))


def arc_margin(rho: float, omega_max: float, dt: float) -> float:
    """[m] how far a point at radius rho leaves its straight step in one period at omega_max."""
    return 0.5 * rho * (omega_max * dt) ** 2


def point_row(pose: Pose, rho: float, p: Point, gx: float, gy: float, b: float) -> Row3:
    """The row g . P' <= b on the point P = ``p``, in z = (vx, vy, rho omega), normalised."""
    a3 = (gy * (p[0] - pose.cx) - gx * (p[1] - pose.cy)) / rho
    n = math.sqrt(gx * gx + gy * gy + a3 * a3)
    if n < 1e-12:
        return (0.0, 0.0, 0.0, b)
    return (gx / n, gy / n, a3 / n, b / n)


# ---------------------------------------------------------------------------------- rows


def circle_rows(pose: Pose, rho: float, p: Point, o: Obstacle, ds: float, gamma: float) -> Row3:
    """Appendix A.1 (4) on a body point: keep P at least ``ds`` from the moving circle o."""
    dx, dy = p[0] - o.x, p[1] - o.y
    h = dx * dx + dy * dy - ds * ds
    return point_row(pose, rho, p, -2.0 * dx, -2.0 * dy, gamma * h - 2.0 * (dx * o.vx + dy * o.vy))


def shape_point_row(pose: Pose, rho: float, p: Point, sh: Shape, ds: float, gamma: float) -> Row3:
    """eq. 4.5 on the distance to a wall or shelf: -grad d . P' <= gamma (d - ds)."""
    d, gx, gy = shape_distance(p[0], p[1], sh)
    return point_row(pose, rho, p, -gx, -gy, gamma * (d - ds))


def ellipse_point_row(pose: Pose, rho: float, p: Point, e: Ellipse, gamma: float,
                      grow: float = 0.0, linear: bool = False, shared: bool = True) -> Row3:
    """Appendix A.3 (19) on a body point (as :func:`agent.barriers.ellipse_row`), the ellipse's
    semi-axes grown by ``grow`` (members sit up to about that far from their slots); ``linear``:
    alpha = gamma h (BodyParams.linear_ellipses). Where the other formation sends its member
    points (``e.points``), it keeps its own ellipse off this formation's points by half of
    alpha (:func:`mirror_rows`), so this row takes the other half and leaves the ellipse's
    motion out: -dh/dp . P' <= alpha(h) / 2 (not for a point the other does not know of:
    ``shared`` False, the load's vertices)."""
    h, gx, gy, ga = ellipse_terms(p[0], p[1], e.cx, e.cy, e.alpha, e.a + grow, e.b + grow)
    alpha = gamma * h if linear else ellipse_class_k(h, gamma)
    if shared and e.points:
        b = BODY_TUNING.mirror_share * alpha
    else:
        b = alpha - (gx * e.vx + gy * e.vy) + ga * e.alpha_rate
    return point_row(pose, rho, p, -gx, -gy, b)


def mirror_rows(own: Ellipse, pose: Pose, rho: float, others: Sequence[Ellipse],
                p: BodyParams) -> list[Row3]:
    """The formation's own ellipse kept off the other formations' member points q (those
    ``e.points`` each other formation sends; module docstring), by the half of appendix A.3's
    alpha that the other leaves to it: with h = h_own(q) of eq. 4.6 and q held still,
    dh/dt = dh/dc . v + dh/dalpha omega = -dh/dq . v + dh/dalpha omega >= -alpha(h) / 2, so

        dh/dq . v - dh/dalpha omega <= alpha(h) / 2.

    The own ellipse is grown by the load margin, as the other's rows grow it for their slots
    (:func:`_member_rows`): both halves then bound the same h, and a formation standing still
    is not pushed by one that keeps to its half."""
    rows: list[Row3] = []
    gamma = p.gamma_formations
    a, b = own.a + p.load_margin, own.b + p.load_margin
    for e in others:
        for qx, qy in e.points:
            h, gx, gy, ga = ellipse_terms(qx, qy, own.cx, own.cy, own.alpha, a, b)
            alpha = gamma * h if p.linear_ellipses else ellipse_class_k(h, gamma)
            a3 = -ga / rho
            n = math.sqrt(gx * gx + gy * gy + a3 * a3)
            if n > 1e-12:
                rows.append((gx / n, gy / n, a3 / n, BODY_TUNING.mirror_share * alpha / n))
    return rows


def edge_row(pose: Pose, rho: float, edge: tuple[Point, Point], q: Point, qv: Point, clear: float,
             gamma: float) -> Row3:
    """An outline edge against a point q moving at qv: n . P*' <= gamma (d - clear) + n . q'."""
    (ax, ay), (bx, by) = edge
    d, nx, ny = segment_distance(q[0], q[1], ax, ay, bx, by)  # n: from the edge's point to q
    px, py = q[0] - d * nx, q[1] - d * ny
    return point_row(pose, rho, (px, py), nx, ny, gamma * (d - clear) + nx * qv[0] + ny * qv[1])


@functools.lru_cache(maxsize=64)
def twist_limit_rows(rho: float, p: BodyParams) -> tuple[Row3, ...]:
    """|v| + rho |omega| <= vmax (every slot's speed: the speed polygon of
    :mod:`geometry.speed_polygon` in v for each sign of omega) and |omega| <= omega_max, in z
    (the same for every tick of a formation: cached)."""
    face = speed_polygon.face(p.vmax)
    k = 1.0 / math.sqrt(2.0)
    rows: list[Row3] = []
    for c, s in speed_polygon.normals():
        rows += [(k * c, k * s, k, k * face), (k * c, k * s, -k, k * face)]
    if math.isfinite(p.omega_max):
        rows += [(0.0, 0.0, 1.0, rho * p.omega_max), (0.0, 0.0, -1.0, rho * p.omega_max)]
    return tuple(rows)


class Snapshot(NamedTuple):
    """What the formation shares this tick (besides its own ellipse)."""

    obstacles: Sequence[Obstacle] = ()
    shapes: Sequence[Shape] = ()
    ellipses: Sequence[Ellipse] = ()  # the other formations'


def far(gap: float, speed: float, gamma: float, rho: float, p: BodyParams) -> bool:
    """Whether a thing ``gap`` [m] beyond the body's bounding circle (radius rho), moving at
    ``speed``, is too far for any of its rows to be active: a row is normalised with |a| <= sqrt 2
    before normalisation of the turn part, and a circle's b >= gamma gap / 2 - speed."""
    return gamma * (gap - p.grow - p.load_margin - rho) > 3.0 * (p.vmax + speed)


def near(snap: Snapshot, pose: Pose, rho: float, p: BodyParams) -> Snapshot:
    """The part of ``snap`` whose rows can be active: a row is normalised, so one with b at or
    above vmax never is, and b >= gamma (gap) - (the thing's speed) for a gap beyond the body's
    bounding circle of radius rho. A cheap test per thing before the rows."""
    c = (pose.cx, pose.cy)
    go, gf = p.gamma_obstacle, p.gamma_formations
    obstacles = [o for o in snap.obstacles
                 if not far(math.dist(c, (o.x, o.y)) - o.ds, math.hypot(o.vx, o.vy), go, rho, p)]
    shapes = [sh for sh in snap.shapes  # the shape's bounding circle first (a lower bound)
              if not far(distance_floor(c[0], c[1], sh) - sh.ds, 0.0, go, rho, p)
              and not far(shape_distance(c[0], c[1], sh)[0] - sh.ds, 0.0, go, rho, p)]
    ellipses = [e for e in snap.ellipses
                if not far(math.dist(c, (e.cx, e.cy)) - e.a,
                           math.hypot(e.vx, e.vy) + e.a * abs(e.alpha_rate), gf, rho, p)]
    return Snapshot(obstacles, shapes, ellipses)


def footprint_rows(fp: Footprint, pose: Pose, snap: Snapshot, p: BodyParams,
                   own: Ellipse | None = None) -> list[Row3]:
    """Every footprint barrier row that can be active (b below the largest |z| the limits
    allow); with the formation's ``own`` ellipse, its :func:`mirror_rows` too."""
    rho = fp.rho
    others = snap.ellipses
    snap = near(snap, pose, rho, p)
    margin = arc_margin(rho, min(p.omega_max, p.vmax / rho), p.dt)  # the limits bound omega so
    slots = [place(pose, s) for s in fp.slots]
    rows = _member_rows(pose, rho, slots, snap, p, margin)
    rows += _load_rows(fp, pose, rho, snap, p, margin)
    if own is not None:  # the own ellipse reaches beyond rho: its bounding circle for near's test
        wide = [e for e in others if e.points and not far(
            math.dist((own.cx, own.cy), (e.cx, e.cy)) - e.a - max(0.0, own.a + p.load_margin - rho),
            math.hypot(e.vx, e.vy) + e.a * abs(e.alpha_rate), p.gamma_formations, rho, p)]
        rows += mirror_rows(own, pose, rho, wide, p)
    reach = p.vmax * (1.0 + 1e-9)
    return [r for r in rows if r[3] < reach]


def _member_rows(pose: Pose, rho: float, slots: Sequence[Point], snap: Snapshot, p: BodyParams,
                 margin: float) -> list[Row3]:
    rows: list[Row3] = []
    grow = p.grow + margin
    for q in slots:
        rows += [circle_rows(pose, rho, q, o, o.ds + grow, p.gamma_obstacle) for o in snap.obstacles]
        rows += [shape_point_row(pose, rho, q, sh, sh.ds + grow, p.gamma_obstacle)
                 for sh in snap.shapes]
        rows += [ellipse_point_row(pose, rho, q, e, p.gamma_formations, p.load_margin,
                                   p.linear_ellipses) for e in snap.ellipses]
    return rows


def _load_rows(fp: Footprint, pose: Pose, rho: float, snap: Snapshot, p: BodyParams,
               margin: float) -> list[Row3]:
    rows: list[Row3] = []
    clear = p.load_margin + margin
    g = p.gamma_obstacle
    for v in (place(pose, q) for q in fp.load_points):
        rows += [circle_rows(pose, rho, v, o, max(0.0, o.ds - p.radius) + clear, g)
                 for o in snap.obstacles]
        rows += [shape_point_row(pose, rho, v, sh, clear, g) for sh in snap.shapes]
        rows += [ellipse_point_row(pose, rho, v, e, p.gamma_formations, 0.0, p.linear_ellipses,
                                   False) for e in snap.ellipses]
    c = (pose.cx, pose.cy)
    things = [((o.x, o.y), (o.vx, o.vy), max(0.0, o.ds - p.radius)) for o in snap.obstacles]
    things += [(q, (0.0, 0.0), 0.0) for sh in snap.shapes for q in sh.corners()
               if not far(math.dist(c, q), 0.0, g, rho, p)]
    if not things:
        return rows
    edges = [(place(pose, a), place(pose, b)) for a, b in fp.load_edges]
    for e in edges:
        rows += [edge_row(pose, rho, e, q, qv, r + clear, g) for q, qv, r in things]
    return rows


# --------------------------------------------------------------------------------- solver


def _basis(a: tuple[float, float, float]) -> tuple[tuple[float, float, float], ...]:
    """Two unit vectors spanning the plane normal to the unit vector a."""
    ax, ay, az = a
    t = (1.0, 0.0, 0.0) if abs(ax) < 0.9 else (0.0, 1.0, 0.0)
    e1 = (ay * t[2] - az * t[1], az * t[0] - ax * t[2], ax * t[1] - ay * t[0])
    n1 = math.sqrt(e1[0] ** 2 + e1[1] ** 2 + e1[2] ** 2)
    e1 = (e1[0] / n1, e1[1] / n1, e1[2] / n1)
    e2 = (ay * e1[2] - az * e1[1], az * e1[0] - ax * e1[2], ax * e1[1] - ay * e1[0])
    return e1, e2


def _dot(a: Sequence[float], b: Sequence[float]) -> float:
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def solve3(zhat: tuple[float, float, float], rows: Sequence[Row3],
           tol: float = FEAS_TOL) -> tuple[float, float, float] | None:
    """Exact minimiser of |z - zhat|^2 subject to ``rows`` (unit normals); None when infeasible.

    Incremental (module docstring): when row k is violated, z = p + s e1 + t e2 on its plane, p
    the projection of zhat, and |z - zhat|^2 = |p - zhat|^2 + s^2 + t^2, so (s, t) is the 2-D
    problem min s^2 + t^2 over the earlier rows (c . e1) s + (c . e2) t <= d - c . p."""
    z = zhat
    for k, (a1, a2, a3, b) in enumerate(rows):
        if a1 * z[0] + a2 * z[1] + a3 * z[2] <= b + tol:  # _dot(a, z), inline: the usual case
            continue
        a = (a1, a2, a3)
        if _dot(a, a) < 1e-24:
            return None  # 0 <= b with b < -tol
        r = _dot(a, zhat) - b
        p = (zhat[0] - r * a1, zhat[1] - r * a2, zhat[2] - r * a3)
        e1, e2 = _basis(a)
        plane = [(_dot(c[:3], e1), _dot(c[:3], e2), c[3] - _dot(c[:3], p)) for c in rows[:k]]
        st = solve_exact(0.0, 0.0, plane, tol)
        if st is None:
            return None
        s, t = st
        z = (p[0] + s * e1[0] + t * e2[0], p[1] + s * e1[1] + t * e2[1],
             p[2] + s * e1[2] + t * e2[2])
    return z


class TwistResult(NamedTuple):
    twist: Twist
    slack: float  # [m/s] how much the barrier rows were relaxed (0: all met)
    rows: int  # footprint rows in the QP
    goal: Twist = (0.0, 0.0, 0.0)  # the part of the goal twist that seeks the goal
    aim: Twist | None = None  # the twist the formation waits to make (:func:`pace` < 1), else None


def spread_rows(goal: Twist, rho: float, spread: float) -> list[Row3]:
    """rho |omega - omega_goal| <= sin(spread / 2) (d . v), d the direction of the goal twist's
    travel (none: omega = omega_goal), in z (module docstring: what unicycle members can
    follow); none without a spread limit (single integrators)."""
    if not math.isfinite(spread):
        return []
    n = math.hypot(goal[0], goal[1])
    k = math.sin(0.5 * min(spread, math.pi)) / n if n > 1e-9 else 0.0
    m = math.sqrt((k * goal[0]) ** 2 + (k * goal[1]) ** 2 + 1.0)
    ax, ay, w = -k * goal[0] / m, -k * goal[1] / m, rho * goal[2] / m
    return [(ax, ay, 1.0 / m, w), (ax, ay, -1.0 / m, -w)]


def solve_twist(goal: Twist, rho: float, limits: Sequence[Row3], rows: Sequence[Row3],
                follow: Sequence[Row3] = ()) -> TwistResult:
    """The twist closest to ``goal`` (weights 1, 1, rho^2) meeting ``limits`` and ``rows``; where
    the rows cannot all hold, they are relaxed by their smallest common slack (the limits never:
    they hold the zero twist). ``follow`` (:func:`spread_rows`) give way first: where the rows
    hold but not with them, they are left out (a barrier never waits on what members can
    follow); where the rows themselves were relaxed (a jam: the least-risk twist), they are
    relaxed after them by their own smallest common slack, so that twist does not jump between
    a tick whose rows held and one whose rows did not (left out there too: 48 reversals in
    tests/scenarios/rigid-doorway-four-unicycle.yaml)."""
    zhat = (goal[0], goal[1], rho * goal[2])
    base = list(limits) + list(rows)
    z = solve3(zhat, base)
    slack = 0.0
    if z is None:
        slack = _min_twist_slack(list(limits), rows)
        base = list(limits) + _shifted(rows, slack)
        z = solve3(zhat, base) or (0.0, 0.0, 0.0)
    if follow:
        zf = solve3(zhat, base + list(follow))
        if zf is None and slack > 0.0:
            zf = solve3(zhat, base + _shifted(follow, _min_twist_slack(base, follow, z)))
        z = zf or z
    return TwistResult((z[0], z[1], z[2] / rho), slack, len(rows), goal)


def _shifted(rows: Sequence[Row3], slack: float) -> list[Row3]:
    return [(a1, a2, a3, b + slack) for a1, a2, a3, b in rows]


def _min_twist_slack(base: list[Row3], rows: Sequence[Row3],
               at: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> float:
    """The smallest s >= 0 with ``base`` and the rows shifted by s feasible (bisection,
    :mod:`geometry.slack`); ``at`` meets ``base`` (the zero twist meets the limits), so
    s = max(a . at - b) is enough."""
    hi = max(0.0, max(_dot(r, at) - r[3] for r in rows)) + 1e-6

    def feasible(mid: float) -> bool:
        return solve3(at, base + _shifted(rows, mid)) is not None

    return smallest_slack(feasible, hi, BODY_TUNING.bisect_steps) + 4.0 * FEAS_TOL


# ---------------------------------------------------------------------------- the motion


def goal_twist(pose: Pose, goal: Point, goal_turn: float, rho: float, p: BodyParams,
               push: Point = (0.0, 0.0), intent: Point | None = None) -> Twist:
    """eq. 4.2 on the centroid and on the orientation towards the goal shape's (a turn within
    :data:`geometry.angles.LEFT_BIAS` of 180 degrees goes left for every member alike,
    :func:`geometry.angles.wrap_left`), both scaled by one factor into the slots' speed limit
    (|v| + rho |omega| <= the speed polygon's face), so the move and the turn end together;
    plus the formation-level ``push`` (the tie-break of :func:`agent.control.tiebreak_push`).
    An ``intent`` (the escape of :func:`agent.control.escape_command`) replaces the centroid's
    part; the turn gets what speed it leaves."""
    turn = goal_turn - pose.theta
    turn = wrap_left(turn)
    vx, vy, w = p.kp * (goal[0] - pose.cx), p.kp * (goal[1] - pose.cy), p.kp * turn
    face = speed_polygon.face(p.vmax)
    if intent is not None:
        vx, vy = intent
        w = math.copysign(min(abs(w), max(0.0, face - math.hypot(vx, vy)) / rho), w)
        return (vx, vy, w)
    scale = min(1.0, face / (math.hypot(vx, vy) + rho * abs(w) + 1e-12))
    return (scale * vx + push[0], scale * vy + push[1], scale * w)


def brake_before_turning_back(want: Twist, moving: Twist, offsets: Sequence[Point],
                              dt: float) -> Twist:
    """The goal twist, or, where it would send a slot back against its motion now, that motion
    braked: ``moving`` is the formation's twist now (its own ellipse's velocity and turn rate),
    ``offsets`` its slots from the centroid (world axes). A slot moving faster than ``brake_from``
    whose velocity under ``want`` lies more than 120 degrees from its velocity now turns back;
    then the body keeps its motion, slowed so its fastest slot loses ``brake_decel`` dt of speed.
    A new route or waypoint that leads back (traffic in the way, a parked thing gone or come)
    makes the body stop before it moves the other way, as a carried load would, instead of its
    members' commands flipping within one tick.

    Why: a rigid body with a load cannot reverse in one tick, and members that try part from
    each other. Pinned by tests/scenarios/route-head-on-aisle.yaml (and route-give-way.yaml)."""
    t = BODY_TUNING
    fastest = 0.0
    back = False
    for rx, ry in offsets:
        nx, ny = moving[0] - moving[2] * ry, moving[1] + moving[2] * rx
        speed = math.hypot(nx, ny)
        fastest = max(fastest, speed)
        wx, wy = want[0] - want[2] * ry, want[1] + want[2] * rx
        if speed > t.brake_from and nx * wx + ny * wy < t.brake_cos * speed * math.hypot(wx, wy):
            back = True
    if not back:
        return want
    k = max(0.0, fastest - t.brake_decel * dt) / fastest
    return (k * moving[0], k * moving[1], k * moving[2])


def formation_twist(fp: Footprint, own: Ellipse, goal: Point, snap: Snapshot, p: BodyParams,
                    push: Point = (0.0, 0.0), intent: Point | None = None,
                    turn: float | None = None) -> tuple[Pose, TwistResult]:
    """The formation's pose and its certified twist this tick (eq. 4.12' of the module docstring);
    ``turn``: the rotation to turn to (a waypoint's heading), else the goal shape's. A formation
    of unicycles whose ellipse came with its members' headings asks for :func:`pace`'s share of
    its goal twist while they turn to face its motion; ``aim`` is then the twist it waits to make
    (certified as the full goal twist would be), which its members turn to face."""
    pose = pose_of(own, fp.alpha0)
    rho = fp.rho
    want = goal_twist(pose, goal, fp.goal_turn if turn is None else turn, rho, p, push, intent)
    if intent is None:
        offsets = [(x - pose.cx, y - pose.cy) for x, y in (place(pose, q) for q in fp.slots)]
        want = brake_before_turning_back(want, (own.vx, own.vy, own.alpha_rate), offsets, p.dt)
    rows = footprint_rows(fp, pose, snap, p, own)
    res = solve_twist(want, rho, twist_limit_rows(rho, p), rows, spread_rows(want, rho, p.spread))
    aim = None
    if intent is None and own.headings and math.isfinite(p.spread):  # unicycle members
        k = pace(res.twist, pose, fp, own.headings)
        if k < 1.0:  # the same rows, a slower goal: the twist once its members face it is the aim
            aim, want = res.twist, (k * want[0], k * want[1], k * want[2])
            res = solve_twist(want, rho, twist_limit_rows(rho, p), rows, spread_rows(want, rho, p.spread))
    # what seeks the goal (for member_nominal's arrival): neither the push nor an escape
    seek = (0.0, 0.0, want[2]) if intent is not None else (want[0] - push[0], want[1] - push[1],
                                                           want[2])
    return pose, res._replace(goal=seek, aim=aim)


class TwistMemo:
    """The last :func:`formation_twist` worked out per formation, by its inputs. Every member of a
    formation works out the same twist from the same shared data (its ellipse, goal and
    snapshot), so a controller that serves every member in turn (the in-process simulator), or
    the agents of one agent host sharing one memo (:data:`SHARED_TWISTS`), solve the formation's
    QP once a tick instead of once a member. A pure cache: equal inputs give the very same
    result; a controller serving one robot pays one comparison a tick for it. One entry per
    formation (by its slots and goal: formations of one shape head for different goals), at
    most ``size`` of them; thread-safe under the GIL (an entry is replaced whole, a lost one
    costs one more solve)."""

    __slots__ = ("last", "size")

    def __init__(self, size: int = 64) -> None:
        # the formation's slots and goal -> (inputs, result) as one pair: replaced whole, so a reader
        # never pairs them wrongly
        self.last: dict[tuple, tuple[tuple, tuple[Pose, TwistResult]]] = {}
        self.size = size

    def twist(self, fp: Footprint, own: Ellipse, goal: Point, snap: Snapshot, p: BodyParams,
              push: Point = (0.0, 0.0), intent: Point | None = None,
              turn: float | None = None) -> tuple[Pose, TwistResult]:
        """:func:`formation_twist` of these inputs (the member's slot in ``fp`` plays no part)."""
        # tuples, not the caller's lists: a list changed in place must not match its old self;
        # the footprint's shape is one object per distinct shape (Footprint.shape), so its
        # identity stands for it
        shape = fp.shape
        key = (own, tuple(snap.obstacles), tuple(snap.shapes), tuple(snap.ellipses), p, push,
               intent, turn)
        which = (id(shape), goal)
        last = self.last.get(which)
        if last is not None and last[0] == key:
            return last[1]
        value = formation_twist(fp, own, goal, snap, p, push, intent, turn)
        if len(self.last) >= self.size:
            self.last.clear()
        self.last[which] = (key, value)
        return value


#: every distinct footprint shape of the process, once (Footprint.shape): kept, so the identity
#: of one never stands for another
_SHAPES: dict[tuple, tuple] = {}

#: the memo the agents of one process share (an agent host's: :class:`agent.tick.Ticker`)
SHARED_TWISTS = TwistMemo()


def pace(want: Twist, pose: Pose, fp: Footprint, headings: Sequence[float]) -> float:
    """The share of its goal twist a formation of unicycles asks for while its members turn to
    face their slots' motion under ``want`` (the twist certified for the full goal): 1 with every
    member (``headings`` [rad], in slot order) within ``pace_aligned`` of it, ``pace_floor`` with one
    ``pace_sideways`` off or more, linear in the cosine between; slots slower than ``pace_from`` do not
    count, and a formation none of whose slots is asked for ``pace_moving`` does not wait (its aims
    there are the band's noise: a member turned back and forth after them). A unicycle drives
    only along its heading, so a member still turning while its slot moves sweeps an arc, and
    members turning round opposite ways (each picks its own way,
    :func:`agent.unicycle.turn_error`) part by twice that. Waiting, they turn in place, their
    bodies still, whichever way each turns. The floor keeps a formation moving whose member
    cannot turn where it stands (its look-ahead point against a shelf's row).

    Why (wait-to-face): members turning round opposite ways while their slots move sweep their
    bodies apart and bend the formation. Pinned by tests/scenarios/lab-unicycles-turn-round.yaml
    (and rigid-doorway-four-unicycle.yaml)."""
    if len(headings) != len(fp.slots):
        return 1.0
    t = BODY_TUNING
    lo, hi = math.cos(t.pace_sideways), math.cos(t.pace_aligned)
    k, fastest = 1.0, 0.0
    for q, th in zip(fp.slots, headings, strict=True):
        vx, vy = point_velocity(pose, want, place(pose, q))
        speed = math.hypot(vx, vy)
        fastest = max(fastest, speed)
        if speed < t.pace_from:
            continue
        cos = (vx * math.cos(th) + vy * math.sin(th)) / speed
        k = min(k, max(0.0, min(1.0, (cos - lo) / (hi - lo))))
    return 1.0 if fastest < t.pace_moving else max(k, t.pace_floor)


def band_gain(kp: float, dt: float) -> float:
    """[1/s] the pull towards the slot: eq. 4.2's kp, at most 1 / (2 dt) so one period closes at
    most half the gap (no overshoot at any control rate)."""
    return min(kp, 0.5 / dt)


def member_nominal(fp: Footprint, pose: Pose, twist: Twist, point: Point, body: Point,
                   target: Point, p: BodyParams, goal: Twist = (0.0, 0.0, 0.0),
                   arriving: bool = True) -> Point:
    """This member's nominal velocity: its slot's velocity under ``twist`` plus k (slot - point)
    (:func:`band_gain`; ``point`` its control point), clamped to vmax. ``arriving`` (its
    ``target`` its goal on the last leg, or its slot where the formation holds), with its
    ``body`` within ``arrive_range`` of it, it blends, by w from 0 to 1, into
    eq. 4.2 on the target plus what the rows added to the ``goal`` twist: at the slot, the twist's
    velocity less the share s of the goal's velocity it carries (s its projection on the goal's,
    in [0, 1]), so a goal shape that is not exactly a rigid copy of the start shape is still
    reached, a unicycle formation parks on its bodies' goals (its pose is its look-ahead points'),
    and a formation parked at its goal still gives way. Only the share carried comes off: rows
    that slow the twist to a crawl (another formation's ellipse beside the goal) leave the
    member's own pull to its target whole, where taking off the whole goal pulled it back
    against that pull and it stopped short (tests/scenarios/rigid-doorway-four-unicycle.yaml). A waypoint the
    formation passes is no place to settle: there the blend took the turn to its heading out of
    the twist, and a pentagon whose members stood within 2 cm of their targets never turned.

    Why (arrival blend): a goal shape is not exactly a rigid copy of the start shape, so only a
    member's own pull settles it on its goal. Pinned by
    tests/scenarios/rigid-doorway-four-unicycle.yaml."""
    slot = place(pose, fp.slots[fp.member])
    dist = math.hypot(target[0] - body[0], target[1] - body[1])
    w = min(1.0, max(0.0, 1.0 - dist / BODY_TUNING.arrive_range)) if arriving else 0.0
    sv = point_velocity(pose, twist, slot)
    if w > 0.0:
        gv = point_velocity(pose, goal, slot)
        gg = gv[0] * gv[0] + gv[1] * gv[1]
        s = min(1.0, max(0.0, (sv[0] * gv[0] + sv[1] * gv[1]) / gg)) if gg > 0.0 else 0.0
        sv = (sv[0] - w * s * gv[0], sv[1] - w * s * gv[1])
    k = band_gain(p.kp, p.dt)
    ux, uy = sv[0] + k * (slot[0] - point[0]), sv[1] + k * (slot[1] - point[1])
    if w > 0.0:  # the slot's pull moves over to the target
        ux += w * (p.kp * (target[0] - body[0]) - k * (slot[0] - point[0]))
        uy += w * (p.kp * (target[1] - body[1]) - k * (slot[1] - point[1]))
    n = math.hypot(ux, uy)
    if n > p.vmax:
        ux, uy = ux * p.vmax / n, uy * p.vmax / n
    return ux, uy


# ---------------------------------------------------------------------- from a scenario


def outline_edges(pts: Sequence[Point]) -> tuple[tuple[Point, Point], ...]:
    """An outline's edges, counter-clockwise (two points: the one segment)."""
    n = len(pts)
    return tuple((pts[k], pts[(k + 1) % n]) for k in range(n if n > 2 else 1))


def footprint_of(starts: Sequence[Point], bodies: Sequence[Point], goals: Sequence[Point],
                 index: int, load: Sequence[Point] = (), declared: bool = True) -> Footprint:
    """A member's :class:`Footprint` from its formation's start control points ``starts``, start
    body positions ``bodies`` and goals (member order), and its load's outline ``load`` (world
    coordinates at the start, counter-clockwise: :func:`scenario.cargo.load_polygon`). A load
    not ``declared`` is the members' hull: its vertices are the members (their own rows keep
    them), so only its edges get rows. Without any outline every pair of members is an edge:
    the hull's edges are among them and the others lie inside it, so their rows are implied."""
    ref = reference_shape(list(starts))
    cx = sum(x for x, _y in starts) / len(starts)
    cy = sum(y for _x, y in starts) / len(starts)
    turn = shape_turn(bodies, goals)
    bx = sum(x for x, _y in bodies) / len(bodies)
    by = sum(y for _x, y in bodies) / len(bodies)
    fit0 = tuple((x - bx, y - by) for x, y in bodies)
    if len(load) >= 2:
        pts = tuple((x - cx, y - cy) for x, y in load)
        edges = outline_edges(pts)
        return Footprint(ref.offsets, ref.alpha0, index, turn, pts if declared else (), edges,
                         fit0, tuple((x - bx, y - by) for x, y in load))
    offs = ref.offsets
    edges = tuple((offs[i], offs[j]) for i in range(len(offs)) for j in range(i + 1, len(offs)))
    return Footprint(offs, ref.alpha0, index, turn, (), edges, fit0)
