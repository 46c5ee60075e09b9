"""docs/results.md is rendered from the stored result files, and a re-run reads its output back."""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import pytest

from experiments import results

HASH = re.compile(r"^[0-9a-f]{7,40}$")
DATE = re.compile(r"^20\d\d-\d\d-\d\d$")


def test_the_results_page_is_rendered_from_the_stored_files():
    text = results.render(results.load_results())
    assert results.PAGE.read_text(encoding="utf-8") == text, (
        "docs/results.md is out of date: run .venv/bin/python -m experiments.results")


def test_every_stored_row_carries_its_provenance_as_data():
    stored = results.load_results()
    assert len(stored) >= 10
    for result in stored:
        for row in result["rows"]:
            assert HASH.match(row["commit"]), (result["name"], row["commit"])
            assert DATE.match(row["date"]), (result["name"], row["date"])
            assert row["command"].split()[0] in ("formation", "python"), row["command"]
            assert row["machine"]


def test_the_page_holds_the_acceptance_figures():
    page = results.PAGE.read_text(encoding="utf-8")
    for figure in ("`--n 200 --draw warehouse --seed 3`", "| 103 | 105 |", "| 86.25 |"):
        assert figure in page, figure
    bar = [r for r in results.load_results() if r["name"] == "mujoco"][0]
    assert sum(row["values"]["bar"] == "pass" for row in bar["rows"]) == 13


def test_a_result_without_provenance_is_refused_by_name(tmp_path: Path):
    result = json.loads((results.RESULTS_DIR / "demo.json").read_text(encoding="utf-8"))
    del result["rows"][0]["commit"]
    (tmp_path / "demo.json").write_text(json.dumps(result), encoding="utf-8")
    with pytest.raises(ValueError, match="demo.json: row 1 has no 'commit'"):
        results.load_results(tmp_path)


def test_the_check_flag_says_when_the_page_is_out_of_date(tmp_path: Path):
    page = tmp_path / "results.md"
    assert results.main(["--page", str(page)]) == 0
    assert results.main(["--check", "--page", str(page)]) == 0
    page.write_text(page.read_text(encoding="utf-8") + "edited by hand\n", encoding="utf-8")
    assert results.main(["--check", "--page", str(page)]) == 1


def test_summary_and_montecarlo_figures_are_read_back():
    summary = {"all_reached": True, "time_to_goal_s": 86.25, "collisions": 0,
               "formation_error_max_m": 0.0034444, "min_clearance_m": {"obstacle": 0.0656, "robot": 0.0866},
               "motion": {"reversals_total": 0}, "qp": {"hard_row_unmet_ticks": 0}}
    row = results.from_summary(summary, epsilon=0.04)
    assert row == {"reached": True, "time_to_goal_s": 86.25, "collisions": 0, "error_mm": 3.4,
                   "eps": 0.086, "obstacle_mm": 65.6, "robot_mm": 86.6, "reversals": 0, "unmet": 0}
    report = {"runs": 200, "reached_rate": 0.995, "collisions": 0, "runs_with_collision": 0,
              "deadlocks": 1, "worst_formation_error_over_epsilon": 1.2449, "runs_over_1_5_epsilon": 0,
              "fallback_ticks": 4, "min_obstacle_clearance_m": 0.0071}
    assert results.from_montecarlo(report) == {
        "runs": 200, "reached": 199, "collisions": "0 (0)", "deadlocks": 1, "worst_eps": 1.24,
        "over_band": 0, "fallback_ticks": 4, "clearance_mm": 7.1}
    lines = ['ok   {"name": "a"}', 'FAIL {"name": "route-closed-room"}', "1 of 2 files meet the bar"]
    assert results.from_scenario_bar(lines) == {"met": 1, "files": 2, "failing": "route-closed-room"}


def test_a_stored_command_runs_with_this_interpreter_into_the_given_folder(tmp_path: Path):
    args = results.argv_of("formation sim scenarios/warehouse.yaml --out runs/demo --no-plots")
    assert args[1:3] == ["-m", "formation"]
    assert results.with_out(args, tmp_path)[-2:] == [str(tmp_path), "--no-plots"]
    with pytest.raises(ValueError, match="neither formation nor python"):
        results.argv_of("make demo")


@pytest.mark.integration  # provenance asks git for the commit
def test_a_rerun_stores_the_new_figures_and_this_machine_as_provenance(tmp_path: Path):
    shutil.copy(results.RESULTS_DIR / "demo.json", tmp_path / "demo.json")
    seen = []

    def fake(kind: str, row: dict) -> dict:
        seen.append((kind, row["command"]))
        return {"time_to_goal_s": 80.0}

    result = results.rerun("demo", tmp_path, run=fake)
    assert seen == [("sim", result["rows"][0]["command"])]
    stored = json.loads((tmp_path / "demo.json").read_text(encoding="utf-8"))
    row = stored["rows"][0]
    assert row["values"]["time_to_goal_s"] == 80.0 and row["values"]["collisions"] == 0
    assert row["date"] == results.this_machine()["date"]


def test_a_table_result_is_not_rerun_but_names_its_commands(tmp_path: Path):
    shutil.copy(results.RESULTS_DIR / "physics-rtf.json", tmp_path / "physics-rtf.json")
    with pytest.raises(ValueError, match="benchmarks/physics_rtf.py"):
        results.rerun("physics-rtf", tmp_path)


