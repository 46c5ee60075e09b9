"""What the command line shows while and after a run: the progress bar and the run summary."""

from __future__ import annotations

import sys
from pathlib import Path


class Progress:
    """A one-line progress display on stderr (redrawn in place on a terminal).

    The bar runs against the scenario's duration; a run that ends early (every goal reached)
    closes it at full with the time it ended."""

    def __init__(self, label: str, quiet: bool = False) -> None:
        self.label = label
        self.quiet = quiet
        self.tty = sys.stderr.isatty()
        self._last = -1
        self._time = 0.0

    def __enter__(self) -> Progress:
        return self

    def update(self, done: int, total: int, sim_time: float) -> None:
        self._time = sim_time
        if self.quiet or total <= 0:
            return
        pct = int(100 * done / total)
        step = 1 if self.tty else 10
        if pct // step == self._last // step and done != total:
            return
        self._last = pct
        self._draw(done / total, f"{pct:3d}%  t={sim_time:7.2f} s")

    def _draw(self, fraction: float, tail: str) -> None:
        width = 30
        fill = int(width * fraction)
        line = f"{self.label} [{'#' * fill}{'.' * (width - fill)}] {tail}"
        sys.stderr.write(("\r" + line) if self.tty else (line + "\n"))
        sys.stderr.flush()

    def __exit__(self, exc_type, *exc) -> None:
        if self.quiet:
            return
        if exc_type is None and self._last >= 0 and self._last < 100:
            self._draw(1.0, f"done  t={self._time:7.2f} s")
        if self.tty:
            sys.stderr.write("\n")
            sys.stderr.flush()


def print_summary(summary: dict, out: Path) -> None:
    ok = summary["all_reached"] and summary["collisions"] == 0
    ttg = summary["time_to_goal_s"]
    print(
        f"{summary['scenario']} ({summary['mode']}): "
        f"{'all robots reached their goals' if summary['all_reached'] else 'NOT all goals reached'}"
        f"{f' at t={ttg:.2f} s' if ttg is not None else ''}; collisions {summary['collisions']}; "
        f"max formation error {summary['formation_error_max_m']:.4f} m; "
        f"QP infeasible ticks {summary['qp']['infeasible']}/{summary['qp']['solves']}"
        + ("" if ok else "  [UNSAFE OR INCOMPLETE]")
    )
    print(f"wrote {out / 'summary.json'} and figures in {out}/")
