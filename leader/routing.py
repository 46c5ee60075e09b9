"""When a formation's route is made again, and around what (issue 26; the leader's part, pure).

A :class:`Replanner` keeps the footprint's route (:func:`geometry.footprint_plan.plan_footprint`)
to one goal pose and says each tick whether to plan it again:

* **off the route**: the centroid is further than the footprint's smaller extent
  (:attr:`geometry.footprint_plan.Body.width`) from the leg it walks;
* **no progress**: the distance to go along the route has not shrunk by :data:`PROGRESS_M` in
  :data:`NO_PROGRESS_S` (not on the last :data:`SETTLE_M` to the goal, where it settles; the
  clock stops while something moving is near: waiting for traffic is not being stuck);
* **the things changed**: a round thing planned around moved, went or came
  (:class:`StillThings`: circles that stand still, parked formations);
* **way clear**: on a blocked plan's detour, every formation it went round has left the way
  it was on (:meth:`Replanner.way_clear`);
* **blocked**: no progress for :data:`BLOCKED_S` although traffic is near (two formations
  head-on in a one-lane aisle wait for each other for ever: each creeps, so neither is ever
  still): this plan goes round the moving formations near it too (:func:`blockers`), where it
  is at that moment. They are not kept as planned-around things (they move on), and where no
  route goes round them the formation keeps its route (the way may clear; it is not
  unreachable) and is **boxed in** (:attr:`Replanner.boxed_in`, reported ``stalled``) until it
  makes progress again: a formation that holds with no route of its own (``unreachable``) and
  stands in its way gives way to it as to one with no route (:meth:`Replanner.give_way`). Since
  formations keep their ellipses off each other's members (:mod:`agent.body`), one no longer
  shoves a holding one aside (route-give-way: hexagon c, boxed in behind the holding d).

At most one plan per :data:`REPLAN_EVERY_S`. No route: the formation holds where it is
(:meth:`leader.navigation.Follower.hold`) and the reason is kept in ``unreachable`` until a
later plan (tried again every :data:`RETRY_S`, or when the things change) finds one. Routes
given by hand are never planned again. A plan whose legs meet a moving circle head-on within
:data:`LANE_S` is made again round where it drives, where that finds a route (:func:`oncoming`).

Headings: the planner's are the footprint's rotation from its start frame (theta of
:class:`agent.body.Pose`); a route's are the goal shape's turn (as ``GoalMsg.heading``), theta
less the rotation from the start shape to the goal shape (``goal_turn``).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from typing import NamedTuple

from geometry.ellipse import wrap_angle
from geometry.footprint_plan import Body, Circle, FootprintPlan, Pose3, plan_aside, plan_footprint
from geometry.shapes import Shape, segment_distance, segment_segment_distance
from wire.payloads import MAX_WAYPOINTS as MAX_ROUTE  # the most route points a plan holds

STILL_S = 3.0  # [s] a round thing still this long is planned around (a parked forklift)
STILL_SPEED = 0.01  # [m/s] slower than this is still
MOVED_M = 0.3  # [m] a planned-around thing that moved this far is a change
NO_PROGRESS_S = 5.0  # [s] no progress along the route this long: plan again
PROGRESS_M = 0.1  # [m] progress: the distance to go shrinks by this
SETTLE_M = 0.5  # [m] this near the goal on the last leg the formation settles (no replan)
REPLAN_EVERY_S = 2.0  # [s] at most one plan this often
RETRY_S = 5.0  # [s] no route: try again this often
TRAFFIC_M = 1.0  # [m] a moving thing this near: the formation waits, the progress clock stops
BLOCKED_S = 10.0  # [s] no progress this long with traffic near: plan round the formations there
BLOCKED = "blocked"
WAY_CLEAR = "way clear"  # the formations a blocked plan went round have left the way it was on
GIVE_WAY = "give way"
GIVE_WAY_S = 90.0  # [s] a formation giving way stands aside at most this long
LANE_S = 60.0  # [s] a moving thing's way this far ahead is what a route does not meet head-on
HEAD_ON = math.cos(math.radians(135.0))  # a leg this far or further from its motion meets it
LANE_CLEAR_M = 0.1  # [m] beyond its Ds and the footprint's reach: a lane circle the start is clear of
# [m] this near its goal a formation counts as parked there (it may stand in another's way; one
# kept 0.6 m short of it by the formation it blocks never settles: warehouse draw run 300117)
PARKED_M = 1.0
GIVE_WAY_MARGIN = 0.3  # [m] beyond both radii: how far from the other's way it stands aside
UNREACHABLE = "unreachable"  # status states (wire.payloads.STATUS_STATES)
REACHED = "reached"
STALLED = "stalled"
FORMATION = "formation/"  # a Thing's name prefix for another formation
NEAR_SLACK_M = 0.02  # [m] giving way, the other's circle shrinks to this inside the footprint's reach


class Thing(NamedTuple):
    """A round thing as seen this tick: a circle obstacle or another formation's ellipse."""

    name: str
    x: float
    y: float
    speed: float  # [m/s]
    ds: float  # [m] from a robot's centre: a circle's Ds; a formation's semi-major axis and its Ds
    static: bool = False  # a circle that never moves (still from the start)
    vx: float = 0.0  # [m/s] its velocity
    vy: float = 0.0


