"""A formation's route, from its first plan to the one its members follow (the leader's part, pure).

The route's life:

1. **start**: the route each formation starts with is its file's waypoints or the plan round the
   walls and shelves (:func:`scenario.routes.start_plan`; the planners are
   :func:`geometry.route.plan_route` for a centroid and :func:`geometry.footprint_plan.plan_footprint`
   for a footprint under ``method: rigid``);
2. **goal**: a goal from the fleet manager is checked and routed by the leader's
   :class:`leader.navigation.Navigator`, which hands it to every member as a
   :class:`wire.navigation.PlanMsg`; each member walks it with its
   :class:`leader.navigation.Follower`;
3. **replanning**: under ``method: rigid`` a :class:`Replanner` (this module: the policy) says each
   tick whether to plan again and why (:class:`Reason`), and :class:`leader.route_driver.RouteDriver`
   (the one driver, for the agent's leader and the in-process simulator alike) runs the plan and
   hands the new route (an :class:`Update`) to the followers, on ``plan`` to the other members.

Why a route is planned again is one :class:`Reason` each (their values are what ``summary.json``
and the log say); the tuning constants are grouped by what they decide (:class:`Stillness`,
:class:`Progress`, :class:`Pace`, :class:`GiveWay`, :class:`Lanes`). At most one plan per
:attr:`Pace.every_s`. No route: the formation holds where it is
(:meth:`leader.navigation.Follower.hold`) and the reason is kept in ``unreachable`` until a later
plan (:attr:`Reason.RETRY` every :attr:`Pace.retry_s`, or when the things change) finds one.
Routes given by hand are never planned again. A plan whose legs meet a moving circle head-on
within :attr:`Lanes.ahead_s` is made again round where it drives, where that finds a route
(:func:`oncoming`).

The deadlock rules (each pinned by the tests/scenarios file named):

* **blocked** (:attr:`Reason.BLOCKED`): no progress for :attr:`Progress.blocked_s` although
  traffic is near: the plan goes round the moving formations near it (:func:`blockers`), because
  two formations head-on in a one-lane aisle each creep and so wait for each other for ever
  (route-head-on-aisle.yaml);
* **the later name goes round** (:meth:`Replanner.waits_for`): of two formations blocked by each
  other, the one whose name sorts later plans round, the earlier keeps its route a while, because
  both going round each other the opposite ways met at the same gap again
  (route-head-on-aisle.yaml);
* **way clear** (:attr:`Reason.WAY_CLEAR`): once the formations a detour went round have left
  the way it was on, it plans again without them, because a detour kept after the way cleared
  sent a formation far off for nothing (no scenario file reaches it yet: the rule's test in
  tests/test_footprint_plan.py pins it);
* **boxed in** (:attr:`Replanner.boxed_in`, reported ``stalled``): blocked, and no route round
  the formations in its way: it keeps its route, because the way may clear and it is not
  unreachable (route-give-way.yaml: hexagon c behind the holding d);
* **give way** (:attr:`Reason.GIVE_WAY`, :meth:`Replanner.give_way`): a formation with no route
  only because another stands in it stands aside for it when that one sorts earlier and reports
  no route or boxed in, and a formation parked at its goal or stuck on its way stands aside for
  one with no route, because two formations in each other's only way otherwise hold to the end
  (route-give-way.yaml, route-stuck-in-the-way-unicycle.yaml,
  route-parked-in-the-way-unicycle.yaml); :attr:`Reason.GIVEN_WAY` takes it back to its goal once
  the other has arrived, or after :attr:`GiveWay.most_s`.

The other reasons: :attr:`Reason.OFF_ROUTE` (the centroid further than the footprint's smaller
extent, :attr:`geometry.footprint_plan.Body.width`, from the leg it walks), :attr:`Reason.NO_PROGRESS`
(the distance to go has not shrunk by :attr:`Progress.progress_m` in
:attr:`Progress.no_progress_s`, not on the last :attr:`Progress.settle_m` to the goal; the clock
stops while something moving is near), :attr:`Reason.THINGS_CHANGED` (a round thing planned
round moved, went or came: :class:`StillThings`; for a replanner that keeps a clear route,
``keep_if_clear``, only one that came or moved across the rest of the route).

Headings: the planner's are the footprint's rotation from its start frame (theta of
:class:`agent.body.Pose`); a route's are the goal shape's turn (as ``GoalMsg.heading``), theta
less the rotation from the start shape to the goal shape (``goal_turn``).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from enum import Enum
from typing import NamedTuple

from geometry.ellipse import wrap_angle
from geometry.footprint_plan import Body, Circle, FootprintPlan, Pose3, plan_aside, plan_footprint
from geometry.shapes import Shape, segment_distance, segment_segment_distance
from wire.navigation import MAX_WAYPOINTS as MAX_ROUTE  # the most route points a plan holds


class Reason(str, Enum):
    """Why a formation's route is planned again (:meth:`Replanner.check`), one sentence of why
    each and the tests/scenarios file that pins it; the value is what ``summary.json``'s
    ``replans`` and the agent's log say (unchanged strings)."""

    #: the agent leader's first tick plans: the route it was configured with was planned before it
    #: saw any thing (route-line-aisle.yaml, tests/test_route_agent.py)
    START = "start"
    #: a goal taken from the fleet manager is planned for at the next tick: the route it came with
    #: was planned from elsewhere (route-line-aisle.yaml, tests/test_route_agent.py)
    NEW_GOAL = "new goal"
    #: the centroid left the leg it walks by more than the footprint's smaller extent: the route no
    #: longer starts where the formation is (route-pushed-off.yaml)
    OFF_ROUTE = "off route"
    #: the distance to go has not shrunk for a while with no traffic near: a minimum the route did
    #: not foresee (route-parked-twitch-unicycle.yaml)
    NO_PROGRESS = "no progress"
    #: a round thing planned round moved, went or came: the route was made for other things
    #: (route-forklift-parks.yaml)
    THINGS_CHANGED = "things changed"
    #: no route yet, tried again now and then: the way may have opened (route-closed-room.yaml)
    RETRY = "retry"
    #: no progress for long with traffic near: plan round it (the deadlock rules, module docstring)
    BLOCKED = "blocked"
    #: the formations a blocked plan went round have left the way (the deadlock rules)
    WAY_CLEAR = "way clear"
    #: stand aside for a formation with no route (the deadlock rules)
    GIVE_WAY = "give way"
    #: the one it stood aside for has arrived, or it stood aside long enough: back to its own goal
    #: (route-give-way.yaml)
    GIVEN_WAY = "given way"

    def __str__(self) -> str:
        return self.value


