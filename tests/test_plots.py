"""The run figures say what they show: time-matched snapshots, collisions, axes that fit the robots."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import matplotlib.pyplot as plt
import pytest
from matplotlib.patches import Circle

from scenario import load_scenario
from simulator.inprocess import SimOptions, simulate
from simulator.plots import (
    COLLISION_GID,
    LEGEND_BODY,
    LEGEND_COLLISION,
    LEGEND_MOVING,
    LEGEND_SAFE_DISK,
    MARGIN_M,
    OBSTACLE_REACH_M,
    robot_extent,
    safety_figure,
    snapshot_times,
    symlog_scale,
    trajectory_figure,
)

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="module")
def crate_run():
    """thesis-5.1.2: a crate moving at the formation (safe run)."""
    scenario = load_scenario(ROOT / "scenarios" / "thesis-5.1.2.yaml")
    return scenario, simulate(scenario)


@pytest.fixture(scope="module")
def unsafe_run():
    """thesis-5.2.2 without barriers: the two formations collide."""
    scenario = load_scenario(ROOT / "scenarios" / "thesis-5.2.2.yaml")
    return scenario, simulate(scenario, SimOptions(safety=False))


def _legend_texts(fig) -> list[str]:
    return [t.get_text() for legend in fig.legends + [ax.get_legend() for ax in fig.axes]
            if legend is not None for t in legend.get_texts()]


def test_the_axes_cover_the_robots_plus_a_margin_and_not_a_far_away_obstacle(crate_run):
    scenario, result = crate_run
    # A forklift whose track ends 40 m away and a static shelf 30 m away stay off the figure.
    far = replace(scenario, obstacles=(
        replace(scenario.obstacles[0], center=(40.0, 0.05)),
        replace(scenario.obstacles[0], name="shelf", center=(0.0, 30.0), velocity=(0.0, 0.0))))
    fig = trajectory_figure(result.series, far)
    try:
        x0, x1, y0, y1 = robot_extent(result.series, far)
        ax = fig.axes[0]
        m = max(MARGIN_M, 0.05 * max(x1 - x0, y1 - y0)) + OBSTACLE_REACH_M + 1e-9
        lx, ly = ax.get_xlim(), ax.get_ylim()
        assert x0 - m <= lx[0] <= x0 and x1 <= lx[1] <= x1 + m
        assert y0 - m <= ly[0] <= y0 and y1 <= ly[1] <= y1 + m
    finally:
        plt.close(fig)


def test_the_moving_obstacle_is_drawn_at_each_robot_snapshot_with_a_time_label(crate_run):
    scenario, result = crate_run
    fig = trajectory_figure(result.series, scenario)
    try:
        ax = fig.axes[0]
        snaps = snapshot_times(sorted({row[0] for row in result.series.robots}))
        crate = scenario.obstacles[0]
        drawn = {(round(p.center[0], 6), round(p.center[1], 6)) for p in ax.patches
                 if isinstance(p, Circle) and math.isclose(p.radius, crate.safe_distance)}
        for t in snaps:
            x, y = crate.position(t)
            assert (round(x, 6), round(y, 6)) in drawn, f"crate not drawn at t={t}"
        texts = {t.get_text() for t in ax.texts}
        for t in snaps:
            assert f"{crate.name} t={t:.0f}s" in texts
            assert f"t={t:.0f}s" in texts  # the formation at the same instant
        assert not [c for c in ax.lines if c.get_gid() == COLLISION_GID]
        legend = _legend_texts(fig)
        assert LEGEND_MOVING in legend and LEGEND_BODY in legend
        assert LEGEND_COLLISION not in legend
    finally:
        plt.close(fig)


def test_time_labels_do_not_overlap(crate_run):
    scenario, result = crate_run
    fig = trajectory_figure(result.series, scenario)
    try:
        renderer = fig.canvas.get_renderer()
        from matplotlib.text import Text

        texts = [t for t in fig.axes[0].texts if "t=" in t.get_text()]
        for t in texts:
            t.update_positions(renderer)
        boxes = [Text.get_window_extent(t, renderer) for t in texts]
        assert len(boxes) >= 10
        for i, a in enumerate(boxes):
            for b in boxes[i + 1:]:
                assert not a.overlaps(b)
    finally:
        plt.close(fig)


def test_every_collision_onset_gets_a_red_x_where_it_began(unsafe_run):
    scenario, result = unsafe_run
    assert result.summary["collisions"] > 0
    fig = trajectory_figure(result.series, scenario)
    try:
        ax = fig.axes[0]
        marks = [line for line in ax.lines if line.get_gid() == COLLISION_GID]
        assert len(marks) == result.summary["collisions"]
        log = result.summary["collision_log"]
        rows = {(round(row[0], 6), row[1]): (row[3], row[4]) for row in result.series.robots}
        assert any(e.get("kind") != "load" for e in log)
        for mark, entry in zip(marks, log, strict=True):
            if entry.get("kind") == "load":  # a load's: where the log says (issue 25)
                x, y = entry["x"], entry["y"]
            else:
                a, b = rows[(entry["t"], entry["a"])], rows[(entry["t"], entry["b"])]
                x, y = (a[0] + b[0]) / 2, (a[1] + b[1]) / 2
            assert mark.get_xdata()[0] == pytest.approx(x)
            assert mark.get_ydata()[0] == pytest.approx(y)
            assert mark.get_color() == "red"
        assert LEGEND_COLLISION in _legend_texts(fig)
    finally:
        plt.close(fig)


def test_the_legend_says_static_obstacle_disks_are_safe_distances():
    scenario = load_scenario(ROOT / "scenarios" / "thesis-5.1.1.yaml")
    result = simulate(replace(scenario, duration=2.0))
    fig = trajectory_figure(result.series, scenario)
    try:
        assert LEGEND_SAFE_DISK in _legend_texts(fig)
    finally:
        plt.close(fig)


def test_the_safety_figure_has_one_legend_for_all_panels_naming_every_robot(unsafe_run):
    scenario, result = unsafe_run
    fig = safety_figure(result.series, scenario)
    try:
        assert len(fig.axes) == 2  # formation and other-formation barriers; no obstacles
        assert len(fig.legends) == 1
        assert set(_legend_texts(fig)) == set(scenario.robot_ids)
    finally:
        plt.close(fig)


def test_the_symlog_axis_starts_just_below_the_data_with_no_empty_band():
    assert symlog_scale([0.5, 1.0, 2.0]) is None  # one decade: linear
    linthresh, (bottom, top) = symlog_scale([0.8, 3.0, 50.0, 200.0])
    assert linthresh <= 0.8 and -0.1 * linthresh <= bottom < 0 and top >= 200.0
    linthresh, (bottom, _) = symlog_scale([-0.66, 0.1, 1.0, 100.0])
    assert linthresh >= 0.66 / 10 and -0.66 * 1.5 <= bottom < -0.66


def test_the_unsafe_safety_plot_spends_most_of_its_height_on_data(unsafe_run):
    scenario, result = unsafe_run
    fig = safety_figure(result.series, scenario)
    try:
        ax = fig.axes[1]
        assert ax.get_yscale() == "symlog"
        lo = min(row[16] for row in result.series.robots if math.isfinite(row[16]))
        bottom, _ = ax.get_ylim()
        assert lo * 1.5 <= bottom < lo  # the axis ends just below the deepest violation
    finally:
        plt.close(fig)
