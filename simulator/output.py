"""What a run leaves in its output folder: ``summary.json``, time series (CSV) and figures.

Shared by ``formation sim`` and ``formation run`` so both write the same files:

* ``summary.json`` - the contract of docs/outputs.md;
* ``robots.csv`` - one row per robot per tick (:data:`simulator.inprocess.ROBOT_COLUMNS`; a run of
  double integrators adds ``ax, ay``, :func:`simulator.series.robot_columns`);
* ``ellipses.csv``, ``obstacles.csv`` - per tick;
* ``trajectories.png`` - paths, obstacles and ellipse snapshots (like thesis Figs. 5.2, 5.11, 5.15);
* ``safety.png`` - the smallest barrier value of each kind per robot over time (Figs. 5.3, 5.4, 5.12);
* ``run.mcap`` - the run for Foxglove or Lichtblick (:func:`viewer.record.write_recording`).

``summary.json`` is written first: on a disk that fills part way the bulk files that did not fit
are deleted and listed in its ``lost_files`` (:func:`write_run`), so a run never loses its summary
to its own time series.
"""

from __future__ import annotations

import csv
import errno
import functools
import json
import logging
import math
import os
import shutil
from collections.abc import Callable
from pathlib import Path

from scenario import Scenario
from viewer.orders import OrderBoard
from viewer.record import write_recording

from .goals import with_goals
from .series import Series, robot_columns

ELLIPSE_COLUMNS = ("t", "formation", "cx", "cy", "alpha", "a", "b", "vx", "vy", "alpha_rate")
OBSTACLE_COLUMNS = ("t", "obstacle", "x", "y", "safe_distance")


BULK = ("robots.csv", "ellipses.csv", "obstacles.csv", "run.mcap")  # after summary.json, in order
PLOTS = ("trajectories.png", "safety.png", "motion.png")
STAGING = ".writing"  # in the output folder: this run's files until they are all written
NO_ROOM = 64 * 1024  # [bytes] free below this after a failed write: the disk is full

logger = logging.getLogger(__name__)


class OutputError(OSError):
    """The run's files could not be written (the message says why: a full disk, say)."""


def write_run(summary: dict, series: Series, scenario: Scenario, out: Path,
              plots: bool = True, board: OrderBoard | None = None) -> list[dict[str, str]]:
    """Write every file of a run, ``summary.json`` first (small: it is what a run must not
    lose), then each bulk file to a temporary name and renamed whole. The previous run's
    files of these names go first, so none passes for this run's.

    A bulk file that cannot be written (a full disk part way) is deleted and the others are
    still tried; ``summary.json`` is then rewritten with ``lost_files`` (``{file, error}`` each,
    after those ``summary`` named already: agents' counters, say; also set in ``summary``) and
    the whole list is returned ([] when nothing was lost). ``board``: a lifelong run's loads and
    orders, for ``run.mcap``. Only a ``summary.json`` that cannot
    be written at all raises :class:`OutputError` (``disk full`` for ENOSPC), leaving nothing of
    this run behind."""
    out = Path(out)
    try:
        for name in ("summary.json", *BULK, *PLOTS):  # the summary first: never beside old files
            (out / name).unlink(missing_ok=True)
        out.mkdir(parents=True, exist_ok=True)
        write_json(out / "summary.json", _json_safe(summary))
    except OSError as exc:
        raise output_error(exc, out) from None
    staging = out / STAGING  # every bulk file is written here first, then renamed into out
    lost: list[dict[str, str]] = list(summary.get("lost_files") or [])
    named = len(lost)  # already in the summary as written
    try:
        for name, write in _bulk_writers(summary, series, scenario, plots, board):
            problem = _write_one(staging / name, out / name, write)
            if problem is not None:
                lost.append({"file": name, "error": problem})
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    if len(lost) > named:
        summary["lost_files"] = lost
        try:  # the space the deleted files held is free again; if not, the first one stands
            write_json(out / "summary.json", _json_safe(summary))
        except OSError:
            logger.info("could not add lost_files to %s", out / "summary.json")
    return lost


def _bulk_writers(summary: dict, series: Series, scenario: Scenario, plots: bool,
                  board: OrderBoard | None = None) -> list[tuple[str, Callable[[Path], None]]]:
    """(name, writer of that file at a given path) for each bulk file of the run, in order."""
    writers: list[tuple[str, Callable[[Path], None]]] = [
        ("robots.csv", functools.partial(write_csv_rows, columns=robot_columns(scenario),
                                         rows=series.robots)),
        ("ellipses.csv", functools.partial(write_csv_rows, columns=ELLIPSE_COLUMNS,
                                           rows=series.ellipses)),
        ("obstacles.csv", functools.partial(write_csv_rows, columns=OBSTACLE_COLUMNS,
                                            rows=series.obstacles)),
        ("run.mcap", lambda path: _record(summary, series, scenario, path.parent, board)),
    ]
    if plots and series.robots:
        # here, not at the top: matplotlib loads only for a run that draws its figures
        from .plots import plot_motion, plot_safety, plot_trajectories

        # the goals drawn are those the run was judged at (a goal sent at run time: that one)
        drawn = with_goals(scenario, summary.get("goals_sent") or {})
        for name, draw in zip(PLOTS, (plot_trajectories, plot_safety, plot_motion), strict=True):
            writers.append((name, functools.partial(draw, series, drawn)))
    return writers


def _write_one(tmp: Path, final: Path, write: Callable[[Path], None]) -> str | None:
    """``write(tmp)``, then ``tmp`` renamed to ``final``; on failure the partial file is deleted
    and why is returned (:func:`lost_words`)."""
    try:
        tmp.parent.mkdir(exist_ok=True)
        write(tmp)
        tmp.replace(final)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        logger.info("could not write %s: %s", final, exc)  # the closing line names it
        return lost_words(exc)
    return None


def lost_words(exc: OSError) -> str:
    """Why a file could not be written, in a few words (``disk full`` for ENOSPC/EDQUOT)."""
    if exc.errno in (errno.ENOSPC, errno.EDQUOT):
        return "disk full"
    return exc.strerror or str(exc) or type(exc).__name__


def _record(summary: dict, series: Series, scenario: Scenario, folder: Path,
            board: OrderBoard | None = None) -> None:
    """``folder/run.mcap``; the MCAP writer reports a full disk as its own error (after a
    warning per message it could not log, here kept quiet): that becomes ENOSPC."""
    quiet = logging.getLogger("foxglove")
    level = quiet.level
    quiet.setLevel(logging.ERROR)
    try:
        write_recording(summary, series, scenario, folder, board)
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
    reader sees the old file or the whole new one (a temporary file that failed is deleted)."""
    text = json.dumps(data, indent=2, allow_nan=False) + "\n"
    target = path.with_name(f".{path.name}.tmp") if rename else path
    try:
        with target.open("w", encoding="utf-8") as fh:
            fh.write(text)
            fh.flush()
        if rename:
            target.replace(path)
    except OSError:
        target.unlink(missing_ok=True)
        raise


def write_csv_rows(path: Path, columns, rows) -> None:
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
