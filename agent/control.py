"""One robot's control step: nominal command, barrier rows, QP (thesis eq. 4.12).

:func:`control_step` is the single function the agent process, the in-process simulator and the
tests all call. It takes plain numbers (the robot's pose, its goal, what its neighbours, the
obstacles and its leader told it) and returns the command with the barrier values it saw.

Deadlock tie-break (``keep_right``): two formations meeting head-on, or a formation facing an
obstacle dead ahead, can stall under a pure CBF-QP, because the optimum is symmetric and has no
sideways part. Every member therefore adds the same formation-level vector to its nominal
command, computed only from data all members share (their formation's ellipse and goal
centroid, the other formations' ellipses, the obstacles):

* intended motion relative to each hazard (another formation's ellipse, or an obstacle):
  w = max_speed * g - v_hazard, with g = unit(goal centroid - own centroid), left normal n of w;
* the hazard is "in the way" when it is ahead along w, not beyond the goal along g, and inside
  the corridor |d.n| < own half-width + its half-width + TIEBREAK_MARGIN (half-widths across w:
  the ellipses' supports, an obstacle's Ds), with d = hazard centre - own centroid;
* each such hazard pushes along n, away from the side it lies on; within TIEBREAK_DEAD of the
  centre line it pushes to the right. Using the relative motion makes the rule symmetric:
  two formations meeting head-on see each other on the same side and pass; two crossing at
  right angles on a collision course both turn right of their relative motion, so one passes
  behind the other, as ships do;
* the push fades linearly with the hazard's distance ahead beyond contact (TIEBREAK_RANGE) and
  is scaled to TIEBREAK_GAIN * max_speed.

Because every member adds the same vector, the formation moves sideways as a whole and its
shape is untouched; the barriers still decide what is safe.

Jams (three or more formations locked at an intersection) are broken by priority: a formation
whose centroid has been nearly still for STALL_TIME while away from its goal (:func:`update_stall`,
computed by every member from the same ellipse) backs away for RETREAT_TIME from each nearby
formation whose name sorts before its own (:func:`retreat_command`); the formation with priority
keeps going.

Escape (:func:`escape_command`): a barrier that only lets robots back away cannot outrun a hazard
faster than they are. For each moving obstacle every member computes, from shared data only, the
closest approach of its formation's intended motion (eq. 4.2 on the centroid; zero when parked)
relative to the hazard; if it comes within the hazard's Ds + the members' half-width across its
path + ESCAPE_MARGIN, the formation's nominal becomes one vector for all members: sideways, away
from the hazard's path line, plus the intended motion without its part towards that line, so a
formation gives way rather than crossing ahead of a hazard about as fast as itself. Where that
cannot be done in time, the hard rows meet and the QP returns the least-risk command (counted).

Band (:func:`yield_push`, :func:`band_nominal`; both models, on the control points): formation keeping first,
the goal second. The band broke where one member was pushed by a hard row (another formation's
ellipse coming at it) while the others still drove at their goals: the pushed member alone gives
way, the rest slide along their band rows, the formation shears and its members' rows become
infeasible together (measured: each edge that passed 1.5 epsilon did so while its robots were
``relaxed`` or in ``fallback``). Two rules, both on the nominal command only (the rows, and so
safety, are the same):

* give way as one body: a formation whose ellipse another formation's ellipse comes at, closer
  than YIELD_RANGE between them, adds that formation's approach speed (along the line of their
  centres, faded in with the gap) to every member's nominal: the same vector for all, from
  data all members share, so the whole formation moves off before one member is pushed;
* a member whose own edges have drifted beyond BAND_EASE epsilon blends its nominal from the
  goal's towards moving with its neighbours (their last velocities) and back to each Df,
  wholly from BAND_HOLD epsilon, and takes up its goal again as the edges recover.

Shape (:func:`shape_push`; both models): the rows above hold each member, but nothing held the
formation's shape. A formation given way into a shelf row could close round a round shelf, two
members on each side, where no motion keeps both the band and the shelf's safe distance (a
deadlock); a formation another one came at from two sides was squeezed, as the two give-way
pushes cancelled and each pushing ellipse's rows shoved one member alone. The motion the members
share (eq. 4.2 on the centroid with the formation-level terms above, from shared data only) is
projected, like a CBF-QP of eq. 4.12 on the formation's centre, onto the rows: a static
obstacle's centre stays outside the formation's ellipse (eq. 4.6, which contains every member
with room for a body), and the formation closes on another formation's ellipse no faster than
that one moves away plus gamma times their gap (so one that cannot give way is no longer
pressed). The difference is added to every member's
nominal: the same vector for all, so the formation slides round a shelf, or stops pressing into
a formation that cannot give way, as one body. Only the nominal changes.

Separation (:func:`agent.barriers.separation_row`): every pair of robots that can touch gets a
hard row with a reciprocal split of the pair's slack; see that function for why two robots
acting at once cannot both cross.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, fields
from typing import NamedTuple

from geometry.ellipse import Ellipse, ellipse_terms
from geometry.limits import BURGER_MAX_SPEED, BURGER_MAX_TURN_RATE, BURGER_RADIUS
from geometry.route import ADVANCE_RADIUS
from geometry.shapes import Shape
from scenario import limits as ranges
from scenario.model import METHODS

from . import barriers, body, unicycle
from .barriers import Neighbour, Obstacle, Partner
from .qp import STATUS_NOMINAL, QPResult, Row, normalized_row, solve_cbf_qp, solve_exact

TIEBREAK_MARGIN = 0.15  # [m] corridor half-width beyond both radii
TIEBREAK_DEAD = 0.05  # [m] lateral offsets this small count as dead ahead: keep right
TIEBREAK_RANGE = 2.0  # [m] distance ahead of contact over which the push fades in
TIEBREAK_GAIN = 0.35  # push as a fraction of max speed
STALL_SPEED = 0.02  # [m/s] a formation centroid slower than this is "still"
STALL_TIME = 4.0  # [s] still this long, away from the goal: a jam
STALL_GOAL_DISTANCE = 0.3  # [m] closer than this to its goal centroid a formation is not jammed
RETREAT_TIME = 5.0  # [s] how long a jammed formation backs away
RETREAT_RANGE = 1.0  # [m] beyond touching ellipses, formations that count for the retreat
RETREAT_GAIN = 0.5  # retreat speed as a fraction of max speed
ESCAPE_MIN_SPEED = 0.02  # [m/s] obstacles slower than this are static for the escape rule
ESCAPE_RANGE = 6.0  # [m] moving hazards farther than this from the centroid are ignored
ESCAPE_HORIZON = 20.0  # [s] closest approaches further ahead than this do not count yet
ESCAPE_MARGIN = 0.15  # [m] lateral room beyond the hazard's Ds and the members' half-width
ESCAPE_PAD = 0.02  # [m] the ellipse's pad beyond the members (leader.ellipse derives it so)
ESCAPE_OVERSHOOT = 0.05  # [m] the sideways step aims this far beyond the room needed
ESCAPE_GAIN = 2.0  # [1/s] sideways speed per metre still to clear
SEP_MARGIN = 0.0  # [m] separation rows keep bodies this much beyond touching
YIELD_RANGE = 0.3  # [m] gap between two formations' ellipses over which giving way fades in
SHAPE_RANGE = 1.0  # [m] static obstacles farther than this beyond the ellipse's major axis are left out
BAND_EASE = 0.2  # own edges' error (in epsilon) up to which the nominal is the goal's alone
BAND_HOLD = 0.8  # own edges' error (in epsilon) from which the nominal keeps the band only
BAND_REPAIR_GAIN = 3.0  # [1/s] band-keeping speed per metre of edge error
NARROW_CAP = 0.5  # unicycles: the band on the look-ahead points narrows by at most this x eps
RIGID_LEAD = 1.0  # [s] unicycle formations: the rigid carrot leads the centroid by vmax x this
RIGID_TURN_LEAD = 0.25  # [rad] ... and the orientation by this (it turns at about kp x this)
RIGID_FADE = (0.02, 0.1)  # [rad] remaining turns over which the carrot takes over from the goal
RIGID_LEFT_BIAS = math.radians(20.0)  # a turn within this of 180 degrees goes left (all alike)


#: The range of each number of :class:`ControlParams`: the scenario's (:mod:`scenario.limits`);
#: ``period`` may be a camera's pose period, in the same range as a control period.
PARAM_RANGES: dict[str, ranges.Range] = {
    "kp": ranges.GAIN,
    "gamma_formation": ranges.GAMMA,
    "gamma_obstacle": ranges.GAMMA,
    "gamma_formations": ranges.GAMMA,
    "epsilon": ranges.EPSILON,
    "max_speed": ranges.MAX_SPEED,
    "lookahead": ranges.LOOKAHEAD,
    "max_turn_rate": ranges.MAX_TURN_RATE,
    "d_af": ranges.DISTANCE,
    "period": ranges.DT,
    "radius": ranges.RADIUS,
}


@dataclass(frozen=True)
class ControlParams:
    """The controller's parameters; every number is checked against :data:`PARAM_RANGES` and
    every switch must be a bool (ValueError naming the field) when one is built."""

    kp: float = 2.0  # eq. 4.2
    gamma_formation: float = 1.0
    gamma_obstacle: float = 1.0
    gamma_formations: float = 1.0
    epsilon: float = 0.05  # [m]
    max_speed: float = BURGER_MAX_SPEED  # [m/s]
    unicycle: bool = False
    lookahead: float = 0.05  # [m]
    max_turn_rate: float = BURGER_MAX_TURN_RATE  # [rad/s]
    tiebreak: bool = True
    safety: bool = True  # False: the nominal command, no barriers (to show what happens)
    d_af: float = 0.5  # [m] pairwise distance for the all-to-all baseline (eq. 3.5)
    period: float = 0.05  # [s] control period (sizes the unicycle's discretisation margin)
    radius: float = BURGER_RADIUS  # [m] body radius: separation rows keep bodies 2 r + SEP_MARGIN apart
    band_first: bool = True  # formation keeping first (yield_push, band_nominal)
    shape_clear: bool = True  # static obstacles kept out of the formation's shape (shape_push)
    method: str = "rules"  # scenario.model.METHODS: rules (this module's), thesis, rigid (agent.body)

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            allowed = PARAM_RANGES.get(f.name)
            if allowed is not None:
                ranges.check(value, f.name, allowed)
            elif f.name == "method":
                if value not in METHODS:
                    raise ValueError(f"method: must be one of {', '.join(METHODS)}, got {value!r}")
            elif not isinstance(value, bool):
                raise ValueError(f"{f.name}: must be true or false, got {value!r}")

    @classmethod
    def from_scenario(cls, scenario, safety: bool = True) -> ControlParams:
        r, c = scenario.robot, scenario.controller
        return cls(
            kp=c.kp,
            gamma_formation=c.gamma.formation,
            gamma_obstacle=c.gamma.obstacle,
            gamma_formations=c.gamma.formations,
            epsilon=c.epsilon,
            max_speed=r.max_speed,
            unicycle=r.is_unicycle,
            lookahead=r.lookahead,
            max_turn_rate=r.max_turn_rate,
            tiebreak=c.tiebreak == "keep_right",
            safety=safety,
            d_af=c.d_af if c.d_af is not None else 2.0 * r.radius + 0.25,
            period=scenario.dt,
            radius=r.radius,
            method=c.method,
        )

    @property
    def keeps_band_first(self) -> bool:
        """Whether :func:`yield_push` and :func:`band_nominal` shape the nominal (with barriers
        on; both models). On unicycles they act on the look-ahead points, before
        :func:`agent.unicycle.steer`; with the unicycles' rigid motion (:func:`rigid_target`) they
        took the unicycle runs of `formation montecarlo --n 60` over 1.5 epsilon from 6 to 1
        (seed 7, worst 2.14 -> 1.67) and 7 to 2 (seed 11, worst 2.67 -> 1.73), their least-risk
        ticks from 12 and 90 to 0, and left every unicycle scenario's band as good or better."""
        return self.band_first and self.safety

    @property
    def keeps_shape_clear(self) -> bool:
        """Whether :func:`shape_push` keeps static obstacles out of the formation's ellipse
        (with barriers on; both models)."""
        return self.shape_clear and self.safety

    @property
    def offset(self) -> float:
        """Control point offset from the body centre [m]."""
        return self.lookahead if self.unicycle else 0.0

    @property
    def separation(self) -> float:
        """[m] distance the separation rows keep between two body centres: two radii (for
        unicycles the pair barrier adds l HEADING_SMOOTH, 1 cm for a TurtleBot, which covers
        the look-ahead points' second-order sampling error: :func:`agent.barriers.separation_terms`)."""
        return 2.0 * self.radius + SEP_MARGIN

    @property
    def sampling_margin(self) -> float:
        """[m] extra obstacle clearance for a unicycle's look-ahead point under sampled control.

        Over one period the look-ahead point of a unicycle turning at omega moves off the
        straight line u dt by up to l (omega dt)^2 / 2; the barrier, which assumed s' = u, then
        settles that far divided by gamma dt inside its boundary. Ds grows by that bound at the
        largest turn rate, so the body still keeps Ds (single integrators move exactly: 0)."""
        if not self.unicycle:
            return 0.0
        return 0.5 * self.lookahead * self.max_turn_rate ** 2 * self.period / self.gamma_obstacle


