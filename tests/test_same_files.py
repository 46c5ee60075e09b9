"""The identity tests' comparison (tests/same_files.py) names where two files part."""

from __future__ import annotations

import json

import pytest

from tests.same_files import assert_same


def test_equal_files_pass_and_unequal_ones_name_the_first_line_and_the_runs_counts(tmp_path):
    sim, run = tmp_path / "sim", tmp_path / "run"
    for d in (sim, run):
        d.mkdir()
    (sim / "robots.csv").write_text("t,x\n0,1\n0.05,1.5\n0.1,2\n", encoding="utf-8")
    (run / "robots.csv").write_text("t,x\n0,1\n0.05,1.50001\n0.1,2\n", encoding="utf-8")
    (run / "summary.json").write_text(json.dumps(
        {"agents": {"lockstep_timeouts": 2, "stale": 0}, "world": {"missing_cmds": 7}}),
        encoding="utf-8")
    assert_same(sim / "robots.csv", sim / "robots.csv")
    with pytest.raises(AssertionError) as err:
        assert_same(sim / "robots.csv", run / "robots.csv", "one-pallet robots.csv")
    text = str(err.value)
    assert text.startswith("one-pallet robots.csv differs at line 3:")
    assert "sim: 0.05,1.5\n" in text and "run: 0.05,1.50001" in text
    assert "run: agents.lockstep_timeouts 2, agents.stale 0, world.missing_cmds 7" in text
    (run / "robots.csv").write_text("t,x\n0,1\n", encoding="utf-8")
    with pytest.raises(AssertionError, match="4 lines against 2"):
        assert_same(sim / "robots.csv", run / "robots.csv")
