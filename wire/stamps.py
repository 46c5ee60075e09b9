"""The one stamp check every input passes (docs/faults.md, "Time: the one stamp check").

A message's ``stamp`` is the time its content was measured (a pose: the camera frame's capture
time; a state, ellipse or command: the stamp of the pose it was computed from). A receiver judges
the message by that stamp, never by when it arrived, against its own clock ``now``:

1. ``future``: stamped more than ``tolerance`` after ``now`` (a clock ahead of ours by more than
   the clocks may disagree, or a forged stamp);
2. ``stale``: older than ``stale_after`` (``now - stamp > stale_after``);
3. ``older``: older than the last stamp this receiver used (or kept) for the same input, so a
   late or replayed message never replaces a newer one.

The first that applies is the reason; ``None`` accepts. The order matters: a stamp far in the
future is refused before it can become "the last used", so one forged or mis-clocked message
never blocks the genuine ones after it (the receiver only records a stamp as used once it
accepted it).

A stamp inside the tolerance but ahead of ``now`` is accepted (clocks may disagree that much),
but what the receiver records as the last used stamp is :func:`used_stamp`: the stamp, never
later than the receiver's own clock when it accepted it. Recorded as it came, one message stamped
90 ms ahead (a faulty camera, a clock step, a forger with the camera's credentials) made every
genuine message for the next 90 ms "older", and a stream of them took the input over for good:
a pose walked 2 cm a message moved two robots into each other, empty obstacle lists erased the
obstacles. Clamped, a message ahead of the clock can refuse the genuine messages stamped before
the moment it arrived, and no later ones: one forged message costs at most the genuine messages
already in flight (the latency's worth), and a forged stream interleaved with the genuine one no
longer hides it: a message stamped before the kept one that disagrees with it is a second
source, and the agent stops until the input has had one source for a while (``agent.inbox``,
docs/faults.md).

Which clock is ``now``:

* **lock-step** (the simulated world): simulated time, i.e. the stamp of the frame the receiver
  is on; ``tolerance`` is a few control periods (:data:`LOCKSTEP_AHEAD_PERIODS`: a neighbour
  may be one frame ahead of this agent), so a stamp outside the run's current window is refused;
* **real time**: the receiver's wall clock (``time.time()``), which must agree with the camera
  PC's and the other robots' to within ``tolerance`` (chrony on every machine; docs/faults.md
  gives the offsets measured to be tolerated).

:class:`StampCounter` counts rejections per input class and reason. Pure: no clock is read here.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Mapping

FUTURE = "future"
STALE = "stale"
OLDER = "older"
REASONS: tuple[str, ...] = (FUTURE, STALE, OLDER)  # checked in this order

CLOCK_TOLERANCE_S = 0.1  # [s] default: how far ahead of ours another clock's stamp may be
LOCKSTEP_AHEAD_PERIODS = 2.0  # lock-step: stamps up to this many periods past the current frame
EPS = 1e-9  # [s] stamps in lock-step are multiples of dt computed in floating point
# [s] lock-step: the longest an agent waits for one phase's inputs. A tick that plans a route
# takes a second of CPU at worst, several seconds of wall time on a loaded machine, and a wait
# cut short makes a run differ from the in-process simulation, so only a dead or stopped process
# should outlast it (a fault run waits far less: simulator.faults)
LOCKSTEP_WAIT_S = 20.0
# [s] lock-step: the longest the world waits for a tick's commands. Longer than an agent's
# phases in a row (a leader waits for its members' states, then the other leaders' ellipses,
# then its tick's inputs): around a dead agent its neighbours give up first and command, so the
# world waits only for the dead robot. Were the world to give up first, every robot would be
# late at once and the world would run ahead of all of them.
LOCKSTEP_WORLD_WAIT_S = 3 * LOCKSTEP_WAIT_S


def check_stamp(now: float, stamp: float, last: float | None, tolerance: float,
                stale_after: float) -> str | None:
    """Why a message stamped ``stamp`` is rejected at ``now`` (``FUTURE``, ``STALE`` or
    ``OLDER``, checked in that order), or ``None`` to accept it. ``last`` is the stamp last
    used for the same input (``None``: nothing used yet). An equal stamp is not older."""
    if not math.isfinite(stamp):
        return FUTURE if stamp > 0 else STALE
    if stamp > now + tolerance + EPS:
        return FUTURE
    if now - stamp > stale_after + EPS:
        return STALE
    if last is not None and stamp < last - EPS:
        return OLDER
    return None


def used_stamp(now: float, stamp: float) -> float:
    """The stamp a receiver records as the last used for an input when it accepts a message
    stamped ``stamp`` at ``now``: never later than its own clock (module docstring)."""
    return min(stamp, now)


def validate_window(tolerance: float, stale_after: float) -> None:
    """ValueError naming the parameter unless both are finite and positive."""
    for name, v in (("clock_tolerance", tolerance), ("stale_after", stale_after)):
        if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v) \
                or v <= 0:
            raise ValueError(f"{name}: must be a positive number of seconds, got {v!r}")


class StampCounter:
    """Rejections per input class and reason (thread-safe: receivers count on Zenoh threads)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._counts: dict[str, dict[str, int]] = {}

    def count(self, cls: str, reason: str) -> None:
        if reason not in REASONS:
            raise ValueError(f"reason: {reason!r} is not one of {REASONS}")
        with self._lock:
            per = self._counts.setdefault(cls, dict.fromkeys(REASONS, 0))
            per[reason] += 1

    def check(self, cls: str, now: float, stamp: float, last: float | None, tolerance: float,
              stale_after: float) -> bool:
        """:func:`check_stamp`, counting a rejection under ``cls``; True when accepted."""
        reason = check_stamp(now, stamp, last, tolerance, stale_after)
        if reason is None:
            return True
        self.count(cls, reason)
        return False

    def snapshot(self) -> dict[str, dict[str, int]]:
        """``{class: {future: n, stale: n, older: n}}`` for every class with a rejection."""
        with self._lock:
            return {cls: dict(per) for cls, per in self._counts.items()}

    @property
    def total(self) -> int:
        with self._lock:
            return sum(sum(per.values()) for per in self._counts.values())


def merge_counts(snapshots: list[Mapping[str, Mapping[str, int]]]) -> dict[str, dict[str, int]]:
    """Add :meth:`StampCounter.snapshot` results of many processes."""
    out: dict[str, dict[str, int]] = {}
    for snap in snapshots:
        for cls, per in snap.items():
            mine = out.setdefault(cls, dict.fromkeys(REASONS, 0))
            for reason, n in per.items():
                mine[reason] = mine.get(reason, 0) + int(n)
    return out