@dataclass(frozen=True)
class Stillness:
    """What counts as a thing standing still, to be planned round (:class:`StillThings`)."""

    still_s: float = 3.0  # [s] still this long: planned round (shorter: round a forklift's pause)
    speed: float = 0.01  # [m/s] slower is still (higher: a creeping formation taken for parked)
    moved_m: float = 0.3  # [m] a planned-round thing this far off is a change (lower: replans for jitter)


@dataclass(frozen=True)
class Progress:
    """When the formation counts as stuck on its route (:meth:`Replanner.check`)."""

    no_progress_s: float = 5.0  # [s] no progress this long: plan again (shorter: replans mid-turn)
    progress_m: float = 0.1  # [m] progress is the distance to go shrinking this (lower: drift counts)
    settle_m: float = 0.5  # [m] this near the goal on the last leg: settling (lower: replans parking)
    traffic_m: float = 1.0  # [m] a moving thing this near stops the clock (larger: waits on traffic longer)
    blocked_s: float = 10.0  # [s] stuck in traffic this long: plan round it (shorter: detours for passers-by)


@dataclass(frozen=True)
class Pace:
    """How often the formation plans at most."""

    every_s: float = 2.0  # [s] at most one plan this often (shorter: reacts sooner, more plans)
    retry_s: float = 5.0  # [s] no route: try again this often (shorter: finds an opened way sooner)


