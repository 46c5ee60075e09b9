"""One robot's control step: nominal command, barrier rows, QP (thesis eq. 4.12).

:func:`control_step` is the single function the agent process, the in-process simulator and the
tests all call. It takes plain numbers (the robot's pose, its goal, what its neighbours, the
obstacles and its leader told it) and returns the command with the barrier values it saw.

The nominal (``controller.method``): ``rigid``, the default, takes each member's nominal from
its formation's rigid motion (:mod:`agent.body`: one small QP over the formation's twist with the
footprint's barrier rows, then the member's slot velocity plus a pull to its slot); ``thesis`` is
eq. 4.2 on the member's own goal alone. Either way the per-robot CBF-QP below, every row as the
thesis has it, is the last safety filter; hard rows are never relaxed to reach a goal.

Three formation-level rules stay, each only shaping the goal motion the formation's QP starts from,
each computed by every member from the same shared data (the formation's ellipse and goal, the
other formations' ellipses, the obstacles); each does what a barrier cannot, as it is about which
safe motion to choose, not which motions are safe:

* keep right (:func:`tiebreak_push`, ``controller.tiebreak: keep_right``): two formations meeting
  head-on, or a formation facing a hazard dead ahead, stall under a CBF-QP, whose optimum is
  symmetric and has no sideways part. Relative to each hazard in the way (ahead along the relative
  motion w = max_speed g - v_hazard, inside the corridor of both half-widths + TIEBREAK_MARGIN) the
  formation is pushed along w's normal, away from the hazard's side (its right within
  TIEBREAK_DEAD of the centre line), faded over TIEBREAK_RANGE, scaled to TIEBREAK_GAIN max_speed.
  Seen from each other two formations head-on push to the same side and pass; two on a collision
  course at right angles both turn right of their relative motion, so one passes behind. Another
  formation whose centre lies past our waypoint (``ahead`` > dist along g) weighs less, by the
  part of its reach before the waypoint, (dist + reach - ahead) / reach: g points at a waypoint
  ``dist`` away, so a step delta sideways turns g by delta / dist and moves the hazard's offset
  by delta (ahead / dist - 1). Up to the waypoint that is against the step (the side chosen is
  kept); past it, with the step, so each push moved the hazard's offset across the dead band's
  edge and the next tick pushed back (route-head-on-aisle: a pair near its waypoint reversed
  its command 32 times in 7 s). A formation past the waypoint is not in the way to it. An
  obstacle keeps its whole weight: a shelf row's circles past a waypoint still push the
  formation off them (faded as well, di-pushed-to-shelves had 8 ticks with a hard row unmet).
* escape (:func:`escape_command`): a barrier that only lets robots back away cannot outrun a
  moving hazard about as fast as they are. For each moving obstacle whose closest approach under
  the formation's intended motion comes within its Ds + the formation's half-width across its
  path + ESCAPE_MARGIN, the intended motion becomes a step sideways, away from the hazard's path
  line, plus what is left of the motion without its part towards that line. Where that cannot be
  done in time, the hard rows meet and the QP returns the least-risk command (counted).
* yield (:func:`yield_command`): formations standing still in each other's way (the stall clock,
  :func:`update_stall`) are a jam whose order no barrier picks; the later name backs away.

Separation (:func:`agent.barriers.separation_row`): every pair of robots that can touch gets a
hard row with a reciprocal split of the pair's slack; see that function for why two robots
acting at once cannot both cross.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, fields
from typing import NamedTuple

from geometry.ellipse import Ellipse
from geometry.limits import BURGER_MAX_SPEED, BURGER_MAX_TURN_RATE, BURGER_RADIUS
from geometry.shapes import Shape, distance_floor
from scenario import limits as ranges
from scenario.model import METHODS, Bounds

from . import accel_limit, barriers, body, double_integrator, load_rows, margins, unicycle
from .barriers import Neighbour, Obstacle, Partner
from .qp import STATUS_NOMINAL, QPResult, Row, solve_exact

TIEBREAK_MARGIN = 0.15  # [m] corridor half-width beyond both radii
TIEBREAK_DEAD = 0.05  # [m] lateral offsets this small count as dead ahead: keep right
TIEBREAK_RANGE = 2.0  # [m] distance ahead of contact over which the push fades in
TIEBREAK_GAIN = 0.35  # push as a fraction of max speed
STALL_SPEED = 0.02  # [m/s] a formation centroid slower than this is "still"
STALL_TIME = 4.0  # [s] still this long, away from the goal: a jam
YIELD_TIME = 5.0  # [s] how long a jammed formation without priority backs away
YIELD_RANGE = 1.0  # [m] beyond touching ellipses, formations that count for yielding
YIELD_GAIN = 0.5  # backing speed as a fraction of max speed
YIELD_EASE = 1.0  # [s] the backing slows to zero over the yield's last this long
STALL_GOAL_DISTANCE = 0.1  # [m] closer than this to its target (goal or waypoint) a formation is not jammed
ESCAPE_MIN_SPEED = 0.02  # [m/s] obstacles slower than this are static for the escape rule
ESCAPE_RANGE = 6.0  # [m] moving hazards farther than this from the centroid are ignored
ESCAPE_HORIZON = 20.0  # [s] closest approaches further ahead than this do not count yet
ESCAPE_MARGIN = 0.15  # [m] lateral room beyond the hazard's Ds and the members' half-width
ESCAPE_PAD = 0.02  # [m] the ellipse's pad beyond the members (leader.ellipse derives it so)
ESCAPE_OVERSHOOT = 0.05  # [m] the sideways step aims this far beyond the room needed
ESCAPE_GAIN = 2.0  # [1/s] sideways speed per metre still to clear
SEP_MARGIN = 0.0  # [m] separation rows keep bodies this much beyond touching
NARROW_CAP = 0.5  # unicycles: the band on the look-ahead points narrows by at most this x eps


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
    "max_accel": ranges.MAX_ACCEL,
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
    method: str = "rigid"  # scenario.model.METHODS: rigid (agent.body) or thesis (eq. 4.2 alone)
    double_integrator: bool = False  # input acceleration (agent.double_integrator)
    max_accel: float | None = None  # [m/s^2] None: no acceleration limit
    bounds: Bounds = Bounds()  # declared sensing and motor bounds: margins (agent.margins)

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            allowed = PARAM_RANGES.get(f.name)
            if f.name == "max_accel" and value is None:
                continue
            if allowed is not None:
                ranges.check(value, f.name, allowed)
            elif f.name == "method":
                if value not in METHODS:
                    raise ValueError(f"method: must be one of {', '.join(METHODS)}, got {value!r}")
            elif f.name == "bounds":
                if not isinstance(value, Bounds):
                    raise ValueError(f"bounds: must be a Bounds, got {value!r}")
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
            double_integrator=r.is_double_integrator,
            max_accel=r.max_accel,
            bounds=c.bounds,
        )

    @property
    def offset(self) -> float:
        """Control point offset from the body centre [m]."""
        return self.lookahead if self.unicycle else 0.0

    @property
    def separation(self) -> float:
        """[m] distance the separation rows keep between two body centres: two radii (for
        unicycles the pair barrier adds l HEADING_SMOOTH, 1 cm for a TurtleBot, which covers
        the look-ahead points' second-order sampling error: :func:`agent.barriers.separation_terms`);
        each pair adds its margin for the declared bounds (:meth:`pair_margin`)."""
        return 2.0 * self.radius + SEP_MARGIN

    @property
    def margin(self) -> float:
        """[m] this robot's margin for its declared bounds (:func:`agent.margins.robot_margin`;
        0.0 without bounds): obstacles, walls and shelves keep it beyond Ds."""
        return margins.robot_margin(self.bounds, self.max_speed, self.offset)

    def pair_margin(self, u: tuple[float, float], v: tuple[float, float]) -> float:
        """[m] the margin for the declared bounds between this robot (last velocity ``u``)
        and a robot or formation moving at ``v`` (:func:`agent.margins.pair_margin`; 0.0
        without bounds)."""
        return margins.pair_margin(self.bounds, math.hypot(u[0] - v[0], u[1] - v[1]),
                                   self.offset)

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
    yielding: float = 0.0  # [s] the stall clock says jammed, yield this long still (update_stall)
    goal_heading: float | None = None  # [rad] the current waypoint's heading (the goal shape's turn)
    arriving: bool = True  # the target is where the member settles (not a waypoint passed)


class Stall(NamedTuple):
    """How long the formation has been nearly still away from its goal, and how long it still
    yields (every member keeps an identical copy; the leader reports ``stalled`` from it)."""

    still: float = 0.0  # [s]
    yielding: float = 0.0  # [s] left


def update_stall(prev: Stall, view: FormationView, dt: float) -> Stall:
    """The stall clock: it runs while the formation's centroid is slower than STALL_SPEED
    farther than STALL_GOAL_DISTANCE from its target, from what every member shares (its
    formation's ellipse and target); still for STALL_TIME, the formation yields for YIELD_TIME
    (:func:`yield_command`), and the clock starts again after the yield."""
    own = view.own
    far = math.hypot(view.goal_x - own.cx, view.goal_y - own.cy) > STALL_GOAL_DISTANCE
    slow = math.hypot(own.vx, own.vy) < STALL_SPEED
    still = prev.still + dt if far and slow and prev.yielding <= 0.0 else 0.0
    if still >= STALL_TIME:
        return Stall(0.0, YIELD_TIME)
    return Stall(still, max(0.0, prev.yielding - dt))


def yield_command(view: FormationView, others: Sequence[Ellipse], vmax: float
                  ) -> tuple[float, float] | None:
    """A jam (two formations in a doorway, three or more at a crossing: no barrier picks who
    goes first) is broken by priority: a yielding formation backs away from every nearby
    formation whose name sorts before its own, at YIELD_GAIN vmax; None when there is none (it
    has priority and keeps going). Over its last YIELD_EASE seconds the backing slows to zero
    (an instant turn back to the goal was a reversal of every member's command)."""
    own = view.own
    rx = ry = 0.0
    for e, name in zip(others, view.other_names, strict=False):
        if not name or name >= view.name:
            continue
        dx, dy = own.cx - e.cx, own.cy - e.cy
        d = math.hypot(dx, dy)
        if d < 1e-9 or d > own.a + e.a + YIELD_RANGE:
            continue
        rx += dx / d
        ry += dy / d
    n = math.hypot(rx, ry)
    if n < 1e-9:
        return None
    speed = YIELD_GAIN * vmax * min(1.0, view.yielding / YIELD_EASE)
    return (speed * rx / n, speed * ry / n)


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
    ax: float = 0.0  # [m/s^2] double integrators: the certified acceleration (ux, uy: the
    ay: float = 0.0  # velocity it gives at the end of the tick, what ``state`` carries)


def nominal(kp: float, x: float, y: float, gx: float, gy: float, vmax: float):
    """eq. 4.2 on the body centre, clamped to the speed limit."""
    ux, uy = kp * (gx - x), kp * (gy - y)
    n = math.hypot(ux, uy)
    if n > vmax:
        ux, uy = ux * vmax / n, uy * vmax / n
    return ux, uy


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
        ahead = dx * gx + dy * gy  # the hazard's centre along the way to our waypoint
        if ahead >= dist + hr:
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
        if ell is not None:  # another formation: only the part of it before our waypoint counts
            weight *= min(1.0, (dist + hr - ahead) / hr)
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
    """Append the rows of the walls and shelves that can be active to ``hard``; the smallest h.
    A shape's bounding circle bounds its h from below: a shape whose bound is at least
    reach / gamma has no active row, and is measured only if its bound lies below the smallest
    h of the others (the same rows, in the same order, and the same h as measuring all)."""
    hmin = math.inf
    later = []
    for sh in shapes:
        low = distance_floor(px, py, sh) - sh.ds - grow
        if gamma * low >= reach:
            later.append((low, sh))
            continue
        h, row = barriers.shape_row(px, py, sh, gamma, grow)
        hmin = min(hmin, h)
        if row[2] < reach:
            hard.append(row)
    for low, sh in later:
        if low < hmin:
            hmin = min(hmin, barriers.shape_row(px, py, sh, gamma, grow)[0])
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
    load: load_rows.MemberLoad | None = None,
) -> Rows:
    """Every barrier row (eq. 4.12b-e with appendix A's velocity terms) and limit row for the
    control point (px, py) of a robot with heading ``theta``.

    A barrier row with b >= the largest speed the limit rows allow can never be active: it is
    left out of the QP (exactly: it cannot change the solution, nor any relaxation, since the
    limits are never relaxed). Its barrier value still counts for the reported minimum.
    ``load``: this member's formation's load (:func:`agent.load_rows.member_load`): its rows
    (:mod:`agent.load_rows`) are contact rows, their barrier counted with the obstacles'."""
    if p.unicycle:
        reach = math.hypot(p.max_speed, p.lookahead * p.max_turn_rate)
    else:
        reach = p.max_speed
    hf, soft = _band_rows(p, px, py, theta, neighbours, reach, last_u)
    ho, contact = _contact_rows(p, px, py, obstacles, shapes, reach)
    he, hard = _hazard_rows(p, px, py, others, pairwise, reach, last_u)
    hs, sep = _separation_rows(p, px, py, theta, partners, last_u, reach)
    contact += sep
    if load is not None:
        hl, lrows = load_rows.load_rows(load, obstacles, shapes, p.radius, load_rows.LOAD_CLEAR
                                        + p.sampling_margin + p.margin, p.gamma_obstacle, reach)
        ho = min(ho, hl)
        contact += lrows
    limit_rows = _limit_rows(p, theta, view, nominal_u)
    return Rows(limit_rows, hard, soft, hf, ho, he, hs, contact)


def _band_rows(p: ControlParams, px: float, py: float, theta: float,
               neighbours: Sequence[Neighbour], reach: float,
               last_u: tuple[float, float] = (0.0, 0.0)) -> tuple[float, list[Row]]:
    """The formation edges' rows (eq. 4.12b) that can be active, and the smallest h. With
    declared bounds the band narrows by the pair's margin (:meth:`ControlParams.pair_margin`:
    the edge is measured with both ends' errors), with the unicycles' heading narrowing at most
    NARROW_CAP epsilon in all, so the band is never empty."""
    soft: list[Row] = []
    hf = math.inf
    eps = p.epsilon
    for n in neighbours:
        narrow = 0.0
        if p.unicycle and n.theta is not None:  # the band is meant for the bodies
            narrow = heading_narrowing(theta, n.theta, p.lookahead, eps)
        if p.bounds.declared:
            narrow = min(narrow + p.pair_margin(last_u, (n.vx, n.vy)), NARROW_CAP * eps)
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
    grow = p.offset + p.sampling_margin + p.margin
    for o in obstacles:
        if grow:  # the body stays Ds away; a moving obstacle is seen through the camera too
            seen = margins.moving_obstacle_margin(p.bounds, math.hypot(o.vx, o.vy))
            o = Obstacle(o.x, o.y, o.vx, o.vy, o.ds + grow + seen)
        h, row = barriers.obstacle_row(px, py, o, p.gamma_obstacle)
        ho = min(ho, h)
        if row[2] < reach:
            contact.append(row)
    if shapes:  # walls and shelves: the body stays Ds from the shape itself (hard, like circles)
        ho = min(ho, _shape_rows(px, py, shapes, p.gamma_obstacle, grow, reach, contact))
    return ho, contact


def _hazard_rows(p: ControlParams, px: float, py: float, others: Sequence[Ellipse],
                 pairwise: Sequence[Neighbour], reach: float,
                 last_u: tuple[float, float] = (0.0, 0.0)) -> tuple[float, list[Row]]:
    """Other formations' rows (their ellipses, eq. 4.12d, or the all-to-all pairs, eq. 3.5)
    that can be active, and the smallest h; each grown by the pair's margin for the declared
    bounds (this robot's and the other's members' errors: :meth:`ControlParams.pair_margin`)."""
    hard: list[Row] = []
    he = math.inf
    for e in others:
        grow = p.pair_margin(last_u, (e.vx, e.vy))
        if grow:
            a, b = margins.grown_axes(e.a, e.b, grow)
            e = e._replace(a=a, b=b)
        h, row = barriers.ellipse_row(px, py, e, p.gamma_formations)
        he = min(he, h)
        if row[2] < reach:
            hard.append(row)
    for n in pairwise:
        grow = p.pair_margin(last_u, (n.vx, n.vy))
        h, row = barriers.pairwise_row(px, py, n, p.d_af + grow, p.gamma_formations)
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
    gamma, off = p.gamma_formation, p.offset
    for q in partners:
        dsep = p.separation + p.pair_margin(last_u, (q.vx, q.vy))
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
    ``last_u`` this robot's own last certified velocity, as its ``state`` told them (for a
    double integrator its velocity now: :mod:`agent.double_integrator`); ``hazards``
    are the other formations' ellipses for the formation's motion only (its QP and the
    tie-break; default: ``others``), so all-to-all keeps them without ellipse rows.
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
    ux, uy = nominal(p.kp, x, y, goal[0], goal[1], p.max_speed)
    if hazards is None:
        hazards = others
    escaping = False
    aim = None
    if p.method == "rigid" and p.safety and view is not None and footprint is not None:
        esc = escape_command(p, view, obstacles) if p.tiebreak else None  # a faster hazard
        if esc is None and p.tiebreak and view.yielding:  # a jam: the later name backs off
            esc = yield_command(view, hazards, p.max_speed)
        push = tiebreak_push(view, hazards, obstacles, p.max_speed) if p.tiebreak else (0.0, 0.0)
        (ux, uy), aim = rigid_nominal(p, footprint, view, body.Snapshot(obstacles, shapes, hazards),
                                      (px, py), (x, y), goal, push, esc)
        escaping = esc is not None
    if p.unicycle and p.safety and p.method != "thesis":  # turn about the body, then drive
        near = math.hypot(goal[0] - x, goal[1] - y) < unicycle.STEER_REVERSE_RANGE
        lead = 1.0 / body.band_gain(p.kp, p.period)  # where the slot's pull aims the point
        turning = unicycle.to_unicycle(last_u[0], last_u[1], theta, p.lookahead)[1]
        ux, uy = unicycle.steer(ux, uy, theta, p.lookahead, p.max_turn_rate, reverse=near, lead=lead,
                                turning=turning, aim=aim)
    nux, nuy = ux, uy
    load = (load_rows.member_load(footprint, pose, last_u, partners, off, p.unicycle)
            if p.method == "rigid" and p.safety and footprint is not None else None)
    if p.double_integrator:  # the same nominal, as an acceleration under relative-degree-2 rows
        d = double_integrator.step(p, (x, y), last_u, (ux, uy), double_integrator.Inputs(
            neighbours, obstacles, others, pairwise, partners, shapes, load), solve, clock)
        return StepResult(d.vx, d.vy, math.hypot(d.vx, d.vy), 0.0, x, y, d.status, d.slack,
                          d.h_formation, d.h_obstacle, d.h_formations, nux, nuy, d.solve_us,
                          d.h_separation, escaping, d.ax, d.ay)

    rows = build_rows(p, px, py, theta, (ux, uy), neighbours, obstacles, others, view, pairwise,
                      partners, last_u, shapes, load)
    limits, hard, soft = rows.limits, rows.hard, rows.soft

    t0 = clock() if clock is not None else 0
    if p.safety:  # with a unicycle's acceleration rows where it has max_accel (agent.accel_limit)
        res = accel_limit.solve(ux, uy, limits, hard, soft, rows.contact, accel_limit.accel_rows(
            last_u, (ux, uy), p.max_accel, p.period), solve)
    else:
        u = solve_exact(ux, uy, limits) or (0.0, 0.0)
        res = QPResult(u[0], u[1], STATUS_NOMINAL, 0.0, True)
    solve_us = (clock() - t0) * 1e-3 if clock is not None else 0.0

    v, w = (unicycle.to_unicycle(res.ux, res.uy, theta, p.lookahead) if p.unicycle
            else (math.hypot(res.ux, res.uy), 0.0))
    return StepResult(
        res.ux, res.uy, v, w, px, py, res.status, res.slack, rows.h_formation, rows.h_obstacle,
        rows.h_formations, nux, nuy, solve_us, rows.h_separation, escaping,
    )


