"""What the command line shows while and after a run: the progress bar and the run summary."""

from __future__ import annotations

import sys
from pathlib import Path


class Progress:
    """A one-line progress display on stderr (redrawn in place on a terminal).

    ``unit="time"``: the bar runs against the scenario's duration and shows the simulated time.
    A run that ends early (it stops when every goal is reached) is not drawn as full: its last
    line says where and why it ended (``ended early at t=9.60 s of 40.00 s: every goal
    reached``). ``unit="runs"``: the bar counts finished runs (``12/40 runs``). A lifelong run
    tells :meth:`orders` the orders delivered and posted: the line shows them
    (``3/5 orders delivered``) and is drawn again as soon as another is delivered."""

    def __init__(self, label: str, quiet: bool = False, unit: str = "time",
                 early: str = "every goal reached") -> None:
        if unit not in ("time", "runs"):
            raise ValueError(f"unit: {unit!r} is not 'time' or 'runs'")
        self.label = label
        self.early = early  # why a run stops before its duration (a held run: stopped from outside)
        self.quiet = quiet
        self.unit = unit
        self.tty = sys.stderr.isatty()
        self._last = -1
        self._time = 0.0
        self._done = 0
        self._total = 0
        self._orders: tuple[int, int] | None = None  # (delivered, posted) of a lifelong run

    def __enter__(self) -> Progress:
        return self

    def orders(self, delivered: int, posted: int) -> None:
        """A lifelong run's orders delivered and posted so far; a new delivery is drawn at the
        next :meth:`update`."""
        if self._orders is not None and delivered != self._orders[0]:
            self._last = -1
        self._orders = (delivered, posted)

    def update(self, done: int, total: int, sim_time: float) -> None:
        self._time, self._done, self._total = sim_time, done, total
        if self.quiet or total <= 0:
            return
        pct = int(100 * done / total)
        step = 1 if self.tty else 10
        if pct // step == self._last // step and done != total:
            return
        self._last = pct
        self._draw(done / total, f"{pct:3d}%  {self._where()}")

    def _where(self) -> str:
        if self.unit == "runs":
            return f"{self._done}/{self._total} runs"
        duration = self._time * self._total / self._done if self._done else 0.0
        where = f"t={self._time:7.2f} s of {duration:.2f} s"
        if self._orders is not None:
            where += f", {self._orders[0]}/{self._orders[1]} orders delivered"
        return where

    def _draw(self, fraction: float, tail: str) -> None:
        width = 30
        fill = int(width * fraction)
        line = f"{self.label} [{'#' * fill}{'.' * (width - fill)}] {tail}"
        sys.stderr.write(("\r" + line) if self.tty else (line + "\n"))
        sys.stderr.flush()

    def __exit__(self, exc_type, *exc) -> None:
        if self.quiet:
            return
        if exc_type is None and 0 < self._done < self._total and self.unit == "time":
            # the run stopped before its duration: every goal was reached (the only early stop
            # of a run that is not held)
            self._draw(self._done / self._total, f"ended early at {self._where()}: {self.early}")
        if self.tty:
            sys.stderr.write("\n")
            sys.stderr.flush()


def qp_words(qp: dict, hard_ticks: int | None = None) -> str:
    """The QP counters of a summary in words: a formation relaxation is by design (the formation
    tolerance bends, minimally, when the QP is infeasible); ticks on which a hard row was not met
    (``hard_ticks``: the summary's ``hard_row_unmet_ticks``; the fallback ticks where a summary
    has none) and solver errors are what would alarm."""
    solves = qp["solves"]
    relaxed = qp.get("relaxed", 0)
    hard = qp.get("fallback", 0) if hard_ticks is None else hard_ticks
    failed = qp.get("failed", 0)
    words = (f"formation tolerance relaxed (by design, minimal) on {relaxed:,} of {solves:,} "
             f"ticks; hard rows unmet: {hard:,}")
    if failed:
        words += f"; solver failures: {failed:,}"
    return words


def reach_words(summary: dict) -> str:
    """Whether every robot reached its goal, and when; a held run (``--hold``, stopped by
    Ctrl-C, SIGTERM or ``--duration``) says where it was when it stopped."""
    ttg = summary["time_to_goal_s"]
    if summary.get("hold"):
        where = ("every robot at its last goal" if summary["all_reached"]
                 else "not every robot at its last goal")
        return f"held until t={summary['sim_time_s']:.2f} s, then stopped: {where}"
    if summary["all_reached"]:
        return "all robots reached their goals" + (f" at t={ttg:.2f} s" if ttg is not None else "")
    return "NOT all goals reached"


def realtime_words(summary: dict, epsilon: float | None = None) -> str:
    """A real-time run's trouble, in words (empty when there was none): agent ticks on stale
    inputs (``agents.stale``), robot-ticks without a fresh command (``world.missing_cmds``) and
    the formation error above ``epsilon`` (the band of eq. 3.3)."""
    if not summary.get("realtime"):
        return ""
    parts = []
    stale = summary.get("agents", {}).get("stale", 0)
    missing = summary.get("world", {}).get("missing_cmds", 0)
    if stale:
        parts.append(f"{stale:,} stale ticks (zero command)")
    if missing:
        parts.append(f"{missing:,} missing commands")
    error = summary.get("formation_error_max_m")
    if epsilon and error is not None and error > epsilon:
        parts.append(f"formation error up to {error / epsilon:.2f} epsilon")
    return "; real time: " + ", ".join(parts) if parts else ""


def print_summary(summary: dict, out: Path, plots: bool = True, epsilon: float | None = None) -> None:
    """The closing line of a run; ``epsilon`` [m], the scenario's formation tolerance, names a
    formation error beyond it in a real-time run."""
    ok = summary["all_reached"] and summary["collisions"] == 0
    qp = summary["qp"]
    trouble = realtime_words(summary, epsilon)
    print(
        f"{summary['scenario']} ({summary['mode']}): {reach_words(summary)}; "
        f"collisions {summary['collisions']}; "
        f"max formation error {summary['formation_error_max_m']:.4f} m; "
        f"{qp_words(qp, summary.get('hard_row_unmet_ticks', qp.get('hard_row_unmet_ticks')))}"
        + (f"; tick_errors {n}" if (n := summary.get("agents", {}).get("tick_errors")) else "")
        + trouble + ("" if ok else "  [UNSAFE OR INCOMPLETE]")
    )
    lost = summary.get("lost_files")
    if lost:  # a disk that filled part way: the summary is there, these are not
        print(f"wrote {out / 'summary.json'}; {lost_words(lost)} (listed in its lost_files)")
        return
    print(f"wrote {out / 'summary.json'}" + (f" and figures in {out}/" if plots else f" in {out}/"))


def lost_words(lost: list[dict]) -> str:
    """The files a run could not write, and why (``summary.json``'s ``lost_files``)."""
    return "could not write " + ", ".join(f"{e['file']} ({e['error']})" for e in lost)
