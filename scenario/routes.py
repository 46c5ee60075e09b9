"""The route each formation starts with: its ``waypoints`` from the file, or the leader's plan
around the walls and shelves (:func:`geometry.route.plan_route`), then its goal centroid.

One function for the in-process simulator and the agent configuration, so both start on the
same route."""

from __future__ import annotations

from geometry.route import Point, formation_radius, plan_route

from .model import FormationSpec, Scenario


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
