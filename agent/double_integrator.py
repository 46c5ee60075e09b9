"""Double-integrator robots (thesis, future work): state position and velocity, input acceleration.

A robot of ``robot.model: double_integrator`` moves as  p' = v, v' = a  with |v| <= max_speed and
|a| <= max_accel. Every barrier h(p) of the thesis's per-robot QP (eq. 4.12: formation edges,
circles static and moving, walls and shelves, other formations' ellipses, body separation, the
all-to-all pairs of eq. 3.5) then has relative degree 2: a appears only in h''. Each becomes the
high-order CBF (HOCBF) of W. Xiao and C. Belta, "Control Barrier Functions for Systems with High
Relative Degree", IEEE CDC 2019 (arXiv:1903.04706), with linear class-K functions (the
exponential CBF of Q. Nguyen and K. Sreenath, "Exponential Control Barrier Functions for
enforcing high relative-degree safety-critical constraints", ACC 2016, with poles -k1, -k2):

    psi0 = h,   psi1 = h' + k1 h,   row:  psi1' + k2 psi1 >= 0,

that is  h'' + (k1 + k2) h' + k1 k2 h >= 0.  Writing h'' = g . a + q (g = dh/dp, q the drift:
everything in h'' but the own acceleration), the QP row over a = (ax, ay) is

    -g . a <= q + (k1 + k2) h' + k1 k2 h                                            (R)

normalised to |g| = 1 (so a slack is in m/s^2). The set {h >= 0, psi1 >= 0} is kept: psi1 >= 0
bounds the closing speed s = -h' by k1 h. The other party (neighbour, obstacle, formation) is
taken to keep its velocity over the tick (its acceleration is not on the wire; obstacles and
ellipses move at constant velocity in the scenario), as eq. 4.12's rows take its velocity.

Poles. The first pole k1 sets how fast a hazard may be closed (psi1 >= 0: s <= k1 h, the single
integrator's linear rate with k1 <= gamma) and, with it, how hard a barrier brakes; the second,
k2, only how fast the velocity is brought back into that first stage, which a double integrator
with ample acceleration does within a period. So k2 = 1 / dt - k1 (:func:`second_pole`), and
(R) reads  -g . a <= q + k1 h' + k2 psi1. Each robot takes its neighbours to keep their
velocities, so the relative acceleration a row allows about a neighbour at rest relative to it,
k1 k2 h, bounds the common acceleration of a whole formation; with h small (a band's width, a
separation gap) and k2 at the pace of k1 (k2 = k1, the critically damped choice) that holds a
formation to a crawl; at the sampling rate the band and separation rows let it accelerate as one.

Braking distance. With h a distance (circles, walls and shelves, separation), inside the set
(psi1 >= 0) the row (R) asks for a deceleration along g of at most k1 s - k2 psi1 <= k1 s <=
k1 s_max, s_max the largest closing speed (max_speed, plus the obstacle's speed, or twice
max_speed for a pair sharing it). The first pole is therefore :func:`gain`:
k1 = min(gamma, brake_share max_accel / s_max, 1 / (2 dt)) (:class:`DITuning`), so the braking a
barrier asks is at most brake_share of what the robot has, and from psi1 >= 0 (s <= k1 h) the
stopping distance s^2 / (2 a_b) at a_b = k1 s_max <= brake_share max_accel is at most h / 2: a
robot inside the set can always still brake before h = 0, however large k2. The robot closes on
a hazard no faster than its braking allows: s <= k1 h <= brake_share max_accel h / s_max.

Outside the first stage (psi1 < 0: a hazard first heard at a closing speed its first stage
forbids, another formation's ellipse joining the listen set, a neighbour that accelerated
towards the robot during the period) k2 = 1 / dt - k1 would ask the whole excess back within one
period, more than the robot has. There k2 is capped so that the second stage asks at most
restore_share max_accel along g (:func:`hocbf_bound`): with brake_share the row asks at most
(brake_share + restore_share) max_accel < max_accel cos(pi / 12), the face of the inscribed
acceleration polygon, so a single row is always feasible, and psi1 returns at that braking. For
a distance that bound follows from the poles; the quadratic h of a turning ellipse changes at a
rate proportional to h even for a robot at rest (its level sets sweep at the turn rate times the
distance: |h'| <= |w| (a / b - b / a) (h + 1) from the rotation alone), which neither pole
bounds, so :func:`hocbf_row` caps what a row asks at that bound (:func:`most_asked`): there the
row still brakes along g as hard as a row may, where it would otherwise ask more than the robot
has and leave the tick to the least-risk command.

Sampling (zero-order hold, a constant over the period dt, exact integration; the one-step
property :func:`step` is tested for). For a distance barrier h(p) = dist(p, C) - D to a convex C
(a point, a segment, a box), dist is convex, so with the relative position
d(t) = d + r t + a t^2 / 2 (the other party at constant velocity)
    h(t) >= h + h' t + (g . a) t^2 / 2     (the supporting line of the convex function).
The rows drop the curvature term of h'' (>= 0 for a convex distance), so (R) gives
g . a >= -(k1 + k2) h' - k1 k2 h and, with h' >= -k1 h (psi1 >= 0) and (k1 + k2) t <= 2,
    h(t) >= h (1 - k1 t + k1^2 t^2 / 2) >= 0    for every t in [0, dt]:
no sampling margin is needed for circles, walls, shelves and body separation. For a barrier
linear in the relative position (a wall's face) the row met at the sample also keeps the first
stage at the next: psi1(dt) >= (k1 dt / 2) psi1 + (k1^3 dt^2 / 2) h >= 0, since k1 + k2 = 1 / dt.
The formation edges (soft, relaxed when need be; first pole min(gamma_formation, 1 / (2 dt))) and
other formations' ellipses (whose pad is their margin) use the thesis's quadratic h (eq. 4.3,
4.4, 4.6) with the exact h'' at the sample.

Limits (never relaxed): |a| <= max_accel as a polygon inscribed in the disk, one vertex along the
nominal acceleration, and the speed after the tick, v + a dt, inside the speed polygon of
:func:`agent.barriers.speed_rows` (a face the present velocity already lies beyond may not be
pushed further: a = 0 always meets every limit row).

Nominal: a PD-like acceleration towards the nominal velocity u of eq. 4.2 (with the formation
rules of :mod:`agent.control`), a = 2 kp (u - v), clamped to max_accel: about p = goal this is
p'' + 2 kp p' + 2 kp^2 (p - goal) = 0, damping ratio 1/sqrt(2) whatever kp, so the formation
and goal behaviour stay the thesis's.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import NamedTuple

from geometry.ellipse import Ellipse
from geometry.shapes import Shape, shape_distance

from . import barriers, load_rows
from .barriers import Neighbour, Obstacle, Partner
from .params import ControlParams, StepInput
from .qp import STATUS_NOMINAL, QPResult, Row, Rows, normalized_row, solve_cbf_qp, solve_exact


@dataclass(frozen=True, slots=True)
class DITuning:
    """The double integrator's tuning (module docstring)."""

    brake_share: float = 0.5  # max_accel share a barrier asks at its boundary: more brakes later, harder
    nominal_damping: float = 2.0  # a = this kp (u - v); 2 damps at 1/sqrt(2): more follows u faster
    restore_share: float = 0.4  # max_accel share a row asks beyond brake_share outside its first stage


