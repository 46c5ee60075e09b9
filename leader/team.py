"""A committed roster to a team's formation: who stands where, which edges, who leads.

A load type names its slots in the load frame (origin at the load's centre, x along its long
axis); the roster's robot ``i`` takes slot ``i``. The team's formation (DESIGN.md, "Lifelong
operation") has an edge between every pair of slots at their load-frame distance, the robot at
the first slot leads and the second succeeds. When every member stands at its slot the team
lifts: from then on the load moves with the members as one rigid body (the least-squares rigid
motion of their start positions, :func:`geometry.rigid.rigid_fit`), so each member's goal is
where the rigid motion that takes the load from its pose to the destination's puts it
(:func:`carry_goals`): a team that reaches its goals sets the load down exactly at the
destination, whatever each member's small error at its slot was.

Pure functions over floats; the simulator turns a :class:`TeamPlan` into a formation.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from itertools import combinations

from geometry.ellipse import wrap_angle
from geometry.rigid import rigid_fit

Point = tuple[float, float]
Pose = tuple[float, float, float]  # x, y [m], yaw [rad]


def to_world(pose: Pose, p: Point) -> Point:
    """The load-frame point ``p`` in the world, the load resting at ``pose``."""
    c, s = math.cos(pose[2]), math.sin(pose[2])
    return (pose[0] + c * p[0] - s * p[1], pose[1] + s * p[0] + c * p[1])


def to_load(pose: Pose, p: Point) -> Point:
    """The world point ``p`` in the frame of a load resting at ``pose``."""
    c, s = math.cos(pose[2]), math.sin(pose[2])
    dx, dy = p[0] - pose[0], p[1] - pose[1]
    return (c * dx + s * dy, -s * dx + c * dy)


def slot_points(pose: Pose, slots: Sequence[Point]) -> tuple[Point, ...]:
    """Every slot in the world, the load resting at ``pose``."""
    return tuple(to_world(pose, s) for s in slots)


def rectangle(size: Point) -> tuple[Point, ...]:
    """A load of ``size`` (length along x, width) in its own frame, counter-clockwise."""
    hx, hy = 0.5 * size[0], 0.5 * size[1]
    return ((hx, -hy), (hx, hy), (-hx, hy), (-hx, -hy))


def carry_goals(starts: Sequence[Point], src: Pose, dst: Pose) -> tuple[Point, ...]:
    """Each member's goal: its start position moved by the rigid motion that takes a load from
    ``src`` to ``dst``."""
    return tuple(to_world(dst, to_load(src, p)) for p in starts)


def load_pose(starts: Sequence[Point], now: Sequence[Point], src: Pose) -> Pose:
    """Where the carried load is: its pose at the lift ``src`` moved by the members' rigid
    motion from their positions at the lift ``starts`` to ``now``."""
    m = rigid_fit(starts, now)
    x, y = m.apply((src[0], src[1]))
    return (x, y, wrap_angle(src[2] + m.theta))


def carry_reach(goal_tolerance: float, offset: float) -> float:
    """[m] How near its carry goal each member's body stands for its team to set the load down:
    ``goal_tolerance`` plus twice the control point's ``offset`` from the body (a unicycle's
    look-ahead, thesis section 6.2; 0 for a holonomic robot, whose reach is the goal tolerance).

    Why: the team's rows and its rigid motion hold the members' control points, in the shape
    those points had when the team's formation was built, while each goal is a body position (the
    rigid carry of where the bodies stood at the lift). A unicycle's body sits ``offset`` behind
    its control point on its heading, so a member that ends facing otherwise than when the shape
    was taken stands up to twice that off its goal with its control point where the formation
    puts it, and a team held to the goal tolerance stood short of the set-down for good with its
    load within the set-down tolerance of its station. The load itself is judged at that
    tolerance whatever the robot."""
    return goal_tolerance + 2.0 * offset


def pose_error(a: Pose, b: Pose) -> tuple[float, float]:
    """The distance [m] and the absolute heading difference [rad] between two poses."""
    return math.hypot(a[0] - b[0], a[1] - b[1]), abs(wrap_angle(a[2] - b[2]))


@dataclass(frozen=True)
class TeamPlan:
    """The team of one order: ``robots[i]`` at slot ``i``; ``edges`` (i, j, df) between every
    pair of members; ``starts`` and ``goals`` their body positions at the lift and at the
    set-down; ``outline`` the load in the start frame (origin at the centroid of ``starts``)."""

    oid: str
    robots: tuple[str, ...]
    edges: tuple[tuple[str, str, float], ...]
    starts: tuple[Point, ...]
    goals: tuple[Point, ...]
    outline: tuple[Point, ...]

    @property
    def leader(self) -> str:
        """The robot at the first slot."""
        return self.robots[0]

    @property
    def successor(self) -> str | None:
        """The robot at the second slot, if any."""
        return self.robots[1] if len(self.robots) > 1 else None


def team_edges(robots: Sequence[str], slots: Sequence[Point]) -> tuple[tuple[str, str, float], ...]:
    """An edge between every pair of members, at their slots' distance in the load frame."""
    if len(robots) != len(slots):
        raise ValueError(f"robots: {len(robots)} for {len(slots)} slots")
    return tuple((robots[i], robots[j], math.dist(slots[i], slots[j]))
                 for i, j in combinations(range(len(robots)), 2))


def plan_team(oid: str, robots: Sequence[str], slots: Sequence[Point], outline: Sequence[Point],
              starts: Sequence[Point], moves: tuple[Pose, Pose]) -> TeamPlan:
    """The team that lifts the load of ``outline`` (load frame) resting at ``moves[0]`` with its
    members at ``starts`` (world, slot order) and sets it down at ``moves[1]``."""
    src, dst = moves
    n = len(starts)
    cx, cy = sum(p[0] for p in starts) / n, sum(p[1] for p in starts) / n
    placed = slot_points(src, outline)
    return TeamPlan(oid, tuple(robots), team_edges(robots, slots), tuple(starts),
                    carry_goals(starts, src, dst), tuple((x - cx, y - cy) for x, y in placed))


def axis_turn(heading: float, yaw: float) -> float:
    """[rad] How far ``heading`` is turned from the axis of yaw ``yaw``, either way along it
    (0 to pi/2): a differential drive under a load faces its axis from either end."""
    return abs(wrap_angle(2.0 * (heading - yaw))) / 2.0


def at_slots(positions: Sequence[Point], headings: Sequence[float | None], slots: Sequence[Point],
             tolerance: float, yaw: float, turn_tolerance: float) -> bool:
    """True when every member is within ``tolerance`` of its slot and, where it has a heading
    (``None``: a holonomic robot, any heading), faces within ``turn_tolerance`` of ``yaw`` or its
    opposite (a differential drive lifts from either end)."""
    for p, th, s in zip(positions, headings, slots, strict=True):
        if math.dist(p, s) > tolerance:
            return False
        if th is not None and axis_turn(th, yaw) > turn_tolerance:
            return False
    return True
