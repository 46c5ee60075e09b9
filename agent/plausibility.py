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

Pure functions and a small class over floats; no clock is read here.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass, field

from wire.payloads import EllipseMsg, ObstacleMsg, Obstacles

from .barriers import Obstacle
from .control import ControlParams

SPEED_FACTOR = 1.2  # a genuine message moves at most this times the robots' speed limit
JUMP_MARGIN_M = 0.05  # [m] a pose may move this much more (camera noise, rounding)
REACQUIRE_POSES = 3  # consecutive agreeing poses after a jump that re-acquire the marker
REACQUIRE_SPAN_S = 0.3  # [s] ... over at least this long (several frames of any camera's rate)
POINT_REACH = 2.0  # an ellipse's member points lie within this many semi-major axes of it
POINT_MARGIN_M = 1.0  # [m] ... and this much more
OBSTACLE_HOLD_S = 2.0  # [s] how long a missing obstacle is kept (its Ds grown meanwhile)


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

    def __post_init__(self) -> None:
        if not (math.isfinite(self.hold_s) and self.hold_s >= 0):
            raise ValueError(f"hold_s: must be a finite number >= 0, got {self.hold_s!r}")

    def update(self, msg: Obstacles) -> None:
        """Take a new list (one stamped no later than the last taken changes nothing)."""
        if msg.stamp <= self._stamp:
            return
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
