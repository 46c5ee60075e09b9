"""A held run is judged at the goals its formations were sent (simulator.goals), not at the
scenario's: the verdict (all_reached, time_to_goal_s, per formation) and the goals drawn."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from scenario import load_scenario
from simulator.goals import goals_sent, judge_by_goals_sent, sent_goal, with_goals
from simulator.metrics import SafetyMonitor
from simulator.series import Series, WorldResult
from simulator.summary import formation_goal_times

ROOT = Path(__file__).resolve().parent.parent
SCENARIO = load_scenario(ROOT / "tests" / "scenarios" / "nav-hold.yaml")
SENT = {"A": {"goal": [2.25, 0.25], "heading": None},
        "B": {"goal": [2.25, -0.6], "heading": math.pi / 2}}


def test_a_sent_goal_places_every_member_as_the_leaders_plan_does():
    # the scenario's shape about the goal centroid, turned by the heading when there is one
    assert sent_goal((1.0, 2.0), None, {"a": (0.25, 0.0), "b": (-0.25, 0.0)}) == {
        "a": (1.25, 2.0), "b": (0.75, 2.0)}
    turned = sent_goal((1.0, 2.0), math.pi / 2, {"a": (0.25, 0.0), "b": (-0.25, 0.0)})
    assert turned["a"] == pytest.approx((1.0, 2.25)) and turned["b"] == pytest.approx((1.0, 1.75))


def test_with_goals_moves_only_the_formations_sent_a_goal():
    judged = with_goals(SCENARIO, {"A": SENT["A"]})
    goals = {r.id: r.goal for r in judged.robots}
    assert goals["a1"] == pytest.approx((2.5, 0.25)) and goals["a2"] == pytest.approx((2.0, 0.25))
    assert goals["b1"] == (0.5, -0.6) and goals["b2"] == (0.0, -0.6)  # as in the scenario
    assert with_goals(SCENARIO, {}) is SCENARIO


def _held_run(final: dict[str, tuple[float, float]]) -> WorldResult:
    """A run that starts at the scenario's starts (= its goals) and is recorded for two ticks,
    the second at ``final``."""
    monitor = SafetyMonitor(SCENARIO)
    series = Series()
    starts = {r.id: r.start[:2] for r in SCENARIO.robots}
    for k, at in enumerate((starts, final)):
        t = k * 10.0
        monitor.update(t, np.array([at[r] for r in SCENARIO.robot_ids]), [])
        for r in SCENARIO.robots:
            x, y = at[r.id]
            series.robots.append((t, r.id, r.formation, x, y, 0.0, x, y, 0.0, 0.0, 0.0, 0.0,
                                  "", math.nan, math.nan, math.nan, math.nan))
    return WorldResult(steps=201, sim_time=10.0, monitor=monitor, series=series, traffic={})


def test_a_held_run_at_the_goals_it_was_sent_is_complete():
    sent_goals = {r.id: r.goal for r in with_goals(SCENARIO, SENT).robots}
    result = _held_run(sent_goals)
    assert not result.monitor.all_reached  # against the scenario's goals (where they started)
    judged = judge_by_goals_sent(SCENARIO, result, SENT)
    fields = result.monitor.summary_fields()
    assert fields["all_reached"] is True and fields["time_to_goal_s"] == 10.0
    assert formation_goal_times(judged, result.series, result.monitor.time_to_goal) == {
        "A": 10.0, "B": 10.0}


def test_a_held_run_short_of_a_goal_it_was_sent_is_incomplete():
    short = {r.id: r.goal for r in with_goals(SCENARIO, SENT).robots}
    short["b2"] = (short["b2"][0] + 0.3, short["b2"][1])  # one member still on its way
    result = _held_run(short)
    judged = judge_by_goals_sent(SCENARIO, result, SENT)
    fields = result.monitor.summary_fields()
    assert fields["all_reached"] is False and fields["time_to_goal_s"] is None
    assert formation_goal_times(judged, result.series) == {"A": 10.0, "B": None}


def test_without_goals_sent_the_verdict_is_the_scenarios():
    result = _held_run({r.id: r.start[:2] for r in SCENARIO.robots})
    assert judge_by_goals_sent(SCENARIO, result, {}) is SCENARIO
    assert result.monitor.summary_fields()["all_reached"] is True


def test_the_trajectories_figure_marks_the_goals_sent(monkeypatch, tmp_path):
    from simulator import output, plots

    drawn = {}

    def spy(series, scenario, path):
        drawn[path.name] = {r.id: r.goal for r in scenario.robots}
        path.write_bytes(b"")

    for name in ("plot_trajectories", "plot_safety", "plot_motion"):
        monkeypatch.setattr(plots, name, spy)
    result = _held_run({r.id: r.start[:2] for r in SCENARIO.robots})
    output.write_run({"goals_sent": SENT}, result.series, SCENARIO, tmp_path)
    assert drawn["trajectories.png"]["a1"] == pytest.approx((2.5, 0.25))
    assert drawn["trajectories.png"]["b1"] == pytest.approx((2.25, -0.35))


def test_the_goals_sent_are_those_stamped_after_the_start_or_other_than_the_scenarios():
    a, b = (f.goal_centroid for f in SCENARIO.formations)
    followed = {"A": {"goal": list(a), "heading": None, "goal_stamp": 0.0},  # the scenario's
                "B": {"goal": list(b), "heading": None, "goal_stamp": 3.5}}  # sent again
    assert goals_sent(SCENARIO, followed) == {"B": {"goal": list(b), "heading": None}}
    # taken at the first tick of a lock-step run (stamped 0): told apart by where it lies
    followed["A"] = {"goal": [2.25, 0.25], "heading": None, "goal_stamp": 0.0}
    assert goals_sent(SCENARIO, followed)["A"] == {"goal": [2.25, 0.25], "heading": None}
    followed["A"] = {"goal": list(a), "heading": 1.0, "goal_stamp": 0.0}  # only turned
    assert goals_sent(SCENARIO, followed)["A"]["heading"] == 1.0
    assert goals_sent(SCENARIO, {"Z": followed["A"]}) == {}  # not a formation of the scenario