class FormationView(NamedTuple):
    """What every member knows of its own formation, for the tie-break."""

    own: Ellipse  # the formation's ellipse, as its leader estimates it
    goal_x: float  # [m] goal centroid
    goal_y: float
    name: str = ""  # this formation's name (priority: names sort first-come-first)
    other_names: tuple[str, ...] = ()  # names of ``others``, in the same order
    retreating: bool = False  # see update_stall


class Stall(NamedTuple):
    """Per-formation memory of the jam rule (every member keeps an identical copy)."""

    still: float = 0.0  # [s] the formation has been nearly still, away from its goal
    retreat: float = 0.0  # [s] retreat time left


def update_stall(prev: Stall, view: FormationView, dt: float,
                 reach: float = STALL_GOAL_DISTANCE) -> Stall:
    """Jam rule, state part: a formation still for STALL_TIME while farther than ``reach`` from
    its goal (:func:`stall_reach`) retreats for RETREAT_TIME. Uses only what every member shares
    (its formation's ellipse and goal)."""
    own = view.own
    far = math.hypot(view.goal_x - own.cx, view.goal_y - own.cy) > reach
    slow = math.hypot(own.vx, own.vy) < STALL_SPEED
    still = prev.still + dt if (far and slow and prev.retreat <= 0.0) else 0.0
    retreat = max(0.0, prev.retreat - dt)
    if still >= STALL_TIME:
        return Stall(0.0, RETREAT_TIME)
    return Stall(still, retreat)