DI_TUNING = DITuning()


class DIStep(NamedTuple):
    """One double-integrator tick: the certified acceleration, the velocity it gives at the end
    of the tick (the robot's velocity over the next, what ``state`` carries), and the QP's
    outcome as :class:`agent.control.StepResult` reports it."""

    ax: float  # [m/s^2] certified acceleration
    ay: float
    vx: float  # [m/s] velocity at the end of the tick
    vy: float
    status: str
    slack: float  # [m/s^2]
    solve_us: float


def gain(gamma: float, max_accel: float, closing: float, dt: float,
         share: float = DI_TUNING.brake_share) -> float:
    """[1/s] k1, the first pole of a hazard's HOCBF (module docstring, "Braking distance");
    ``share`` the share of max_accel a barrier asks on its boundary."""
    return min(gamma, share * max_accel / closing, 0.5 / dt)


def second_pole(k1: float, dt: float) -> float:
    """[1/s] k2 = 1 / dt - k1, the pole of the second stage psi1' + k2 psi1 >= 0 (module
    docstring, "Poles")."""
    return 1.0 / dt - k1


def hocbf_bound(h: float, hd: float, k1: float, dt: float, room: float) -> float:
    """The row's right side less the drift q: (k1 + k2) h' + k1 k2 h = k1 h' + k2 psi1 with
    psi1 = h' + k1 h and k2 = :func:`second_pole`; outside the first stage (psi1 < 0) k2 is
    capped so that k2 (-psi1) <= ``room`` (module docstring, "Poles")."""
    psi1 = hd + k1 * h
    k2 = second_pole(k1, dt)
    if psi1 < 0.0:
        k2 = min(k2, room / -psi1)
    return k1 * hd + k2 * psi1


