"""The agent's tick schedulers (the module docstring of :mod:`agent.node` describes them):

* lock-step (:class:`LockstepLoop`): tick on each new frame of the simulated world; each phase
  of the tick waits for its inputs (:class:`agent.clock.LockstepClock`);
* real time on pose arrival (:class:`PoseScheduler`): tick on the Zenoh thread that received a
  due pose (or on an agent host's tick thread), with the event loop's deadline tick;
* real time on the agent's own clock (:class:`ClockLoop`).

Each owns its timing state and counters (:class:`ScheduleCounts`); they share the agent's
:class:`TickGate` (the tick lock and the closing flag) and drive the tick they are given.
"""

from __future__ import annotations

import asyncio
import math
import threading
import time
from collections import deque
from collections.abc import Callable, Coroutine
from dataclasses import dataclass, field
from typing import Any

import zenoh

from agent.clock import STATS_WINDOW, LockstepClock
from agent.inbox import Inbox
from agent.tick_times import INBOX, TickTimes
from wire import keys

DEADLINE_PERIODS = 1.5  # real time: tick without a new pose after this many periods
MIN_SPACING_PERIODS = 0.75  # real time: a pose stamped sooner after the camera's schedule waits
LATE_POSE_PERIODS = 0.5  # real time: a pose stamped up to this much late does not move the schedule

Tick = Callable[[float | None], Coroutine[Any, Any, Any]]  # the agent's tick (t: lock-step frame)