class StillThings:
    """Which round things have stood still for :data:`STILL_S` (static circles at once). One
    counted still stays so while it stays within MOVED_M / 3 of where it stood, whatever its
    speed: a parked formation's ellipse moves now and then as its members settle, and each time
    its speed passed STILL_SPEED it went and came back 3 s later, so every formation planned
    again every 3 s and one that was passing it never got by (warehouse run 200114)."""

    def __init__(self) -> None:
        self._since: dict[str, tuple[float, float, float]] = {}  # name -> (x, y, still since)

    def update(self, t: float, things: Iterable[Thing]) -> tuple[tuple[str, Circle], ...]:
        out = []
        seen = set()
        for th in things:
            seen.add(th.name)
            prev = self._since.get(th.name)
            if prev is not None and math.dist(prev[:2], (th.x, th.y)) > MOVED_M / 3:
                prev = None  # it moved: still from now on, if at all
            settled = prev is not None and t - prev[2] >= STILL_S
            if th.speed >= STILL_SPEED and not settled:
                self._since.pop(th.name, None)
                continue
            if prev is None:
                prev = (th.x, th.y, -math.inf if th.static else t)
                self._since[th.name] = prev
            if t - prev[2] >= STILL_S:
                out.append((th.name, (th.x, th.y, th.ds)))
        for gone in set(self._since) - seen:
            del self._since[gone]
        return tuple(sorted(out))


def traffic(pose: Pose3, rho: float, things: Iterable[Thing]) -> bool:
    """Whether something moving is within TRAFFIC_M of the footprint's bounding circle: then
    the formation is waiting or giving way, not stuck (no progress is no reason to replan)."""
    return any(th.speed >= STILL_SPEED and math.dist(pose[:2], (th.x, th.y)) < rho + th.ds + TRAFFIC_M
               for th in things)


def blockers(pose: Pose3, rho: float, things: Iterable[Thing]) -> tuple[tuple[str, Circle], ...]:
    """The moving formations near the footprint (as :func:`traffic` finds them), as circles to
    plan round once the formation is :data:`BLOCKED` (a forklift drives on by itself)."""
    return tuple(sorted((th.name, (th.x, th.y, th.ds)) for th in things
                        if th.name.startswith("formation/") and th.speed >= STILL_SPEED
                        and math.dist(pose[:2], (th.x, th.y)) < rho + th.ds + TRAFFIC_M))


Lane = tuple[float, float, float, float, float]  # (x, y, vx, vy, Ds) a moving round thing


def lanes(things: Iterable[Thing]) -> tuple[Lane, ...]:
    """The moving round things that are no formation (a forklift drives on by itself, a
    formation plans its own way), for :func:`plan_job`'s check of oncoming traffic."""
    return tuple(sorted((th.x, th.y, th.vx, th.vy, th.ds) for th in things
                        if not th.name.startswith(FORMATION) and th.speed >= STILL_SPEED))