def stall_reach(p: ControlParams) -> float:
    """[m] how close to the goal the jam rule leaves a still formation alone. The goal it sees
    is the route's current waypoint; the route moves on within ADVANCE_RADIUS of one, so under
    ``method: rigid`` a formation still between that and STALL_GOAL_DISTANCE of a waypoint in a
    doorway (both formations at their own side's) is jammed, not there: the rule counts it."""
    return ADVANCE_RADIUS if p.method == "rigid" else STALL_GOAL_DISTANCE


def retreat_command(view: FormationView, others: Sequence[Ellipse], vmax: float):
    """Jam rule, command part: while retreating, back away from every nearby formation that has
    priority (a name sorting before ours); None when there is none, i.e. we have priority."""
    own = view.own
    rx = ry = 0.0
    for e, name in zip(others, view.other_names, strict=False):
        if not name or name >= view.name:
            continue
        dx, dy = own.cx - e.cx, own.cy - e.cy
        d = math.hypot(dx, dy)
        if d < 1e-9 or d > own.a + e.a + RETREAT_RANGE:
            continue
        rx += dx / d
        ry += dy / d
    n = math.hypot(rx, ry)
    if n < 1e-9:
        return None
    return (RETREAT_GAIN * vmax * rx / n, RETREAT_GAIN * vmax * ry / n)


class StepResult(NamedTuple):
    ux: float  # [m/s] control-point velocity (the certified command)
    uy: float
    v: float  # [m/s] unicycle command (v = |u| for a single integrator)
    omega: float  # [rad/s]
    px: float  # [m] control point this step used
    py: float
    status: str  # see agent.qp: ok, relaxed, fallback, failed, nominal
    slack: float  # [m/s]
    h_formation: float  # smallest barrier value of each kind (inf when there was none)
    h_obstacle: float
    h_formations: float
    nominal_ux: float
    nominal_uy: float
    solve_us: float  # [us] wall time of the QP (with any relaxation)
    h_separation: float = math.inf  # smallest separation barrier value (bodies, all partners)
    escape: bool = False  # the formation-level escape from a moving hazard set the nominal


def nominal(kp: float, x: float, y: float, gx: float, gy: float, vmax: float):
    """eq. 4.2 on the body centre, clamped to the speed limit."""
    ux, uy = kp * (gx - x), kp * (gy - y)
    n = math.hypot(ux, uy)
    if n > vmax:
        ux, uy = ux * vmax / n, uy * vmax / n
    return ux, uy


def rigid_target(goal: tuple[float, float], view: FormationView, x: float, y: float,
                 vmax: float) -> tuple[float, float]:
    """Unicycle formations: this member's target on its formation's rigid path to the goal
    shape, for eq. 4.2 in place of its own goal (body position (x, y)).

    A member going straight for its own goal asks the shape to bend wherever the goal shape is
    turned from the current one (members of a rectangle turning 180 degrees cross each other's
    paths, and a formation that arrives turned round has its members' goal commands opposing
    each other: a deadlock). The edge rows then hold the shape against the nominal at the
    band's edge, and members turn their headings every which way, which swings a unicycle's
    body round its look-ahead point (body edge error <= look-ahead edge error + l |e_i - e_j|).
    Here every member aims at one rigid motion: a carrot pose RIGID_LEAD ahead, the centroid c
    (the ellipse's, eq. 4.7) moved towards the goal centroid G by at most vmax RIGID_LEAD and
    the orientation turned towards the goal shape's by at most RIGID_TURN_LEAD; the target is
    the member's goal offset o = goal - G placed on the carrot pose. The remaining turn is the
    angle from o to the member's offset b - c, the same for every member while the shape holds,
    wrapped so that a turn within RIGID_LEFT_BIAS of 180 degrees goes left for all members
    alike. At the goal pose the target is the goal itself. Between RIGID_FADE[0] and
    RIGID_FADE[1] of remaining turn the target fades from the member's goal to the carrot, so a
    formation with no turn to make (a straight crossing) follows eq. 4.2 on its goals as before."""
    own = view.own
    ox, oy = goal[0] - view.goal_x, goal[1] - view.goal_y
    rx, ry = x - own.cx, y - own.cy
    if math.hypot(ox, oy) < 1e-6 or math.hypot(rx, ry) < 1e-6:
        return goal
    turn = math.atan2(ry, rx) - math.atan2(oy, ox)  # from the goal orientation to the current
    turn = (turn + math.pi + RIGID_LEFT_BIAS) % (2.0 * math.pi) - math.pi - RIGID_LEFT_BIAS
    fade = (abs(turn) - RIGID_FADE[0]) / (RIGID_FADE[1] - RIGID_FADE[0])
    if fade <= 0.0:
        return goal
    left = turn - max(-RIGID_TURN_LEAD, min(RIGID_TURN_LEAD, turn))  # carrot, from the goal's
    dx, dy = view.goal_x - own.cx, view.goal_y - own.cy
    dist = math.hypot(dx, dy)
    lead = vmax * RIGID_LEAD
    if dist > lead:
        cx, cy = own.cx + dx * lead / dist, own.cy + dy * lead / dist
    else:
        cx, cy = view.goal_x, view.goal_y
    c, s = math.cos(left), math.sin(left)
    tx, ty = cx + c * ox - s * oy, cy + s * ox + c * oy
    w = min(1.0, fade)
    return (goal[0] + w * (tx - goal[0]), goal[1] + w * (ty - goal[1]))


