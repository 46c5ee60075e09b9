"""What a run leaves in its output folder: ``summary.json``, time series (CSV) and figures.

Shared by ``formation sim`` and ``formation run`` so both write the same files:

* ``summary.json`` - the contract of DESIGN.md ("Run output");
* ``robots.csv`` - one row per robot per tick (:data:`simulator.inprocess.ROBOT_COLUMNS`);
* ``ellipses.csv``, ``obstacles.csv`` - per tick;
* ``trajectories.png`` - paths, obstacles and ellipse snapshots (like thesis Figs. 5.2, 5.11, 5.15);
* ``safety.png`` - the smallest barrier value of each kind per robot over time (Figs. 5.3, 5.4, 5.12);
* ``run.mcap`` - the run for Foxglove or Lichtblick (:func:`viewer.record.write_recording`).
"""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

from scenario import Scenario
from viewer.record import write_recording

from .inprocess import ROBOT_COLUMNS, Series

ELLIPSE_COLUMNS = ("t", "formation", "cx", "cy", "alpha", "a", "b", "vx", "vy", "alpha_rate")
OBSTACLE_COLUMNS = ("t", "obstacle", "x", "y", "safe_distance")


def write_run(summary: dict, series: Series, scenario: Scenario, out: Path, plots: bool = True):
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "summary.json").write_text(
        json.dumps(_json_safe(summary), indent=2, allow_nan=False) + "\n", encoding="utf-8"
    )
    _write_csv(out / "robots.csv", ROBOT_COLUMNS, series.robots)
    _write_csv(out / "ellipses.csv", ELLIPSE_COLUMNS, series.ellipses)
    _write_csv(out / "obstacles.csv", OBSTACLE_COLUMNS, series.obstacles)
    write_recording(summary, series, scenario, out)
    if plots and series.robots:
        from .plots import plot_safety, plot_trajectories

        plot_trajectories(series, scenario, out / "trajectories.png")
        plot_safety(series, scenario, out / "safety.png")


def _write_csv(path: Path, columns, rows) -> None:
    with path.open("w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(columns)
        for row in rows:
            w.writerow([_cell(v) for v in row])


def _cell(v):
    if isinstance(v, float):
        return "" if not math.isfinite(v) else f"{v:.6g}"
    return v


def _json_safe(obj):
    if isinstance(obj, dict):
        return {k: _json_safe(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_json_safe(v) for v in obj]
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj
