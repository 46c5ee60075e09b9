"""The route each formation starts with: its ``waypoints`` from the file, or the leader's plan
around the walls and shelves (:func:`geometry.route.plan_route`; under ``controller.method:
rigid`` the footprint's, :func:`geometry.footprint_plan.plan_footprint`, with a heading per
point), then its goal centroid.

One function for the in-process simulator and the agent configuration, so both start on the
same route."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple

from geometry.ellipse import estimate, reference_shape, wrap_angle
from geometry.footprint_plan import PLAN_MARGIN, Body, Circle, plan_footprint
from geometry.route import Point, formation_radius, plan_route

from .cargo import load_polygon
from .limits import MAX_WAYPOINTS
from .model import FormationSpec, Scenario

RIGID = "rigid"


class StartPlan(NamedTuple):
    """A formation's first route: the points (its goal centroid last), a heading per point (the
    goal shape's turn; () for none) and, where no route reaches the goal, why."""

    route: tuple[Point, ...]
    headings: tuple[float | None, ...] = ()
    reason: str = ""


def shape_turn(bodies: Sequence[Point], goals: Sequence[Point]) -> float:
    """[rad] the rotation from the start shape (body positions) to the goal shape: the
    least-squares rotation of :func:`geometry.ellipse.estimate`."""
    ref = reference_shape(list(bodies))
    return wrap_angle(estimate(ref, (1.0, 1.0), list(goals), [(0.0, 0.0)] * len(goals)).alpha
                      - ref.alpha0)


def control_points(scenario: Scenario, formation: FormationSpec) -> list[Point]:
    """The members' start control points (a unicycle's look-ahead point, eq. 6.2)."""
    off = scenario.robot.control_offset
    return [(r.start[0] + off * math.cos(r.start[2]), r.start[1] + off * math.sin(r.start[2]))
            for r in formation.robots]


def footprint_body(scenario: Scenario, formation: FormationSpec) -> tuple[Body, Point, float]:
    """The footprint the planner moves (its slots: the start control points about their
    centroid; its load as declared), that centroid, and the turn to the goal shape. The margin
    covers what the formation QP keeps (epsilon and the look-ahead offset) and PLAN_MARGIN."""
    pts = control_points(scenario, formation)
    cx, cy = sum(x for x, _y in pts) / len(pts), sum(y for _x, y in pts) / len(pts)
    load = tuple((x - cx, y - cy) for x, y in load_polygon(formation)) if formation.load else ()
    margin = PLAN_MARGIN + scenario.controller.epsilon + scenario.robot.control_offset
    body = Body(tuple((x - cx, y - cy) for x, y in pts), load, scenario.robot.radius, margin)
    turn = shape_turn([r.start[:2] for r in formation.robots], [r.goal for r in formation.robots])
    return body, (cx, cy), turn


def static_circles(scenario: Scenario) -> tuple[Circle, ...]:
    """The circles that never move (planned around like shelves)."""
    return tuple((o.center[0], o.center[1], o.safe_distance) for o in scenario.obstacles
                 if o.velocity == (0.0, 0.0))


def start_plan(scenario: Scenario, formation: FormationSpec) -> StartPlan:
    """:func:`initial_route`, and under ``method: rigid`` the footprint's plan with headings."""
    if formation.waypoints or scenario.controller.method != RIGID \
            or scenario.controller.planner == "none":
        hs = formation.waypoint_headings
        return StartPlan(initial_route(scenario, formation), hs + (None,) if hs else ())
    circles = static_circles(scenario)
    if not scenario.shapes and not circles:  # open floor: the straight move, turning as it goes
        return StartPlan((formation.goal_centroid,), (0.0,))
    body, start, turn = footprint_body(scenario, formation)
    gx, gy = formation.goal_centroid
    plan = plan_footprint((start[0], start[1], 0.0), (gx, gy, turn), body, scenario.shapes,
                          circles)
    if plan.reason:
        return StartPlan((formation.goal_centroid,), (), plan.reason)
    route = plan.route
    if len(route) > MAX_WAYPOINTS + 1:  # a plan holds no more: the leader plans the rest later
        route = route[:MAX_WAYPOINTS] + route[-1:]
    return StartPlan(tuple((x, y) for x, y, _th in route),
                     tuple(wrap_angle(th - turn) for _x, _y, th in route))


def goal_offsets(formation: FormationSpec) -> tuple[Point, ...]:
    """Each member's goal relative to the goal centroid (the shape the route carries)."""
    gx, gy = formation.goal_centroid
    return tuple((r.goal[0] - gx, r.goal[1] - gy) for r in formation.robots)


def route_radius(formation: FormationSpec) -> float:
    """The formation's radius for planning: its larger extent at the start and at the goal."""
    sx, sy = formation.start_centroid
    start = [(r.start[0] - sx, r.start[1] - sy) for r in formation.robots]
    return max(formation_radius(start), formation_radius(goal_offsets(formation)))


def initial_route(scenario: Scenario, formation: FormationSpec) -> tuple[Point, ...]:
    """Waypoints for the formation's centroid; the last is its goal centroid."""
    goal = formation.goal_centroid
    if formation.waypoints:
        return tuple((float(x), float(y)) for x, y in formation.waypoints) + (goal,)
    if scenario.controller.planner == "none" or not scenario.shapes:
        return (goal,)
    return plan_route(formation.start_centroid, goal, scenario.shapes, route_radius(formation))


def route_problem(scenario: Scenario) -> str | None:
    """Why a formation's goal has no route at the start (the footprint's plan), or None."""
    for k, f in enumerate(scenario.formations):
        why = start_plan(scenario, f).reason
        if why:
            return f"formations[{k}] {f.name!r}: no route to its goal: {why}"
    return None
