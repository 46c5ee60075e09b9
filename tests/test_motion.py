"""Reversals of the certified command (issue 25 item 4): counted per robot, forced ones apart,
drawn in motion.png; and the load drawn and its collisions marked in trajectories.png."""

from __future__ import annotations

import copy
import math
from pathlib import Path

import matplotlib.pyplot as plt
from hypothesis import given
from hypothesis import strategies as st

from scenario import load_scenario
from scenario.load import scenario_from_dict
from simulator.inprocess import ROBOT_COLUMNS, Series, simulate
from simulator.motion import is_reversal, motion_fields
from simulator.output import write_run
from simulator.plots import COLLISION_GID, REVERSAL_GID, motion_figure, trajectory_figure

ROOT = Path(__file__).resolve().parent.parent
NAN = float("nan")


def _row(t, rid, ux, uy, h_obstacle=NAN, h_formations=NAN):
    values = {"t": t, "robot": rid, "formation": "A", "x": 0.0, "y": 0.0, "theta": 0.0,
              "px": 0.0, "py": 0.0, "ux": ux, "uy": uy, "v": math.hypot(ux, uy), "omega": 0.0,
              "status": "ok", "slack": 0.0, "h_formation": 1.0, "h_obstacle": h_obstacle,
              "h_formations": h_formations}
    return tuple(values[c] for c in ROBOT_COLUMNS)


speed = st.floats(0.0501, 1.0)  # above REVERSAL_SPEED: at exactly 0.05 the rounding of hypot decides


@given(speed, speed, st.floats(-math.pi, math.pi), st.floats(0.0, math.pi))
def test_a_reversal_is_two_fast_commands_more_than_120_degrees_apart(sa, sb, heading, turn):
    a = (sa * math.cos(heading), sa * math.sin(heading))
    b = (sb * math.cos(heading + turn), sb * math.sin(heading + turn))
    if abs(turn - math.radians(120.0)) > 1e-9:
        assert is_reversal(a, b) == (turn > math.radians(120.0))
    assert is_reversal(a, b) == is_reversal(b, a)
    slow = (0.049 * math.cos(heading + turn), 0.049 * math.sin(heading + turn))
    assert not is_reversal(a, slow)


def test_reversals_are_counted_per_robot_with_the_worst_and_the_forced_ones_apart():
    s = load_scenario(ROOT / "tests/scenarios/two-small.yaml")
    rows = []
    for k in range(10):
        t = k * 0.05
        sign = 1.0 if k % 2 == 0 else -1.0
        # a1 chatters from tick 0; its obstacle row comes within reach (gamma h < vmax) at tick 6
        rows.append(_row(t, "a1", 0.1 * sign, 0.0, h_obstacle=1.0 if k < 6 else 0.1))
        rows.append(_row(t, "a2", 0.1, 0.01 * sign))  # turns a little: no reversal
        rows.append(_row(t, "b1", 0.04 * sign, 0.0))  # too slow to count
    m = motion_fields(rows, ROBOT_COLUMNS, s)
    assert m["reversals"] == {"a1": 9, "a2": 0, "b1": 0}
    assert m["reversals_forced"] == {"a1": 1, "a2": 0, "b1": 0}
    assert (m["worst_robot"], m["worst_reversals"], m["reversals_total"]) == ("a1", 9, 9)
    assert (m["first_reversal_s"], m["last_reversal_s"]) == (0.05, 0.45)


def test_a_calm_run_reports_no_reversals_and_draws_its_figures(tmp_path):
    s = load_scenario(ROOT / "tests/scenarios/two-small.yaml")
    result = simulate(s)
    motion = result.summary["motion"]
    assert motion["reversals_total"] == sum(motion["reversals"].values())
    assert set(motion["reversals"]) == set(s.robot_ids)
    write_run(result.summary, result.series, s, tmp_path)
    assert (tmp_path / "motion.png").stat().st_size > 0


def test_the_motion_figure_marks_every_reversal():
    s = load_scenario(ROOT / "tests/scenarios/two-small.yaml")
    series = Series(robots=[_row(k * 0.05, "a1", 0.1 * (-1) ** k, 0.0) for k in range(5)])
    fig = motion_figure(series, s)
    try:
        marks = [line for ax in fig.axes for line in ax.get_lines() if line.get_gid() == REVERSAL_GID]
        assert [len(line.get_xdata()) for line in marks] == [4, 4]  # on both panels
    finally:
        plt.close(fig)


def test_a_load_collision_is_a_red_x_and_the_load_is_drawn():
    from test_load import PAIR

    s = scenario_from_dict(copy.deepcopy(PAIR))
    result = simulate(s)
    fig = trajectory_figure(result.series, s)
    try:
        marks = [line for line in fig.axes[0].get_lines() if line.get_gid() == COLLISION_GID]
        assert len(marks) == 1
        x, y = marks[0].get_xdata()[0], marks[0].get_ydata()[0]
        assert 1.5 <= x <= 2.6 and abs(y) < 0.6
        # the two-robot load is a segment drawn between the members at each snapshot
        segments = [line for line in fig.axes[0].get_lines() if line.get_linewidth() == 2.5]
        assert segments
    finally:
        plt.close(fig)
