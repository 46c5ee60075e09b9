"""Issue 26's bar on its own scenarios (tests/scenarios/route-*.yaml), in process, both robot
models: every goal reached, 0 collisions (loads counted), formation error <= 1.5 epsilon; and
each kind does what it is there for: a line, a triangle and a pentagon turn to fit an aisle or
a slot, a pushed formation and one whose aisle a forklift parks in are planned again, two
formations head-on in a one-lane aisle do not wait for each other for ever, a goal in a closed
room is unreachable and the formation stays parked, and of two formations in each other's only
way the later name gives way."""

from __future__ import annotations

import functools
import math
from pathlib import Path

import pytest

from scenario import load_scenario
from simulator.inprocess import SimOptions, simulate
from tests.scenario_runs import summary_of

SCENARIOS = Path(__file__).parent / "scenarios"
KINDS = ["route-line-aisle", "route-triangle-slot", "route-pentagon-slot", "route-door-two-way",
         "route-pushed-off", "route-round-shelves", "route-forklift-parks", "route-head-on-aisle"]
MODELS = ["", "-unicycle"]


def _run(name: str, record: bool = False):
    s = load_scenario(SCENARIOS / f"{name}.yaml")
    return simulate(s, SimOptions(record=record)), s


@pytest.mark.slow
@pytest.mark.parametrize("model", MODELS)
@pytest.mark.parametrize("kind", KINDS)
def test_route_scenarios_meet_the_issue_bar(kind, model):
    s = load_scenario(SCENARIOS / f"{kind + model}.yaml")
    summary = summary_of(SCENARIOS / f"{kind + model}.yaml")  # recorded: the motion counters
    assert summary["collisions"] == 0, summary["collision_log"]
    assert summary["formation_error_max_m"] <= 1.5 * s.controller.epsilon
    assert summary["all_reached"]
    assert not summary["unreachable"]
    motion = summary["motion"]  # a formation waiting near its waypoint does not chatter
    assert motion["reversals_total"] == motion["reversals_forced_total"], motion
    whys = {r["why"] for r in summary["replans"]}
    if kind == "route-forklift-parks":
        assert "things changed" in whys  # the parked forklift is planned round
    if kind == "route-pushed-off":
        assert "off route" in whys
    if kind + model == "route-head-on-aisle":  # the unicycles came apart without it too
        assert "blocked" in whys  # one plans round the other (without it both wait for ever)


@pytest.mark.slow
@pytest.mark.parametrize("model", MODELS)
@pytest.mark.parametrize("kind", ["route-line-aisle", "route-triangle-slot", "route-pentagon-slot"])
def test_a_long_formation_turns_to_pass_and_back(kind, model):
    """Crosswise it does not fit the aisle or slot: its route turns it by more than 30 degrees."""
    res, _s = _run(kind + model, record=True)
    angles = [e[4] for e in res.series.ellipses]  # (t, name, cx, cy, alpha, ...)
    start = angles[0]
    turned = max(abs(math.remainder(a - start, math.pi)) for a in angles)
    assert turned > math.radians(30)
    assert abs(math.remainder(angles[-1] - start, math.pi)) < math.radians(10)


@pytest.mark.parametrize("model", MODELS)
def test_a_goal_in_a_closed_room_is_unreachable_and_the_formation_stays_parked(model):
    res, s = _run("route-closed-room" + model, record=True)
    summary = res.summary
    assert "R" in summary["unreachable"] and summary["unreachable"]["R"]
    assert not summary["all_reached"] and summary["collisions"] == 0
    first: dict[str, tuple[float, float]] = {}
    moved = 0.0
    for row in res.series.robots:  # (t, id, formation, x, y, ...)
        first.setdefault(row[1], (row[3], row[4]))
        moved = max(moved, math.dist(first[row[1]], (row[3], row[4])))
    assert moved < 0.1  # parked, not driving into the room's wall


@functools.cache
def _give_way():
    return _run("route-give-way", record=True)


@pytest.mark.slow
def test_of_two_formations_in_each_others_only_way_the_later_name_gives_way():
    """c and d each found no route while the other stood in
    its way and held to the end. Now d (the later name) stands aside off c's way, c passes,
    and every goal is reached within the band, without contact."""
    res, s = _give_way()
    summary = res.summary
    assert summary["all_reached"] and summary["collisions"] == 0, summary["collision_log"]
    assert summary["formation_error_max_m"] <= 1.5 * s.controller.epsilon
    assert not summary["unreachable"]
    gave = [r for r in summary["replans"] if r["why"] == "give way"]
    assert [r["formation"] for r in gave] == ["d"]


@pytest.mark.slow
def test_giving_way_reverses_no_command():
    res, _s = _give_way()
    motion = res.summary["motion"]
    assert motion["reversals_total"] == motion["reversals_forced_total"], motion
