"""A fleet robot's errand as a pure state machine: from idle to a team, the load carried, idle again.

No Zenoh here: the agent hands an :class:`Errand` the committed roster it follows
(:meth:`Errand.take`), the team leader's statuses (:meth:`Errand.hear`) and, each tick, where it
and its teammates stand (:meth:`Errand.step`); the step says what the agent does
(:class:`Move`): walk alone to a point, form the team, stand still, put a status, or dissolve.
Time is counted in ticks, so every member of a lock-step run agrees on it.

The phases (DESIGN.md "Lifelong operation"; the in-process :mod:`simulator.lifelong` runs the
same ones for the whole fleet):

* **idle**: bid (:mod:`agent.bidder`) and walk to the robot's parking spot (:func:`parking`).
* **gathering**: walk to my slot as a formation of one. The *speaker* (the first robot of the
  roster not lost: the leader, else its successor) sees every member within
  ``goal_tolerance`` of its slot; a member that reaches its slot stands there.
* **lifting**: every member stands ``lift_ticks`` still.
* **carrying**: the team forms (:func:`leader.team.plan_team` over the members' positions, which
  the lift held still) and carries the load to the destination (the leader routes the
  formation).
  The speaker sees the load (:func:`leader.team.load_pose`) within :data:`SET_DOWN_M` and
  :data:`SET_DOWN_RAD` of the destination, both where it is and wherever it may come to rest
  as the members stop or move on through the set-down (:func:`arrived`), and every member at
  its goal.
* **setting down**: the team stands ``lift_ticks`` still; then the order is delivered: the team
  dissolves, each robot walks out from under the load (:func:`exit_point`), then to its parking
  spot, and is idle again.

A member is lost on positive knowledge of its death (``dead``: its agent's liveliness token
went, :class:`agent.leader_step.Deaths`) from the first tick without its state of the tick
before, or when its position is older than ``lost_ticks`` (:data:`SILENT_S`: a frozen agent whose
token stays); before the lift the speaker releases the roster (the order waits again, as the
simulator's), after it the order fails with ``member lost: RID`` and the load rests where it
stands; either way the team dissolves. A member merely late (a starved machine, a lock-step agent
catching up frames) is waited for: while its state is stale its teammates command zero and its
own robot stops by its base's command watchdog, so the wait costs time, never safety.

Statuses (:class:`wire.orders.OrderStatusMsg` on ``order/{oid}/status``) go out from the
speaker: ``gathering`` from the roster's commit through the lift, ``carrying`` from the lift's
end through the set-down, ``delivered`` once set down, ``failed`` (or ``waiting``, a release)
when a member is lost; each change at once, then again every ``repeat_ticks``. The other members
follow the statuses they hear: ``carrying`` forms the team, ``delivered``, ``failed`` and a
release dissolve it.

A lost status only delays. A member that hears ``carrying`` a repeat late forms the team from
the positions where the whole team last stood still at its slots (:class:`Rest`: every
member's position reported unchanged over half a lift), the speaker's own positions at the
lift, not from where the others have carried the load since. The speaker puts the order's
final status (``delivered`` or ``failed``) again every ``repeat_ticks`` after the team
dissolved, until it speaks another's, so that a member (or any robot) that lost it still
learns the order ended. A status of another round than the job's (an old roster of the same
order) is not this team's.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, replace
from itertools import product
from typing import Any

from geometry.shapes import Shape, box, distance_floor, shape_distance
from leader.team import Point, Pose, TeamPlan, carry_reach, load_pose, plan_team, pose_error
from scenario.lifelong import LoadType
from wire.orders import OrderStatusMsg

#: [s] a teammate silent this long while its liveliness token stays is lost (a frozen agent):
#: Zenoh's default transport lease, after which the token of an agent on a lost link goes
#: anyway, so no shorter silence can be told from a late message
SILENT_S = 10.0
SET_DOWN_M = 0.05  # [m] a load is set down this near its station
SET_DOWN_RAD = math.radians(3.0)  # [rad] and turned this near its heading
LOAD_MARGIN = 0.045  # [m] a resting load's safe distance beyond the robot's radius
EXIT_GAP = 0.15  # [m] a robot leaving a load stops this far beyond its outline
ALLY_REACH = 0.5  # [m] gathering members this near their slots keep apart by separation rows

IDLE, GATHERING, LIFTING, CARRYING, SETTING_DOWN = (
    "idle", "gathering", "lifting", "carrying", "setting-down")
#: each phase's state as the status reports it
REPORTED = {GATHERING: "gathering", LIFTING: "gathering", CARRYING: "carrying",
            SETTING_DOWN: "carrying"}
DELIVERED, FAILED, RELEASED = "delivered", "failed", "waiting"


def load_box(name: str, t: LoadType, pose: Pose, ds: float) -> Shape:
    """A resting load as a box shape (what the planner and the rows keep clear of)."""
    return box(name, (pose[0], pose[1]), t.size, pose[2], ds)


def inside_box(sh: Shape, x: float, y: float, margin: float) -> bool:
    """True when (x, y) lies within ``margin`` of the box (its bounding circle first)."""
    return distance_floor(x, y, sh) < margin and shape_distance(x, y, sh)[0] < margin


def exit_point(load: Shape, p: Point, clear: Callable[[float, float], bool], gap: float) -> Point:
    """Where a robot under ``load`` at ``p`` goes to be out: straight away from the load's
    centre, else turned by steps of 45 degrees, to the first point ``clear`` allows."""
    base = math.atan2(p[1] - load.cy, p[0] - load.cx)
    reach = math.hypot(load.hx, load.hy) + gap
    for k in (0, 1, -1, 2, -2, 3, -3, 4):
        a = base + k * math.pi / 4
        q = (load.cx + reach * math.cos(a), load.cy + reach * math.sin(a))
        if clear(*q):
            return q
    return p


def allies(job: Job, rid: str, at: Mapping[str, Point]) -> tuple[str, ...]:
    """The teammates ``rid`` keeps apart from by separation rows instead of their ellipses while
    gathering (:func:`allies_at` over the job's roster and slots)."""
    return allies_at(job.robots, job.slots, rid, at)


def allies_at(robots: Sequence[str], slots: Sequence[Point], rid: str, at: Mapping[str, Point]
              ) -> tuple[str, ...]:
    """The teammates ``rid`` keeps apart from by separation rows instead of their ellipses while
    gathering, so that members can stand at adjacent slots: when ``rid`` is within
    :data:`ALLY_REACH` of its slot, the others that are (``at``: the members' positions known);
    farther out the ellipses keep them apart as any two formations."""
    mine = slots[robots.index(rid)]
    if rid not in at or math.dist(at[rid], mine) > ALLY_REACH:
        return ()
    return mates_at(robots, slots, rid, at)


def mates_at(robots: Sequence[str], slots: Sequence[Point], rid: str, at: Mapping[str, Point]
             ) -> tuple[str, ...]:
    """The teammates of ``rid`` standing within :data:`ALLY_REACH` of their slots, wherever
    ``rid`` is (``at``: the members' positions known): its route to its own slot goes round
    them as the formations of one its rows keep it off, else past them as robots
    (:func:`leader.routing.round_mates`)."""
    return tuple(r for r, s in zip(robots, slots, strict=True)
                 if r != rid and r in at and math.dist(at[r], s) <= ALLY_REACH)


def route_mates(robots: Sequence[str], slots: Sequence[Point], rid: str,
                at: Mapping[str, Point]) -> tuple[str, ...]:
    """The teammates that ``rid``'s routes go round as robots (:func:`mates_at`) while it is
    farther than :data:`ALLY_REACH` from its own slot; near it they are its allies
    (:func:`allies_at`), out of its planner's view and kept off by separation rows."""
    return mates_at(robots, slots, rid, at) if not allies_at(robots, slots, rid, at) else ()


def way_out(load: Shape, me: Point, clear: Callable[[float, float], bool], radius: float
            ) -> Point | None:
    """Where a robot of ``radius`` at ``me`` goes when its team sets ``load`` (its box) down:
    out from under it (:func:`exit_point`) when it stands within :data:`EXIT_GAP` of it, else
    nowhere (None)."""
    if inside_box(load, me[0], me[1], radius + EXIT_GAP):
        return exit_point(load, me, clear, EXIT_GAP + radius)
    return None


def clear_spot(x: float, y: float, shapes: Sequence[Shape],
               circles: Sequence[tuple[float, float, float]], radius: float) -> bool:
    """True when a robot of ``radius`` may stand with its body at (x, y): its safe distance
    plus the radius off every wall, shelf and resting load (``shapes``) and every circle
    standing still (``circles``: centre and Ds). A way out (:func:`way_out`) inside a pillar's
    safe distance held its robot between the pillar and the load for good, by a sink, in the
    way of the next team there."""
    return all(shape_distance(x, y, sh)[0] >= sh.ds + radius for sh in shapes) and all(
        math.dist((x, y), (cx, cy)) >= ds + radius for cx, cy, ds in circles)


def standing_circles(obstacles: Iterable[Any]) -> tuple[tuple[float, float, float], ...]:
    """The circles among ``obstacles`` (each with ``x``, ``y``, ``ds``, ``vx``, ``vy``) that
    stand still, as centre and Ds: what a way out keeps off (:func:`clear_spot`)."""
    return tuple((o.x, o.y, o.ds) for o in obstacles if o.vx == 0.0 and o.vy == 0.0)


def out_from_under(me: Point, leaving: Point, tolerance: float, offset: float) -> bool:
    """Whether a robot whose body stands at ``me`` is out from under the load its team set
    down, at its way out ``leaving`` (:func:`way_out`): within
    :func:`leader.team.carry_reach` of it (``tolerance`` the goal tolerance, ``offset`` the
    control point's). A unicycle's rows hold its control point, its body sits the look-ahead
    behind on whatever heading: one whose control point stood short of the way out (a body
    position) on the load's barrier, its body 0.12 m off it, counted as never out and never
    walked to its parking spot, standing by a dock in the way of the next team there."""
    return math.dist(me, leaving) <= carry_reach(tolerance, offset)


def sees_load(load: Shape, me: Point, offset: float) -> bool:
    """Whether a robot whose body centre is at ``me`` (its control point ``offset`` ahead) keeps
    clear of the resting ``load``: not while it stands under it (within the load's safe
    distance of its control point's reach), so that it can walk out."""
    return not inside_box(load, me[0], me[1], load.ds + offset)


def per_tick(now: Point, then: Point, ticks: int) -> Point:
    """[m/tick] A robot's motion from ``then`` to ``now``, ``ticks`` apart (none: standing)."""
    if ticks <= 0:
        return (0.0, 0.0)
    return ((now[0] - then[0]) / ticks, (now[1] - then[1]) / ticks)


def rest_points(at: Sequence[Point], steps: Sequence[Point], lift_ticks: int
                ) -> Iterator[list[Point]]:
    """Where the members of a team judged arrived on ``at`` (their positions of the tick before
    the judgement, in slot order, the speaker first) may stand when its load comes to rest, each
    moving at most as over its last tick (``steps``, [m/tick]): every corner of that reach.

    The speaker stands still from the tick it judges on, so it moves one tick more. The others
    stand still at no point of the set-down, to the tick the speaker puts ``delivered``, whose
    positions the load rests on (the simulator sets it down then; the world takes the status at
    that tick, before it moves the robots): each either stops after that one tick too (held back
    by its rows to the standing speaker) or goes on through the ``lift_ticks`` of the set-down,
    or anything between. The load's turn is the angle of sums linear in the members' positions
    (:func:`geometry.rigid.rigid_fit`), so over all the members' places between stopping and
    going on it is at its extremes where each member does one or the other: the corners
    yielded here. A team standing still has its every corner where it stands."""
    for going in product((False, True), repeat=max(0, len(at) - 1)):
        ahead = (1, *(lift_ticks + 1 if g else 1 for g in going))
        yield [(p[0] + n * d[0], p[1] + n * d[1]) for p, d, n in zip(at, steps, ahead, strict=True)]


def set_down_within(pose: Pose, dst: Pose) -> bool:
    """Whether a load at ``pose`` is within :data:`SET_DOWN_M` and :data:`SET_DOWN_RAD` of its
    station's ``dst``."""
    d, a = pose_error(pose, dst)
    return d <= SET_DOWN_M and a <= SET_DOWN_RAD


def arrived(plan: TeamPlan, at: Sequence[Point], steps: Sequence[Point], src: Pose, dst: Pose,
            reach: float, lift_ticks: int) -> bool:
    """Whether a team whose members' bodies stand at ``at`` (moving by ``steps`` a tick) has
    brought its load (lifted at ``src``) to its station ``dst``: every member within ``reach``
    of its goal (:func:`leader.team.carry_reach`: a unicycle's rows hold its control point, its
    body sits the look-ahead behind it, on whatever heading it ends), and the load within the
    set-down tolerance of it (:func:`set_down_within`) both where it is and wherever it may come
    to rest once the speaker stands still and the others stop or move on through the set-down
    (:func:`rest_points`). A team judged on where it is alone would set down a load that its
    members, still moving (a unicycle turning), carry past the tolerance; a still team is judged
    on where it stands, so a team converging on its goals arrives as it slows."""
    if not all(math.dist(p, g) <= reach for p, g in zip(at, plan.goals, strict=True)):
        return False
    return set_down_within(load_pose(plan.starts, at, src), dst) and all(
        set_down_within(load_pose(plan.starts, rest, src), dst)
        for rest in rest_points(at, steps, lift_ticks))


def lost(k: int, seen: Seen | None, since: int, limit: int, dead: bool) -> bool:
    """Whether a teammate last ``seen`` (None: not since the team was taken at tick ``since``)
    is lost at tick ``k``: known ``dead`` and without its state of the tick before (a dead
    robot's last state is its last: every member of a lock-step run decides at the same tick
    whenever it heard the token go, by the next frame), or silent for more than ``limit``
    ticks."""
    last = since if seen is None else max(seen.k, since)
    return (dead and (seen is None or seen.k < k - 1)) or k - last > limit


def parking(robots: Sequence[str], starts: Mapping[str, Pose], spots: Sequence[Point]
            ) -> dict[str, Point]:
    """Each robot's parking spot, the same in every agent: in fleet order, the free spot
    nearest its start (ties to the first listed); a robot left without one has none."""
    free = list(spots)
    out: dict[str, Point] = {}
    for rid in robots:
        if not free:
            break
        s = starts[rid]
        best = min(free, key=lambda q: math.dist(q, (s[0], s[1])))
        out[rid] = best
        free.remove(best)
    return out


@dataclass(frozen=True)
class Job:
    """An order this robot's committed roster serves: the load it moves (its type, its pose
    at the roster's commit), the roster in slot order, each slot in the world, the destination's
    pose and name, and the round that committed the roster."""

    oid: str
    load: str
    type: LoadType
    robots: tuple[str, ...]
    slots: tuple[Point, ...]
    src: Pose
    dst: Pose
    round: int = 0

    def slot_of(self, rid: str) -> Point:
        return self.slots[self.robots.index(rid)]


@dataclass(frozen=True)
class ErrandSettings:
    """The machine's numbers, in ticks: a lift or set-down (``fleet.lift_s``), a member lost
    by silence (its position older than this, :data:`SILENT_S`), statuses put again; the
    arrival tolerance [m], the tick [s] and the control point's offset [m]."""

    lift_ticks: int
    lost_ticks: int
    repeat_ticks: int
    goal_tolerance: float
    tick_s: float = 0.05  # [s] one tick (status stamps are in seconds)
    offset: float = 0.0  # [m] the control point's offset ahead of the body (unicycles)

    def __post_init__(self) -> None:
        if min(self.lift_ticks, self.lost_ticks, self.repeat_ticks) < 0 or self.repeat_ticks < 1:
            raise ValueError("lift_ticks and lost_ticks must be >= 0, repeat_ticks >= 1")


@dataclass(frozen=True)
class Seen:
    """Where a teammate's body stood at tick ``k`` (as its last state said), and ``was``: where
    it stood at the tick of the state before (x, y, tick; None: not known)."""

    x: float
    y: float
    k: int
    was: tuple[float, float, int] | None = None

    def motion(self) -> Point:
        """[m/tick] Its motion between the two (:func:`per_tick`; not known: standing)."""
        if self.was is None:
            return (0.0, 0.0)
        return per_tick((self.x, self.y), (self.was[0], self.was[1]), self.k - self.was[2])


class Rest:
    """Where a team last stood still at its slots: each member's position and the ticks over
    which its reports held it unchanged; :meth:`see` each tick, :attr:`at` the positions (slot
    order) of the last tick at which every member had stood still for ``span`` ticks within
    ``tolerance`` of its slot (None: not yet)."""

    def __init__(self, slots: Sequence[Point], span: int, tolerance: float) -> None:
        self.slots = tuple(slots)
        self.span = span
        self.tolerance = tolerance
        self.still: list[tuple[Point, int, int] | None] = [None] * len(self.slots)
        self.at: tuple[Point, ...] | None = None

    def see(self, reports: Sequence[tuple[Point, int] | None]) -> None:
        """Each member's newest report (position, tick; None: none yet), in slot order."""
        for i, rep in enumerate(reports):
            if rep is None:
                continue
            p, k = rep
            old = self.still[i]
            self.still[i] = (p, old[1], max(k, old[2])) if old is not None and old[0] == p \
                else (p, k, k)
        if all(v is not None and v[2] - v[1] >= self.span
               and math.dist(v[0], q) <= self.tolerance
               for v, q in zip(self.still, self.slots, strict=True)):
            self.at = tuple(v[0] for v in self.still if v is not None)


@dataclass(frozen=True)
class Move:
    """What the agent does after a step: ``walk`` alone to this point (a new goal as a formation
    of one; None: as before), ``team`` form this team (None: as before), ``hold`` stand still
    this tick, ``status`` put this order status, ``done`` the team dissolved (the bidder is told:
    :meth:`agent.bidder.Bidder.finish`)."""

    walk: Point | None = None
    team: TeamPlan | None = None
    hold: bool = False
    status: OrderStatusMsg | None = None
    done: bool = False


class Errand:
    """One fleet robot's errand (module docstring). ``home``: its parking spot (None: where it
    stands when idle); ``clear``: whether a robot may stand at a point (the exit rule);
    ``dead``: whether a robot is known dead (its liveliness token gone; None: never known)."""

    def __init__(self, rid: str, settings: ErrandSettings, home: Point | None = None,
                 clear: Callable[[float, float], bool] | None = None, radius: float = 0.105,
                 dead: Callable[[str], bool] | None = None) -> None:
        self.rid = rid
        self.settings = settings
        self.home = home
        self.clear = clear or (lambda x, y: True)
        self.dead = dead or (lambda r: False)
        self.radius = radius
        self.phase = IDLE
        self.job: Job | None = None
        self.plan: TeamPlan | None = None
        self.since = 0  # [tick] the phase began
        self.said: OrderStatusMsg | None = None  # the status this robot last put as speaker
        self.said_at = -1  # [tick]
        self.heard: str = ""  # the last state heard from the team's speaker
        self.leaving: Point | None = None  # out from under the load just set down
        self.lost: set[str] = set()
        self.finished: list[tuple[str, str]] = []  # (order, how it ended), as seen here
        self.rest: Rest | None = None  # where the team last stood still at its slots
        self.ended: OrderStatusMsg | None = None  # the last final status this robot spoke
        self.ended_at = -1  # [tick] it was last put
        self.was: tuple[Point, int] | None = None  # this robot's position of its last step, tick
        self.moved: Point = (0.0, 0.0)  # [m/tick] its motion from there to this step's

    # --- what it hears --------------------------------------------------------------------

    def take(self, job: Job, k: int) -> Move:
        """The committed roster of ``job`` names this robot: walk to its slot."""
        self.job, self.plan, self.phase, self.since = job, None, GATHERING, k
        self.heard, self.lost, self.leaving = "", set(), None
        self.said, self.said_at = None, -1
        self.rest = Rest(job.slots, max(1, self.settings.lift_ticks // 2),
                         self.settings.goal_tolerance)
        return Move(walk=job.slot_of(self.rid))

    def hear(self, msg: OrderStatusMsg) -> None:
        """A status of this robot's order from its speaker (kept; :meth:`step` acts on it)."""
        job = self.job
        if job is not None and msg.oid == job.oid and msg.round == job.round \
                and msg.leader != self.rid:
            self.heard = msg.state

    @property
    def speaker(self) -> str | None:
        """The robot that decides for the team: the first of the roster not lost."""
        if self.job is None:
            return None
        return next((r for r in self.job.robots if r not in self.lost), None)

    # --- each tick ------------------------------------------------------------------------

    def step(self, k: int, me: Point, mates: Mapping[str, Seen]) -> Move:
        """Tick ``k``, this robot at ``me`` (its position of the tick before), its teammates last
        seen at ``mates``."""
        self.moved = (0.0, 0.0) if self.was is None else per_tick(me, self.was[0],
                                                                  k - 1 - self.was[1])
        self.was = (me, k - 1)
        if self.job is None:
            return self._idle(k, me)
        if self.plan is None and self.rest is not None:
            self.rest.see(self._reports(k, me, mates))
        if self.heard in (DELIVERED, FAILED, RELEASED):  # said by the speaker (or for it)
            return self._dissolve(me, self._positions(me, mates), self.heard, None)
        self._watch(k, mates)
        if self.lost:
            return self._lose(k, me, mates)
        if self.speaker == self.rid:
            return self._speak(k, me, mates)
        return self._follow(k, me, mates)

    def _idle(self, k: int, me: Point) -> Move:
        again = self._again(k)
        if self.leaving is not None and out_from_under(
                me, self.leaving, self.settings.goal_tolerance, self.settings.offset):
            self.leaving = None
            return Move(walk=self.home, status=again) if self.home is not None \
                else Move(status=again)
        return Move(status=again)

    def _again(self, k: int) -> OrderStatusMsg | None:
        """The last final status this robot spoke, due again this tick (every repeat)."""
        if self.ended is None or k - self.ended_at < self.settings.repeat_ticks:
            return None
        self.ended_at = k
        return replace(self.ended, stamp=k * self.settings.tick_s)

    def _reports(self, k: int, me: Point, mates: Mapping[str, Seen]
                 ) -> list[tuple[Point, int] | None]:
        """Each member's newest position and its tick, in slot order (this robot's own: the
        tick before ``k``)."""
        assert self.job is not None
        out: list[tuple[Point, int] | None] = []
        for r in self.job.robots:
            seen = mates.get(r)
            out.append((me, k - 1) if r == self.rid else
                       None if seen is None else ((seen.x, seen.y), seen.k))
        return out

    def _watch(self, k: int, mates: Mapping[str, Seen]) -> None:
        assert self.job is not None
        for r in self.job.robots:
            if r != self.rid and lost(k, mates.get(r), self.since, self.settings.lost_ticks,
                                      self.dead(r)):
                self.lost.add(r)

    def _positions(self, me: Point, mates: Mapping[str, Seen]) -> list[Point] | None:
        assert self.job is not None
        out = []
        for r in self.job.robots:
            if r == self.rid:
                out.append(me)
            elif r in mates:
                out.append((mates[r].x, mates[r].y))
            else:
                return None
        return out

    def _form(self, at: Sequence[Point]) -> TeamPlan:
        """The team's plan from where its members stood still through the lift (``at``, the
        positions of the moment, until they have)."""
        job = self.job
        assert job is not None
        if self.rest is not None and self.rest.at is not None:
            at = self.rest.at
        self.plan = plan_team(job.oid, job.robots, job.type.slots, job.type.outline, at,
                              (job.src, job.dst))
        return self.plan

    def _status(self, k: int, state: str, reason: str = "") -> OrderStatusMsg | None:
        """The status to put this tick as speaker: a change at once, else every repeat."""
        job = self.job
        assert job is not None
        msg = OrderStatusMsg(job.oid, state, job.round, job.robots, self.rid, reason,
                             k * self.settings.tick_s)
        if self.said is None or (self.said.state, self.said.reason) != (state, reason) \
                or k - self.said_at >= self.settings.repeat_ticks:
            self.said, self.said_at = msg, k
            return msg
        return None

    def _speak(self, k: int, me: Point, mates: Mapping[str, Seen]) -> Move:
        """The speaker's tick: the phase's condition, then its status."""
        job, s = self.job, self.settings
        assert job is not None
        at = self._positions(me, mates)
        team: TeamPlan | None = None
        if self.phase == GATHERING and at is not None and all(
                math.dist(p, q) <= s.goal_tolerance for p, q in zip(at, job.slots, strict=True)):
            self.phase, self.since = LIFTING, k
        elif self.phase == LIFTING and at is not None and k - self.since >= s.lift_ticks:
            team = self._form(at)
            self.phase, self.since = CARRYING, k
        elif self.phase == CARRYING and at is not None and self._arrived(at, mates):
            self.phase, self.since = SETTING_DOWN, k
        elif self.phase == SETTING_DOWN and k - self.since >= s.lift_ticks:
            return self._dissolve(me, at, DELIVERED, self._status(k, DELIVERED))
        hold = self.phase in (LIFTING, SETTING_DOWN)
        return Move(team=team, hold=hold, status=self._status(k, REPORTED[self.phase]))

    def _arrived(self, at: Sequence[Point], mates: Mapping[str, Seen]) -> bool:
        """The team has brought the load to its station (:func:`arrived`, each member moving as
        over its last two reports, this robot as over its last two steps)."""
        job, plan = self.job, self.plan
        assert job is not None and plan is not None
        s = self.settings
        steps = [self.moved if r == self.rid else mates[r].motion() for r in job.robots]
        return arrived(plan, at, steps, job.src, job.dst, carry_reach(s.goal_tolerance, s.offset),
                       s.lift_ticks)

    def _follow(self, k: int, me: Point, mates: Mapping[str, Seen]) -> Move:
        """A member's tick: the speaker's statuses decide; at its slot it stands."""
        job = self.job
        assert job is not None
        if self.heard == CARRYING and self.plan is None:
            at = self._positions(me, mates)
            if at is not None:
                self.phase, self.since = CARRYING, k
                return Move(team=self._form(at))
        if self.plan is None:
            near = math.dist(me, job.slot_of(self.rid)) <= self.settings.goal_tolerance
            return Move(hold=near)
        return Move()

    def _lose(self, k: int, me: Point, mates: Mapping[str, Seen]) -> Move:
        """A member lost: the speaker fails the order (releases the roster before the lift)."""
        lost = min(self.lost)
        state = FAILED if self.plan is not None else RELEASED
        status = self._status(k, state, f"member lost: {lost}") if self.speaker == self.rid \
            else None
        # after a lift the load rests where the members hold it (a lost one where last seen)
        return self._dissolve(me, self._positions(me, mates), state, status)

    def rests(self, at: Sequence[Point] | None, how: str) -> Pose:
        """Where the load of the team's order rests once it dissolves ``how``: at the
        destination when delivered, where the members hold it after a lift (``at``: their
        positions, None: not all known), else where it was."""
        job = self.job
        assert job is not None
        if how == DELIVERED:
            return job.dst
        if self.plan is not None and at is not None:
            return load_pose(self.plan.starts, at, job.src)
        return job.src

    def _dissolve(self, me: Point, at: Sequence[Point] | None, how: str,
                  status: OrderStatusMsg | None) -> Move:
        """The team dissolves: out from under the load, then to the parking spot."""
        job = self.job
        assert job is not None
        self.finished.append((job.oid, how))
        if status is not None and how in (DELIVERED, FAILED):
            self.ended, self.ended_at = status, round(status.stamp / self.settings.tick_s)
        walk = self.home
        sh = load_box(job.load, job.type, self.rests(at, how), self.radius + LOAD_MARGIN)
        out = way_out(sh, me, self.clear, self.radius)
        if out is not None:
            self.leaving = walk = out
        self.job, self.plan, self.phase, self.heard = None, None, IDLE, ""
        return Move(walk=walk if walk is not None else me, status=status, done=True)