def twist_gamma(cp: ControlParams) -> float:
    """[1/s] k_t, the gain of the formation twist's ellipse rows when its members are double
    integrators (linear alpha = k_t h: ``agent.body.BodyParams.linear_ellipses``), so that a
    slot velocity the twist allows asks nothing of its member's own :func:`ellipse_hocbf`.

    That row, -g . a <= q + k1 h' + k2 psi1 (psi1 = h' + k1 h, k2 = 1 / dt - k1 >= k1), is met
    by a = 0 whenever h' >= -(k1 / 2) h: then psi1 >= (k1 / 2) h and the right side is at least
    q + (k1 / 2) (k2 - k1) h >= 0, with q >= 0 for an ellipse that does not turn (its drift is
    2 (u1'^2 / a^2 + u2'^2 / b^2)). k_t = k_min / 2, k_min the smallest first pole any member's
    ellipse row can have (:func:`gain` with another formation at most max_speed), gives
    h' >= -k_t h >= -(k1 / 2) h; and the other formation's twist closing at the same pace, the
    two together close at most at k1 h: the members' first stage holds (each member takes the
    other formation's velocity, not its acceleration). With the single integrator's extended
    class-K (``ellipse_class_k``, k h (1 + h) outside) the twist drove a formation on at full
    speed towards another two or three semi-axes out while the member nearest it braked alone,
    and the formation rows gave way (tests/scenarios/di-three-cross.yaml)."""
    return 0.5 * gain(cp.gamma_formations, _accel(cp), 2.0 * cp.max_speed, cp.period)


def hocbf_row(h: float, hd: float, q: float, g: tuple[float, float], k1: float, dt: float,
              amax: float) -> Row:
    """The row (R):  -g . a <= q + (k1 + k2) h' + k1 k2 h,  normalised; ``hd`` = h',
    ``q`` the drift of h''; outside its first stage the row asks at most restore_share of
    ``amax`` beyond k1 h' (:func:`hocbf_bound`), and never more than :func:`most_asked` in all
    (module docstring, "Outside the first stage")."""
    t = DI_TUNING
    room = t.restore_share * amax * math.hypot(g[0], g[1])
    nx, ny, b = normalized_row(-g[0], -g[1], q + hocbf_bound(h, hd, k1, dt, room))
    return nx, ny, max(b, -most_asked(amax))


def most_asked(amax: float) -> float:
    """[m/s^2] the most braking one row asks: (brake_share + restore_share) amax."""
    return (DI_TUNING.brake_share + DI_TUNING.restore_share) * amax


def circle_terms(p: tuple[float, float], v: tuple[float, float], c: tuple[float, float],
                 w: tuple[float, float], ds: float) -> tuple[float, float, tuple[float, float]]:
    """(h, h', g) of the distance barrier h = |p - c| - ds (eq. 4.5's set, as a distance) for a
    centre c moving at w: g = unit(p - c), h' = g . (v - w). The curvature of h'' is left out
    (module docstring, "Sampling")."""
    dx, dy = p[0] - c[0], p[1] - c[1]
    d = math.hypot(dx, dy)
    if d < 1e-12:
        return -ds, 0.0, (0.0, 0.0)
    gx, gy = dx / d, dy / d
    return d - ds, gx * (v[0] - w[0]) + gy * (v[1] - w[1]), (gx, gy)


