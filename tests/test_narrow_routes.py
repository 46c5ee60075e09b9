"""Routes wherever the shape fits (tests/scenarios/narrow-*.yaml): a line, a triangle and a
pentagon, single integrators and unicycles, each crosswise to a slot between two shelf blocks
that it passes turned, with its members from epsilon (and the look-ahead offset) plus
geometry.footprint_plan.NARROW.clearance a side beyond the shelves' safe distance to a roomy
slot. Every one is planned (what ``formation check`` asks) and reached in process: every goal,
0 collisions, band within 1.5 epsilon, wall and shelf clearance >= -5 mm. A goal in a closed
room stays unreachable."""

from __future__ import annotations

from pathlib import Path

import pytest

from scenario import load_scenario
from scenario.routes import route_problem, start_plan
from tests.scenario_runs import summary_of

SCENARIOS = Path(__file__).parent / "scenarios"
NARROW = sorted(p.stem for p in SCENARIOS.glob("narrow-*.yaml"))


def test_every_kind_and_model_is_there():
    """Lines, triangles and pentagons, both models, from the narrow clearance to roomy."""
    for kind in ("line-tight", "line-roomy", "triangle-tight", "triangle-shelves", "pentagon-tight",
                 "pentagon-wide"):
        assert f"narrow-{kind}" in NARROW and f"narrow-{kind}-unicycle" in NARROW


@pytest.mark.parametrize("stem", NARROW)
def test_a_narrow_slot_the_footprint_fits_is_planned_through(stem):
    s = load_scenario(SCENARIOS / f"{stem}.yaml")
    assert route_problem(s) is None
    f = s.formations[0]
    plan = start_plan(s, f)
    assert plan.route[-1] == f.goal_centroid
    slot = min(sh.cy - sh.hy for sh in s.shapes if sh.name == "block-n")
    pts = [f.start_centroid, *plan.route]
    crossing = [a[1] + (b[1] - a[1]) * (0.0 - a[0]) / (b[0] - a[0])
                for a, b in zip(pts[:-1], pts[1:], strict=True) if a[0] < 0.0 <= b[0]]
    assert len(crossing) == 1 and abs(crossing[0]) < slot  # once through the slot, between the blocks


@pytest.mark.parametrize("stem", ["route-closed-room", "route-closed-room-unicycle"])
def test_a_goal_in_a_closed_room_stays_unreachable(stem):
    why = route_problem(load_scenario(SCENARIOS / f"{stem}.yaml"))
    assert why is not None and "no way for the footprint" in why


@pytest.mark.slow
@pytest.mark.parametrize("stem", NARROW)
def test_a_narrow_slot_scenario_meets_the_bar(stem):
    s = load_scenario(SCENARIOS / f"{stem}.yaml")
    summary = summary_of(SCENARIOS / f"{stem}.yaml")
    assert summary["all_reached"] and not summary["unreachable"]
    assert summary["collisions"] == 0, summary["collision_log"]
    assert summary["formation_error_max_m"] <= 1.5 * s.controller.epsilon
    assert min(summary["min_clearance_shape_m"].values()) >= -0.005
