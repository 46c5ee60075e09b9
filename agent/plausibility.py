"""Plausibility of what an agent hears: inputs that break physics are refused, lost obstacles held.

A pose or a neighbour's state can be wrong without being malformed: a camera that misreads a
marker, a peer with a bug, or (with access control off) anyone on the network. Physics bounds
what a genuine message can say, given the last one accepted on the same key:

* a **position jump** (a robot's pose, a neighbour's control point) longer than the distance the
  robot can cover in the time between the two stamps, ``speed_bound * elapsed +
  JUMP_MARGIN_M`` (the margin covers the camera's noise; ``elapsed`` is taken from the stamps,
  so a pose after a dropout may move as far as the robot could have driven meanwhile);
* a **velocity** beyond what the robots' limits allow: a state's ``(ux, uy)`` or an ellipse's
  centroid velocity longer than :func:`speed_bound`;
* an ellipse's **member point** far outside it (:func:`points_ok`).

Such a message is dropped and counted; the agent's next tick commands zero (the least-risk
command) and counts it (``agent.node``). The first message on a key has nothing to be compared
with and is accepted (its stamp still passes :mod:`wire.stamps`).

A **marker that jumps** (the camera found the robot's marker elsewhere, or read another marker
with its id) is re-acquired by :class:`Reacquire`: once at least :data:`REACQUIRE_POSES` poses in a row,
spanning at least :data:`REACQUIRE_SPAN_S`, each refused as a jump from the pose kept, agree
with each other (each plausible after the one before it), and only while the robot has been
commanded zero since the jump (it cannot have driven off meanwhile). A genuine pose that still
agrees with the kept one breaks the run, so two sources of one marker (a forger at three times
the camera's rate, a second marker with the id) never agree for long enough: the robot stays
commanded zero, which is safe, and is counted.

A **moving obstacle missing from a new obstacle list** (the camera lost it, or a list was
forged) is not forgotten at once: :class:`ObstacleMemory` keeps its last sighting for
``hold_s`` seconds, during which the agent avoids the disc it can have reached, its safe distance
grown by ``speed * age`` (:func:`held_obstacle`); after that it is dropped and counted (a
forklift that drove out of the camera's view is gone for good). Static obstacles missing from a
list are held the same way (they grow by nothing).

**Two sources on the obstacle list** (:class:`ObstacleRivals`): a list that disagrees with the
one kept (:func:`obstacles_agree`, :func:`common_agree`) where one publisher's lists cannot is a
second source, a forger or a faulty camera, and neither can be trusted to be the genuine one.
While both come the agent avoids every obstacle either reports: the kept list's, and each
rival's moved on by its velocity to now (:func:`rival_obstacles`), with the walls and shelves
of both. A forger can at worst make a robot avoid a phantom (or, with more sources than it
tracks, stop); it cannot take a real obstacle away.

Pure functions and small classes over floats; no clock is read here.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass, field

from wire.payloads import EllipseMsg, ObstacleMsg, Obstacles, ShapeMsg

from .barriers import Obstacle
from .control import ControlParams

SPEED_FACTOR = 1.2  # a genuine message moves at most this times the robots' speed limit
JUMP_MARGIN_M = 0.05  # [m] a pose may move this much more (camera noise, rounding)
REACQUIRE_POSES = 3  # consecutive agreeing poses after a jump that re-acquire the marker
REACQUIRE_SPAN_S = 0.3  # [s] ... over at least this long (several frames of any camera's rate)
POINT_REACH = 2.0  # an ellipse's member points lie within this many semi-major axes of it
POINT_MARGIN_M = 1.0  # [m] ... and this much more
OBSTACLE_HOLD_S = 2.0  # [s] how long a missing obstacle is kept (its Ds grown meanwhile)
DS_TOLERANCE_M = 1e-3  # [m] a later sighting of an obstacle may not have a Ds smaller by more
RIVAL_HOLD_S = 1.0  # [s] a rival obstacle list is avoided this long after it came
MAX_RIVALS = 4  # rival sources tracked at once; more and the robot stops (ObstacleRivals)


def speed_bound(params: ControlParams) -> float:
    """[m/s] The fastest a robot's control point (or a formation's centroid) can genuinely move:
    the speed limit, for a unicycle combined with the look-ahead point's sweep
    ``lookahead * max_turn_rate`` (chapter 6.2), times :data:`SPEED_FACTOR`."""
    v = params.max_speed
    if params.unicycle:
        v = math.hypot(v, params.lookahead * params.max_turn_rate)
    return SPEED_FACTOR * v


def jump_ok(prev_x: float, prev_y: float, prev_stamp: float, x: float, y: float, stamp: float,
            speed: float, margin: float = JUMP_MARGIN_M) -> bool:
    """Whether moving from (prev_x, prev_y) at ``prev_stamp`` to (x, y) at ``stamp`` is possible
    at ``speed`` [m/s], with ``margin`` [m] to spare."""
    elapsed = max(0.0, stamp - prev_stamp)
    return math.hypot(x - prev_x, y - prev_y) <= speed * elapsed + margin


@dataclass
class Reacquire:
    """The run of jumped poses that agree with each other since the kept pose (module docstring).
    :meth:`offer` each refused pose; :meth:`reset` on each pose accepted as plausible."""

    speed: float  # [m/s] :func:`speed_bound`
    need: int = REACQUIRE_POSES
    span: float = REACQUIRE_SPAN_S
    run: list[tuple[float, float, float]] = field(default_factory=list)  # (x, y, stamp)

    def offer(self, x: float, y: float, stamp: float, still_since_jump: bool) -> bool:
        """A pose refused as a jump: True when it completes the run and the robot has been
        commanded zero since the jump, i.e. take it as the new kept pose (the run restarts)."""
        if self.run and not jump_ok(*self.run[-1], x, y, stamp, self.speed):
            self.run.clear()
        self.run.append((x, y, stamp))
        lasted = self.run[-1][2] - self.run[0][2] >= self.span
        if len(self.run) >= self.need and lasted and still_since_jump:
            self.run.clear()
            return True
        return False

    def reset(self) -> None:
        self.run.clear()


def velocity_ok(vx: float, vy: float, speed: float) -> bool:
    """Whether a claimed velocity is within ``speed`` [m/s] (a small rounding allowance)."""
    return math.hypot(vx, vy) <= speed + 1e-9


def points_ok(e: EllipseMsg) -> bool:
    """Whether every member point of ``e`` is within :data:`POINT_REACH` of it: 2 a (its
    semi-major axis) from its centre, plus :data:`POINT_MARGIN_M`. A genuine leader's members
    sit inside their ellipse, and one whose band broke stays well within this."""
    reach = (POINT_REACH * e.a + POINT_MARGIN_M) ** 2
    return all((x - e.cx) ** 2 + (y - e.cy) ** 2 <= reach for x, y in e.points)


def ellipse_ok(e: EllipseMsg, speed: float) -> bool:
    """Whether ``e``'s centroid velocity is within ``speed`` and its points near it."""
    return velocity_ok(e.vx, e.vy, speed) and points_ok(e)