@pytest.mark.integration
def test_a_sim_result_is_rerun_for_real(tmp_path: Path):
    result = json.loads((results.RESULTS_DIR / "demo.json").read_text(encoding="utf-8"))
    result["rows"][0]["command"] = "formation sim scenarios/thesis-5.2.1.yaml --out runs/x --no-plots"
    (tmp_path / "demo.json").write_text(json.dumps(result), encoding="utf-8")
    row = results.rerun("demo", tmp_path)["rows"][0]
    assert row["values"]["reached"] is True and row["values"]["collisions"] == 0


def test_the_engines_rows_are_read_back_by_scenario():
    lines = ["| scenario | every goal (kin. / MuJoCo) | collisions (kin. / MuJoCo) | MuJoCo contacts "
             "| worst error [eps] (kin. / MuJoCo) | time to goal [s] (kin. / MuJoCo) "
             "| sides: pairs compared, flipped | bar |",
             "| --- | --- | --- | --- | --- | --- | --- | --- |",
             "| warehouse | yes / yes | 0 / 0 | 0 | 0.09 / 1.13 | 86.2 / 88.8 | 168: same | pass |",
             "| rigid-cross-aisle-four | yes / yes | 0 / 2 | 0 | 0.19 / 1.44 | 81.5 / 130.0 "
             "| 80: 12 flipped: a1/D, a2/D | FAIL |"]
    figures = results.from_engines(lines)
    assert figures["warehouse"] == {"reached": "yes / yes", "collisions": "0 / 0", "contacts": 0,
                                    "eps": "0.09 / 1.13", "sides": "same", "bar": "pass"}
    assert figures["rigid-cross-aisle-four"]["sides"] == "12 of 80 pairs flipped"
    assert figures["rigid-cross-aisle-four"]["bar"] == "fail"


def test_a_lifelong_montecarlo_reports_its_orders_beside_the_usual_figures():
    report = {"runs": 50, "reached_rate": 1.0, "collisions": 0, "runs_with_collision": 0,
              "deadlocks": 0, "worst_formation_error_over_epsilon": 0.0,
              "runs_over_1_5_epsilon": 0, "fallback_ticks": 0, "min_obstacle_clearance_m": 0.0697,
              "orders": {"posted": 331, "delivered": 329, "failed": 1, "open": 1, "stuck": 1,
                         "load_contacts": 2, "intrusions": 1, "runs_with_stuck_order": 1}}
    figures = results.from_montecarlo(report)
    assert figures["reached"] == 50 and figures["clearance_mm"] == 69.7
    assert {k: figures[k] for k in ("delivered", "failed", "open", "stuck", "load_contacts")} == {
        "delivered": "329 of 331", "failed": 1, "open": 1, "stuck": "1 (1)", "load_contacts": 3}


LIFELONG_MC = {
    "title": "Lifelong Monte Carlo", "order": 21, "kind": "montecarlo", "about": "drawn halls",
    "columns": [["draw", "label"], ["runs", "runs"], ["every order delivered", "reached"],
                ["orders delivered", "delivered"], ["stuck (runs)", "stuck"],
                ["collisions (runs)", "collisions"]],
    "rows": []}


def test_a_row_measured_elsewhere_is_taken_from_its_output_folder(tmp_path: Path, monkeypatch):
    (tmp_path / "mc.json").write_text(json.dumps(LIFELONG_MC), encoding="utf-8")
    monkeypatch.setattr(results, "this_machine", lambda: {
        "commit": "abc1234", "machine": "this one", "date": "2026-01-02"})
    out = tmp_path / "out"
    out.mkdir()
    report = {"runs": 50, "reached_rate": 0.98, "collisions": 0, "runs_with_collision": 0,
              "deadlocks": 1, "worst_formation_error_over_epsilon": 0.0,
              "runs_over_1_5_epsilon": 0, "fallback_ticks": 3, "min_obstacle_clearance_m": None,
              "orders": {"posted": 331, "delivered": 330, "failed": 0, "open": 1, "stuck": 1,
                         "load_contacts": 0, "intrusions": 0, "runs_with_stuck_order": 1}}
    (out / "montecarlo.json").write_text(json.dumps(report), encoding="utf-8")
    argv = ["--dir", str(tmp_path), "--page", str(tmp_path / "results.md"),
            "--take", "mc", str(out), "--command", "formation montecarlo --n 50",
            "--label", "`--n 50`", "--machine", "16 cores elsewhere"]
    assert results.main(argv) == 0
    (row,) = json.loads((tmp_path / "mc.json").read_text(encoding="utf-8"))["rows"]
    assert row["machine"] == "16 cores elsewhere" and row["commit"] == "abc1234"
    assert row["command"] == "formation montecarlo --n 50"
    assert row["values"]["reached"] == 49 and row["values"]["delivered"] == "330 of 331"
    assert "| `--n 50` | 50 | 49 | 330 of 331 | 1 (1) | 0 (0) |" in (
        tmp_path / "results.md").read_text(encoding="utf-8")
    # the same label again replaces that row, another label comes after it
    assert results.main(argv) == 0
    assert results.main([*argv[:-3], "`--seed 2`", *argv[-2:]]) == 0
    rows = json.loads((tmp_path / "mc.json").read_text(encoding="utf-8"))["rows"]
    assert [r["values"]["label"] for r in rows] == ["`--n 50`", "`--seed 2`"]
    assert results.main(argv[:7] + ["--label", "x"]) == 2  # no --machine


def test_only_a_sim_or_montecarlo_output_is_taken(tmp_path: Path):
    shutil.copy(results.RESULTS_DIR / "physics-rtf.json", tmp_path / "physics-rtf.json")
    with pytest.raises(ValueError, match="physics-rtf: a table result"):
        results.take("physics-rtf", tmp_path, {"command": "x", "machine": "m",
                                                "values": {"label": "y"}}, tmp_path)
