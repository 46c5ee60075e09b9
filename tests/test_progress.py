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


def _summary(**over) -> dict:
    base = {"scenario": "s", "mode": "multiprocess", "all_reached": True, "collisions": 0,
            "time_to_goal_s": 20.0, "sim_time_s": 20.5, "formation_error_max_m": 0.0745,
            "qp": {"solves": 100, "relaxed": 0, "fallback": 0, "failed": 0},
            "hard_row_unmet_ticks": 0, "realtime": True,
            "agents": {"stale": 921}, "world": {"missing_cmds": 2061}}
    base.update(over)
    return base


def test_a_real_time_run_names_stale_ticks_missing_commands_and_the_band(capsys, tmp_path):
    print_summary(_summary(), tmp_path, plots=False, epsilon=0.05)
    line = capsys.readouterr().out.splitlines()[0]
    assert "all robots reached their goals at t=20.00 s" in line
    assert ("real time: 921 stale ticks (zero command), 2,061 missing commands, formation error "
            "up to 1.49 epsilon") in line


def test_a_clean_real_time_run_and_a_lock_step_run_add_nothing(capsys, tmp_path):
    print_summary(_summary(agents={"stale": 0}, world={"missing_cmds": 0},
                           formation_error_max_m=0.04), tmp_path, plots=False, epsilon=0.05)
    print_summary(_summary(realtime=False), tmp_path, plots=False, epsilon=0.05)
    out = capsys.readouterr().out
    assert "real time" not in out and "epsilon" not in out


def test_an_interrupted_held_run_ends_one_way(capsys, tmp_path):
    with Progress("run s", early="stopped (Ctrl-C or SIGTERM)") as p:
        for k in range(1, 3347):
            p.update(k, 12000, k * 0.05)
    progress = _lines(capsys.readouterr().err)[-1]
    assert "ended early at t= 167.30 s" in progress and "stopped (Ctrl-C or SIGTERM)" in progress
    assert "every goal reached" not in progress
    print_summary(_summary(hold=True, all_reached=False, time_to_goal_s=18.05, sim_time_s=167.3,
                           realtime=False), tmp_path, plots=False)
    line = capsys.readouterr().out.splitlines()[0]
    assert "held until t=167.30 s, then stopped: not every robot at its last goal" in line
    assert "18.05" not in line and "every goal reached" not in line


def test_not_all_reached_names_no_time(capsys, tmp_path):
    print_summary(_summary(all_reached=False, realtime=False), tmp_path, plots=False)
    line = capsys.readouterr().out.splitlines()[0]
    assert "NOT all goals reached;" in line and "at t=" not in line and "[UNSAFE OR INCOMPLETE]" in line