def ellipses_ok(ellipses: Iterable[EllipseMsg], speed: float) -> bool:
    """Whether every ellipse passes :func:`ellipse_ok`."""
    return all(ellipse_ok(e, speed) for e in ellipses)


def held_obstacle(o: ObstacleMsg, age: float, px: float, py: float) -> Obstacle:
    """The row-ready obstacle for ``o`` last seen ``age`` seconds ago, for a robot whose control
    point is (px, py): the disc everywhere it can have reached, centred on its last sighting
    with ``Ds + speed * age``. Its velocity is ``speed`` pointing at the robot, so the CBF row's
    time term is the disc's growth seen from the robot (eq. 4.5 with a growing Ds: at the
    boundary, d/dt of ``|p - c|^2 - (Ds + s t)^2`` is ``2 (p - c) . u - 2 |p - c| s``)."""
    speed = math.hypot(o.vx, o.vy)
    grown = o.ds + speed * max(0.0, age)
    dx, dy = px - o.x, py - o.y
    d = math.hypot(dx, dy)
    vx, vy = (speed * dx / d, speed * dy / d) if d > 1e-9 else (0.0, 0.0)
    return Obstacle(o.x, o.y, vx, vy, grown)


_ROWS: dict[int, tuple[Obstacles, tuple[Obstacle, ...]]] = {}  # id of a list -> its rows' form
_ROWS_MAX = 64  # lists remembered (emptied when full)