def obstacle_hocbf(p, v, o: Obstacle, gamma: float, amax: float, vmax: float,
                 dt: float) -> tuple[float, Row]:
    """A circle (static or moving at constant velocity) of eq. 4.5: (h, row)."""
    h, hd, g = circle_terms(p, v, (o.x, o.y), (o.vx, o.vy), o.ds)
    k = gain(gamma, amax, vmax + math.hypot(o.vx, o.vy), dt)
    return h, hocbf_row(h, hd, 0.0, g, k, dt, amax)


def shape_hocbf(p, v, sh: Shape, gamma: float, amax: float, vmax: float,
              dt: float) -> tuple[float, Row]:
    """A wall or shelf: h = dist(p, shape) - Ds, h' = g . v with g = d dist / dp (a unit
    vector); the shape is convex and still, so (R) holds with q = 0 (module docstring)."""
    d, gx, gy = shape_distance(p[0], p[1], sh)
    h = d - sh.ds
    k = gain(gamma, amax, vmax, dt)
    return h, hocbf_row(h, gx * v[0] + gy * v[1], 0.0, (gx, gy), k, dt, amax)


def band_hocbf(p, v, n: Neighbour, eps: float, k: float, dt: float,
               amax: float) -> tuple[float, float, Row, Row]:
    """One formation edge (eq. 4.3, 4.4, soft): with d = p - p_j, r = v - v_j,
    h_g = |d|^2 - (Df - eps)^2:  h_g' = 2 d . r,  h_g'' = 2 d . a + 2 |r|^2;
    h_l = (Df + eps)^2 - |d|^2:  h_l' = -2 d . r, h_l'' = -2 d . a - 2 |r|^2;
    ``k`` the first pole (the second :func:`second_pole` of it and ``dt``).
    Returns (h_g, h_l, row_g, row_l)."""
    dx, dy = p[0] - n.x, p[1] - n.y
    rx, ry = v[0] - n.vx, v[1] - n.vy
    hg, hl = barriers.formation_h(p[0], p[1], n.x, n.y, n.df, eps)
    dr, r2 = 2.0 * (dx * rx + dy * ry), 2.0 * (rx * rx + ry * ry)
    row_g = hocbf_row(hg, dr, r2, (2.0 * dx, 2.0 * dy), k, dt, amax)
    row_l = hocbf_row(hl, -dr, -r2, (-2.0 * dx, -2.0 * dy), k, dt, amax)
    return hg, hl, row_g, row_l


def ellipse_hocbf(p, v, e: Ellipse, gamma: float, amax: float, vmax: float,
                dt: float) -> tuple[float, Row]:
    """Another formation's ellipse (eq. 4.6), moving at (vx, vy) and turning at alpha_rate = w,
    both taken constant. In its frame u = R(alpha)^T (p - c), h = u1^2/a^2 + u2^2/b^2 - 1; with
    q = R^T (v - c'):  u1' = q1 + w u2,  u2' = q2 - w u1,  and
    u'' = R^T a + w (q2, -q1) + w (u2', -u1'), so
    h' = 2 u1 u1'/a^2 + 2 u2 u2'/b^2,
    h'' = g . a + 2 (u1'^2 + u1 w (q2 + u2'))/a^2 + 2 (u2'^2 - u2 w (q1 + u1'))/b^2,
    g = dh/dp (appendix A.3 (14, 15))."""
    c, s = math.cos(e.alpha), math.sin(e.alpha)
    dx, dy = p[0] - e.cx, p[1] - e.cy
    rx, ry = v[0] - e.vx, v[1] - e.vy
    u1, u2 = c * dx + s * dy, -s * dx + c * dy
    q1, q2 = c * rx + s * ry, -s * rx + c * ry
    w = e.alpha_rate
    d1, d2 = q1 + w * u2, q2 - w * u1
    ia2, ib2 = 1.0 / (e.a * e.a), 1.0 / (e.b * e.b)
    h = u1 * u1 * ia2 + u2 * u2 * ib2 - 1.0
    hd = 2.0 * (u1 * d1 * ia2 + u2 * d2 * ib2)
    q = 2.0 * ((d1 * d1 + u1 * w * (q2 + d2)) * ia2 + (d2 * d2 - u2 * w * (q1 + d1)) * ib2)
    g1, g2 = 2.0 * u1 * ia2, 2.0 * u2 * ib2
    k = gain(gamma, amax, vmax + math.hypot(e.vx, e.vy), dt)
    return h, hocbf_row(h, hd, q, (g1 * c - g2 * s, g1 * s + g2 * c), k, dt, amax)


