"""One robot's control step: nominal command, barrier rows, QP (thesis eq. 4.12).

:class:`Controller` is what the agent process, the in-process simulator and the tests all use:
made once from the robot's parameters (:class:`agent.params.ControlParams`), its solver, an
optional clock and the rules' tuning (:class:`ControlTuning`), and called once a tick with one
:class:`agent.params.StepInput` (plain numbers: the robot's pose, its goal, what its neighbours,
the obstacles and its leader told it); it returns one :class:`StepResult`, the command with the
barrier values it saw. Each robot model has one row builder (:class:`RowBuilder`): velocity rows
for single integrators and unicycles (:func:`build_rows`), acceleration rows for double
integrators (:func:`agent.double_integrator.hocbf_rows`).

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
  motion w = max_speed g - v_hazard, inside the corridor of both half-widths + ``margin``) the
  formation is pushed along w's normal, away from the hazard's side (its right within ``dead``
  of the centre line), faded over ``range``, scaled to ``gain`` max_speed (:class:`TiebreakTuning`).
  Seen from each other two formations head-on push to the same side and pass; two on a collision
  course at right angles both turn right of their relative motion, so one passes behind. Another
  formation whose centre lies past our waypoint (``ahead`` > dist along g) weighs less, by the
  part of its reach before the waypoint, (dist + reach - ahead) / reach: g points at a waypoint
  ``dist`` away, so a step delta sideways turns g by delta / dist and moves the hazard's offset
  by delta (ahead / dist - 1). Up to the waypoint that is against the step (the side chosen is
  kept); past it, with the step, so each push moved the hazard's offset across the dead band's
  edge and the next tick pushed back (a pair near its waypoint reversed its command tick after
  tick in tests/scenarios/route-head-on-aisle.yaml). A formation past the waypoint is not in the way to it. An
  obstacle keeps its whole weight: a shelf row's circles past a waypoint still push the
  formation off them (faded as well: tests/scenarios/di-pushed-to-shelves.yaml).
* escape (:func:`escape_command`): a barrier that only lets robots back away cannot outrun a
  moving hazard about as fast as they are. For each moving obstacle whose closest approach under
  the formation's intended motion comes within its Ds + the formation's half-width across its
  path + ``margin`` (:class:`EscapeTuning`), the intended motion becomes a step sideways, away
  from the hazard's path line, plus what is left of the motion without its part towards that
  line. Where that cannot be
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
from dataclasses import dataclass
from typing import NamedTuple, Protocol

from geometry.ellipse import Ellipse
from geometry.shapes import Shape, distance_floor

from . import accel_limit, barriers, body, double_integrator, load_rows, margins, unicycle
from .barriers import Neighbour, Obstacle, Partner
from .params import PARAM_RANGES as PARAM_RANGES
from .params import ROW_TUNING, ControlParams, FormationView, Stall, StepInput
from .params import RowTuning as RowTuning
from .qp import STATUS_NOMINAL, QPResult, Row, Rows, solve_exact


@dataclass(frozen=True, slots=True)
class TiebreakTuning:
    """Keep right (:func:`tiebreak_push`)."""

    margin: float = 0.15  # [m] corridor beyond both radii: wider steers round more hazards, narrower fewer
    dead: float = 0.05  # [m] offsets this small are dead ahead (keep right): wider decides more meetings
    range: float = 2.0  # [m] the push fades in over this before contact: longer turns aside earlier
    gain: float = 0.35  # push / max speed: stronger passes wider, weaker bends the path less


@dataclass(frozen=True, slots=True)
class StallTuning:
    """The stall clock (:func:`update_stall`) and the yield (:func:`yield_command`)."""

    speed: float = 0.02  # [m/s] a centroid slower than this is still: higher counts crawls as jams
    time: float = 4.0  # [s] still this long is a jam: shorter yields sooner, longer waits for it to clear
    goal_distance: float = 0.1  # [m] nearer its target a formation is not jammed: wider ignores more
    yield_time: float = 5.0  # [s] the yield's length: longer frees more room, shorter loses less ground
    yield_range: float = 1.0  # [m] beyond touching ellipses, formations that count: wider yields to more
    yield_gain: float = 0.5  # backing speed / max speed: faster frees the way sooner, slower jerks less
    yield_ease: float = 1.0  # [s] the backing eases to zero over this: longer is a softer turn back


@dataclass(frozen=True, slots=True)
class EscapeTuning:
    """The escape from moving hazards (:func:`escape_command`)."""

    min_speed: float = 0.02  # [m/s] slower obstacles are static (barriers alone): lower escapes crawlers
    range: float = 6.0  # [m] farther hazards are ignored: longer starts sooner, on more false alarms
    horizon: float = 20.0  # [s] later closest approaches do not count yet: longer reacts earlier
    margin: float = 0.15  # [m] room beyond Ds and the half-width: more clears wider, stepping farther
    pad: float = 0.02  # [m] the ellipse's pad beyond the members (as leader.ellipse derives it)
    overshoot: float = 0.05  # [m] the step aims this far beyond the room needed: more gets there sooner
    gain: float = 2.0  # [1/s] sideways speed per metre to clear: higher steps faster, less speed onward


@dataclass(frozen=True, slots=True)
class ControlTuning:
    """The formation rules' tuning a :class:`Controller` is made with."""

    tiebreak: TiebreakTuning = TiebreakTuning()
    stall: StallTuning = StallTuning()
    escape: EscapeTuning = EscapeTuning()