def oncoming(start: Pose3, route: Sequence[Pose3], rho: float, lane: Lane,
             speed: float = math.inf) -> bool:
    """Whether a leg of ``route`` (from ``start``) runs head-on (within HEAD_ON) into where
    the thing of ``lane`` drives in the next LANE_S: within its Ds and the footprint's reach.
    ``speed`` [m/s]: the formation's top speed; the thing's way counts from the earliest the
    formation can reach the leg on (one that has driven past the leg by then is gone: warehouse
    run 300091's hexagon, sent 40 m east round a forklift that was already past the aisle's
    mouth and leaving it; it came back after the pentagon had parked in its way)."""
    x, y, vx, vy, ds = lane
    u = math.hypot(vx, vy)
    pts = [start[:2]] + [p[:2] for p in route]
    done = 0.0  # [m] the route before this leg
    for a, b in zip(pts[:-1], pts[1:], strict=True):
        dx, dy = b[0] - a[0], b[1] - a[1]
        leg = math.hypot(dx, dy)
        ahead = done / speed  # [s] the earliest the formation is on this leg
        done += leg
        if leg <= 1e-9 or ahead >= LANE_S or dx * vx + dy * vy >= HEAD_ON * leg * u:
            continue
        ends = ((x + vx * ahead, y + vy * ahead), (x + vx * LANE_S, y + vy * LANE_S))
        if segment_segment_distance(a, b, *ends) < ds + rho:
            return True
    return False


def lane_circles(start: Pose3, rho: float, lane: Lane) -> tuple[Circle, ...]:
    """Where the thing of ``lane`` drives in the next LANE_S, as circles of its Ds half a Ds
    apart, less those the footprint at ``start`` already reaches (it is not planned out of a
    place it stands in: its barriers keep it off the thing itself)."""
    x, y, vx, vy, ds = lane
    n = max(1, math.ceil(math.hypot(vx, vy) * LANE_S / (0.5 * ds)))
    out = []
    for k in range(n + 1):
        cx, cy = x + vx * LANE_S * k / n, y + vy * LANE_S * k / n
        if math.dist(start[:2], (cx, cy)) > ds + rho + LANE_CLEAR_M:
            out.append((cx, cy, ds))
    return tuple(out)


def changed(a: Sequence[tuple[str, Circle]], b: Sequence[tuple[str, Circle]]) -> bool:
    """Whether two sets of planned-around things differ (one came or went, or moved MOVED_M)."""
    if [n for n, _c in a] != [n for n, _c in b]:
        return True
    return any(math.dist(ca[:2], cb[:2]) > MOVED_M for (_n, ca), (_m, cb) in zip(a, b, strict=True))


class PlanJob(NamedTuple):
    """The arguments of one :func:`geometry.footprint_plan.plan_footprint` call (picklable: a
    worker process may run it), and the parked formations among ``circles`` (:func:`plan_job`)."""

    start: Pose3
    goal: Pose3
    body: Body
    shapes: tuple[Shape, ...]
    circles: tuple[Circle, ...]
    formations: tuple[tuple[str, Circle], ...] = ()
    lanes: tuple[Lane, ...] = ()  # moving things (:func:`lanes`): a route head-on into one goes round
    speed: float = math.inf  # [m/s] the formation's top speed (:func:`oncoming`)


class JobResult(NamedTuple):
    """A plan, and where it found no route only because of parked formations, their names."""

    plan: FootprintPlan
    blocked_by: tuple[str, ...] = ()