@dataclass(frozen=True)
class GiveWay:
    """Standing aside for a formation with no route (:meth:`Replanner.give_way`)."""

    most_s: float = 90.0  # [s] aside at most this long (longer: lets a slow one by, may strand this)
    parked_m: float = 1.0  # [m] this near its goal: parked there (larger: more formations stand aside)
    margin: float = 0.3  # [m] beyond both radii off the other's way (larger: safer, needs more room)
    near_slack_m: float = 0.02  # [m] the other's circle inside the reach (larger: a tighter way out)


@dataclass(frozen=True)
class Lanes:
    """Moving things' ways a route does not meet head-on (:func:`oncoming`)."""

    ahead_s: float = 60.0  # [s] a thing's way this far ahead counts (longer: avoids more, detours more)
    # a leg this far from the thing's motion or further meets it (nearer -1: fewer legs meet it)
    head_on: float = math.cos(math.radians(135.0))
    clear_m: float = 0.1  # [m] a lane circle beyond Ds and reach of the start (larger: fewer dropped)


STILL = Stillness()
PROGRESS = Progress()
PACE = Pace()
GIVING = GiveWay()
LANES = Lanes()
UNREACHABLE = "unreachable"  # status states (wire.navigation.STATUS_STATES)
REACHED = "reached"
STALLED = "stalled"
FORMATION = "formation/"  # a Thing's name prefix for another formation


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
    """Which round things have stood still for :attr:`Stillness.still_s` (static circles at once).
    One counted still stays so while it stays within a third of :attr:`Stillness.moved_m` of where
    it stood, whatever its
    speed: a parked formation's ellipse moves now and then as its members settle, and each time
    its speed passed STILL.speed it went and came back 3 s later, so every formation planned
    again every 3 s and one that was passing it never got by (in a warehouse run)."""

    def __init__(self) -> None:
        self._since: dict[str, tuple[float, float, float]] = {}  # name -> (x, y, still since)

    def update(self, t: float, things: Iterable[Thing]) -> tuple[tuple[str, Circle], ...]:
        out = []
        seen = set()
        for th in things:
            seen.add(th.name)
            prev = self._since.get(th.name)
            if prev is not None and math.dist(prev[:2], (th.x, th.y)) > STILL.moved_m / 3:
                prev = None  # it moved: still from now on, if at all
            settled = prev is not None and t - prev[2] >= STILL.still_s
            if th.speed >= STILL.speed and not settled:
                self._since.pop(th.name, None)
                continue
            if prev is None:
                prev = (th.x, th.y, -math.inf if th.static else t)
                self._since[th.name] = prev
            if t - prev[2] >= STILL.still_s:
                out.append((th.name, (th.x, th.y, th.ds)))
        for gone in set(self._since) - seen:
            del self._since[gone]
        return tuple(sorted(out))


def traffic(pose: Pose3, rho: float, things: Iterable[Thing]) -> bool:
    """Whether something moving is within PROGRESS.traffic_m of the footprint's bounding circle: then
    the formation is waiting or giving way, not stuck (no progress is no reason to replan)."""
    return any(th.speed >= STILL.speed
               and math.dist(pose[:2], (th.x, th.y)) < rho + th.ds + PROGRESS.traffic_m
               for th in things)


def blockers(pose: Pose3, rho: float, things: Iterable[Thing]) -> tuple[tuple[str, Circle], ...]:
    """The moving formations near the footprint (as :func:`traffic` finds them), as circles to
    plan round once the formation is :data:`Reason.BLOCKED` (a forklift drives on by itself)."""
    return tuple(sorted((th.name, (th.x, th.y, th.ds)) for th in things
                        if th.name.startswith("formation/") and th.speed >= STILL.speed
                        and math.dist(pose[:2], (th.x, th.y)) < rho + th.ds + PROGRESS.traffic_m))


Lane = tuple[float, float, float, float, float]  # (x, y, vx, vy, Ds) a moving round thing


def lanes(things: Iterable[Thing]) -> tuple[Lane, ...]:
    """The moving round things that are no formation (a forklift drives on by itself, a
    formation plans its own way), for :func:`plan_job`'s check of oncoming traffic."""
    return tuple(sorted((th.x, th.y, th.vx, th.vy, th.ds) for th in things
                        if not th.name.startswith(FORMATION) and th.speed >= STILL.speed))


def oncoming(start: Pose3, route: Sequence[Pose3], rho: float, lane: Lane,
             speed: float = math.inf) -> bool:
    """Whether a leg of ``route`` (from ``start``) runs head-on (within LANES.head_on) into where
    the thing of ``lane`` drives in the next LANES.ahead_s: within its Ds and the footprint's reach.
    ``speed`` [m/s]: the formation's top speed; the thing's way counts from the earliest the
    formation can reach the leg on (one that has driven past the leg by then is gone: counted
    from now, a hexagon of the warehouse draw was sent 40 m round a forklift that was already
    past the aisle's mouth and leaving it)."""
    x, y, vx, vy, ds = lane
    u = math.hypot(vx, vy)
    pts = [start[:2]] + [p[:2] for p in route]
    done = 0.0  # [m] the route before this leg
    for a, b in zip(pts[:-1], pts[1:], strict=True):
        dx, dy = b[0] - a[0], b[1] - a[1]
        leg = math.hypot(dx, dy)
        ahead = done / speed  # [s] the earliest the formation is on this leg
        done += leg
        if leg <= 1e-9 or ahead >= LANES.ahead_s or dx * vx + dy * vy >= LANES.head_on * leg * u:
            continue
        ends = ((x + vx * ahead, y + vy * ahead), (x + vx * LANES.ahead_s, y + vy * LANES.ahead_s))
        if segment_segment_distance(a, b, *ends) < ds + rho:
            return True
    return False


def lane_circles(start: Pose3, rho: float, lane: Lane) -> tuple[Circle, ...]:
    """Where the thing of ``lane`` drives in the next LANES.ahead_s, as circles of its Ds half a Ds
    apart, less those the footprint at ``start`` already reaches (it is not planned out of a
    place it stands in: its barriers keep it off the thing itself)."""
    x, y, vx, vy, ds = lane
    n = max(1, math.ceil(math.hypot(vx, vy) * LANES.ahead_s / (0.5 * ds)))
    out = []
    for k in range(n + 1):
        cx, cy = x + vx * LANES.ahead_s * k / n, y + vy * LANES.ahead_s * k / n
        if math.dist(start[:2], (cx, cy)) > ds + rho + LANES.clear_m:
            out.append((cx, cy, ds))
    return tuple(out)


def changed(a: Sequence[tuple[str, Circle]], b: Sequence[tuple[str, Circle]]) -> bool:
    """Whether two sets of planned-around things differ (one came or went, or moved STILL.moved_m)."""
    if [n for n, _c in a] != [n for n, _c in b]:
        return True
    return any(math.dist(ca[:2], cb[:2]) > STILL.moved_m for (_n, ca), (_m, cb) in zip(a, b, strict=True))


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
    movable: tuple[Circle, ...] = ()  # other formations among ``circles``: not squeezed past
    # teammates among ``circles`` (as formations of one), each with its circle as a robot
    # (:func:`mate_reach`): where no route keeps off their ellipses, the route goes past them so
    mates: tuple[tuple[Circle, Circle], ...] = ()


class JobResult(NamedTuple):
    """A plan, and where it found no route only because of parked formations, their names."""

    plan: FootprintPlan
    blocked_by: tuple[str, ...] = ()


def mate_reach(radius: float) -> float:
    """[m] How far a route past a teammate standing near its slot keeps a robot's centre from
    the teammate's where no way keeps off the teammate's ellipse (:func:`round_mates`): two
    bodies' radii, what their separation row keeps once both are near their slots
    (:func:`agent.errand.allies_at`). The ellipse (the reach of a formation of one, plus a
    radius) can shut off a slot between the teammate and a shelf that the members reach."""
    return 2.0 * radius


