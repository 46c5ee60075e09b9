"""The world's extent and the goal check at the door (scenario.extent)."""

from __future__ import annotations

import math
from pathlib import Path

from hypothesis import given
from hypothesis import strategies as st

from scenario import load_scenario
from scenario.extent import MARGIN_M, Extent, goal_problem, world_extent
from scenario.limits import COORDINATE, MAX_WAYPOINTS

ROOT = Path(__file__).resolve().parents[1]
WAREHOUSE = load_scenario(ROOT / "scenarios" / "warehouse.yaml")


def test_the_extent_holds_every_start_goal_and_obstacle_with_the_margin() -> None:
    e = world_extent(WAREHOUSE)
    for r in WAREHOUSE.robots:
        for x, y in (r.start[:2], r.goal):
            assert e.xmin + MARGIN_M <= x <= e.xmax - MARGIN_M
            assert e.ymin + MARGIN_M <= y <= e.ymax - MARGIN_M
    for o in WAREHOUSE.obstacles:
        assert e.contains(*o.center)
    assert goal_problem(e.xmax, e.ymin, None, [], e) is None


def test_the_extent_never_runs_past_the_coordinate_range() -> None:
    e = world_extent(WAREHOUSE, margin=1e9)
    assert (e.xmin, e.ymin, e.xmax, e.ymax) == (COORDINATE.lo, COORDINATE.lo, COORDINATE.hi,
                                                 COORDINATE.hi)


@given(st.sampled_from([math.inf, -math.inf, math.nan, 1e308, -1e308, 1e5]))
def test_absurd_goals_are_refused_in_one_line_naming_the_value(v: float) -> None:
    e = Extent(-10.0, -10.0, 10.0, 10.0)
    for problem in (goal_problem(v, 0.0, None, [], e), goal_problem(0.0, v, None, [], e),
                    goal_problem(1.0, 1.0, None, [(0.0, 0.0), (v, 1.0)], e)):
        assert problem is not None and "\n" not in problem
        assert "goal" in problem or "route point 2" in problem


def test_headings_and_long_routes_are_refused() -> None:
    e = Extent(-10.0, -10.0, 10.0, 10.0)
    assert "heading" in (goal_problem(1.0, 1.0, math.nan, [], e) or "")
    assert "heading" in (goal_problem(1.0, 1.0, 100.0, [], e) or "")
    assert goal_problem(1.0, 1.0, math.pi, [(0.0, 0.0)] * MAX_WAYPOINTS, e) is None
    assert "at most" in (goal_problem(1.0, 1.0, None, [(0.0, 0.0)] * (MAX_WAYPOINTS + 1), e) or "")