def separation_hocbf(p, v, q: Partner, dsep: float, gamma: float, amax: float, vmax: float,
                   dt: float) -> tuple[float, Row]:
    """Two bodies kept dsep apart: h = |p - p_j| - dsep, the pair's condition
    g . (a - a_j) >= -B with B = (k1 + k2) h' + k1 k2 h (h' = g . (v - v_j); :func:`hocbf_bound`)
    split in halves: this robot takes g . a >= -B / 2 and its partner, computing the same
    numbers from the same ``state``s, the mirror row; the two rows add up to the pair's
    condition for any two accelerations the two QPs return (the reciprocal split of
    :func:`agent.barriers.separation_row`, here about a = 0). Each robot's share of the braking
    is k1 s / 2 <= brake_share max_accel for closing speeds s <= 2 max_speed, and outside the
    first stage at most restore_share max_accel more."""
    h, hd, g = circle_terms(p, v, (q.x, q.y), (q.vx, q.vy), dsep)
    k = gain(gamma, 2.0 * amax, 2.0 * vmax, dt)
    room = DI_TUNING.restore_share * 2.0 * amax
    return h, normalized_row(-g[0], -g[1], 0.5 * hocbf_bound(h, hd, k, dt, room))


def accel_limit_rows(v: tuple[float, float], u_nom: tuple[float, float], a_nom: tuple[float, float],
               vmax: float, amax: float, dt: float) -> list[Row]:
    """|a| <= amax (a polygon, a vertex along ``a_nom``) and v + a dt inside the speed polygon
    (a vertex along ``u_nom``), each face n . (v + a dt) <= max(face, n . v)."""
    rows = barriers.speed_rows(amax, math.atan2(a_nom[1], a_nom[0]))
    for nx, ny, face in barriers.speed_rows(vmax, math.atan2(u_nom[1], u_nom[0])):
        nv = nx * v[0] + ny * v[1]
        rows.append((nx, ny, max(face - nv, 0.0) / dt))
    return rows


def nominal_accel(u_nom: tuple[float, float], v: tuple[float, float], kp: float,
                  amax: float, c: float = DI_TUNING.nominal_damping) -> tuple[float, float]:
    """a = c kp (u - v), clamped to amax (module docstring, "Nominal"); ``c`` the nominal
    damping (:class:`DITuning`)."""
    ax, ay = c * kp * (u_nom[0] - v[0]), c * kp * (u_nom[1] - v[1])
    n = math.hypot(ax, ay)
    if n > amax:
        ax, ay = ax * amax / n, ay * amax / n
    return ax, ay


def integrate(x: float, y: float, vx: float, vy: float, ax: float, ay: float, dt: float,
              vmax: float) -> tuple[float, float, float, float]:
    """The exact double integrator over ``dt`` under a constant acceleration:
    p + v dt + a dt^2 / 2, v + a dt, the velocity then clipped to vmax (the certified command
    keeps it inside; a fallback may not). The world and the in-process simulator both call it."""
    nvx, nvy = vx + ax * dt, vy + ay * dt
    s = math.hypot(nvx, nvy)
    if s > vmax:
        nvx, nvy = nvx * vmax / s, nvy * vmax / s
    return x + vx * dt + 0.5 * ax * dt * dt, y + vy * dt + 0.5 * ay * dt * dt, nvx, nvy