def round_mates(job: PlanJob) -> tuple[FootprintPlan, tuple[Circle, ...]]:
    """The footprint's route round the circles, the teammates among them as the formations of
    one that their rows keep it off while it is far from its slot; where there is none, past
    the teammates as robots (``job.mates``); and the circles of the route. A route past them as
    robots alone went between two teammates standing 0.74 m apart, whose ellipses its rows kept
    it off: it stood there for good, in the way of a third teammate's slot, while a way round
    the far side of one of them led to its own slot."""
    res = plan_footprint(job.start, job.goal, job.body, job.shapes, job.circles, movable=job.movable)
    if res.route or not job.mates:
        return res, job.circles
    near = dict(job.mates)
    circles = tuple(near.get(c, c) for c in job.circles)
    past = plan_footprint(job.start, job.goal, job.body, job.shapes, circles, movable=job.movable)
    return past._replace(expanded=res.expanded + past.expanded), circles


def plan_job(job: PlanJob) -> JobResult:
    """The footprint's route (:func:`round_mates`); where there is none and formations are
    parked in the way, the route without them too: the formations it passes are what blocks
    the way (each may be waiting for this one: :meth:`Replanner.give_way`)."""
    res, circles = round_mates(job)
    job = job._replace(circles=circles)
    ahead = [ln for ln in job.lanes
             if res.route and oncoming(job.start, res.route, job.body.rho, ln, job.speed)]
    if ahead:  # round where they drive, if there is a way; else the way, and the barriers wait
        lane = tuple(c for ln in ahead for c in lane_circles(job.start, job.body.rho, ln))
        round_ = plan_footprint(job.start, job.goal, job.body, job.shapes, job.circles + lane,
                                movable=job.movable + lane)
        res = round_ if round_.route else res
    if res.route or not job.formations:
        return JobResult(res)
    parked = [c for _n, c in job.formations]
    rest = tuple(c for c in job.circles if c not in parked)
    through = plan_footprint(job.start, job.goal, job.body, job.shapes, rest, movable=job.movable)
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

    state: str  # a status state (wire.navigation.STATUS_STATES)
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
    is GIVING.margin beyond both radii off it (:func:`plan_aside`); no route where the other
    has no way either, or this formation is not in it."""
    o = job.other
    disc = Body(((0.0, 0.0),), radius=job.radius)  # a robot's body, its centre on the way
    way = plan_footprint((o.x, o.y, 0.0), (o.gx, o.gy, 0.0), disc, job.shapes, job.other_circles)
    if not way.route:
        return FootprintPlan((), "the other formation has no way either")
    pts = [(o.x, o.y)] + [p[:2] for p in way.route]
    clear = job.body.rho + o.a + job.radius + GIVING.margin
    if way_distance(pts, job.start[0], job.start[1]) >= clear:
        return FootprintPlan((), "not in the other formation's way")
    return plan_aside(job.start, job.body, job.shapes, job.circles, pts, clear)


class Update(NamedTuple):
    """A new route for the formation (the goal last), or an order to hold (``route`` empty)."""

    route: tuple[tuple[float, float], ...]
    headings: tuple[float | None, ...]
    why: Reason  # what made the plan
    reason: str = ""  # no route: why


@dataclass
class ProgressClock:
    """How far the formation had yet to go at its best, and since when (:meth:`Replanner.check`)."""

    best: float = math.inf  # [m] the least distance to go since the last plan
    best_at: float = 0.0  # [s] when it was reached (or traffic last held the formation up)
    moved_at: float = 0.0  # [s] the last progress, traffic or not

    def restart(self, t: float) -> None:
        """A new route at ``t``: no distance to go yet."""
        self.best, self.best_at, self.moved_at = math.inf, t, t


@dataclass
class Detour:
    """The way a blocked plan left (from where the formation stood) and the formations it went
    round (:meth:`Replanner.way_clear`); empty when the route is no such detour."""

    way: tuple[tuple[float, float], ...] = ()  # where it stood when blocked, then its route
    left: tuple[tuple[float, float], ...] = ()  # the way the current detour left
    round: tuple[str, ...] = ()  # the formations it went round


class Replanner:
    """One formation's route to one goal pose (module docstring)."""

    def __init__(self, body: Body, goal_turn: float, goal: Pose3, shapes: Sequence[Shape],
                 start: tuple[float, float] | None = None, by_hand: bool = False,
                 speed: float = math.inf) -> None:
        self.body = body
        self.speed = speed  # [m/s] the formation's top speed (a robot's: :func:`oncoming`)
        self.goal_turn = goal_turn
        self.goal = goal
        self.shapes = tuple(shapes)
        self.by_hand = by_hand
        self.planned: tuple[tuple[str, Circle], ...] = ()
        self.unreachable = ""
        self.plans = 0
        self.last_plan = -math.inf
        self._progress = ProgressClock()
        self._detour = Detour()
        self._leg_start = start  # where the route's first leg starts
        self.due: Reason | None = None  # a plan asked for (a new goal): the next check says so
        self.name = ""  # the formation's (who gives way to whom: the later name to the earlier)
        self.blocked_by: tuple[str, ...] = ()  # no route only because these formations stand in it
        self.giving_way = ""  # the formation this one stands aside for
        self._gave_at = -math.inf
        self.boxed_in = False  # blocked, and no route round the formations in its way
        # a change of the still things plans again only where one lies across the rest of the
        # route (a lifelong fleet's robots stop and start all the time, mostly far off its way)
        self.keep_if_clear = False
        # the formations that stand where they are until this one has arrived (a lifelong
        # team's members at their slots, to a member on its way to its own: they wait for it):
        # bodies it goes round (as formations where a way does, else as robots: round_mates), by
        # a narrow way if need be, never ones to wait for or give way to
        self.mates: frozenset[str] = frozenset()

    def plan(self, t: float, pose: Pose3, things: tuple[tuple[str, Circle], ...], why: Reason,
             extra: tuple[tuple[str, Circle], ...] = (), moving: tuple[Lane, ...] = ()
             ) -> Update | None:
        """Plan from ``pose`` now around the shapes, ``things`` and ``extra`` (:meth:`begin`)."""
        return self.finish(plan_job(self.begin(t, pose, things, extra, moving)), why)

    def job_for(self, t: float, pose: Pose3, things: tuple[tuple[str, Circle], ...], why: Reason,
                seen: Sequence[Thing]) -> PlanJob | None:
        """The plan :meth:`check`'s ``why`` asks for (:meth:`begin`; run :func:`plan_job`, then
        :meth:`finish`), or None: blocked by a formation that goes round instead
        (:meth:`waits_for`). Blocked, it plans round the formations there (:func:`blockers`)
        once; every plan keeps off the ways of the moving things (:func:`lanes`)."""
        extra = blockers(pose, self.body.rho, seen) if why == Reason.BLOCKED else ()
        if why == Reason.BLOCKED and self.waits_for(t, extra):
            return None
        return self.begin(t, pose, things, extra, lanes(seen))

    def parked(self, pose: Pose3) -> bool:
        """At or near its goal (within GIVING.parked_m of it; a route given by hand is never moved):
        where a formation stops, and may stand in another's only way."""
        return not self.by_hand and math.dist(pose[:2], self.goal[:2]) <= GIVING.parked_m

    def stuck(self, t: float) -> bool:
        """No progress along its route for PROGRESS.blocked_s (traffic or not; a route given by hand is
        never moved): it may be waiting for one that waits for it."""
        return not self.by_hand and t - self._progress.moved_at >= PROGRESS.blocked_s

    def give_way(self, t: float, others: Mapping[str, Other], pose: Pose3 | None = None) -> str:
        """The formation to stand aside for now, or "": one whose name sorts before this one's,
        that blocks this one's way (this one finds no route while that one stands in it) and
        reports no route itself, or that it is boxed in (``stalled``): it may be waiting for
        this one (two formations in each other's only way: route-give-way).
        A formation ``parked`` at its goal (``pose``), or :meth:`stuck` on its way, tries standing
        aside for any that reports no route (:func:`give_way_job` finds out whether it stands in
        that one's way: a formation parked in the only way through deadlocked the one behind it,
        route-parked-in-the-way-unicycle; a triangle just short of its goal waited in a one-lane
        aisle for the pentagon it stood in the way of, route-stuck-in-the-way-unicycle)."""
        if self.giving_way or t - self._gave_at < PACE.retry_s:
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
        met at the same gap again). For :attr:`Progress.blocked_s` more at most: the later one
        may not be waiting for this one at all."""
        return (not self.by_hand and t - self._progress.moved_at < 2.0 * PROGRESS.blocked_s
                and any(n[len(FORMATION):] > self.name for n, _c in extra
                        if n.startswith(FORMATION)))

    def way_clear(self, seen: Sequence[Thing]) -> bool:
        """On a detour round formations it was blocked by, whether all of them have left the
        way it was on (none within its reach and the footprint's of that way, from where the
        formation stood when blocked): then it plans again without them (:attr:`Reason.WAY_CLEAR`).
        Without it a formation sent round another passing through the gap it needed came back
        only when that one had parked at its goal, long after the gap was free."""
        if not self._detour.round or not self._detour.left:
            return False
        where = {th.name: th for th in seen}
        for name in self._detour.round:
            th = where.get(name)
            if th is not None and way_distance(self._detour.left, th.x, th.y) < th.ds + self.body.rho:
                return False
        return True

    def begin_give_way(self, t: float, pose: Pose3, things: tuple[tuple[str, Circle], ...],
                       name: str, other: Other, radius: float) -> GiveWayJob:
        """Start standing aside for formation ``name`` (:func:`give_way_job`; then
        :meth:`finish_give_way`). The other is planned round where it stands, still or not (one
        with no route creeps as it holds: a triangle planning round the shelves alone was sent past
        the pentagon it gave way to in a one-lane aisle, route-stuck-in-the-way-unicycle)."""
        self.plans += 1
        self.last_plan = self._gave_at = t
        self.planned = things
        own = FORMATION + name
        near = math.dist(pose[:2], (other.x, other.y)) - self.body.rho - GIVING.near_slack_m
        circles = [(x, y, ds) for n, (x, y, ds) in things if n != own]
        # no nearer than it is now: the way out may pass it closely
        circles.append((other.x, other.y, min(other.a + radius, near)))
        return GiveWayJob(pose, self.body, self.shapes, tuple(circles), other,
                          tuple(c for n, c in things if n != own), radius)

    def finish_give_way(self, res: FootprintPlan, name: str) -> Update | None:
        """The route aside (the formation holds at its end until :meth:`check` plans again), or
        None: no place aside, it stays unreachable (tried again after PACE.retry_s)."""
        if not res.route:
            return None
        self.giving_way = name
        self._progress.restart(self._gave_at)
        return Update(tuple((x, y) for x, y, _th in res.route),
                      tuple(wrap_angle(th - self.goal_turn) for _x, _y, th in res.route),
                      Reason.GIVE_WAY)

    def begin(self, t: float, pose: Pose3, things: tuple[tuple[str, Circle], ...],
              extra: tuple[tuple[str, Circle], ...] = (), moving: tuple[Lane, ...] = ()) -> PlanJob:
        """Start a plan from ``pose`` at ``t``: the arguments of
        :func:`geometry.footprint_plan.plan_footprint` (run it anywhere, then :meth:`finish`).
        ``extra``: round things planned round this once (:func:`blockers`), not kept;
        ``moving``: the things driving about (:func:`lanes`), whose way a route does not meet
        head-on where it can go round."""
        self.plans += 1
        self.due = None
        self.last_plan = t
        self.planned = things
        self._progress.restart(t)
        self._detour.round = tuple(n for n, _c in extra)
        self._detour.left = self._detour.way if extra else ()
        self._leg_start = (pose[0], pose[1])
        self.giving_way = ""
        others = tuple((n[len(FORMATION):], c) for n, c in things if n.startswith(FORMATION)
                       and n[len(FORMATION):] not in self.mates)
        parked = () if extra else others
        movable = tuple(c for _n, c in others) + tuple(c for _n, c in extra)
        near = mate_reach(self.body.radius)
        mates = tuple((c, (c[0], c[1], min(c[2], near))) for n, c in things
                      if n.startswith(FORMATION) and n[len(FORMATION):] in self.mates)
        return PlanJob(pose, self.goal, self.body, self.shapes,
                       tuple(c for _n, c in things) + tuple(c for _n, c in extra), parked, moving,
                       self.speed, movable, mates)

    def finish(self, res: FootprintPlan | JobResult, why: Reason) -> Update | None:
        """The route (or the order to hold) from a plan :meth:`begin` started; None: keep the
        route (no way round the blockers)."""
        plan = res.plan if isinstance(res, JobResult) else res
        self.blocked_by = res.blocked_by if isinstance(res, JobResult) else ()
        self.boxed_in = bool(plan.reason) and bool(self._detour.round)  # it went round blockers
        if plan.reason:
            self._detour.round, self._detour.left = (), ()
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
              others: Mapping[str, Other] | None = None, seen: Sequence[Thing] = ()
              ) -> Reason | None:
        """Why to plan again now (module docstring), or None; ``turn`` [rad]: what the formation
        has yet to turn to the current waypoint's heading (turning is progress too); ``busy``:
        traffic is near (:func:`traffic`: the progress clock stops); ``others``: the other
        formations' reports (:class:`Other`), for giving way (:attr:`Reason.GIVE_WAY`:
        :meth:`begin_give_way`
        with :meth:`give_way`'s formation); ``seen``: every round thing this tick
        (:meth:`way_clear`)."""
        others = others or {}
        if self._leg_start is None:
            self._leg_start = (pose[0], pose[1])
        if self.due:
            return self.due
        if self.by_hand or t - self.last_plan < PACE.every_s:
            return None
        if self.giving_way:  # aside until the other has arrived (or for GIVING.most_s)
            o = others.get(self.giving_way)
            if o is not None and o.state != REACHED and t - self._gave_at < GIVING.most_s:
                return None
            return Reason.GIVEN_WAY
        if self.give_way(t, others, pose):
            return Reason.GIVE_WAY
        if self._things_changed(pose, route, index, things):
            return Reason.THINGS_CHANGED
        if self.way_clear(seen):
            return Reason.WAY_CLEAR
        if self.unreachable:
            return Reason.RETRY if t - self.last_plan >= PACE.retry_s else None
        return self._off(pose, route, index) or self._stuck(t, pose, route, index, turn, busy)

    def _things_changed(self, pose: Pose3, route: Sequence[tuple[float, float]], index: int,
                        things: tuple[tuple[str, Circle], ...]) -> bool:
        """Whether the still things changed (:func:`changed`) so that the route is planned
        again; with :attr:`keep_if_clear`, only where one new or moved lies across the rest of
        the route (otherwise they count as planned round from now on)."""
        if not changed(things, self.planned):
            return False
        if not self.keep_if_clear:
            return True
        before = dict(self.planned)
        way = [pose[:2]] + list(route[index:])
        reach = self.body.rho + self.body.margin
        if any(way_distance(way, c[0], c[1]) < c[2] + reach for n, c in things
               if n not in before or math.dist(c[:2], before[n][:2]) > STILL.moved_m):
            return True
        self.planned = things
        return False

    def _off(self, pose: Pose3, route: Sequence[tuple[float, float]], index: int) -> Reason | None:
        a = route[index - 1] if index > 0 else (self._leg_start or route[0])
        b = route[index]
        d = segment_distance(pose[0], pose[1], a[0], a[1], b[0], b[1])[0]
        return Reason.OFF_ROUTE if d > self.body.width else None

    def _stuck(self, t: float, pose: Pose3, route: Sequence[tuple[float, float]],
               index: int, turn: float, busy: bool) -> Reason | None:
        togo = math.dist(pose[:2], route[index]) + self.body.rho * abs(turn) + sum(
            math.dist(route[k], route[k + 1]) for k in range(index, len(route) - 1))
        p = self._progress
        if busy:  # waiting for traffic is not being stuck (the clock stops), for a while
            p.best_at = t
        if index >= len(route) - 1 and togo < PROGRESS.settle_m:
            return None
        if togo < p.best - PROGRESS.progress_m:
            p.best, p.best_at, p.moved_at = togo, t, t
            self.boxed_in = False
            return None
        if busy and t - p.moved_at >= PROGRESS.blocked_s:
            self._detour.way = ((pose[0], pose[1]),) + tuple(route[index:])  # should it go round: way_clear
            return Reason.BLOCKED
        if busy:
            return None
        return Reason.NO_PROGRESS if t - p.best_at >= PROGRESS.no_progress_s else None