def listed_obstacles(msg: Obstacles) -> tuple[Obstacle, ...]:
    """The obstacles of the list ``msg`` in the rows' form (:class:`agent.barriers.Obstacle`),
    converted once per list in a process: every agent of an agent host holds the same decoded
    list (:class:`agent.inbox.DecodeMemo`), each tick until the next one comes; lists are
    frozen, so the form of one is the form of it for every reader."""
    hit = _ROWS.get(id(msg))
    if hit is not None and hit[0] is msg:
        return hit[1]
    rows = tuple(Obstacle(o.x, o.y, o.vx, o.vy, o.ds) for o in msg.obstacles)
    if len(_ROWS) >= _ROWS_MAX:
        _ROWS.clear()
    _ROWS[id(msg)] = (msg, rows)
    return rows


@dataclass
class ObstacleMemory:
    """Every obstacle seen, with the stamp of the list it was last in (see the module
    docstring). :meth:`update` with each new list; :meth:`held` for the missing ones."""

    hold_s: float = OBSTACLE_HOLD_S
    missing: int = 0  # times an obstacle was absent from a list after being in the previous one
    dropped: int = 0  # obstacles dropped once held for hold_s
    _seen: dict[str, tuple[ObstacleMsg, float]] = field(default_factory=dict)
    _current: frozenset[str] = frozenset()
    _stamp: float = -math.inf
    _last: Obstacles | None = None  # the list last taken (taking it again changes nothing)

    def __post_init__(self) -> None:
        if not (math.isfinite(self.hold_s) and self.hold_s >= 0):
            raise ValueError(f"hold_s: must be a finite number >= 0, got {self.hold_s!r}")

    def update(self, msg: Obstacles) -> None:
        """Take a new list (one stamped before the last taken changes nothing; one stamped the
        same is taken: two sources can stamp alike, and the agent steps on whichever it kept)."""
        if msg is self._last or msg.stamp < self._stamp:
            return
        self._last = msg
        self._stamp = msg.stamp
        present = frozenset(o.id for o in msg.obstacles)
        self.missing += sum(1 for i in self._current if i not in present)
        self._current = present
        for o in msg.obstacles:
            self._seen[o.id] = (o, msg.stamp)

    def held(self, now: float) -> list[tuple[ObstacleMsg, float]]:
        """The obstacles missing from the newest list and last seen at most ``hold_s`` before
        ``now``, with their ages [s]; older ones are dropped here (counted)."""
        out: list[tuple[ObstacleMsg, float]] = []
        for ident, (o, stamp) in list(self._seen.items()):
            if ident in self._current:
                continue
            age = now - stamp
            if age > self.hold_s:
                del self._seen[ident]
                self.dropped += 1
            else:
                out.append((o, age))
        return out


def sighting_agrees(a: ObstacleMsg, a_stamp: float, b: ObstacleMsg, b_stamp: float,
                    margin: float = JUMP_MARGIN_M) -> bool:
    """Whether two sightings of one obstacle, ``a`` in the list stamped ``a_stamp`` and ``b`` in
    the one stamped ``b_stamp``, can be of the same thing: the later one's disc holds the
    earlier one moved on by its velocity, within ``margin`` plus what the change of velocity
    between them can have moved it (``|dv| |dt|``: a forklift that turned). The later Ds may
    have grown (a camera holding an obstacle it lost grows its Ds and keeps its position), and
    then its centre may be off by that much more; it may not have shrunk."""
    early, late, t0, t1 = (a, b, a_stamp, b_stamp) if a_stamp <= b_stamp else \
        (b, a, b_stamp, a_stamp)
    grown = late.ds - early.ds
    if grown < -DS_TOLERANCE_M:
        return False
    dt = t1 - t0
    off = math.hypot(late.x - (early.x + early.vx * dt), late.y - (early.y + early.vy * dt))
    return off <= margin + math.hypot(late.vx - early.vx, late.vy - early.vy) * dt + max(0.0, grown)


