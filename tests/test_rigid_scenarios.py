"""Issue 25's bar for ``controller.method: rigid`` on its own scenarios (tests/scenarios/rigid-*.yaml),
in process: 0 collisions (loads counted), formation error <= 1.5 epsilon, every goal reached, 0 hard
rows unmet, 0 reversals of the certified command outside ``motion.reversals_forced``.

Each scenario is a kind the issue names: a rectangle next to a wall pushed by a forklift, a
parked forklift in an aisle, a pentagon passing a shelf corner, a 180-degree unicycle turn at
10 and 50 Hz, two unicycle formations through one 1.3 m doorway starting turned away, and the
warehouse demo; both robot models. ``rigid`` is the default; the same files under ``method: thesis``
are measured side by side in docs (not asserted here: they are the comparison)."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import pytest

from agent.config import build_agent_configs, config_to_dict, load_config, save_config
from leader import routing
from scenario import load_scenario
from simulator.inprocess import SimOptions, simulate
from tests.scenario_runs import summary_of

SCENARIOS = Path(__file__).parent / "scenarios"

#: The issue's "Done when" set that does not meet the bar yet, and why (strict: a fix shows).
# every file meets the bar since 2026-11-28 (the pace floor at 0.1 and the later name going
# round; rigid-shelves-eight-unicycle had 1 unforced reversal: while formation e waited for a
# member to face its motion, e1 turned towards its own slot's barely moving aim and back)
FAILING: dict[str, str] = {}

PASSING = sorted(p.stem for p in SCENARIOS.glob("rigid-*.yaml") if p.stem not in FAILING)


def _run(name: str, method: str | None = None) -> tuple[dict, float]:
    s = load_scenario(SCENARIOS / f"{name}.yaml")
    if method is None:
        return summary_of(SCENARIOS / f"{name}.yaml"), s.controller.epsilon
    s = dataclasses.replace(s, controller=dataclasses.replace(s.controller, method=method))
    return simulate(s, SimOptions()).summary, s.controller.epsilon


def _assert_bar(summary: dict, eps: float) -> None:
    assert summary["collisions"] == 0, summary["collision_log"]
    assert summary["formation_error_max_m"] <= 1.5 * eps
    assert summary["all_reached"]
    assert summary["qp"]["hard_row_unmet_ticks"] == 0, summary["qp"]["hard_row_unmet"]
    motion = summary["motion"]
    assert motion["reversals_total"] == motion["reversals_forced_total"], motion


@pytest.mark.slow
@pytest.mark.parametrize("name", PASSING)
def test_rigid_meets_the_issue_bar(name):
    _assert_bar(*_run(name))


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(FAILING))
def test_rigid_short_of_the_bar(name, request):
    request.applymarker(pytest.mark.xfail(reason=FAILING[name], strict=True))
    _assert_bar(*_run(name))


def test_the_set_has_each_kind_with_both_models():
    """At least 24 scenarios, both robot models, some carrying a declared load, several rates."""
    scenarios = [load_scenario(p) for p in SCENARIOS.glob("rigid-*.yaml")]
    assert len(scenarios) >= 24
    assert {s.robot.is_unicycle for s in scenarios} == {False, True}
    assert sum(any(f.load for f in s.formations) for s in scenarios) >= 5
    assert {0.02, 0.05, 0.1} <= {s.dt for s in scenarios}


def test_every_rigid_scenario_says_rigid():
    for path in SCENARIOS.glob("rigid-*.yaml"):
        assert load_scenario(path).controller.method == "rigid", path.name


def test_each_agent_config_carries_its_slot_under_rigid_and_thesis_files_carry_none(tmp_path):
    rigid = load_scenario(SCENARIOS / "rigid-doorway-pair.yaml")
    cfgs = build_agent_configs(rigid)
    assert [cfgs[r].footprint.member for r in ("e1", "e2", "e3", "e4")] == [0, 1, 2, 3]
    assert cfgs["w1"].footprint.slots == cfgs["w3"].footprint.slots
    for rid, cfg in cfgs.items():
        save_config(cfg, tmp_path / rid)
        assert load_config(tmp_path / rid) == cfg
    thesis = dataclasses.replace(rigid, controller=dataclasses.replace(rigid.controller, method="thesis"))
    d = config_to_dict(build_agent_configs(thesis)["e1"])
    assert "footprint" not in d and d["control"]["method"] == "thesis"


@pytest.mark.slow
def test_the_tiebreak_stays_under_rigid_two_rectangles_head_on_pass_sooner_with_it(monkeypatch):
    """The formation QP keeps the bodies apart but has no sideways part when two formations meet
    head-on (the optimum is symmetric): the keep-right push on the goal twist breaks it. Without
    it the two stood for ever until each formation kept its own ellipse off the other's members
    (agent.body.mirror_rows); now they get by without it too, 13.6 s later (42.4 s against
    28.75 s). (The replanner's blocked rule, which plans round the other after 10 s, is off
    here: it would break the jam too, later and by a detour.)"""
    monkeypatch.setattr(routing, "PROGRESS", dataclasses.replace(routing.PROGRESS, blocked_s=math.inf))
    s = load_scenario(SCENARIOS / "head-on-rectangles.yaml")
    with_push = dataclasses.replace(s.controller, method="rigid")
    without = dataclasses.replace(s.controller, method="rigid", tiebreak="none")
    pushed = simulate(dataclasses.replace(s, controller=with_push), SimOptions(record=False)).summary
    assert pushed["all_reached"] and pushed["collisions"] == 0
    slow = simulate(dataclasses.replace(s, controller=without), SimOptions(record=False)).summary
    assert slow["collisions"] == 0
    assert not slow["all_reached"] or slow["time_to_goal_s"] > pushed["time_to_goal_s"] + 5.0


@pytest.mark.slow
def test_a_hexagon_and_a_triangle_in_each_others_way_meet_the_bar():
    """Montecarlo warehouse run 200030: a hexagon and a triangle meet near (0.2, 0) and stood
    still in each other's way; the stall clock's yield (agent.control.yield_command) backed the
    later name off and its blocked replan took it round. Since each formation keeps its own
    ellipse off the other's members (agent.body.mirror_rows), with a body that brakes before
    it turns back, they no longer stand still there: the yield rule does not fire in this run
    (with or without it, every goal at 84.55 s), nor does any file of the set need it now;
    tests/test_control.py keeps its unit tests."""
    _assert_bar(*_run("yield-hexagon-triangle"))


@pytest.mark.slow
def test_a_turning_unicycle_keeps_its_way_round_and_six_and_five_meet_the_bar():
    """Montecarlo run 100094: a six and a five of unicycles turning in place in each other's way.
    Robot a4's aim lay near behind it, either side of the steering's left-bias edge, and it
    turned left, right, left on consecutive ticks (one unforced reversal, 0.92 eps); a robot
    already turning now keeps its way round there (agent.unicycle.turn_error)."""
    _assert_bar(*_run("yield-six-five-unicycle"))
