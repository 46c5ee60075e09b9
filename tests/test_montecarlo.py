"""`formation montecarlo`: random warehouse layouts that validate, replay by seed, and a real
(small) run writing the contract's fields."""

from __future__ import annotations

import json

import pytest

from experiments.montecarlo import DI_MAX_ACCEL, random_scenario, valid_scenario
from formation.cli import main


def test_layouts_are_valid_reproducible_and_cover_both_robot_models():
    models = set()
    for seed in range(12):
        d, scenario, layout_seed = valid_scenario(seed)
        assert random_scenario(layout_seed) == d  # the seed alone replays the layout
        assert 2 <= len(scenario.formations) <= 4
        assert all(2 <= len(f.robots) <= 4 for f in scenario.formations)
        assert any(o.velocity != (0.0, 0.0) for o in scenario.obstacles) or len(scenario.obstacles) == 20
        models.add(scenario.robot.model)
    assert models == {"single_integrator", "unicycle"}


@pytest.mark.integration
def test_a_small_run_writes_montecarlo_json(tmp_path, capsys):
    out = tmp_path / "mc"
    assert main(["montecarlo", "--n", "2", "--seed", "3", "--out", str(out)]) == 0
    summary = json.loads((out / "montecarlo.json").read_text())
    assert summary["runs"] == 2 and summary["seed"] == 3
    assert {"collisions", "reached_rate", "deadlocks", "worst_formation_error_m", "failures",
            "runs_over_1_5_epsilon", "fallback_ticks"} <= set(summary)
    assert summary["fallback_ticks"] == sum(r["fallback_ticks"] for r in
                                            map(json.loads, (out / "runs.jsonl").read_text().splitlines()))
    assert 0.0 <= summary["reached_rate"] <= 1.0
    assert len(summary["over_band"]) == summary["runs_over_1_5_epsilon"]
    by_model = summary["by_model"].values()
    assert sum(m["runs"] for m in by_model) == 2
    assert sum(m["fallback_ticks"] for m in by_model) == summary["fallback_ticks"]
    assert sum(m["runs_over_1_5_epsilon"] for m in by_model) == summary["runs_over_1_5_epsilon"]
    assert max(m["worst_formation_error_over_epsilon"] or 0.0 for m in by_model) == \
        summary["worst_formation_error_over_epsilon"]
    runs = [json.loads(line) for line in (out / "runs.jsonl").read_text().splitlines()]
    assert [r["seed"] for r in runs] == [300000, 300001]
    for f in summary["failures"]:
        assert (out / f"failure-{f['seed']}.yaml").exists()
    assert "montecarlo: 2 runs" in capsys.readouterr().out


@pytest.mark.integration
def test_the_number_of_jobs_changes_nothing_in_the_results_and_a_bad_one_exits_2(tmp_path, capsys):
    runs = {}
    for jobs in ("1", "3"):
        out = tmp_path / f"mc{jobs}"
        assert main(["montecarlo", "--n", "3", "--seed", "5", "--jobs", jobs, "--out", str(out)]) == 0
        runs[jobs] = (out / "runs.jsonl").read_text()
    assert runs["1"] == runs["3"]
    assert main(["montecarlo", "--n", "3", "--jobs", "0", "--out", str(tmp_path / "bad")]) == 2
    assert "--jobs" in capsys.readouterr().err


@pytest.mark.parametrize("model", ["single_integrator", "unicycle", "double_integrator"])
def test_model_gives_every_drawn_layout_that_model_and_leaves_the_rest_of_the_draw(model):
    for seed in range(6):
        d, scenario, layout_seed = valid_scenario(seed, model=model)
        assert scenario.robot.model == model
        assert (scenario.robot.max_accel == DI_MAX_ACCEL) == (model == "double_integrator")
        drawn = random_scenario(layout_seed)
        assert d["robot"].pop("max_accel", None) == (DI_MAX_ACCEL if model == "double_integrator" else None)
        assert {**d, "robot": {**d["robot"], "model": drawn["robot"]["model"]}} == drawn
    assert valid_scenario(4, model=None)[0] == random_scenario(valid_scenario(4)[2])  # default: the mix


def test_model_double_integrator_outside_the_ideal_world_exits_2(tmp_path, capsys):
    assert main(["montecarlo", "--n", "1", "--model", "double_integrator", "--world", "turtlebot3-lab",
                 "--out", str(tmp_path / "bad")]) == 2
    err = capsys.readouterr().err
    assert "--model double_integrator" in err and "Traceback" not in err
    with pytest.raises(SystemExit) as bad:
        main(["montecarlo", "--n", "1", "--model", "bicycle", "--out", str(tmp_path / "bad2")])
    assert bad.value.code == 2


@pytest.mark.integration
def test_a_double_integrator_run_records_the_model(tmp_path, capsys):
    out = tmp_path / "mc"
    assert main(["montecarlo", "--n", "1", "--seed", "3", "--model", "double_integrator",
                 "--out", str(out)]) == 0
    summary = json.loads((out / "montecarlo.json").read_text())
    assert summary["model"] == "double_integrator"
    assert summary["by_model"]["double_integrator"]["runs"] == 1
    assert summary["by_model"]["unicycle"]["runs"] == summary["by_model"]["single_integrator"]["runs"] == 0
    assert "double_integrator model" in capsys.readouterr().out


@pytest.mark.integration
def test_the_lifelong_draw_runs_its_orders_and_totals_them(tmp_path):
    out = tmp_path / "mc"
    assert main(["montecarlo", "--draw", "lifelong", "--n", "1", "--seed", "1", "--jobs", "1",
                 "--out", str(out)]) == 0
    summary = json.loads((out / "montecarlo.json").read_text())
    (run,) = [json.loads(line) for line in (out / "runs.jsonl").read_text().splitlines()]
    orders = run["orders"]
    assert orders["posted"] > 0 and orders["delivered"] + orders["open"] + orders["failed"] \
        == orders["posted"]
    assert summary["orders"]["posted"] == orders["posted"]
    assert run["robots"] > 0 and run["formations"] == 0  # a fleet's robots, no fixed formation
    assert summary["orders"]["stuck"] == orders["stuck"]
    # every order delivered and none stuck is what "reached" means for a lifelong run
    assert run["all_reached"] == (orders["delivered"] == orders["posted"] and not orders["stuck"])