def common_agree(a: Obstacles, b: Obstacles) -> bool:
    """Whether two obstacle lists agree on what they both report: the same walls and shelves,
    and every obstacle in both seen where the other puts it (:func:`sighting_agrees`). An
    obstacle in one list only says nothing here (it came into or left the camera's view)."""
    if a.shapes is not b.shapes and a.shapes != b.shapes:
        return False
    if not a.obstacles or not b.obstacles:
        return True
    mine = {o.id: o for o in a.obstacles}
    for o in b.obstacles:
        m = mine.get(o.id)
        if m is not None and not sighting_agrees(m, a.stamp, o, b.stamp):
            return False
    return True


def obstacles_agree(a: Obstacles, b: Obstacles) -> bool:
    """Whether two obstacle lists can come from one source at their stamps: the same obstacles
    (by id) agreeing on each (:func:`common_agree`)."""
    if {o.id for o in a.obstacles} != {o.id for o in b.obstacles}:
        return False
    return common_agree(a, b)


def moved_on(o: ObstacleMsg, age: float) -> Obstacle:
    """The row-ready obstacle ``o`` seen ``age`` seconds ago, moved on by its velocity to now
    (a list stamped ahead of the clock is not moved back)."""
    age = max(0.0, age)
    return Obstacle(o.x + o.vx * age, o.y + o.vy * age, o.vx, o.vy, o.ds)


def rival_obstacles(rivals: Iterable[Obstacles], now: float) -> list[Obstacle]:
    """Every obstacle of the rival lists, each moved on to ``now`` (:func:`moved_on`)."""
    return [moved_on(o, now - msg.stamp) for msg in rivals for o in msg.obstacles]


def shapes_of_all(kept: Obstacles, rivals: Iterable[Obstacles]) -> tuple[ShapeMsg, ...]:
    """The walls and shelves of the kept list and of every rival, each once."""
    out = dict.fromkeys(kept.shapes)
    for msg in rivals:
        out.update(dict.fromkeys(msg.shapes))
    return tuple(out)


@dataclass
class ObstacleRivals:
    """The obstacle lists of the sources other than the kept list's (module docstring), each
    source the newest of a run of lists that agree with each other (:func:`obstacles_agree`),
    kept :data:`RIVAL_HOLD_S` after its last list came. :meth:`offer` each list found to
    disagree with the kept one; :meth:`current` for the tick. More than ``capacity`` sources at
    once overflow: :meth:`overflowed` until the hold has passed (the robot stops)."""

    hold_s: float = RIVAL_HOLD_S
    capacity: int = MAX_RIVALS
    # (the source's newest list, when it came); replaced whole, read by the tick's thread
    _sources: tuple[tuple[Obstacles, float], ...] = ()
    _overflow_at: float = -math.inf

    def offer(self, msg: Obstacles, now: float) -> None:
        """A list of a second source, come at ``now`` (the receiver's clock)."""
        sources = [s for s in self._sources if now - s[1] < self.hold_s]
        for i, (kept, _) in enumerate(sources):
            if obstacles_agree(kept, msg):  # the same source's next list: newest wins
                sources[i] = (msg, now) if msg.stamp >= kept.stamp else (kept, now)
                self._sources = tuple(sources)
                return
        if len(sources) >= self.capacity:
            self._overflow_at = now
            sources.sort(key=lambda s: s[1])
            sources.pop(0)
        sources.append((msg, now))
        self._sources = tuple(sources)

    def current(self, now: float) -> tuple[Obstacles, ...]:
        """The rival sources' newest lists at ``now`` (none once each has been quiet for the
        hold)."""
        if not self._sources:
            return ()
        return tuple(msg for msg, came in self._sources if now - came < self.hold_s)

    def overflowed(self, now: float) -> bool:
        """Whether more sources than ``capacity`` came within the hold before ``now``."""
        return now - self._overflow_at < self.hold_s
