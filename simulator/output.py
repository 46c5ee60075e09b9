"""What a run leaves in its output folder: ``summary.json``, time series (CSV) and figures.

Shared by ``formation sim`` and ``formation run`` so both write the same files:

* ``summary.json`` - the contract of DESIGN.md ("Run output");
* ``robots.csv`` - one row per robot per tick (:data:`simulator.inprocess.ROBOT_COLUMNS`; a run of
  double integrators adds ``ax, ay``, :func:`simulator.series.robot_columns`);
* ``ellipses.csv``, ``obstacles.csv`` - per tick;
* ``trajectories.png`` - paths, obstacles and ellipse snapshots (like thesis Figs. 5.2, 5.11, 5.15);
* ``safety.png`` - the smallest barrier value of each kind per robot over time (Figs. 5.3, 5.4, 5.12);
* ``run.mcap`` - the run for Foxglove or Lichtblick (:func:`viewer.record.write_recording`).
"""

from __future__ import annotations

import csv
import errno
import json
import logging
import math
import os
import shutil
from pathlib import Path

from scenario import Scenario
from viewer.record import write_recording

from .series import Series, robot_columns

ELLIPSE_COLUMNS = ("t", "formation", "cx", "cy", "alpha", "a", "b", "vx", "vy", "alpha_rate")
OBSTACLE_COLUMNS = ("t", "obstacle", "x", "y", "safe_distance")


PLOTS = ("trajectories.png", "safety.png", "motion.png")
STAGING = ".writing"  # in the output folder: this run's files until they are all written
NO_ROOM = 64 * 1024  # [bytes] free below this after a failed write: the disk is full


class OutputError(OSError):
    """The run's files could not be written (the message says why: a full disk, say)."""


def write_run(summary: dict, series: Series, scenario: Scenario, out: Path, plots: bool = True):
    """Write every file of a run atomically: each to a temporary name, then all renamed, the
    old ``summary.json`` removed first and the new one renamed last, so a reader never sees a
    summary beside another run's or half-written series. On failure nothing of this run is
    left and :class:`OutputError` says why (``disk full`` for ENOSPC)."""
    out = Path(out)
    staging = out / STAGING  # every file is written here first, then renamed into out
    written: list[tuple[Path, Path]] = []  # (temporary, final)

    def tmp(name: str) -> Path:
        written.append((staging / name, out / name))
        return staging / name

    try:
        staging.mkdir(parents=True, exist_ok=True)
        _write_csv(tmp("robots.csv"), robot_columns(scenario), series.robots)
        _write_csv(tmp("ellipses.csv"), ELLIPSE_COLUMNS, series.ellipses)
        _write_csv(tmp("obstacles.csv"), OBSTACLE_COLUMNS, series.obstacles)
        _record(summary, series, scenario, staging)
        tmp("run.mcap")
        if plots and series.robots:
            # here, not at the top: matplotlib loads only for a run that draws its figures
            from .plots import plot_motion, plot_safety, plot_trajectories

            plot_trajectories(series, scenario, tmp("trajectories.png"))
            plot_safety(series, scenario, tmp("safety.png"))
            plot_motion(series, scenario, tmp("motion.png"))
        write_json(tmp("summary.json"), _json_safe(summary), rename=False)
        (out / "summary.json").unlink(missing_ok=True)
        names = {final.name for _, final in written}
        for name in PLOTS:  # a previous run's figures must not pass for this run's
            if name not in names:
                (out / name).unlink(missing_ok=True)
        for t, final in written:
            t.replace(final)  # summary.json last
        staging.rmdir()
    except OSError as exc:
        shutil.rmtree(staging, ignore_errors=True)
        raise output_error(exc, out) from None


def _record(summary: dict, series: Series, scenario: Scenario, folder: Path) -> None:
    """``folder/run.mcap``; the MCAP writer reports a full disk as its own error (after a
    warning per message it could not log, here kept quiet): that becomes ENOSPC."""
    quiet = logging.getLogger("foxglove")
    level = quiet.level
    quiet.setLevel(logging.ERROR)
    try:
        write_recording(summary, series, scenario, folder)
    except OSError:
        raise
    except Exception:
        if shutil.disk_usage(folder).free < NO_ROOM:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(folder / "run.mcap")) from None
        raise
    finally:
        quiet.setLevel(level)


def output_error(exc: OSError, out: Path) -> OutputError:
    """An :class:`OutputError` that names the folder and says "disk full" for ENOSPC/EDQUOT."""
    where = out
    if exc.errno in (errno.ENOSPC, errno.EDQUOT):
        return OutputError(f"disk full: cannot write {where} (run output not saved)")
    return OutputError(f"cannot write {where}: {exc.strerror or exc}")


def write_json(path: Path, data, rename: bool = True) -> None:
    """``data`` as indented JSON; with ``rename`` through a temporary file and a rename, so a
    reader sees the old file or the whole new one."""
    text = json.dumps(data, indent=2, allow_nan=False) + "\n"
    target = path.with_name(f".{path.name}.tmp") if rename else path
    with target.open("w", encoding="utf-8") as fh:
        fh.write(text)
        fh.flush()
    if rename:
        target.replace(path)


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
