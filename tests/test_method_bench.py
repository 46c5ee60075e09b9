"""``formation bench --method``: the per-member control step under each controller method."""

from __future__ import annotations

from pathlib import Path

import pytest

from agent.control import Controller
from experiments.method_bench import bench_method, format_methods, parse_methods
from formation.cli import main
from scenario import load_scenario

SCENARIO = Path(__file__).parent / "scenarios" / "rigid-turn-180-dt005.yaml"


def test_methods_are_parsed_and_a_wrong_one_is_named():
    assert parse_methods("rigid, thesis") == ["rigid", "thesis"]
    with pytest.raises(ValueError, match="'bogus'"):
        parse_methods("rigid,bogus")
    with pytest.raises(ValueError):
        parse_methods(",")


def test_every_member_step_is_timed_and_the_formation_qp_only_under_rigid():
    step = Controller.step
    robots = len(load_scenario(SCENARIO).robot_ids)
    rigid = bench_method(SCENARIO, "rigid", duration=1.0)
    thesis = bench_method(SCENARIO, "thesis", duration=1.0)
    assert rigid["steps"] == thesis["steps"] == robots * round(1.0 / 0.05)
    assert rigid["formation_qp"]["median_us"] is not None
    assert thesis["formation_qp"]["median_us"] is None
    assert rigid["formation_qp"]["median_us"] > 0.0
    assert Controller.step is step  # the timer is gone after the run
    table = format_methods({"scenario": str(SCENARIO), "methods": [rigid, thesis]})
    assert "rigid" in table and "thesis" in table


def test_a_wrong_method_exits_2_naming_it(tmp_path, capsys):
    assert main(["bench", "--method", "rigid,nope", "--out", str(tmp_path / "b")]) == 2
    assert "'nope'" in capsys.readouterr().err