TUNING = ControlTuning()


def update_stall(prev: Stall, view: FormationView, dt: float, t: StallTuning = TUNING.stall
                 ) -> Stall:
    """The stall clock: it runs while the formation's centroid is slower than ``t.speed``
    farther than ``t.goal_distance`` from its target, from what every member shares (its
    formation's ellipse and target); still for ``t.time``, the formation yields for
    ``t.yield_time`` (:func:`yield_command`), and the clock starts again after the yield.

    Why: formations standing still in each other's way are a jam no barrier resolves; the clock
    is how every member agrees, from the same shared data, that they are in one.
    Pinned by tests/scenarios/yield-hexagon-triangle.yaml."""
    own = view.own
    far = math.hypot(view.goal_x - own.cx, view.goal_y - own.cy) > t.goal_distance
    slow = math.hypot(own.vx, own.vy) < t.speed
    still = prev.still + dt if far and slow and prev.yielding <= 0.0 else 0.0
    if still >= t.time:
        return Stall(0.0, t.yield_time)
    return Stall(still, max(0.0, prev.yielding - dt))


def yield_command(view: FormationView, others: Sequence[Ellipse], vmax: float,
                  t: StallTuning = TUNING.stall) -> tuple[float, float] | None:
    """A jam (two formations in a doorway, three or more at a crossing: no barrier picks who
    goes first) is broken by priority: a yielding formation backs away from every nearby
    formation whose name sorts before its own, at ``t.yield_gain`` vmax, unless that formation
    is parked at its goal (``view.parked``); None when there is none (it has priority and keeps
    going). Over its last ``t.yield_ease`` seconds the backing slows to zero (an instant turn
    back to the goal was a reversal of every member's command).

    Why: a jam's order is not a safety question, so no barrier picks it; a fixed priority by
    name does, the same on every member. A formation parked at its goal holds there: backing
    away from it frees no way, and a formation that crawls past it with its rows intact
    (tests/scenarios/door-gamma005-four-unicycle.yaml) would back off again and again.
    Pinned by tests/scenarios/yield-hexagon-triangle.yaml."""
    own = view.own
    rx = ry = 0.0
    parked = view.parked
    for e, name in zip(others, view.other_names, strict=False):
        if not name or name >= view.name or name in parked:
            continue
        dx, dy = own.cx - e.cx, own.cy - e.cy
        d = math.hypot(dx, dy)
        if d < 1e-9 or d > own.a + e.a + t.yield_range:
            continue
        rx += dx / d
        ry += dy / d
    n = math.hypot(rx, ry)
    if n < 1e-9:
        return None
    speed = t.yield_gain * vmax * min(1.0, view.yielding / t.yield_ease)
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
    view: FormationView, others: Sequence[Ellipse], obstacles: Sequence[Obstacle], vmax: float,
    t: TiebreakTuning = TUNING.tiebreak,
) -> tuple[float, float]:
    """Keep right: the formation-level sideways push of the module docstring (same for every
    member).

    Why: the CBF-QP's optimum for two formations head-on, or one facing a hazard dead ahead, is
    symmetric and has no sideways part, so they stall; a push to one agreed side breaks the
    symmetry. Pinned by tests/scenarios/head-on-rectangles.yaml."""
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
        if math.hypot(dx, dy) - (own.a + hr) >= t.range:
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
        reach = _half_width(own, nx, ny) + hw + t.margin
        if along <= 0.0 or abs(lateral) >= reach:
            continue
        contact = own.a + hr  # distance ahead at which the two could touch
        weight = min(1.0, max(0.0, 1.0 - (along - contact) / t.range))
        if ell is not None:  # another formation: only the part of it before our waypoint counts
            weight *= min(1.0, (dist + hr - ahead) / hr)
        if -t.dead <= lateral <= t.dead:
            side = -1.0  # dead ahead: keep right
        else:
            side = -math.copysign(1.0, lateral)  # away from the side the hazard is on
        px += side * weight * nx
        py += side * weight * ny
    n = math.hypot(px, py)
    if n > 1.0:
        px, py = px / n, py / n
    return (px * t.gain * vmax, py * t.gain * vmax)


