"""What the command line shows (issue 12): an honest progress bar and a summary line that does
not alarm on what happens by design."""

from __future__ import annotations

import pytest

from formation.progress import Progress, print_summary, qp_words


def _lines(err: str) -> list[str]:
    return [ln for ln in err.replace("\r", "\n").splitlines() if ln.strip()]


def test_a_run_that_ends_early_says_so_and_does_not_fill_the_bar(capsys):
    with Progress("sim x") as p:
        for k in range(1, 193):  # 192 of 800 ticks of 0.05 s: every goal reached at 9.60 s
            p.update(k, 800, k * 0.05)
    last = _lines(capsys.readouterr().err)[-1]
    assert "ended early at t=   9.60 s of 40.00 s: every goal reached" in last
    assert "#" * 30 not in last and "100%" not in last


def test_a_run_that_goes_the_whole_duration_ends_full(capsys):
    with Progress("sim x") as p:
        for k in range(1, 801):
            p.update(k, 800, k * 0.05)
    last = _lines(capsys.readouterr().err)[-1]
    assert "100%" in last and "t=  40.00 s of 40.00 s" in last and "ended early" not in last


def test_the_monte_carlo_bar_counts_runs_not_time(capsys):
    with Progress("montecarlo n=4", unit="runs") as p:
        for k in range(1, 5):
            p.update(k, 4, 0.0)
    lines = _lines(capsys.readouterr().err)
    assert lines[-1].endswith("100%  4/4 runs")
    assert not any("t=" in ln for ln in lines)


def test_an_interrupted_run_draws_no_end_line(capsys):
    with pytest.raises(KeyboardInterrupt), Progress("sim x") as p:
        p.update(1, 800, 0.05)
        raise KeyboardInterrupt
    assert "ended early" not in capsys.readouterr().err


def test_formation_relaxations_are_reported_as_by_design_and_hard_rows_separately(capsys,
                                                                                tmp_path):
    summary = {"scenario": "s", "mode": "inprocess", "all_reached": True, "collisions": 0,
               "time_to_goal_s": 20.0, "formation_error_max_m": 0.01,
               "qp": {"solves": 11220, "infeasible": 13, "relaxed": 13, "fallback": 0,
                      "failed": 0}}
    print_summary(summary, tmp_path, plots=False)
    out = capsys.readouterr().out
    assert ("formation tolerance relaxed (by design, minimal) on 13 of 11,220 ticks; "
            "hard rows unmet: 0") in out
    assert "infeasible" not in out and "UNSAFE" not in out and "figures" not in out
    assert "solver failures: 2" in qp_words({"solves": 5, "relaxed": 0, "fallback": 1,
                                            "failed": 2})