def plan_job(job: PlanJob) -> JobResult:
    """The footprint's route (:func:`plan_footprint`); where there is none and formations are
    parked in the way, the route without them too: the formations it passes are what blocks
    the way (each may be waiting for this one: :meth:`Replanner.give_way`)."""
    res = plan_footprint(job.start, job.goal, job.body, job.shapes, job.circles)
    ahead = [ln for ln in job.lanes
             if res.route and oncoming(job.start, res.route, job.body.rho, ln, job.speed)]
    if ahead:  # round where they drive, if there is a way; else the way, and the barriers wait
        round_ = plan_footprint(job.start, job.goal, job.body, job.shapes, job.circles + tuple(
            c for ln in ahead for c in lane_circles(job.start, job.body.rho, ln)))
        res = round_ if round_.route else res
    if res.route or not job.formations:
        return JobResult(res)
    parked = [c for _n, c in job.formations]
    rest = tuple(c for c in job.circles if c not in parked)
    through = plan_footprint(job.start, job.goal, job.body, job.shapes, rest)
    if not through.route:
        return JobResult(res)
    way = [job.start[:2]] + [p[:2] for p in through.route]
    return JobResult(res, tuple(n for n, (x, y, ds) in job.formations
                                if way_distance(way, x, y) < ds + job.body.rho))


def way_distance(way: Sequence[tuple[float, float]], x: float, y: float) -> float:
    """The distance from (x, y) to the polyline ``way``."""
    if len(way) == 1:
        return math.dist(way[0], (x, y))
    return min(segment_distance(x, y, a[0], a[1], b[0], b[1])[0]
               for a, b in zip(way[:-1], way[1:], strict=True))


class Other(NamedTuple):
    """Another formation as its leader reports it (``status``) where its ellipse is seen."""

    state: str  # a status state (wire.payloads.STATUS_STATES)
    x: float  # [m] its centroid now
    y: float
    gx: float  # [m] its goal centroid
    gy: float
    a: float  # [m] its ellipse's semi-major axis


class GiveWayJob(NamedTuple):
    """One :func:`give_way_job` (picklable)."""

    start: Pose3
    body: Body
    shapes: tuple[Shape, ...]
    circles: tuple[Circle, ...]  # what this formation plans round (the other one included)
    other: Other
    other_circles: tuple[Circle, ...]  # what the other's way goes round (neither of the two)
    radius: float  # [m] a robot's


def give_way_job(job: GiveWayJob) -> FootprintPlan:
    """Where to stand aside: the other's way (a robot's disc from its centroid to its goal,
    round the shapes and ``other_circles``), and the route to the nearest pose whose centroid
    is GIVE_WAY_MARGIN beyond both radii off it (:func:`plan_aside`); no route where the other
    has no way either, or this formation is not in it."""
    o = job.other
    disc = Body(tuple((0.01 * math.cos(k * 2.1), 0.01 * math.sin(k * 2.1)) for k in range(3)),
                radius=job.radius)  # a robot's body, its centre on the way
    way = plan_footprint((o.x, o.y, 0.0), (o.gx, o.gy, 0.0), disc, job.shapes, job.other_circles)
    if not way.route:
        return FootprintPlan((), "the other formation has no way either")
    pts = [(o.x, o.y)] + [p[:2] for p in way.route]
    clear = job.body.rho + o.a + job.radius + GIVE_WAY_MARGIN
    if way_distance(pts, job.start[0], job.start[1]) >= clear:
        return FootprintPlan((), "not in the other formation's way")
    return plan_aside(job.start, job.body, job.shapes, job.circles, pts, clear)


class Update(NamedTuple):
    """A new route for the formation (the goal last), or an order to hold (``route`` empty)."""

    route: tuple[tuple[float, float], ...]
    headings: tuple[float | None, ...]
    why: str  # what made the plan: start, off route, no progress, things changed, retry
    reason: str = ""  # no route: why