def body_params(cp: ControlParams) -> body.BodyParams:
    """The formation QP's numbers from a member's :class:`agent.control.ControlParams`: the turn
    limit is a unicycle's turn rate (single integrators: none beyond the slots' speeds); the
    load keeps epsilon (how far members sit from their slots) plus the look-ahead offset; a
    unicycle formation's heading spread is epsilon / l (:func:`agent.body.spread_rows`). A
    formation of double integrators plans its ellipse rows at the pace its members' own
    relative-degree-2 rows keep (:func:`agent.double_integrator.twist_gamma`), so no member
    brakes alone for another formation while the twist drives the others on; and its load
    keeps max_speed dt more: a double integrator's velocity is part of its state, so a velocity
    the twist asks for takes hold only over the next period, in which the members, and the load
    fitted to them, can still move up to max_speed dt beyond what the twist's load rows allowed
    (montecarlo --model double_integrator seeds 7 and 11: 4 loads into shelves, up to 223 mm
    deep, and a deadlock in 400 runs before; 1 load, 0 deadlocks after)."""
    di = cp.double_integrator
    return body.BodyParams(
        vmax=cp.max_speed,
        omega_max=cp.max_turn_rate if cp.unicycle else math.inf,
        gamma_obstacle=cp.gamma_obstacle,
        gamma_formations=double_integrator.twist_gamma(cp) if di else cp.gamma_formations,
        linear_ellipses=di,
        kp=cp.kp,
        dt=cp.period,
        grow=cp.offset + cp.sampling_margin + cp.margin,
        radius=cp.radius,
        load_margin=cp.epsilon + cp.offset + (cp.max_speed * cp.period if di else 0.0),
        spread=cp.epsilon / cp.offset if cp.unicycle else math.inf,
    )


def rigid_nominal(cp: ControlParams, fp: body.Footprint, view: FormationView, snap: body.Snapshot,
                  point: body.Point, at: body.Point, target: body.Point,
                  push: body.Point = (0.0, 0.0), intent: body.Point | None = None
                  ) -> tuple[body.Point, body.Point | None]:
    """``controller.method: rigid``: a member's nominal from the formation's twist
    (:func:`agent.body.formation_twist`) and its slot (:func:`agent.body.member_nominal`);
    ``point`` is its control point, ``at`` its body position."""
    p = body_params(cp)
    turn = None if view.goal_heading is None else fp.goal_turn + view.goal_heading
    pose, res = body.formation_twist(fp, view.own, (view.goal_x, view.goal_y), snap, p, push, intent,
                                     turn)
    nominal = body.member_nominal(fp, pose, res.twist, point, at, target, p, res.goal,
                                  view.arriving)
    if res.aim is None:
        return nominal, None
    slot = body.place(pose, fp.slots[fp.member])
    return nominal, body.point_velocity(pose, res.aim, slot)  # the slot's motion once faced