def shared_push(view: FormationView, others: Sequence[Ellipse], obstacles: Sequence[Obstacle],
                vmax: float, t: TiebreakTuning = TUNING.tiebreak) -> tuple[float, float]:
    """:func:`tiebreak_push`, remembered per formation (by its goal) with its inputs: every
    member works out the same push from the same shared data (its ellipse and goal, the hazards
    and obstacles it sees), so the members of one process work it out once a tick. A pure
    cache: equal inputs give the very same push; thread-safe under the GIL."""
    key = (view.own, tuple(others), tuple(obstacles), vmax, t)
    which = (view.goal_x, view.goal_y)
    last = _PUSHES.get(which)
    if last is not None and last[0] == key:
        return last[1]
    push = tiebreak_push(view, others, obstacles, vmax, t)
    if len(_PUSHES) >= 64:
        _PUSHES.clear()
    _PUSHES[which] = (key, push)
    return push


#: formation goal -> (the inputs of its last push, the push) (:func:`shared_push`)
_PUSHES: dict[tuple[float, float], tuple[tuple, tuple[float, float]]] = {}


def _half_width(e: Ellipse, nx: float, ny: float) -> float:
    """Support of the ellipse along the unit direction (nx, ny): its half-width across it."""
    c, s = math.cos(e.alpha), math.sin(e.alpha)
    p, q = nx * c + ny * s, -nx * s + ny * c
    return math.sqrt((e.a * p) ** 2 + (e.b * q) ** 2)


