"""A dense warehouse of 14 formations (47 robots) in process meets the scenario bar, and the
bench warehouses of ``formation bench --inprocess`` are what they say."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import pytest

from experiments.inprocess_bench import bench_warehouse, fleet_kinds, parse_sizes
from formation.commands.bench import bench_command
from formation.exits import UsageError
from scenario.load import scenario_from_dict
from scenario.routes import start_plan
from tests.scenario_runs import summary_of

DENSE = Path(__file__).parent / "scenarios" / "dense-warehouse.yaml"


@pytest.mark.slow
def test_fourteen_formations_of_47_robots_reach_every_goal_within_the_bar():
    s = summary_of(DENSE)
    assert s["all_reached"], s["time_to_goal_s"]
    assert s["collisions"] == 0, s["collision_log"]  # loads counted
    assert s["formation_error_max_m"] <= 1.5 * 0.05
    assert s["min_clearance_m"]["obstacle"] >= -0.005
    assert s["min_clearance_m"]["load"] is None or s["min_clearance_m"]["load"] >= 0.0
    assert s["qp"]["hard_row_unmet_ticks"] == 0, s["qp"]["hard_row_unmet"]


@pytest.mark.parametrize("n", [2, 3, 4, 5, 7, 50, 200])
def test_a_bench_warehouse_holds_n_robots_and_plans_every_formation_round_a_shelf(n):
    scenario = scenario_from_dict(bench_warehouse(n, 5.0))
    assert len(scenario.robot_ids) == n
    assert len(scenario.formations) == len(fleet_kinds(n))
    assert scenario.controller.method == "rigid"
    for f in scenario.formations[:3]:
        plan = start_plan(scenario, f)
        assert not plan.reason
        assert len(plan.route) > 1  # round the shelf row between its aisles


def test_fleet_kinds_are_rectangles_and_one_formation_for_the_remainder():
    assert fleet_kinds(8) == ["rectangle"] * 2
    assert fleet_kinds(50) == ["rectangle"] * 12 + ["pair"]
    assert fleet_kinds(5) == ["pentagon"]
    assert fleet_kinds(3) == ["triangle"]
    with pytest.raises(ValueError, match="n: need at least 2"):
        fleet_kinds(1)


def test_inprocess_sizes_name_the_bad_item():
    assert parse_sizes("4, 8,50") == [4, 8, 50]
    for bad in ("4,x", "1", "4,,8"):
        with pytest.raises(ValueError, match="--inprocess"):
            parse_sizes(bad)


def test_inprocess_and_fleets_together_are_refused(tmp_path):
    ns = argparse.Namespace(out=str(tmp_path / "b"), quick=True, inprocess="4", fleets="4@50",
                            method=None)
    with pytest.raises(UsageError, match="one at a time"):
        bench_command(ns)


def test_the_inprocess_curve_reports_each_fleet_it_ran(tmp_path):
    out = tmp_path / "bench"
    ns = argparse.Namespace(out=str(out), quick=True, inprocess="4,6", fleets=None, method=None)
    assert bench_command(ns) == 0
    curve = json.loads((out / "bench.json").read_text(encoding="utf-8"))["inprocess_curve"]
    assert [f["robots"] for f in curve["fleets"]] == [4, 6]
    for f in curve["fleets"]:
        assert f["ticks"] == round(curve["duration_s"] / 0.05)
        assert f["robot_ticks_per_cpu_s"] > 0 and f["x_real_time"] > 0
        assert f["collisions"] == 0
    assert "x real time" in (out / "bench.txt").read_text(encoding="utf-8")
