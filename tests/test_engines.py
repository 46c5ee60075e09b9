"""experiments.engines: a scenario in both engines, compared (contacts, eps, goals, sides)."""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from experiments.engines import compare, main, other_sides, run_both, winding
from scenario import parse_scenario

ROOT = Path(__file__).resolve().parent.parent
TWO_SMALL = ROOT / "tests" / "scenarios" / "two-small.yaml"

coord = st.floats(-5.0, 5.0)


@given(coord, coord, st.floats(0.1, 3.0), st.integers(-3, 3), st.floats(-math.pi, math.pi))
def test_a_path_round_a_point_n_times_winds_2_pi_n(cx, cy, r, n, phase):
    steps = 24 * max(1, abs(n))
    path = [(cx + r * math.cos(phase + 2 * math.pi * n * k / steps),
             cy + r * math.sin(phase + 2 * math.pi * n * k / steps)) for k in range(steps + 1)]
    assert winding(path, [(cx, cy)] * len(path)) == pytest.approx(2 * math.pi * n, abs=1e-9)


@given(st.floats(0.05, 1.0), st.floats(1.0, 4.0), coord)
def test_passing_a_point_above_or_below_is_told_apart(h, half, cx):
    def past(side: float) -> list[tuple[float, float]]:
        """From (cx - half, 0) to (cx + half, 0), as two runs from one start to one goal go,
        passing at side * h (paths with different ends wind by less than pi apart when they
        pass close: hypothesis found h = half = 1)."""
        middle = [(cx - half + 2 * half * k / 50, side * h) for k in range(1, 50)]
        return [(cx - half, 0.0), *middle, (cx + half, 0.0)]

    centres = [(cx, 0.0)] * 51
    above, below = winding(past(1.0), centres), winding(past(-1.0), centres)
    assert above < 0.0 < below  # clockwise over it, counter-clockwise under it
    flipped = other_sides({("r", "o"): above}, {("r", "o"): below})
    assert flipped == [("r", "o")]
    assert other_sides({("r", "o"): above}, {("r", "o"): winding(past(0.5), centres)}) == []


def _write_run(out: Path, path: list[tuple[float, float]], contacts: int) -> None:
    out.mkdir(parents=True)
    with (out / "robots.csv").open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["t", "robot", "formation", "x", "y", "theta"])
        for k, (x, y) in enumerate(path):
            w.writerow([k * 0.1, "a1", "A", x, y, 0.0])
    (out / "summary.json").write_text(json.dumps({
        "all_reached": True, "collisions": 0, "formation_error_max_m": 0.0,
        "time_to_goal_s": 5.0, "physics": {"collisions": contacts}}))


ONE = """
name: one
dt: 0.1
controller: {epsilon: 0.05}
formations:
  - name: A
    leader: a1
    robots:
      a1: {start: [-2.0, 0.0], goal: [2.0, 0.0]}
obstacles:
  - {name: post, center: [0.0, 0.0], safe_distance: 0.3}
  - {name: cart, center: [0.0, 5.0], safe_distance: 0.3, velocity: [0.0, -1.0]}
"""


def test_the_side_of_each_obstacle_is_compared_moving_ones_where_they_were(tmp_path):
    sc = parse_scenario(ONE)
    line = [(-2.0 + 0.08 * k, 0.0) for k in range(51)]

    def bump(side: float) -> list[tuple[float, float]]:
        return [(x, side * 0.5 * math.exp(-x * x)) for x, _y in line]

    _write_run(tmp_path / "k", bump(1.0), 0)
    _write_run(tmp_path / "same", bump(0.6), 0)
    _write_run(tmp_path / "other", bump(-1.0), 0)
    same = compare(sc, tmp_path / "k", tmp_path / "same")
    assert same.pairs == 2 and same.flipped == [] and same.holds
    other = compare(sc, tmp_path / "k", tmp_path / "other")
    # the post is passed on the other side; the cart, which crosses the line at t = 5 s (x =
    # 2.0, the end), is passed the same way: it comes down from above while the robot drives
    assert other.flipped == [("a1", "post")] and not other.holds
    assert "1 flipped: a1/post" in other.row() and other.row().endswith("| FAIL |")
    _write_run(tmp_path / "touched", bump(1.0), 1)
    assert not compare(sc, tmp_path / "k", tmp_path / "touched").holds  # a contact fails it


@pytest.mark.integration
def test_a_small_scenario_runs_in_both_engines_and_holds(tmp_path, capsys):
    pytest.importorskip("mujoco")  # the physics extra (make test installs it)
    assert main([str(TWO_SMALL), "--out", str(tmp_path)]) == 0
    table = capsys.readouterr().out.splitlines()
    assert table[0].startswith("| scenario |") and table[2].startswith("| two-small | yes / yes |")
    assert table[2].endswith("| pass |") and "| 10: same |" in table[2]
    # 5 robots around 1 circle, and each around the other formation's centroid
    for engine in ("kinematic", "mujoco"):
        assert (tmp_path / "two-small" / engine / "robots.csv").is_file()
    # comparing again what is there gives the same table without running anything
    assert main([str(TWO_SMALL), "--out", str(tmp_path), "--compare-only"]) == 0
    assert capsys.readouterr().out.splitlines() == table


def test_a_run_that_fails_is_reported_with_its_command(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: bad\n")
    with pytest.raises(RuntimeError, match=r"bad.yaml: formation sim --engine kinematic exited 2"):
        run_both(bad, tmp_path / "out")