def shape_rows(px: float, py: float, shapes: Sequence[Shape], gamma: float, grow: float,
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


class RowBuilder(Protocol):
    """One robot model's QP rows for a tick: every barrier row and limit row for the point
    ``point`` (the control point; a double integrator's body) of a robot with heading
    ``theta``, its nominal ``nominal_u`` and the tick's input; ``load``: its formation's load
    (:func:`agent.load_rows.member_load`), whose rows are contact rows. :func:`build_rows`
    builds velocity rows (single integrators, and unicycles through their look-ahead point),
    :func:`agent.double_integrator.hocbf_rows` acceleration rows (double integrators)."""

    def __call__(self, p: ControlParams, point: tuple[float, float], theta: float,
                 nominal_u: tuple[float, float], inp: StepInput,
                 load: load_rows.MemberLoad | None = None, /) -> Rows: ...


def build_rows(p: ControlParams, point: tuple[float, float], theta: float,
               nominal_u: tuple[float, float], inp: StepInput,
               load: load_rows.MemberLoad | None = None) -> Rows:
    """Every barrier row (eq. 4.12b-e with appendix A's velocity terms) and limit row for the
    control point ``point`` of a robot with heading ``theta`` (the :class:`RowBuilder` of single
    integrators and unicycles; a unicycle's edges measured between the bodies, :func:`body_df`).

    A barrier row with b >= the largest speed the limit rows allow can never be active: it is
    left out of the QP (exactly: it cannot change the solution, nor any relaxation, since the
    limits are never relaxed). Its barrier value still counts for the reported minimum.
    ``load``: this member's formation's load (:func:`agent.load_rows.member_load`): its rows
    (:mod:`agent.load_rows`) are contact rows, their barrier counted with the obstacles'."""
    px, py = point
    last_u = inp.last_u
    neighbours = inp.neighbours
    if p.unicycle:
        reach = math.hypot(p.max_speed, p.lookahead * p.max_turn_rate)
        # the band is meant for the bodies: measure each edge there (body_df)
        neighbours = [n._replace(df=body_df(px, py, theta, n, p.offset)) for n in neighbours]
    else:
        reach = p.max_speed
    hf, soft = _band_rows(p, px, py, theta, neighbours, reach, last_u)
    ho, contact = _contact_rows(p, px, py, inp.obstacles, inp.shapes, reach)
    he, hard = _hazard_rows(p, px, py, inp.others, inp.pairwise, reach, last_u)
    hs, sep = _separation_rows(p, px, py, theta, inp.partners, last_u, reach)
    contact += sep
    if load is not None:
        hl, lrows = load_rows.load_rows(load, inp.obstacles, inp.shapes, p.radius,
                                        load_rows.LOAD_CLEAR + p.load_sampling_margin + p.margin,
                                        p.gamma_obstacle, reach)
        ho = min(ho, hl)
        contact += lrows
    limits = velocity_limit_rows(p, theta, inp.view, nominal_u)
    if p.turn_capped:
        limits = near_limit_rows(p, px, py, theta, inp) or limits
    return Rows(limits, hard, soft, hf, ho, he, hs, contact)


def near_limit_rows(p: ControlParams, px: float, py: float, theta: float, inp: StepInput
                    ) -> list[Row] | None:
    """A unicycle's drive limits with its turn rate capped near things
    (:func:`agent.unicycle.near_turn_cap`, for :attr:`ControlParams.turn_capped`), or None
    where the cap does not bind. The clearance is the control point's beyond the obstacles'
    and shapes' Ds grown as their rows grow it."""
    grow = p.offset + p.sampling_margin + p.margin
    obstacles = inp.obstacles
    if p.declared:  # a moving obstacle is seen through the camera too (its rows' margin)
        obstacles = [o._replace(ds=o.ds + margins.moving_obstacle_margin(
            p.bounds, math.hypot(o.vx, o.vy))) for o in obstacles]
    near = barriers.clearance(px, py, obstacles, inp.shapes, grow)
    cap = unicycle.near_turn_cap(near, p.sampling_margin, p.lookahead, p.period,
                                 p.gamma_obstacle, p.max_turn_rate)
    if cap >= p.max_turn_rate:
        return None
    return unicycle.drive_limit_rows(theta, p.lookahead, p.max_speed, cap)


def _band_rows(p: ControlParams, px: float, py: float, theta: float,
               neighbours: Sequence[Neighbour], reach: float,
               last_u: tuple[float, float] = (0.0, 0.0)) -> tuple[float, list[Row]]:
    """The formation edges' rows (eq. 4.12b) that can be active, and the smallest h. With
    declared bounds the band narrows by the pair's margin (:meth:`ControlParams.pair_margin`:
    the edge is measured with both ends' errors), with the unicycles' heading narrowing at most
    ``narrow_cap`` (:class:`RowTuning`) epsilon in all, so the band is never empty."""
    soft: list[Row] = []
    hf = math.inf
    eps = p.epsilon
    gamma = unicycle.member_gamma(p.gamma_formation) if p.unicycle else p.gamma_formation
    for n in neighbours:
        narrow = 0.0
        if p.unicycle and n.theta is not None:  # the band is meant for the bodies
            narrow = heading_narrowing(theta, n.theta, p.lookahead, eps)
        if p.declared:
            narrow = min(narrow + p.pair_margin(last_u, (n.vx, n.vy)), ROW_TUNING.narrow_cap * eps)
        hg, hl, rg, rl = barriers.formation_rows(px, py, n, eps, gamma, narrow)
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
        ho = min(ho, shape_rows(px, py, shapes, p.gamma_obstacle, grow, reach, contact))
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
    The formation rows and the members' pull to their slots measure every unicycle edge against this
    distance, so they hold the bodies where the headings differ. Against Df_ij itself they held
    the look-ahead points: a member turning in place (bodies still) moved its look-ahead point
    by up to 2 l, and the rows and the band's repair then moved its neighbours' bodies after it
    (look-ahead edges inside the band while the bodies were well out of it, at arrival and where
    one member was pushed round by another formation's ellipse row:
    tests/scenarios/unicycle-arrival-shelves.yaml). Without the neighbour's heading the edge keeps Df_ij."""
    if n.theta is None:
        return n.df
    dx, dy = px - n.x, py - n.y
    qx = lookahead * (math.cos(theta) - math.cos(n.theta))
    qy = lookahead * (math.sin(theta) - math.sin(n.theta))
    return n.df + math.hypot(dx, dy) - math.hypot(dx - qx, dy - qy)


def heading_narrowing(theta_i: float, theta_j: float, lookahead: float, eps: float) -> float:
    """[m] how much a unicycle edge's band on the look-ahead points narrows on each side:
    min(l |e_i - e_j|, narrow_cap eps) (:class:`RowTuning`).

    The edge is measured against :func:`body_df`, which is exact for the headings of this tick.
    The headings change: members that face apart turn towards one motion (:func:`rigid_target`,
    :func:`agent.unicycle.steer`), and each turn moves a look-ahead point but not its body, which
    moves the body-equivalent distance by up to l |e_i - e_j| (|s_i - s_j| and |b_i - b_j| differ
    by at most that much). The narrowing keeps that much room for the turns still to come.
    Uncapped, the band would be empty once l |e_i - e_j| > eps (members facing 47 degrees apart,
    for a TurtleBot's 5 cm look-ahead and eps = 4 cm), and an empty band relaxes every tick;
    capped at narrow_cap eps it keeps at least (1 - narrow_cap) eps either side. The headings
    are the members' own and their neighbours' ``state`` (wire version 2)."""
    q = math.hypot(math.cos(theta_i) - math.cos(theta_j), math.sin(theta_i) - math.sin(theta_j))
    return min(lookahead * q, ROW_TUNING.narrow_cap * eps)


def _separation_rows(p: ControlParams, px: float, py: float, theta: float,
                     partners: Sequence[Partner], last_u: tuple[float, float],
                     reach: float) -> tuple[float, list[Row]]:
    """The smallest separation barrier value and the hard separation rows that can be active."""
    hs = math.inf
    rows: list[Row] = []
    gamma = unicycle.member_gamma(p.gamma_formation) if p.unicycle else p.gamma_formation
    off = p.offset
    for q in partners:
        dsep = p.separation + p.pair_margin(last_u, (q.vx, q.vy))
        h, gi, gj = barriers.separation_terms((px, py), theta, (q.x, q.y), q.theta, dsep, off)
        row = barriers.separation_row(h, gi, last_u, gj, (q.vx, q.vy), gamma)
        hs = min(hs, h)
        if row[2] < reach:
            rows.append(row)
    return hs, rows


def velocity_limit_rows(p: ControlParams, theta: float, view: FormationView | None,
                        nominal_u: tuple[float, float]) -> list[Row]:
    """Speed (and for unicycles turn-rate) limit rows."""
    if p.unicycle:
        return unicycle.drive_limit_rows(theta, p.lookahead, p.max_speed, p.max_turn_rate)
    # Members of a formation share the polygon's orientation (their travel direction), so a
    # neighbour's last velocity is always inside this robot's own speed polygon.
    if (view is not None and math.hypot(view.goal_x - view.own.cx, view.goal_y - view.own.cy)
            > ROW_TUNING.heading_from):
        heading = math.atan2(view.goal_y - view.own.cy, view.goal_x - view.own.cx)
    else:
        heading = math.atan2(nominal_u[1], nominal_u[0])
    key = (p.max_speed, heading)
    last = _SPEED_ROWS.get(key)
    if last is None:  # the members of a formation share the heading: made once for them
        if len(_SPEED_ROWS) >= 64:
            _SPEED_ROWS.clear()
        last = _SPEED_ROWS[key] = barriers.speed_rows(p.max_speed, heading)
    return last


#: (max speed, heading) -> the speed polygon's rows (read only: every solver copies its rows)
_SPEED_ROWS: dict[tuple[float, float], list[Row]] = {}


def escape_command(
    p: ControlParams, view: FormationView, obstacles: Sequence[Obstacle],
    tuning: ControlTuning = TUNING,
) -> tuple[float, float] | None:
    """The formation-level escape from moving hazards (module docstring, "Escape"): the same
    vector for every member, or None when no moving hazard threatens the formation.

    Why: a barrier only lets robots back away, which does not outrun a hazard about as fast as
    they are; stepping off its path does. Pinned by tests/scenarios/forklift-crossing-fast.yaml."""
    t, dead = tuning.escape, tuning.tiebreak.dead
    own = view.own
    vmax = p.max_speed
    # The formation's intended motion: eq. 4.2 on the centroid (zero once parked at the goal).
    wx, wy = nominal(p.kp, own.cx, own.cy, view.goal_x, view.goal_y, vmax)
    ex = ey = 0.0
    threat = False
    pad = 2.0 * p.radius + 2.0 * p.offset + p.epsilon + t.pad
    for o in obstacles:
        speed = math.hypot(o.vx, o.vy)
        if speed < t.min_speed:
            continue
        hx, hy = o.vx / speed, o.vy / speed  # the hazard's heading; n its left normal
        nx, ny = -hy, hx
        rx, ry = own.cx - o.x, own.cy - o.y
        along, lat = rx * hx + ry * hy, rx * nx + ry * ny
        half = max(0.0, _half_width(own, nx, ny) - pad)  # members' body centres across its path
        need = o.ds + half + t.margin
        if along < -(need + _half_width(own, hx, hy)) or math.hypot(rx, ry) > t.range:
            continue  # passed us, or too far to matter yet
        # Closest approach under the intended motion (relative velocity w - v_hazard).
        vx, vy = wx - o.vx, wy - o.vy
        v2 = vx * vx + vy * vy
        tca = max(0.0, -(rx * vx + ry * vy) / v2) if v2 > 1e-12 else 0.0
        miss = math.hypot(rx + vx * tca, ry + vy * tca)
        if miss >= need or tca > t.horizon:
            continue
        threat = True
        side = math.copysign(1.0, lat) if abs(lat) > dead else -1.0  # else: its right
        gap = max(0.0, need + t.overshoot - abs(lat))  # aim a little beyond, to get there
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
    lx, ly = t.gain * ex, t.gain * ey
    ln = math.hypot(lx, ly)
    if ln > vmax:
        return (lx * vmax / ln, ly * vmax / ln)
    # Sideways first; what speed is left goes to the (filtered) intended motion.
    rest = math.sqrt(max(0.0, vmax * vmax - ln * ln))
    wn = math.hypot(wx, wy)
    if wn > rest:
        wx, wy = wx * rest / wn, wy * rest / wn
    return (lx + wx, ly + wy)


class Controller:
    """One robot's controller, made once from its parameters and called once a tick.

    ``params`` are the robot's and the scenario's numbers (:class:`ControlParams`); ``solve``
    the QP solver (:func:`agent.qp.solve_exact` by default, or
    :func:`agent.qp.make_solver`'s backend); ``clock`` (e.g. ``time.perf_counter_ns``) times the
    QP for ``solve_us``, and without one the step reads no clock and ``solve_us`` is 0;
    ``tuning`` the formation rules' tuning (:class:`ControlTuning`). Its robot model picks the
    row builder (:class:`RowBuilder`) once: velocity rows, or a double integrator's
    acceleration rows. :meth:`step` holds no state between ticks: one Controller serves every
    robot with the same parameters (its one memory, the last formation twist by its inputs, is
    a pure cache: :class:`agent.body.TwistMemo`, its own or ``twists``: one memo the agents of
    one process share)."""

    __slots__ = ("params", "solve", "clock", "tuning", "rows", "body", "twists")

    def __init__(self, params: ControlParams, solve: Callable = solve_exact,
                 clock: Callable[[], int] | None = None, tuning: ControlTuning = TUNING,
                 twists: body.TwistMemo | None = None) -> None:
        self.params = params
        self.solve = solve
        self.clock = clock
        self.tuning = tuning
        self.rows: RowBuilder = (double_integrator.hocbf_rows if params.double_integrator
                                 else build_rows)
        # the formation QP's numbers, which depend on the parameters alone (method rigid)
        self.body = (body_params(params) if params.method == "rigid" and params.safety
                     else None)
        # a pure cache: members of one formation share a twist
        self.twists = body.TwistMemo() if twists is None else twists

    def step(self, inp: StepInput) -> StepResult:
        """One tick for one robot (:class:`StepInput` says what each input is)."""
        p = self.params
        x, y, theta = inp.pose
        off = p.offset
        px, py = (unicycle.control_point(x, y, theta, off) if p.unicycle else (x, y))
        (ux, uy), escaping = self._nominal(inp, (px, py))
        fp = inp.footprint
        load = (load_rows.member_load(fp, inp.pose, inp.last_u, inp.partners, off, p.unicycle)
                if self.body is not None and fp is not None else None)
        rows = self.rows(p, (px, py), theta, (ux, uy), inp, load)
        if p.double_integrator:  # the same nominal, as an acceleration under relative-degree-2 rows
            d = double_integrator.step(p, rows, (x, y), inp.last_u, self.solve, self.clock)
            return StepResult(d.vx, d.vy, math.hypot(d.vx, d.vy), 0.0, x, y, d.status, d.slack,
                              rows.h_formation, rows.h_obstacle, rows.h_formations, ux, uy,
                              d.solve_us, rows.h_separation, escaping, d.ax, d.ay)
        return self._drive(inp, rows, (px, py), (ux, uy), escaping)

    def _nominal(self, inp: StepInput, point: body.Point) -> tuple[body.Point, bool]:
        """The nominal command: eq. 4.2 on the goal, under ``method: rigid`` the formation's
        (:func:`rigid_nominal`, with the formation rules), turned first for a unicycle
        (:func:`agent.unicycle.steer`); and whether the escape set it."""
        p = self.params
        x, y, _theta = inp.pose
        goal = inp.goal
        u = nominal(p.kp, x, y, goal[0], goal[1], p.max_speed)
        aim = None
        escaping = False
        view, fp, bp = inp.view, inp.footprint, self.body
        if bp is not None and view is not None and fp is not None:
            u, aim, escaping = self._formation_nominal(inp, bp, view, fp, point)
        if p.unicycle and p.safety and p.method != "thesis":  # turn about the body, then drive
            u = self._face(inp, u, aim)
        return u, escaping

    def _formation_nominal(self, inp: StepInput, bp: body.BodyParams, view: FormationView,
                           fp: body.Footprint, point: body.Point
                           ) -> tuple[body.Point, body.Point | None, bool]:
        """``method: rigid``: the member's nominal from its formation's twist, with the escape,
        the yield and keep right shaping the formation's goal motion."""
        p, t = self.params, self.tuning
        hazards = inp.others if inp.hazards is None else inp.hazards
        esc = escape_command(p, view, inp.obstacles, t) if p.tiebreak else None  # a faster hazard
        if esc is None and p.tiebreak and view.yielding:  # a jam: the later name backs off
            esc = yield_command(view, hazards, p.max_speed, t.stall)
        push = (shared_push(view, hazards, inp.obstacles, p.max_speed, t.tiebreak)
                if p.tiebreak else (0.0, 0.0))
        u, aim = rigid_nominal(bp, fp, view, body.Snapshot(inp.obstacles, inp.shapes, hazards),
                               point, inp.pose[:2], inp.goal, push, esc, self.twists.twist)
        return u, aim, esc is not None

    def _face(self, inp: StepInput, u: body.Point, aim: body.Point | None) -> body.Point:
        """A unicycle's nominal: turn about the body to face ``u`` (or the formation's ``aim``),
        then drive (:func:`agent.unicycle.steer`)."""
        p = self.params
        x, y, theta = inp.pose
        goal, last_u = inp.goal, inp.last_u
        near = math.hypot(goal[0] - x, goal[1] - y) < unicycle.STEER.reverse_range
        lead = 1.0 / body.band_gain(p.kp, p.period)  # where the slot's pull aims the point
        turning = unicycle.to_unicycle(last_u[0], last_u[1], theta, p.lookahead)[1]
        return unicycle.steer(u[0], u[1], theta, p.lookahead, p.max_turn_rate, reverse=near,
                              lead=lead, turning=turning, aim=aim)

    def _drive(self, inp: StepInput, rows: Rows, point: body.Point, u: body.Point,
               escaping: bool) -> StepResult:
        """The velocity QP (single integrators and unicycles) on ``rows`` for the nominal ``u``,
        with a unicycle's acceleration rows where it has max_accel (:mod:`agent.accel_limit`)."""
        p, clock = self.params, self.clock
        ux, uy = u
        theta = inp.pose[2]
        t0 = clock() if clock is not None else 0
        if p.safety:
            res = accel_limit.solve(ux, uy, rows.limits, rows.hard, rows.soft, rows.contact,
                                    accel_limit.accel_rows(inp.last_u, u, p.max_accel, p.period),
                                    self.solve)
        else:
            c = solve_exact(ux, uy, rows.limits) or (0.0, 0.0)
            res = QPResult(c[0], c[1], STATUS_NOMINAL, 0.0, True)
        solve_us = (clock() - t0) * 1e-3 if clock is not None else 0.0
        v, w = (unicycle.to_unicycle(res.ux, res.uy, theta, p.lookahead) if p.unicycle
                else (math.hypot(res.ux, res.uy), 0.0))
        return StepResult(res.ux, res.uy, v, w, point[0], point[1], res.status, res.slack,
                          rows.h_formation, rows.h_obstacle, rows.h_formations, ux, uy, solve_us,
                          rows.h_separation, escaping)


def body_params(cp: ControlParams) -> body.BodyParams:
    """The formation QP's numbers from a member's :class:`agent.params.ControlParams`: the turn
    limit is a unicycle's turn rate (single integrators: none beyond the slots' speeds); the
    load keeps epsilon (how far members sit from their slots) plus the look-ahead offset; a
    unicycle formation's heading spread is epsilon / l (:func:`agent.body.spread_rows`). A
    formation of double integrators plans its ellipse rows at the pace its members' own
    relative-degree-2 rows keep (:func:`agent.double_integrator.twist_gamma`), so no member
    brakes alone for another formation while the twist drives the others on; and its load
    keeps max_speed dt more: a double integrator's velocity is part of its state, so a velocity
    the twist asks for takes hold only over the next period, in which the members, and the load
    fitted to them, can still move up to max_speed dt beyond what the twist's load rows allowed
    (without it, loads of double-integrator formations ran into shelves in the ``formation
    montecarlo --model double_integrator`` draws)."""
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


def rigid_nominal(p: body.BodyParams, fp: body.Footprint, view: FormationView, snap: body.Snapshot,
                  point: body.Point, at: body.Point, target: body.Point,
                  push: body.Point = (0.0, 0.0), intent: body.Point | None = None,
                  twist: Callable[..., tuple[body.Pose, body.TwistResult]] = body.formation_twist,
                  ) -> tuple[body.Point, body.Point | None]:
    """``controller.method: rigid``: a member's nominal from the formation's twist
    (:func:`agent.body.formation_twist`, or ``twist`` with its signature: a
    :class:`agent.body.TwistMemo`'s) and its slot (:func:`agent.body.member_nominal`);
    ``point`` is its control point, ``at`` its body position; ``p`` the formation QP's numbers
    (:func:`body_params`)."""
    turn = None if view.goal_heading is None else fp.goal_turn + view.goal_heading
    pose, res = twist(fp, view.own, (view.goal_x, view.goal_y), snap, p, push, intent, turn)
    nominal = body.member_nominal(fp, pose, res.twist, point, at, target, p, res.goal,
                                  view.arriving)
    if res.aim is None:
        return nominal, None
    slot = body.place(pose, fp.slots[fp.member])
    return nominal, body.point_velocity(pose, res.aim, slot)  # the slot's motion once faced
