"""Scenario outcomes of the in-process simulator: safe, in formation, at the goal; and the
``formation sim`` command's output contract."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from formation.cli import main
from scenario import load_scenario
from simulator.inprocess import SimOptions, simulate

ROOT = Path(__file__).resolve().parents[1]
SCENARIOS = sorted((ROOT / "scenarios").glob("*.yaml")) + sorted((ROOT / "tests/scenarios").glob("*.yaml"))

SUMMARY_FIELDS = {
    "scenario", "mode", "steps", "sim_time_s", "all_reached", "time_to_goal_s", "collisions",
    "min_clearance_m", "formation_error_max_m", "min_h", "qp", "comm",
}


@pytest.mark.parametrize("path", SCENARIOS, ids=[p.stem for p in SCENARIOS])
def test_scenario_reaches_every_goal_safely_and_in_formation(path):
    scenario = load_scenario(path)
    s = simulate(scenario, SimOptions(record=False)).summary
    assert s["all_reached"], s
    assert s["collisions"] == 0, s["collision_log"]
    assert s["formation_error_max_m"] <= 1.5 * scenario.controller.epsilon
    if s["min_clearance_m"]["obstacle"] is not None:
        assert s["min_clearance_m"]["obstacle"] >= -0.005
    assert s["min_clearance_m"]["robot"] is None or s["min_clearance_m"]["robot"] >= 0.0
    assert s["qp"]["fallback"] == 0 and s["qp"]["failed"] == 0


def test_without_barriers_the_four_robot_formations_collide():
    scenario = load_scenario(ROOT / "scenarios/thesis-5.2.2.yaml")
    s = simulate(scenario, SimOptions(safety=False, record=False)).summary
    assert s["collisions"] > 0
    assert s["min_h"]["formations"] < 0


def test_head_on_meeting_is_resolved_by_the_tie_break_and_stalls_without_it():
    scenario = load_scenario(ROOT / "scenarios/thesis-5.2.1.yaml")
    assert simulate(scenario, SimOptions(record=False)).summary["all_reached"]
    from dataclasses import replace

    stalled = replace(scenario, controller=replace(scenario.controller, tiebreak="none"), duration=60.0)
    s = simulate(stalled, SimOptions(record=False)).summary
    assert not s["all_reached"] and s["collisions"] == 0


def test_osqp_backend_drives_the_same_run_as_the_exact_solver():
    scenario = load_scenario(ROOT / "scenarios/thesis-5.2.1.yaml")
    exact = simulate(scenario, SimOptions(record=False)).summary
    osqp = simulate(scenario, SimOptions(record=False, solver="osqp")).summary
    assert osqp["all_reached"] and osqp["collisions"] == 0
    assert abs(osqp["time_to_goal_s"] - exact["time_to_goal_s"]) <= 2 * scenario.dt


def test_sim_command_writes_the_summary_contract_series_and_figures(tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["sim", str(ROOT / "scenarios/thesis-5.1.2.yaml"), "--out", str(out), "--quiet"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert SUMMARY_FIELDS <= set(summary)
    assert summary["mode"] == "inprocess" and summary["scenario"] == "thesis-5.1.2"
    assert set(summary["min_clearance_m"]) == {"obstacle", "robot"}
    assert set(summary["min_h"]) == {"formation", "obstacle", "formations"}
    assert {"solves", "infeasible", "solve_us_median"} <= set(summary["qp"])
    assert {"topology", "messages", "bytes", "messages_per_robot_per_s",
            "bytes_per_robot_per_s"} <= set(summary["comm"])
    rows = (out / "robots.csv").read_text().splitlines()
    assert rows[0].startswith("t,robot,formation,x,y,theta")
    assert len(rows) == 1 + summary["steps"] * 4
    for fig in ("trajectories.png", "safety.png"):
        assert (out / fig).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "all robots reached their goals" in capsys.readouterr().out


def test_unknown_solver_is_invalid_input(tmp_path, capsys):
    code = main(["sim", str(ROOT / "scenarios/thesis-5.2.1.yaml"), "--out", str(tmp_path / "o"),
                 "--solver", "nonexistent"])
    assert code == 2
    assert "solver: 'nonexistent'" in capsys.readouterr().err