class Replanner:
    """One formation's route to one goal pose (module docstring)."""

    def __init__(self, body: Body, goal_turn: float, goal: Pose3, shapes: Sequence[Shape],
                 start: tuple[float, float] | None = None, by_hand: bool = False,
                 speed: float = math.inf) -> None:
        self.body = body
        self.width = body.width
        self.speed = speed  # [m/s] the formation's top speed (a robot's: :func:`oncoming`)
        self.goal_turn = goal_turn
        self.goal = goal
        self.shapes = tuple(shapes)
        self.by_hand = by_hand
        self.planned: tuple[tuple[str, Circle], ...] = ()
        self.unreachable = ""
        self.plans = 0
        self.last_plan = -math.inf
        self._best = math.inf
        self._best_at = 0.0
        self._moved_at = 0.0  # the last progress, traffic or not
        # the way a blocked plan left (from where the formation stood) and the formations it went
        # round (:meth:`way_clear`); () when the route is no such detour
        self._way: tuple[tuple[float, float], ...] = ()  # where it stood when blocked, then its route
        self._left: tuple[tuple[float, float], ...] = ()
        self._round: tuple[str, ...] = ()
        self._leg_start = start  # where the route's first leg starts
        self.due = ""  # a plan asked for (a new goal): the next check says so
        self.name = ""  # the formation's (who gives way to whom: the later name to the earlier)
        self.blocked_by: tuple[str, ...] = ()  # no route only because these formations stand in it
        self.giving_way = ""  # the formation this one stands aside for
        self._gave_at = -math.inf
        self.boxed_in = False  # blocked, and no route round the formations in its way

    def plan(self, t: float, pose: Pose3, things: tuple[tuple[str, Circle], ...], why: str,
             extra: tuple[tuple[str, Circle], ...] = (), moving: tuple[Lane, ...] = ()
             ) -> Update | None:
        """Plan from ``pose`` now around the shapes, ``things`` and ``extra`` (:meth:`begin`)."""
        return self.finish(plan_job(self.begin(t, pose, things, extra, moving)), why)

    def job_for(self, t: float, pose: Pose3, things: tuple[tuple[str, Circle], ...], why: str,
                seen: Sequence[Thing]) -> PlanJob | None:
        """The plan :meth:`check`'s ``why`` asks for (:meth:`begin`; run :func:`plan_job`, then
        :meth:`finish`), or None: blocked by a formation that goes round instead
        (:meth:`waits_for`). Blocked, it plans round the formations there (:func:`blockers`)
        once; every plan keeps off the ways of the moving things (:func:`lanes`)."""
        extra = blockers(pose, self.body.rho, seen) if why == BLOCKED else ()
        if why == BLOCKED and self.waits_for(t, extra):
            return None
        return self.begin(t, pose, things, extra, lanes(seen))

    def parked(self, pose: Pose3) -> bool:
        """At or near its goal (within PARKED_M of it; a route given by hand is never moved):
        where a formation stops, and may stand in another's only way."""
        return not self.by_hand and math.dist(pose[:2], self.goal[:2]) <= PARKED_M

    def stuck(self, t: float) -> bool:
        """No progress along its route for BLOCKED_S (traffic or not; a route given by hand is
        never moved): it may be waiting for one that waits for it."""
        return not self.by_hand and t - self._moved_at >= BLOCKED_S

    def give_way(self, t: float, others: Mapping[str, Other], pose: Pose3 | None = None) -> str:
        """The formation to stand aside for now, or "": one whose name sorts before this one's,
        that blocks this one's way (this one finds no route while that one stands in it) and
        reports no route itself, or that it is boxed in (``stalled``): it may be waiting for
        this one (two formations in each other's only way, montecarlo warehouse run 200148).
        A formation ``parked`` at its goal (``pose``), or :meth:`stuck` on its way, tries standing
        aside for any that reports no route (:func:`give_way_job` finds out whether it stands in
        that one's way: the warehouse draw's runs 300047 and 300117 deadlocked behind a
        formation parked in the only way through; in 300130 a triangle 1.02 m from its goal,
        which the pentagon with no route stood on, waited for it in a one-lane aisle)."""
        if self.giving_way or t - self._gave_at < RETRY_S:
            return ""
        if self.unreachable:
            for name in self.blocked_by:
                o = others.get(name)
                if o is not None and o.state in (UNREACHABLE, STALLED) and name < self.name:
                    return name
        elif pose is not None and (self.parked(pose) or self.stuck(t)):
            for name in sorted(others):
                if name != self.name and others[name].state == UNREACHABLE:
                    return name
        return ""

    def waits_for(self, t: float, extra: Sequence[tuple[str, Circle]]) -> bool:
        """Blocked by ``extra`` (:func:`blockers`), whether to keep the route a while longer:
        one of them sorts after this formation, and the later name is the one that goes round
        (two formations blocked by each other both went round each other, opposite ways, and
        met at the same gap again: montecarlo warehouse run 100187). For BLOCKED_S more at
        most: the later one may not be waiting for this one at all."""
        return (not self.by_hand and t - self._moved_at < 2.0 * BLOCKED_S
                and any(n[len(FORMATION):] > self.name for n, _c in extra
                        if n.startswith(FORMATION)))

    def way_clear(self, seen: Sequence[Thing]) -> bool:
        """On a detour round formations it was blocked by, whether all of them have left the
        way it was on (none within its reach and the footprint's of that way, from where the
        formation stood when blocked): then it plans again without them (WAY_CLEAR). In warehouse
        run 100187, c, blocked by b passing north through the cross-aisle gap c needed, was sent
        8 m west round it at 205 s; b was through 10 s later, and c came back only when b parked
        at its goal, 36 s later: 3 m short of its goal at 300 s."""
        if not self._round or not self._left:
            return False
        where = {th.name: th for th in seen}
        for name in self._round:
            th = where.get(name)
            if th is not None and way_distance(self._left, th.x, th.y) < th.ds + self.body.rho:
                return False
        return True

    def begin_give_way(self, t: float, pose: Pose3, things: tuple[tuple[str, Circle], ...],
                       name: str, other: Other, radius: float) -> GiveWayJob:
        """Start standing aside for formation ``name`` (:func:`give_way_job`; then
        :meth:`finish_give_way`). The other is planned round where it stands, still or not (one
        with no route creeps as it holds: warehouse run 300130's triangle, planning round the
        shelves alone, was sent past the pentagon it gave way to in a one-lane aisle)."""
        self.plans += 1
        self.last_plan = self._gave_at = t
        self.planned = things
        own = FORMATION + name
        near = math.dist(pose[:2], (other.x, other.y)) - self.body.rho - NEAR_SLACK_M
        circles = [(x, y, ds) for n, (x, y, ds) in things if n != own]
        # no nearer than it is now: the way out may pass it closely
        circles.append((other.x, other.y, min(other.a + radius, near)))
        return GiveWayJob(pose, self.body, self.shapes, tuple(circles), other,
                          tuple(c for n, c in things if n != own), radius)

    def finish_give_way(self, res: FootprintPlan, name: str) -> Update | None:
        """The route aside (the formation holds at its end until :meth:`check` plans again), or
        None: no place aside, it stays unreachable (tried again after RETRY_S)."""
        if not res.route:
            return None
        self.giving_way = name
        self._best, self._best_at, self._moved_at = math.inf, self._gave_at, self._gave_at
        return Update(tuple((x, y) for x, y, _th in res.route),
                      tuple(wrap_angle(th - self.goal_turn) for _x, _y, th in res.route), GIVE_WAY)

    def begin(self, t: float, pose: Pose3, things: tuple[tuple[str, Circle], ...],
              extra: tuple[tuple[str, Circle], ...] = (), moving: tuple[Lane, ...] = ()) -> PlanJob:
        """Start a plan from ``pose`` at ``t``: the arguments of
        :func:`geometry.footprint_plan.plan_footprint` (run it anywhere, then :meth:`finish`).
        ``extra``: round things planned round this once (:func:`blockers`), not kept;
        ``moving``: the things driving about (:func:`lanes`), whose way a route does not meet
        head-on where it can go round."""
        self.plans += 1
        self.due = ""
        self.last_plan = t
        self.planned = things
        self._best, self._best_at, self._moved_at = math.inf, t, t
        self._round = tuple(n for n, _c in extra)
        self._left = self._way if extra else ()
        self._leg_start = (pose[0], pose[1])
        self.giving_way = ""
        parked = () if extra else tuple((n[len(FORMATION):], c) for n, c in things
                                        if n.startswith(FORMATION))
        return PlanJob(pose, self.goal, self.body, self.shapes,
                       tuple(c for _n, c in things) + tuple(c for _n, c in extra), parked, moving,
                       self.speed)

    def finish(self, res: FootprintPlan | JobResult, why: str) -> Update | None:
        """The route (or the order to hold) from a plan :meth:`begin` started; None: keep the
        route (no way round the blockers)."""
        plan = res.plan if isinstance(res, JobResult) else res
        self.blocked_by = res.blocked_by if isinstance(res, JobResult) else ()
        self.boxed_in = bool(plan.reason) and bool(self._round)  # it went round blockers
        if plan.reason:
            self._round, self._left = (), ()
        if self.boxed_in:
            return None
        self.unreachable = plan.reason
        if plan.reason and self.blocked_by:
            self.unreachable = f"{plan.reason} while formation {', '.join(self.blocked_by)} stands in it"
        if plan.reason:
            return Update((), (), why, self.unreachable)
        route = plan.route
        if len(route) > MAX_ROUTE:  # a plan holds no more: the first ones and the goal; the
            route = route[:MAX_ROUTE - 1] + route[-1:]  # rest is planned again from there
        return Update(tuple((x, y) for x, y, _th in route),
                      tuple(wrap_angle(th - self.goal_turn) for _x, _y, th in route), why)

    def check(self, t: float, pose: Pose3, route: Sequence[tuple[float, float]], index: int,
              things: tuple[tuple[str, Circle], ...], turn: float = 0.0, busy: bool = False,
              others: Mapping[str, Other] | None = None, seen: Sequence[Thing] = ()) -> str | None:
        """Why to plan again now (module docstring), or None; ``turn`` [rad]: what the formation
        has yet to turn to the current waypoint's heading (turning is progress too); ``busy``:
        traffic is near (:func:`traffic`: the progress clock stops); ``others``: the other
        formations' reports (:class:`Other`), for giving way (GIVE_WAY: :meth:`begin_give_way`
        with :meth:`give_way`'s formation); ``seen``: every round thing this tick
        (:meth:`way_clear`)."""
        others = others or {}
        if self._leg_start is None:
            self._leg_start = (pose[0], pose[1])
        if self.due:
            return self.due
        if self.by_hand or t - self.last_plan < REPLAN_EVERY_S:
            return None
        if self.giving_way:  # aside until the other has arrived (or for GIVE_WAY_S)
            o = others.get(self.giving_way)
            if o is not None and o.state != REACHED and t - self._gave_at < GIVE_WAY_S:
                return None
            return "given way"
        if self.give_way(t, others, pose):
            return GIVE_WAY
        if changed(things, self.planned):
            return "things changed"
        if self.way_clear(seen):
            return WAY_CLEAR
        if self.unreachable:
            return "retry" if t - self.last_plan >= RETRY_S else None
        return self._off(pose, route, index) or self._stuck(t, pose, route, index, turn, busy)

    def _off(self, pose: Pose3, route: Sequence[tuple[float, float]], index: int) -> str | None:
        a = route[index - 1] if index > 0 else (self._leg_start or route[0])
        b = route[index]
        d = segment_distance(pose[0], pose[1], a[0], a[1], b[0], b[1])[0]
        return "off route" if d > self.width else None

    def _stuck(self, t: float, pose: Pose3, route: Sequence[tuple[float, float]],
               index: int, turn: float, busy: bool) -> str | None:
        togo = math.dist(pose[:2], route[index]) + self.body.rho * abs(turn) + sum(
            math.dist(route[k], route[k + 1]) for k in range(index, len(route) - 1))
        if busy:  # waiting for traffic is not being stuck (the clock stops), for a while
            self._best_at = t
        if index >= len(route) - 1 and togo < SETTLE_M:
            return None
        if togo < self._best - PROGRESS_M:
            self._best, self._best_at, self._moved_at = togo, t, t
            self.boxed_in = False
            return None
        if busy and t - self._moved_at >= BLOCKED_S:
            self._way = ((pose[0], pose[1]),) + tuple(route[index:])  # should it go round: way_clear
            return BLOCKED
        if busy:
            return None
        return "no progress" if t - self._best_at >= NO_PROGRESS_S else None