def tiebreak_push(
    view: FormationView, others: Sequence[Ellipse], obstacles: Sequence[Obstacle], vmax: float
) -> tuple[float, float]:
    """The formation-level sideways push of the module docstring (same for every member)."""
    own = view.own
    gx, gy = view.goal_x - own.cx, view.goal_y - own.cy
    dist = math.hypot(gx, gy)
    if dist < 1e-6:
        return (0.0, 0.0)
    gx, gy = gx / dist, gy / dist
    px = py = 0.0
    # (x, y, vx, vy, reach, its ellipse: None for an obstacle)
    hazards: list[tuple[float, float, float, float, float, Ellipse | None]] = [
        (e.cx, e.cy, e.vx, e.vy, e.a, e) for e in others]
    hazards += [(o.x, o.y, o.vx, o.vy, o.ds, None) for o in obstacles]
    for hx, hy, hvx, hvy, hr, ell in hazards:
        dx, dy = hx - own.cx, hy - own.cy
        if dx * gx + dy * gy > dist + hr:
            continue  # beyond our goal
        if math.hypot(dx, dy) - (own.a + hr) >= TIEBREAK_RANGE:
            continue  # too far ahead to weigh anything (cheap test before the geometry)
        # Intended motion relative to the hazard: w = vmax g - v_hazard.
        wx, wy = vmax * gx - hvx, vmax * gy - hvy
        wn = math.hypot(wx, wy)
        if wn < 1e-6:
            continue  # moving along with it: nothing to resolve
        wx, wy = wx / wn, wy / wn
        nx, ny = -wy, wx  # left of the relative motion
        along = dx * wx + dy * wy
        lateral = dx * nx + dy * ny
        hw = _half_width(ell, nx, ny) if ell is not None else hr
        reach = _half_width(own, nx, ny) + hw + TIEBREAK_MARGIN
        if along <= 0.0 or abs(lateral) >= reach:
            continue
        contact = own.a + hr  # distance ahead at which the two could touch
        weight = min(1.0, max(0.0, 1.0 - (along - contact) / TIEBREAK_RANGE))
        if -TIEBREAK_DEAD <= lateral <= TIEBREAK_DEAD:
            side = -1.0  # dead ahead: keep right
        else:
            side = -math.copysign(1.0, lateral)  # away from the side the hazard is on
        px += side * weight * nx
        py += side * weight * ny
    n = math.hypot(px, py)
    if n > 1.0:
        px, py = px / n, py / n
    return (px * TIEBREAK_GAIN * vmax, py * TIEBREAK_GAIN * vmax)


def _gap(e: Ellipse, f: Ellipse) -> float:
    """[m] a lower bound on the distance between two ellipses: the distance of their centres
    less both half-widths along the line joining them (negative: they may overlap)."""
    dx, dy = f.cx - e.cx, f.cy - e.cy
    d = math.hypot(dx, dy)
    if d < 1e-9:
        return -(e.b + f.b)
    return d - _half_width(e, dx / d, dy / d) - _half_width(f, dx / d, dy / d)


def _half_width(e: Ellipse, nx: float, ny: float) -> float:
    """Support of the ellipse along the unit direction (nx, ny): its half-width across it."""
    c, s = math.cos(e.alpha), math.sin(e.alpha)
    p, q = nx * c + ny * s, -nx * s + ny * c
    return math.sqrt((e.a * p) ** 2 + (e.b * q) ** 2)


class Rows(NamedTuple):
    """The QP's rows for one tick (all normalised, ``ax * ux + ay * uy <= b``)."""

    limits: list[Row]  # speed (and, for unicycles, turn-rate) limits: never relaxed
    hard: list[Row]  # other formations' ellipses (or pairwise robots): never relaxed
    soft: list[Row]  # formation edges: relaxed by the smallest slack only if infeasible
    h_formation: float  # smallest barrier value of each kind (inf when there is none)
    h_obstacle: float
    h_formations: float
    h_separation: float = math.inf
    contact: Sequence[Row] = ()  # obstacles and body separation: hard, kept in a fallback


def _shape_rows(px: float, py: float, shapes: Sequence[Shape], gamma: float, grow: float,
                reach: float, hard: list[Row]) -> float:
    """Append the rows of the walls and shelves that can be active to ``hard``; the smallest h."""
    hmin = math.inf
    for sh in shapes:
        h, row = barriers.shape_row(px, py, sh, gamma, grow)
        hmin = min(hmin, h)
        if row[2] < reach:
            hard.append(row)
    return hmin


def build_rows(
    p: ControlParams,
    px: float,
    py: float,
    theta: float,
    nominal_u: tuple[float, float],
    neighbours: Sequence[Neighbour] = (),
    obstacles: Sequence[Obstacle] = (),
    others: Sequence[Ellipse] = (),
    view: FormationView | None = None,
    pairwise: Sequence[Neighbour] = (),
    partners: Sequence[Partner] = (),
    last_u: tuple[float, float] = (0.0, 0.0),
    shapes: Sequence[Shape] = (),
) -> Rows:
    """Every barrier row (eq. 4.12b-e with appendix A's velocity terms) and limit row for the
    control point (px, py) of a robot with heading ``theta``.

    A barrier row with b >= the largest speed the limit rows allow can never be active: it is
    left out of the QP (exactly: it cannot change the solution, nor any relaxation, since the
    limits are never relaxed). Its barrier value still counts for the reported minimum."""
    if p.unicycle:
        reach = math.hypot(p.max_speed, p.lookahead * p.max_turn_rate)
    else:
        reach = p.max_speed
    hf, soft = _band_rows(p, px, py, theta, neighbours, reach)
    ho, contact = _contact_rows(p, px, py, obstacles, shapes, reach)
    he, hard = _hazard_rows(p, px, py, others, pairwise, reach)
    hs, sep = _separation_rows(p, px, py, theta, partners, last_u, reach)
    contact += sep
    limit_rows = _limit_rows(p, theta, view, nominal_u)
    return Rows(limit_rows, hard, soft, hf, ho, he, hs, contact)


def _band_rows(p: ControlParams, px: float, py: float, theta: float,
               neighbours: Sequence[Neighbour], reach: float) -> tuple[float, list[Row]]:
    """The formation edges' rows (eq. 4.12b) that can be active, and the smallest h."""
    soft: list[Row] = []
    hf = math.inf
    eps = p.epsilon
    for n in neighbours:
        narrow = 0.0
        if p.unicycle and n.theta is not None:  # the band is meant for the bodies
            narrow = heading_narrowing(theta, n.theta, p.lookahead, eps)
        hg, hl, rg, rl = barriers.formation_rows(px, py, n, eps, p.gamma_formation, narrow)
        hf = min(hf, hg, hl)
        if rg[2] < reach:
            soft.append(rg)
        if rl[2] < reach:
            soft.append(rl)
    return hf, soft