def brake(vx: float, vy: float, amax: float, dt: float) -> tuple[float, float]:
    """The acceleration that stops a robot moving at (vx, vy) as fast as ``amax`` allows
    (-v / dt, clamped): what a double integrator does without a certified acceleration (a
    zero command, or none; the world applies it and the agent expects it)."""
    ax, ay = -vx / dt, -vy / dt
    n = math.hypot(ax, ay)
    if n > amax:
        ax, ay = ax * amax / n, ay * amax / n
    return ax, ay


def hocbf_rows(cp: ControlParams, point: tuple[float, float], theta: float,
               nominal_u: tuple[float, float], inp: StepInput,
               load: load_rows.MemberLoad | None = None) -> Rows:
    """Every barrier row of the module docstring for a robot at ``point`` moving at
    ``inp.last_u`` (its velocity now), and the limit rows about the nominal acceleration towards
    ``nominal_u`` (the :class:`agent.control.RowBuilder` of double integrators; a double
    integrator has no heading: ``theta`` is not read). A row that no |a| <= max_accel can
    violate (normalised: b >= max_accel) is left out; its h still counts."""
    p, v = point, inp.last_u
    amax, vmax, dt = _accel(cp), cp.max_speed, cp.period
    a_nom = nominal_accel(nominal_u, v, cp.kp, amax)
    limits = accel_limit_rows(v, nominal_u, a_nom, vmax, amax, dt)
    hf, soft = _band_part(cp, p, v, inp.neighbours, amax)
    ho, hs, contact = _contact_part(cp, p, v, inp, amax)
    he, hard = _hazard_part(cp, p, v, inp, amax)
    if load is not None:
        h, rows = load_rows_of(cp, load, inp.obstacles, inp.shapes)
        ho = min(ho, h)
        contact += [row for row in rows if row[2] < amax]
    return Rows(limits, hard, soft, hf, ho, he, hs, contact, a_nom)


def _band_part(cp: ControlParams, p: tuple[float, float], v: tuple[float, float],
               neighbours: Sequence[Neighbour], amax: float) -> tuple[float, list[Row]]:
    """The formation edges' rows (soft) that can be active, and the smallest h."""
    soft: list[Row] = []
    hf = math.inf
    kf = min(cp.gamma_formation, 0.5 / cp.period)  # the first pole (module docstring, "Sampling")
    for n in neighbours:
        hg, hl, rg, rl = band_hocbf(p, v, n, cp.epsilon, kf, cp.period, amax)
        hf = min(hf, hg, hl)
        if rg[2] < amax:
            soft.append(rg)
        if rl[2] < amax:
            soft.append(rl)
    return hf, soft


def _contact_part(cp: ControlParams, p: tuple[float, float], v: tuple[float, float],
                  inp: StepInput, amax: float) -> tuple[float, float, list[Row]]:
    """The circles', walls' and shelves' and the separation rows that can be active, and the
    smallest h of the things and of the separations."""
    vmax, dt = cp.max_speed, cp.period
    contact: list[Row] = []
    ho = hs = math.inf
    for o in inp.obstacles:
        h, row = obstacle_hocbf(p, v, o, cp.gamma_obstacle, amax, vmax, dt)
        ho = min(ho, h)
        if row[2] < amax:
            contact.append(row)
    for sh in inp.shapes:
        h, row = shape_hocbf(p, v, sh, cp.gamma_obstacle, amax, vmax, dt)
        ho = min(ho, h)
        if row[2] < amax:
            contact.append(row)
    for q in inp.partners:
        h, row = separation_hocbf(p, v, q, cp.separation, cp.gamma_formation, amax, vmax, dt)
        hs = min(hs, h)
        if row[2] < amax:
            contact.append(row)
    return ho, hs, contact


def _hazard_part(cp: ControlParams, p: tuple[float, float], v: tuple[float, float],
                 inp: StepInput, amax: float) -> tuple[float, list[Row]]:
    """Other formations' rows (their ellipses, or the all-to-all pairs) that can be active, and
    the smallest h."""
    vmax, dt = cp.max_speed, cp.period
    hard: list[Row] = []
    he = math.inf
    for e in inp.others:
        h, row = ellipse_hocbf(p, v, e, cp.gamma_formations, amax, vmax, dt)
        he = min(he, h)
        if row[2] < amax:
            hard.append(row)
    for nb in inp.pairwise:
        h, row = obstacle_hocbf(p, v, Obstacle(nb.x, nb.y, nb.vx, nb.vy, cp.d_af),
                                cp.gamma_formations, amax, vmax, dt)
        he = min(he, h)
        if row[2] < amax:
            hard.append(row)
    return he, hard


def load_rows_of(cp: ControlParams, load: load_rows.MemberLoad, obstacles: Sequence[Obstacle],
                 shapes: Sequence[Shape]) -> tuple[float, list[Row]]:
    """The load's rows (:mod:`agent.load_rows`) as HOCBFs: with h' = dh/dq . q' +
    sum_k g_k . v_k (the members' velocities now: :attr:`agent.load_rows.Feature.hdot`) the
    condition sum_k g_k . a_k >= -B, B = (k1 + k2) h' + k1 k2 h (:func:`hocbf_bound`; the
    curvature of h'' left out, as for the distances above; k1 = :func:`gain` for a closing speed
    of max_speed plus the thing's) is split in equal shares of acceleration: member i holds
    g_i/|g_i| . a >= -B / S, S = sum_k |g_k| (L.2). Returns (the smallest h, the rows)."""
    amax, vmax, dt = _accel(cp), cp.max_speed, cp.period
    gamma, restore = cp.gamma_obstacle, DI_TUNING.restore_share * amax
    rows: list[Row] = []

    def inactive(h: float, hdot: float, s: float, thing: float) -> bool:  # b = x / S >= amax
        k = gain(gamma, amax, vmax + thing, dt)
        return hocbf_bound(h, hdot, k, dt, restore * s) >= amax * s

    hmin, feats = load_rows.features(load, obstacles, shapes, cp.radius, load_rows.LOAD_CLEAR,
                                     inactive)
    for f in feats:
        gx, gy = f.g[load.member]
        gi = math.hypot(gx, gy)
        if gi < 1e-9:
            continue
        kf = gain(gamma, amax, vmax + f.thing_speed, dt)
        s = sum(math.hypot(g[0], g[1]) for g in f.g)
        rows.append(normalized_row(-gx, -gy, gi * hocbf_bound(f.h, f.hdot, kf, dt, restore * s) / s))
    return hmin, rows


def _accel(cp: ControlParams) -> float:
    if cp.max_accel is None:
        raise ValueError("max_accel: a double integrator needs robot.max_accel")
    return cp.max_accel


def step(cp: ControlParams, rows: Rows, p: tuple[float, float], v: tuple[float, float],
         solve=solve_exact, clock: Callable[[], int] | None = None) -> DIStep:
    """One tick on ``rows`` (:func:`hocbf_rows`): the acceleration closest to the nominal
    (``rows.target``, :func:`nominal_accel` towards the nominal velocity) meeting every row,
    solved by :func:`agent.qp.solve_cbf_qp` (formation rows relaxed if need be, counted; hard
    rows never); with safety off the nominal within the limits."""
    dt = cp.period
    a_nom = rows.target if rows.target is not None else (0.0, 0.0)
    t0 = clock() if clock is not None else 0
    if cp.safety:
        res = solve_cbf_qp(a_nom[0], a_nom[1], rows.limits, rows.hard, rows.soft, solve,
                           rows.contact)
    else:
        a = solve_exact(a_nom[0], a_nom[1], rows.limits) or (0.0, 0.0)
        res = QPResult(a[0], a[1], STATUS_NOMINAL, 0.0, True)
    solve_us = (clock() - t0) * 1e-3 if clock is not None else 0.0
    _, _, vx, vy = integrate(p[0], p[1], v[0], v[1], res.ux, res.uy, dt, cp.max_speed)
    return DIStep(res.ux, res.uy, vx, vy, res.status, res.slack, solve_us)
