"""The world's extent, and the check every goal passes at the door (``formation goal``) and again
at the leader that receives it.

A goal, waypoint or heading is a value from outside the fleet (an operator, a fleet manager's
program): one ``1e308`` made every member of a formation compute NaN on every tick. The extent is
the bounding box of the scenario's starts, goals and obstacles (moving ones where they start),
grown by :data:`MARGIN_M` on every side and never beyond the scenario's coordinate range
(:data:`scenario.limits.COORDINATE`): a goal 100 m past anything the scenario names is taken for
a typing error, not a destination. Pure: numbers in, a one-line reason (or ``None``) out.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

from .limits import COORDINATE, HEADING, MAX_WAYPOINTS
from .model import Scenario

MARGIN_M = 100.0  # [m] room beyond the scenario's starts, goals and obstacles


@dataclass(frozen=True)
class Extent:
    """An axis-aligned box on the floor [m]."""

    xmin: float
    ymin: float
    xmax: float
    ymax: float

    def contains(self, x: float, y: float) -> bool:
        return self.xmin <= x <= self.xmax and self.ymin <= y <= self.ymax

    def text(self) -> str:
        return f"x {self.xmin:g}..{self.xmax:g} m, y {self.ymin:g}..{self.ymax:g} m"


def _points(scenario: Scenario) -> Iterable[tuple[float, float]]:
    for r in scenario.robots:
        yield r.start[0], r.start[1]
        yield r.goal
    for f in scenario.formations:
        yield from f.waypoints
    for o in scenario.obstacles:
        yield o.center
    for s in scenario.shapes:
        yield s.cx, s.cy


def world_extent(scenario: Scenario, margin: float = MARGIN_M) -> Extent:
    """The scenario's extent grown by ``margin``, clipped to the coordinate range."""
    xs, ys = zip(*_points(scenario), strict=True)
    lo, hi = COORDINATE.lo, COORDINATE.hi
    return Extent(max(lo, min(xs) - margin), max(lo, min(ys) - margin),
                  min(hi, max(xs) + margin), min(hi, max(ys) + margin))


def point_problem(name: str, x: float, y: float, extent: Extent) -> str | None:
    """Why the point (x, y) named ``name`` cannot be a goal, or ``None``."""
    if not (math.isfinite(x) and math.isfinite(y)):
        return f"{name} ({x!r}, {y!r}) is not a finite point"
    if not extent.contains(x, y):
        return f"{name} ({x:g}, {y:g}) is outside the world ({extent.text()})"
    return None


def goal_problem(x: float, y: float, heading: float | None,
                 route: Sequence[tuple[float, float]], extent: Extent) -> str | None:
    """Why a goal (x, y), optional ``heading`` [rad] and ``route`` (points passed in order) is
    refused, in one line, or ``None`` to accept it."""
    problem = point_problem("goal", x, y, extent)
    if problem is not None:
        return problem
    if heading is not None and not (math.isfinite(heading) and HEADING.contains(heading)):
        return f"heading {heading!r} is not {HEADING.text()}"
    if len(route) > MAX_WAYPOINTS:  # the route with its goal must fit a plan (wire.payloads)
        return f"the route holds {len(route)} points, at most {MAX_WAYPOINTS}"
    for k, (px, py) in enumerate(route):
        problem = point_problem(f"route point {k + 1}", px, py, extent)
        if problem is not None:
            return problem
    return None