def _contact_rows(p: ControlParams, px: float, py: float, obstacles: Sequence[Obstacle],
                  shapes: Sequence[Shape], reach: float) -> tuple[float, list[Row]]:
    """The obstacles' rows (eq. 4.12c) and the walls' and shelves' that can be active, and the
    smallest h."""
    contact: list[Row] = []
    ho = math.inf
    grow = p.offset + p.sampling_margin
    for o in obstacles:
        if grow:
            o = Obstacle(o.x, o.y, o.vx, o.vy, o.ds + grow)  # the body stays Ds away
        h, row = barriers.obstacle_row(px, py, o, p.gamma_obstacle)
        ho = min(ho, h)
        if row[2] < reach:
            contact.append(row)
    if shapes:  # walls and shelves: the body stays Ds from the shape itself (hard, like circles)
        ho = min(ho, _shape_rows(px, py, shapes, p.gamma_obstacle, grow, reach, contact))
    return ho, contact


def _hazard_rows(p: ControlParams, px: float, py: float, others: Sequence[Ellipse],
                 pairwise: Sequence[Neighbour], reach: float) -> tuple[float, list[Row]]:
    """Other formations' rows (their ellipses, eq. 4.12d, or the all-to-all pairs, eq. 3.5)
    that can be active, and the smallest h."""
    hard: list[Row] = []
    he = math.inf
    for e in others:
        h, row = barriers.ellipse_row(px, py, e, p.gamma_formations)
        he = min(he, h)
        if row[2] < reach:
            hard.append(row)
    for n in pairwise:
        h, row = barriers.pairwise_row(px, py, n, p.d_af, p.gamma_formations)
        he = min(he, h)
        if row[2] < reach:
            hard.append(row)
    return he, hard


def body_df(px: float, py: float, theta: float, n: Neighbour, lookahead: float) -> float:
    """[m] Unicycles: the distance the look-ahead points of the edge (i, j) must have for the
    BODIES to stand Df_ij apart, with the headings as they are (thesis eq. 4.3 and 4.4 on the
    bodies, through the look-ahead points s = b + l e(theta) of section 6.2).

    With d = s_i - s_j and q = l (e_i - e_j), the bodies are |d - q| apart, so the look-ahead
    edge's error against Df_ij + |d| - |d - q| is exactly the body edge's error against Df_ij.
    The formation rows and :func:`band_nominal` measure every unicycle edge against this
    distance, so they hold the bodies where the headings differ. Against Df_ij itself they held
    the look-ahead points: a member turning in place (bodies still) moved its look-ahead point
    by up to 2 l, and the rows and the band's repair then moved its neighbours' bodies after it
    (measured in `formation montecarlo`: look-ahead edges inside the band while the bodies were
    1.6-1.7 epsilon out, at arrival and where one member was pushed round by another
    formation's ellipse row). Without the neighbour's heading the edge keeps Df_ij."""
    if n.theta is None:
        return n.df
    dx, dy = px - n.x, py - n.y
    qx = lookahead * (math.cos(theta) - math.cos(n.theta))
    qy = lookahead * (math.sin(theta) - math.sin(n.theta))
    return n.df + math.hypot(dx, dy) - math.hypot(dx - qx, dy - qy)


def heading_narrowing(theta_i: float, theta_j: float, lookahead: float, eps: float) -> float:
    """[m] how much a unicycle edge's band on the look-ahead points narrows on each side:
    min(l |e_i - e_j|, NARROW_CAP eps).

    The edge is measured against :func:`body_df`, which is exact for the headings of this tick.
    The headings change: members that face apart turn towards one motion (:func:`rigid_target`,
    :func:`agent.unicycle.steer`), and each turn moves a look-ahead point but not its body, which
    moves the body-equivalent distance by up to l |e_i - e_j| (|s_i - s_j| and |b_i - b_j| differ
    by at most that much). The narrowing keeps that much room for the turns still to come.
    Uncapped, the band would be empty once l |e_i - e_j| > eps (members facing 47 degrees apart,
    for a TurtleBot's 5 cm look-ahead and eps = 4 cm), and an empty band relaxes every tick;
    capped at NARROW_CAP eps it keeps at least (1 - NARROW_CAP) eps either side. The headings
    are the members' own and their neighbours' ``state`` (wire version 2)."""
    q = math.hypot(math.cos(theta_i) - math.cos(theta_j), math.sin(theta_i) - math.sin(theta_j))
    return min(lookahead * q, NARROW_CAP * eps)


def _separation_rows(p: ControlParams, px: float, py: float, theta: float,
                     partners: Sequence[Partner], last_u: tuple[float, float],
                     reach: float) -> tuple[float, list[Row]]:
    """The smallest separation barrier value and the hard separation rows that can be active."""
    hs = math.inf
    rows: list[Row] = []
    dsep, gamma, off = p.separation, p.gamma_formation, p.offset
    for q in partners:
        h, gi, gj = barriers.separation_terms((px, py), theta, (q.x, q.y), q.theta, dsep, off)
        row = barriers.separation_row(h, gi, last_u, gj, (q.vx, q.vy), gamma)
        hs = min(hs, h)
        if row[2] < reach:
            rows.append(row)
    return hs, rows


def _limit_rows(p: ControlParams, theta: float, view: FormationView | None,
                nominal_u: tuple[float, float]) -> list[Row]:
    """Speed (and for unicycles turn-rate) limit rows."""
    if p.unicycle:
        return unicycle.limit_rows(theta, p.lookahead, p.max_speed, p.max_turn_rate)
    # Members of a formation share the polygon's orientation (their travel direction), so a
    # neighbour's last velocity is always inside this robot's own speed polygon.
    if view is not None and math.hypot(view.goal_x - view.own.cx, view.goal_y - view.own.cy) > 0.05:
        heading = math.atan2(view.goal_y - view.own.cy, view.goal_x - view.own.cx)
    else:
        heading = math.atan2(nominal_u[1], nominal_u[0])
    return barriers.speed_rows(p.max_speed, heading)


