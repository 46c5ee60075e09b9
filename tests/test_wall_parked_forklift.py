"""A unicycle rectangle parked 0.45 m from a wall gives way to a forklift driving along the wall,
every member facing away from the wall, at 10 Hz (tests/scenarios/wall-parked-forklift-north-
dt01-unicycle.yaml), in process: the scenario bar of the README, and once the forklift has
passed, the rectangle parks on its goal again and plans no more (no replanning loop)."""

from __future__ import annotations

from pathlib import Path

import pytest

from scenario import load_scenario
from tests.scenario_runs import summary_of

PATH = Path(__file__).parent / "scenarios" / "wall-parked-forklift-north-dt01-unicycle.yaml"


@pytest.mark.slow
def test_the_rectangle_gives_way_and_parks_again_without_a_replanning_loop():
    s = load_scenario(PATH)
    summary = summary_of(PATH)
    assert summary["all_reached"]  # the rectangle back on its goal when the pair arrives
    assert summary["collisions"] == 0, summary["collision_log"]
    assert summary["formation_error_max_m"] <= 1.5 * s.controller.epsilon
    walls = summary["min_clearance_shape_m"]
    assert walls and min(walls.values()) >= -0.005, walls
    assert summary["time_to_goal_s"] > 100.0  # the pair runs on long after the forklift passed
    plans = [r for r in summary["replans"] if r["formation"] == "R"]
    assert 1 <= len(plans) <= 3, plans  # it stepped aside, and did not plan in a loop after
    assert all(r["t"] < 60.0 for r in plans), plans