class TickGate:
    """Ticks one at a time whichever thread runs them (``lock``), and none once closing."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.closing = False  # set when closing starts: no tick starts after it (read under the lock)

    def close(self, timeout: float) -> bool:
        """Stop every later tick, then let a tick in progress end (up to ``timeout``); False if
        it still runs. The flag goes first: under a flood, callbacks that take the lock for a
        moment each could keep it from this thread past ``timeout`` (the lock is not fair)."""
        self.closing = True
        got = self.lock.acquire(timeout=timeout)
        if got:
            self.lock.release()
        return got


@dataclass
class ScheduleCounts:
    """What a scheduler counts."""

    overruns: int = 0  # ticks longer than one period
    deadline_ticks: int = 0  # real time: ticks with no new pose for DEADLINE_PERIODS periods
    early_poses: int = 0  # real time: poses not ticked on, too soon (pose_due)
    tick_us: deque[float] = field(default_factory=lambda: deque(maxlen=STATS_WINDOW))  # [us]
    # from tick start (or pose arrival) to cmd put, the newest STATS_WINDOW ticks


def run_now(coro: Any) -> Any:
    """Run a coroutine that does not suspend to its end on the calling thread (a real-time
    tick, see the module docstring of :mod:`agent.node`) and return its result."""
    try:
        coro.send(None)
    except StopIteration as done:
        return done.value
    coro.close()
    raise RuntimeError("a real-time tick tried to suspend")


def pose_due(anchor: float | None, stamp: float, period: float) -> float | None:
    """The spacing rule of real time on pose arrival: None when the pose stamped ``stamp`` is
    not due, else the new *anchor*, the camera's schedule as far as the agent knows it (the
    previous anchor: None before the first pose).

    A pose is due when stamped ``MIN_SPACING_PERIODS`` or more after the anchor, or earlier than
    it (the camera's clock went back). The anchor is not the last ticked pose's stamp: it moves
    on by one period, never past the stamp, and never more than ``LATE_POSE_PERIODS`` behind
    it; the first pose (or one earlier than the anchor) starts it at its stamp. So once one pose
    came on time, a camera at the control rate whose poses are each stamped up to 0.75 of a
    period late (a camera or a world process that lost the CPU for a moment) has every pose
    ticked on, where a rule by the last ticked stamp skipped the punctual pose after one more
    than a quarter of a period late. The anchor still advances at least
    ``MIN_SPACING_PERIODS`` per tick and stays within ``LATE_POSE_PERIODS`` of the ticked
    stamp, so a camera faster than 1/period does not raise the tick rate beyond
    1/(``MIN_SPACING_PERIODS`` period), as before, and the same pose twice ticks once."""
    if anchor is None or stamp < anchor:
        return stamp
    if stamp < anchor + MIN_SPACING_PERIODS * period:
        return None
    return max(stamp - LATE_POSE_PERIODS * period, min(stamp, anchor + period))


class ClockLoop:
    """Real time on the agent's own clock (``NodeOptions(tick_on_pose=False)``): tick against
    deadlines at 1/period, ``next_t += period``, overruns counted."""

    def __init__(self, tick: Tick, period: float, times: TickTimes | None = None) -> None:
        self._tick = tick
        self._period = period
        self.counts = ScheduleCounts()
        self.times = times or TickTimes()  # the tick's parts (agent.tick_times)

    async def run(self, stop: asyncio.Event) -> None:
        period = self._period
        next_t = time.monotonic()
        while not stop.is_set():
            started = time.monotonic()
            self.times.begin()
            await self._tick(None)
            self.times.end()
            self.counts.tick_us.append((time.monotonic() - started) * 1e6)
            next_t += period
            now = time.monotonic()
            if now > next_t:
                self.counts.overruns += 1
                next_t = now  # do not try to catch up with a burst of ticks
            try:
                await asyncio.wait_for(stop.wait(), max(0.0, next_t - time.monotonic()))
            except (TimeoutError, asyncio.TimeoutError):  # distinct classes on 3.10
                pass


class PoseScheduler:
    """Real time on pose arrival (module docstring of :mod:`agent.node`): the pose callback
    (:meth:`on_sample`, on Zenoh's thread) ticks on a due pose, or, under an agent host with a
    tick thread, queues the agent there (``queue``); the loop's :meth:`run` ticks on the
    deadline when no tick has run for ``DEADLINE_PERIODS`` periods."""

    def __init__(self, tick: Tick, gate: TickGate, inbox: Inbox, pose_key: str, period: float,
                 pose_period: float, stale_after: float, times: TickTimes | None = None) -> None:
        self._tick = tick
        self.gate = gate
        self._inbox = inbox
        self._pose_key = pose_key
        self._period = period
        self.pose_period = pose_period  # [s] how often poses really come
        self._stale_after = stale_after
        self._anchor: float | None = None  # the camera's schedule (pose_due)
        self._last_tick = -math.inf  # [s, monotonic] when the last tick of any kind started
        self.queue: Callable[[], None] | None = None  # an agent host's tick thread (agent.host)
        self.counts = ScheduleCounts()
        self.times = times or TickTimes()  # the tick's parts (agent.tick_times)

    def on_sample(self, sample: zenoh.Sample) -> None:
        """Zenoh thread: store the pose and tick on it, or queue it on the host's tick thread."""
        self.feed(lambda: self._inbox.mailbox(keys.POSE).callback(sample))

    def feed(self, store: Callable[[], object]) -> None:
        """Zenoh thread: ``store()`` a pose under the tick lock (the camera's, or the agent's
        own estimate: :mod:`agent.odom_in`) and tick on it, or queue it on the host's tick
        thread."""
        queue = self.queue
        with self.gate.lock:
            if self.gate.closing:
                return
            store()
            if queue is None:
                self.pose_tick(time.monotonic())
                return
        queue()

    def pose_tick(self, now: float) -> bool:
        """Under the tick lock: tick on the newest pose if it is due by :func:`pose_due`
        (True), else nothing (counted ``early_poses``)."""
        entry = self._inbox.latest(keys.POSE, self._pose_key)
        if entry is None:
            return False
        anchor = pose_due(self._anchor, entry[0].stamp, self._period)
        if anchor is None:
            self.counts.early_poses += 1
            return False
        self._anchor = anchor
        self.tick_locked(now)
        return True

    def tick_locked(self, now: float) -> None:
        """Under the tick lock: drain the ring channels, tick, time it."""
        self._last_tick = now
        times = self.times
        times.begin()
        self._inbox.drain()
        times.lap(INBOX)
        run_now(self._tick(None))
        times.end()
        done = time.monotonic()
        self.counts.tick_us.append((done - now) * 1e6)
        if done - now > self._period:
            self.counts.overruns += 1

    async def run(self, stop: asyncio.Event) -> None:
        """The deadline tick when no tick has run for ``DEADLINE_PERIODS`` periods."""
        period = max(self._period, self.pose_period)  # a slower camera: its own rate
        span = DEADLINE_PERIODS * period
        watch = max(span, self._stale_after - span)
        gate = self.gate
        with gate.lock:
            self._last_tick = time.monotonic()  # the first deadline counts from the start
        while not stop.is_set():
            with gate.lock:
                if gate.closing:
                    return
                now = time.monotonic()
                wait = watch
                if now - self._last_tick >= span:
                    self.counts.deadline_ticks += 1
                    self.tick_locked(now)
                    wait = span
            await asyncio.sleep(wait)


class LockstepLoop:
    """Lock-step: tick on each new frame of the simulated world, the first of its pose or
    obstacles message to arrive (module docstring of :mod:`agent.node`)."""

    def __init__(self, tick: Tick, clock: LockstepClock, inbox: Inbox,
                 frame_keys: tuple[str, str], times: TickTimes | None = None) -> None:
        self._tick = tick
        self._clock = clock
        self._inbox = inbox
        self._frame = [(keys.POSE, frame_keys[0]), (keys.OBSTACLES, frame_keys[1])]
        self.counts = ScheduleCounts()
        self.times = times or TickTimes()  # the tick's parts (agent.tick_times)

    def _newest(self) -> float:
        entries = (self._inbox.latest(cls, k) for cls, k in self._frame)
        return max((e[0].stamp for e in entries if e is not None), default=-math.inf)

    async def run(self, stop: asyncio.Event) -> None:
        last = -math.inf
        arrived = self._inbox.arrived
        while not stop.is_set():
            arrived.clear()
            newest = self._newest()
            if newest > last:  # a new frame: its pose or its obstacles arrived
                last = newest
                started = time.monotonic()
                self._clock.begin_frame(last, started)  # the lock-step clock (wire.stamps)
                self.times.begin()
                await self._tick(last)
                self.times.end()
                self.counts.tick_us.append((time.monotonic() - started) * 1e6)
                continue
            stop_wait = asyncio.ensure_future(stop.wait())
            arrived_wait = asyncio.ensure_future(arrived.wait())
            try:
                await asyncio.wait({stop_wait, arrived_wait}, return_when=asyncio.FIRST_COMPLETED)
            finally:
                stop_wait.cancel()
                arrived_wait.cancel()