def escape_command(
    p: ControlParams, view: FormationView, obstacles: Sequence[Obstacle],
) -> tuple[float, float] | None:
    """The formation-level escape from moving hazards (module docstring, "Escape"): the same
    vector for every member, or None when no moving hazard threatens the formation."""
    own = view.own
    vmax = p.max_speed
    # The formation's intended motion: eq. 4.2 on the centroid (zero once parked at the goal).
    wx, wy = nominal(p.kp, own.cx, own.cy, view.goal_x, view.goal_y, vmax)
    ex = ey = 0.0
    threat = False
    pad = 2.0 * p.radius + 2.0 * p.offset + p.epsilon + ESCAPE_PAD
    for o in obstacles:
        speed = math.hypot(o.vx, o.vy)
        if speed < ESCAPE_MIN_SPEED:
            continue
        hx, hy = o.vx / speed, o.vy / speed  # the hazard's heading; n its left normal
        nx, ny = -hy, hx
        rx, ry = own.cx - o.x, own.cy - o.y
        along, lat = rx * hx + ry * hy, rx * nx + ry * ny
        half = max(0.0, _half_width(own, nx, ny) - pad)  # members' body centres across its path
        need = o.ds + half + ESCAPE_MARGIN
        if along < -(need + _half_width(own, hx, hy)) or math.hypot(rx, ry) > ESCAPE_RANGE:
            continue  # passed us, or too far to matter yet
        # Closest approach under the intended motion (relative velocity w - v_hazard).
        vx, vy = wx - o.vx, wy - o.vy
        v2 = vx * vx + vy * vy
        tca = max(0.0, -(rx * vx + ry * vy) / v2) if v2 > 1e-12 else 0.0
        miss = math.hypot(rx + vx * tca, ry + vy * tca)
        if miss >= need or tca > ESCAPE_HORIZON:
            continue
        threat = True
        side = math.copysign(1.0, lat) if abs(lat) > TIEBREAK_DEAD else -1.0  # else: its right
        gap = max(0.0, need + ESCAPE_OVERSHOOT - abs(lat))  # aim a little beyond, to get there
        ex += side * nx * gap
        ey += side * ny * gap
        # Keep from the intended motion only what does not carry us towards its path line.
        toward = (wx * nx + wy * ny) * side
        if toward < 0.0:
            wx, wy = wx - toward * side * nx, wy - toward * side * ny
        if abs(lat) < need and wx * hx + wy * hy < 0.0 and along > 0.0:
            par = wx * hx + wy * hy  # still in its path and driving towards it: stop that
            wx, wy = wx - par * hx, wy - par * hy
    if not threat:
        return None
    lx, ly = ESCAPE_GAIN * ex, ESCAPE_GAIN * ey
    ln = math.hypot(lx, ly)
    if ln > vmax:
        return (lx * vmax / ln, ly * vmax / ln)
    # Sideways first; what speed is left goes to the (filtered) intended motion.
    rest = math.sqrt(max(0.0, vmax * vmax - ln * ln))
    wn = math.hypot(wx, wy)
    if wn > rest:
        wx, wy = wx * rest / wn, wy * rest / wn
    return (lx + wx, ly + wy)


def yield_push(view: FormationView, hazards: Sequence[Ellipse]) -> tuple[float, float]:
    """Give way as one body (module docstring, "Band"): the same vector for every member.

    For each other formation whose ellipse moves towards this one's centroid (speed v_n > 0
    along n, the unit vector from its centre to ours) the push is w v_n n, with
    w = clamp(1 - gap / YIELD_RANGE, 0, 1) and gap = |c - c_e| less both ellipses' half-widths
    along n: close by, the formation moves away as fast as the other comes, before the other's
    ellipse row pushes one member alone."""
    own = view.own
    px = py = 0.0
    for e in hazards:
        dx, dy = own.cx - e.cx, own.cy - e.cy
        d = math.hypot(dx, dy)
        if d < 1e-9:
            continue
        nx, ny = dx / d, dy / d
        v_n = e.vx * nx + e.vy * ny
        if v_n <= 0.0:
            continue
        gap = d - _half_width(own, nx, ny) - _half_width(e, nx, ny)
        w = min(1.0, max(0.0, 1.0 - gap / YIELD_RANGE))
        px += w * v_n * nx
        py += w * v_n * ny
    return px, py


def shape_push(
    p: ControlParams, view: FormationView, obstacles: Sequence[Obstacle],
    hazards: Sequence[Ellipse], w: tuple[float, float],
) -> tuple[float, float]:
    """The formation-level barrier on the shared motion (module docstring, "Shape"): the
    correction to add to every member's nominal, the same vector for all.

    ``w`` is the formation-level motion the members follow (computed from shared data); the
    formation is taken to translate rigidly at w (its centre c moves at w). Two kinds of row,
    each the CBF condition dh/dt >= -gamma h of eq. 4.12 on that motion:

    * static obstacles (speed below ESCAPE_MIN_SPEED) stay out of the formation's ellipse:
      h_k = h of eq. 4.6 at obstacle k's centre o_k (negative inside), dh/dc = -dh/dp
      (appendix A.3 (16, 17)), so  dh/dp(o_k) . w <= gamma_obstacle h_k;
    * the formation does not press into another formation's ellipse faster than that one
      moves away: with n the unit vector from c to the other's centre c_e and
      gap = |c_e - c| - both half-widths along n (:func:`_gap`, a lower bound on the
      ellipses' distance), gap' = (v_e - w) . n >= -gamma_formations gap with v_e the other's
      velocity now (its ellipse's: shared data), as the inter-formation rows of eq. 4.12 take
      the other's velocity (appendix A), so  n . w <= v_e . n + gamma_formations gap. A
      formation that cannot give way (squeezed, or pinned against a shelf) is then no longer
      pressed by the one coming at it. Left out where the other is still (slower than
      STALL_SPEED) and its ellipse reaches into ours placed at our goal (a neighbour parked
      next to our goal shape: the members' rows and :func:`yield_push` settle that, as
      before). Measured and not kept (`formation montecarlo --n 60`, seeds 7 and 11): each
      formation taking half of the pair's condition from both velocities, as
      :func:`agent.barriers.separation_row` does for two robots (1 deadlock, worst 2.37
      epsilon), and a steeper gain max_speed / YIELD_RANGE in place of gamma_formations
      (2 deadlocks: a triangle that gave way was followed south of a shelf row it could not
      cross); this rule: 0 deadlocks, worst 0.89 epsilon.

    The correction is w* - w, w* the closest motion to w meeting every row within SHAPE_RANGE
    (:func:`agent.qp.solve_exact`); where the rows cannot all be met, the obstacle rows alone
    are used, and where those cannot be met either the correction is (0, 0) (the members'
    own rows still hold). An obstacle whose centre lies inside the ellipse placed at the
    formation's goal (its current waypoint) is left out: the goal shape is meant to hold it."""
    rows = _shape_obstacle_rows(p, view, obstacles)
    fixed = len(rows)
    rows += _shape_hazard_rows(p, view, hazards)
    if not rows:
        return (0.0, 0.0)
    u = solve_exact(w[0], w[1], rows)
    if u is None and fixed < len(rows):
        u = solve_exact(w[0], w[1], rows[:fixed])
    if u is None:
        return (0.0, 0.0)
    return (u[0] - w[0], u[1] - w[1])


