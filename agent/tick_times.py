"""Where a tick's time goes: each part of the tick timed on the wall clock, for ``formation bench``.

A tick (:meth:`agent.tick.Ticker.tick`, in real time through :class:`agent.schedule.PoseScheduler`)
is a row of parts; :class:`TickTimes` is lapped at the end of each (``lap(PART)``: the time since
the previous lap goes to ``PART``), and :meth:`TickTimes.end` files the tick: every part that ran
adds its time [us] to its window of the newest :data:`agent.clock.STATS_WINDOW` ticks.
A lap is one ``perf_counter_ns`` and one list update; the windows fill once per tick.

The parts, in the order they run (a part that did not run in a tick, e.g. ``leader`` on a member
or everything after ``pose`` on a stale tick, is not in that tick's figures):

* ``inbox``: the waiting samples drained from the ring channels: decoded, checked (stamp,
  plausibility) and stored (:meth:`agent.inbox.Inbox.drain`);
* ``pose``: the pose taken and checked, carried forward, the control point;
* ``leader``: the leader's part (ellipse estimated and put, ``others`` put);
* ``inputs``: freshness of every input, the obstacles, the neighbours' states at the pose's stamp,
  the step's inputs assembled;
* ``route``: the route walked (:meth:`agent.navigation.NavPart.step`);
* ``step``: the control step (:meth:`agent.control.Controller.step`: nominal command, rows, QP);
* ``command``: the command encoded and put;
* ``record``: the step counted (statuses, barrier values, the trace) and the viewers' diagnostics;
* ``state``: ``state`` encoded and put (real time: after the command).
"""

from __future__ import annotations

import statistics
from collections import deque
from time import perf_counter_ns

from agent.clock import STATS_WINDOW

TICK_PARTS = ("inbox", "pose", "leader", "inputs", "route", "step", "command", "record", "state")
INBOX, POSE, LEADER, INPUTS, ROUTE, STEP, COMMAND, RECORD, STATE = range(len(TICK_PARTS))
_ZEROS = (0,) * len(TICK_PARTS)


class TickTimes:
    """The parts of the ticks (module docstring): :meth:`begin`, :meth:`lap` per part,
    :meth:`end`; :meth:`medians` [us] per part over the window."""

    __slots__ = ("_acc", "_last", "_windows", "last")

    def __init__(self) -> None:
        self._acc = [0] * len(TICK_PARTS)  # [ns] this tick's time per part so far
        self.last = [0] * len(TICK_PARTS)  # [ns] the last ended tick's time per part
        self._last = 0
        self._windows: tuple[deque[float], ...] = tuple(
            deque(maxlen=STATS_WINDOW) for _ in TICK_PARTS)

    def begin(self) -> None:
        """A tick starts now (a part it does not lap later counts nothing)."""
        self._last = perf_counter_ns()

    def lap(self, part: int) -> None:
        """The part ``part`` (an index of :data:`TICK_PARTS`) ends now."""
        now = perf_counter_ns()
        self._acc[part] += now - self._last
        self._last = now

    def skip(self) -> None:
        """Time since the last lap belongs to no part (e.g. a wait between parts)."""
        self._last = perf_counter_ns()

    def end(self) -> None:
        """File this tick's parts in their windows and start the next tick from zero."""
        acc = self._acc
        for ns, window in zip(acc, self._windows, strict=True):
            if ns:
                window.append(ns * 1e-3)
        self._acc, self.last = self.last, acc  # the ended tick's parts kept, no new list
        self._acc[:] = _ZEROS

    def medians(self) -> dict[str, float | None]:
        """Per part: the median [us] over the ticks it ran in (None: it never ran)."""
        return {name: statistics.median(w) if w else None
                for name, w in zip(TICK_PARTS, self._windows, strict=True)}