def _shape_obstacle_rows(p: ControlParams, view: FormationView,
                         obstacles: Sequence[Obstacle]) -> list[Row]:
    """:func:`shape_push`'s rows keeping static obstacles out of the formation's ellipse."""
    own = view.own
    rows: list[Row] = []
    for o in obstacles:
        if math.hypot(o.vx, o.vy) >= ESCAPE_MIN_SPEED:
            continue  # moving: the escape rule's
        if math.hypot(o.x - own.cx, o.y - own.cy) > own.a + SHAPE_RANGE:
            continue
        if ellipse_terms(o.x, o.y, view.goal_x, view.goal_y, own.alpha, own.a, own.b)[0] < 0.0:
            continue  # the goal shape holds it
        h, gx, gy, _ = ellipse_terms(o.x, o.y, own.cx, own.cy, own.alpha, own.a, own.b)
        rows.append(normalized_row(gx, gy, p.gamma_obstacle * h))
    return rows


def _shape_hazard_rows(p: ControlParams, view: FormationView,
                       hazards: Sequence[Ellipse]) -> list[Row]:
    """:func:`shape_push`'s rows: no pressing into another formation's ellipse faster than it
    moves away."""
    own = view.own
    rows: list[Row] = []
    for e in hazards:
        dx, dy = e.cx - own.cx, e.cy - own.cy
        d = math.hypot(dx, dy)
        if d < 1e-9:
            continue
        nx, ny = dx / d, dy / d
        gap = d - _half_width(own, nx, ny) - _half_width(e, nx, ny)
        if gap > SHAPE_RANGE:
            continue
        if math.hypot(e.vx, e.vy) < STALL_SPEED and \
                _gap(own._replace(cx=view.goal_x, cy=view.goal_y), e) < 0.0:
            continue  # parked next to our goal shape: the members' rows and yield_push
        rows.append((nx, ny, e.vx * nx + e.vy * ny + p.gamma_formations * gap))
    return rows


def band_nominal(
    p: ControlParams, px: float, py: float, goal_u: tuple[float, float],
    neighbours: Sequence[Neighbour],
) -> tuple[float, float]:
    """Formation keeping first, the goal second: the nominal command of a member whose own
    edges have drifted in their band (module docstring, "Band").

    With e the largest error of the robot's own edges, | |p - p_j| - Df_j | / epsilon, the
    nominal is  s u_goal + (1 - s) (v_nb + k sum_j (|p - p_j| - Df_j) (p_j - p)/|p_j - p|),
    s = clamp((BAND_HOLD - e) / (BAND_HOLD - BAND_EASE), 0, 1), v_nb the mean of the
    neighbours' last velocities (their ``state``), k = BAND_REPAIR_GAIN; clamped to the speed
    limit. The second part moves with the neighbours and back towards each Df (it is the
    negative gradient of 1/2 sum_j (|p - p_j| - Df_j)^2, so with the neighbours still it only
    lowers the edge error). With every own edge within BAND_EASE epsilon the goal's nominal
    (eq. 4.2) is returned unchanged. Only the nominal changes: every barrier row is the same."""
    eps = p.epsilon
    worst = rx = ry = 0.0
    for n in neighbours:
        dx, dy = n.x - px, n.y - py
        d = math.hypot(dx, dy)
        if d < 1e-9:
            continue
        err = d - n.df
        worst = max(worst, abs(err) / eps)
        rx += err * dx / d
        ry += err * dy / d
    s = min(1.0, max(0.0, (BAND_HOLD - worst) / (BAND_HOLD - BAND_EASE)))
    if s >= 1.0:
        return goal_u
    k = len(neighbours)
    fx = sum(n.vx for n in neighbours) / k
    fy = sum(n.vy for n in neighbours) / k
    ux = s * goal_u[0] + (1.0 - s) * (fx + BAND_REPAIR_GAIN * rx)
    uy = s * goal_u[1] + (1.0 - s) * (fy + BAND_REPAIR_GAIN * ry)
    return nominal(1.0, 0.0, 0.0, ux, uy, p.max_speed)


def formation_nominal(p: ControlParams, view: FormationView, obstacles: Sequence[Obstacle],
                      hazards: Sequence[Ellipse], u: tuple[float, float]
                      ) -> tuple[float, float, bool]:
    """A member's nominal ``u`` with the formation-level terms, each the same for every member
    (module docstring): the escape from a moving hazard or the jam rule's retreat (either
    replaces it), else the tie-break push; giving way as one body (``yield_push``); keeping
    static obstacles and other formations out of the shape (``shape_push``, on the shared motion
    ``fw``: eq. 4.2 on the centroid with the same terms). Returns (ux, uy, escaping)."""
    ux, uy = u
    escaping = False
    fw = nominal(p.kp, view.own.cx, view.own.cy, view.goal_x, view.goal_y, p.max_speed)
    if p.tiebreak and p.safety:
        esc = escape_command(p, view, obstacles)
        back = retreat_command(view, hazards, p.max_speed) if view.retreating else None
        if esc is not None:
            ux, uy = fw = esc  # the whole formation steps out of a moving hazard's way
            escaping = True
        elif back is not None:
            ux, uy = fw = back  # the whole formation backs off the same way
        else:
            bx, by = tiebreak_push(view, hazards, obstacles, p.max_speed)
            if bx or by:
                ux, uy = nominal(1.0, 0.0, 0.0, ux + bx, uy + by, p.max_speed)
                fw = nominal(1.0, 0.0, 0.0, fw[0] + bx, fw[1] + by, p.max_speed)
    if p.keeps_band_first and not escaping:
        yx, yy = yield_push(view, hazards)  # give way as one body to a formation coming at us
        if yx or yy:
            ux, uy = nominal(1.0, 0.0, 0.0, ux + yx, uy + yy, p.max_speed)
            fw = nominal(1.0, 0.0, 0.0, fw[0] + yx, fw[1] + yy, p.max_speed)
    if p.keeps_shape_clear:
        sx, sy = shape_push(p, view, obstacles, hazards, fw)  # static obstacles stay out of the shape
        if sx or sy:
            ux, uy = nominal(1.0, 0.0, 0.0, ux + sx, uy + sy, p.max_speed)
    return ux, uy, escaping


def control_step(
    params: ControlParams,
    pose: tuple[float, float, float],
    goal: tuple[float, float],
    neighbours: Sequence[Neighbour] = (),
    obstacles: Sequence[Obstacle] = (),
    others: Sequence[Ellipse] = (),
    view: FormationView | None = None,
    solve=solve_exact,
    pairwise: Sequence[Neighbour] = (),
    partners: Sequence[Partner] = (),
    last_u: tuple[float, float] = (0.0, 0.0),
    hazards: Sequence[Ellipse] | None = None,
    shapes: Sequence[Shape] = (),
    clock: Callable[[], int] | None = None,
    footprint: body.Footprint | None = None,
) -> StepResult:
    """One tick for one robot.

    ``pose`` is the body (x, y, theta); ``neighbours`` carry their control points and last
    velocities with Df; ``obstacles`` carry Ds for the body (the look-ahead offset is added here
    for unicycles); ``others`` are the other formations' ellipses (barrier rows); ``pairwise``
    are robots of other formations in the all-to-all baseline (eq. 3.5 rows instead of
    ellipses); ``partners`` are the robots this one could touch that get a hard separation row
    (every other member of its formation, and in all-to-all every foreign robot), with
    ``last_u`` this robot's own last certified velocity, as its ``state`` told them; ``hazards``
    are the other formations' ellipses for the formation-level rules only (tie-break, jam;
    default: ``others``), so all-to-all keeps those rules without ellipse rows.
    ``shapes`` are the static walls and shelves (Ds from the shape, offset added likewise).
    ``clock`` (e.g. ``time.perf_counter_ns``) times the QP for ``solve_us``; without one the step
    reads no clock and ``solve_us`` is 0. ``footprint``: this member's slot in its formation's
    body, which ``method: rigid`` needs (:func:`rigid_nominal`); ``method: thesis`` is
    eq. 4.2 and the rows alone.
    """
    x, y, theta = pose
    p = params
    off = p.offset
    px, py = (unicycle.control_point(x, y, theta, off) if p.unicycle else (x, y))
    if p.unicycle:  # the band is meant for the bodies: measure each edge there (body_df)
        neighbours = [n._replace(df=body_df(px, py, theta, n, off)) for n in neighbours]
    rules = p.method == "rules"
    target = goal
    if rules and p.unicycle and p.safety and view is not None:  # one rigid motion for all members
        target = rigid_target(goal, view, x, y, p.max_speed)
    ux, uy = nominal(p.kp, x, y, target[0], target[1], p.max_speed)
    if hazards is None:
        hazards = others
    escaping = False
    if view is not None and rules:
        ux, uy, escaping = formation_nominal(p, view, obstacles, hazards, (ux, uy))
    if rules and p.keeps_band_first and not escaping and neighbours:
        ux, uy = band_nominal(p, px, py, (ux, uy), neighbours)  # formation keeping first
    if p.method == "rigid" and p.safety and view is not None and footprint is not None:
        esc = rigid_intent(p, view, obstacles, hazards)
        push = tiebreak_push(view, hazards, obstacles, p.max_speed) if p.tiebreak else (0.0, 0.0)
        ux, uy = rigid_nominal(p, footprint, view, body.Snapshot(obstacles, shapes, hazards),
                                    (px, py), (x, y), goal, push, esc)
        escaping = esc is not None
    if p.unicycle and p.safety and p.method != "thesis":  # turn about the body, then drive
        ux, uy = steered(p, pose, goal, (ux, uy))
    nux, nuy = ux, uy

    rows = build_rows(p, px, py, theta, (ux, uy), neighbours, obstacles, others, view, pairwise,
                      partners, last_u, shapes)
    limits, hard, soft = rows.limits, rows.hard, rows.soft

    t0 = clock() if clock is not None else 0
    if p.safety:
        res = solve_cbf_qp(ux, uy, limits, hard, soft, solve, rows.contact)
    else:
        u = solve_exact(ux, uy, limits) or (0.0, 0.0)
        res = QPResult(u[0], u[1], STATUS_NOMINAL, 0.0, True)
    solve_us = (clock() - t0) * 1e-3 if clock is not None else 0.0

    if p.unicycle:
        v, w = unicycle.to_unicycle(res.ux, res.uy, theta, p.lookahead)
    else:
        v, w = math.hypot(res.ux, res.uy), 0.0
    return StepResult(
        res.ux, res.uy, v, w, px, py, res.status, res.slack, rows.h_formation, rows.h_obstacle,
        rows.h_formations, nux, nuy, solve_us, rows.h_separation, escaping,
    )


def rigid_intent(p: ControlParams, view: FormationView, obstacles: Sequence[Obstacle],
                 hazards: Sequence[Ellipse]) -> tuple[float, float] | None:
    """``method: rigid``: what replaces the centroid's goal motion, with the tie-break on (both are
    formation-level deadlock rules, ``controller.tiebreak``): the escape from a faster hazard
    (:func:`escape_command`), else, while the jam rule says the formation retreats
    (:func:`update_stall`), backing away from the formations that have priority
    (:func:`retreat_command`). The formation QP keeps two bodies apart but has no order: two
    formations that both need one doorway stand still in front of it for ever without it."""
    if not p.tiebreak:
        return None
    esc = escape_command(p, view, obstacles)
    if esc is None and view.retreating:
        esc = retreat_command(view, hazards, p.max_speed)
    return esc


def steered(p: ControlParams, pose: tuple[float, float, float], goal: tuple[float, float],
            w: tuple[float, float]) -> tuple[float, float]:
    """A unicycle's look-ahead nominal for the intended velocity ``w`` (:func:`agent.unicycle.steer`;
    close to its goal it may back up). Under ``method: rigid`` it is never faster than ``w``
    (:func:`agent.unicycle.no_faster`): a member whose intent is a slot correction of millimetres
    turns at the speed of that intent, not at its full turn rate."""
    x, y, theta = pose
    near = math.hypot(goal[0] - x, goal[1] - y) < unicycle.STEER_REVERSE_RANGE
    u = unicycle.steer(w[0], w[1], theta, p.lookahead, p.max_turn_rate, reverse=near)
    if p.method == "rigid":
        u = unicycle.no_faster(u, math.hypot(w[0], w[1]))
    return u


def body_params(cp: ControlParams) -> body.BodyParams:
    """The formation QP's numbers from a member's :class:`agent.control.ControlParams`: the turn
    limit is a unicycle's turn rate (single integrators: none beyond the slots' speeds); the
    load keeps epsilon (how far members sit from their slots) plus the look-ahead offset."""
    return body.BodyParams(
        vmax=cp.max_speed,
        omega_max=cp.max_turn_rate if cp.unicycle else math.inf,
        gamma_obstacle=cp.gamma_obstacle,
        gamma_formations=cp.gamma_formations,
        kp=cp.kp,
        dt=cp.period,
        grow=cp.offset + cp.sampling_margin,
        radius=cp.radius,
        load_margin=cp.epsilon + cp.offset,
    )


def rigid_nominal(cp: ControlParams, fp: body.Footprint, view: FormationView, snap: body.Snapshot,
                  point: body.Point, at: body.Point, target: body.Point,
                  push: body.Point = (0.0, 0.0), intent: body.Point | None = None) -> body.Point:
    """``controller.method: rigid``: a member's nominal from the formation's twist
    (:func:`agent.body.formation_twist`) and its slot (:func:`agent.body.member_nominal`);
    ``point`` is its control point, ``at`` its body position."""
    p = body_params(cp)
    pose, res = body.formation_twist(fp, view.own, (view.goal_x, view.goal_y), snap, p, push, intent)
    return body.member_nominal(fp, pose, res.twist, point, at, target, p, res.goal)
