"""The agent's two clocks, so that its tick is written once (:meth:`agent.tick.Ticker.tick`).

*Lock-step* (:class:`LockstepClock`, the simulated world): the tick belongs to a frame, stamped
``t``; each phase waits (up to ``lockstep_timeout``) for the inputs stamped ``t``; freshness is
``t - stamp``; the receiver's clock for the stamp check is the frame the agent is on; ``state``
is published before the command (the neighbours and the leader wait for it); neighbours' states
are this frame's as they are.

*Real time* (:class:`RealtimeClock`): nothing waits; freshness is the wall clock against the
stamp; a neighbour's state is carried from its stamp to this tick's pose
(:func:`agent.inputs.predict_state`); ``state`` is published after the command, with the velocity
just certified; a command whose pose went stale while it was computed is not sent.

An input whose wait timed out is *late*: later ticks do not wait for it again until a message
arrives on its key (:class:`agent.inbox.Inbox`), so a dead neighbour costs one timeout.
"""

from __future__ import annotations

import asyncio
import logging
import math
import time
from collections import deque
from collections.abc import Callable
from typing import Any, Protocol

from agent.inputs import predict_state
from wire.payloads import State

logger = logging.getLogger(__name__)

STATS_WINDOW = 10_000  # per-tick timings kept for the medians in the counters (the newest ticks)
Entry = tuple[Any, float]  # a mailbox's (message, local reception time)
Inputs = list[tuple[str, str]]  # (mailbox class, key)
Kin = tuple[float, float, float, float, float]  # a neighbour's x, y, ux, uy, theta at a stamp


class Waitable(Protocol):
    """What a lock-step wait reads of the inbox (:class:`agent.inbox.Inbox`)."""

    arrived: asyncio.Event

    def missing(self, inputs: Inputs, t: float) -> list[str]: ...
    def mark_late(self, late: list[str]) -> None: ...
    def advance(self, t: float) -> bool: ...


class Clock(Protocol):
    """What the tick asks of its clock; ``t`` is the frame's stamp in lock-step, None in real
    time, and only the clock reads it."""

    lockstep: bool
    stale_after: float
    timeouts: int
    pose_age_us: deque[float]
    pose_in_us: deque[float]

    def now(self) -> float: ...
    def starved(self) -> bool: ...
    def at(self, ref: float | None) -> float: ...
    def fresh(self, entry: Entry | None, ref: float | None) -> bool: ...
    async def start(self, inbox: Waitable, inputs: Inputs, t: float | None) -> None: ...
    async def wait(self, inbox: Waitable, inputs: Inputs, t: float) -> bool: ...
    def pose_current(self, entry: Entry, t: float | None) -> bool: ...
    def cmd_stamp(self, t: float | None, last: float) -> float: ...
    def note_pose(self, entry: Entry) -> None: ...
    def align(self, states: dict[str, State], stamp: float) -> dict[str, Kin]: ...
    def gone_stale(self, stamp: float) -> bool: ...
    def state_before(self, send: Callable[[], None]) -> None: ...
    def state_after(self, send: Callable[[], None]) -> None: ...


class _Common:
    def __init__(self, stale_after: float) -> None:
        self.stale_after = stale_after
        self.timeouts = 0  # lock-step waits that gave up (lockstep_timeouts)
        self.pose_age_us: deque[float] = deque(maxlen=STATS_WINDOW)  # [us] real time: pose
        # reception -> tick start
        self.pose_in_us: deque[float] = deque(maxlen=STATS_WINDOW)  # [us] real time: pose
        # stamp -> reception (wall clock; the bench's split of the latency)

    def at(self, ref: float | None) -> float:
        raise NotImplementedError

    def fresh(self, entry: Entry | None, ref: float | None) -> bool:
        """Whether a (message, receive time) entry is fresh at ``ref`` (lock-step) or now (real
        time: by its stamp against the wall clock, not by when it arrived): the stale part of
        :func:`wire.stamps.check_stamp` (future stamps and older ones never reach a mailbox)."""
        if entry is None:
            return False
        return self.at(ref) - entry[0].stamp <= self.stale_after + 1e-9


class LockstepClock(_Common):
    """The simulated world's clock (module docstring)."""

    lockstep = True

    def __init__(self, stale_after: float, timeout: float, sim_start: float, robot_id: str,
                 eps: float) -> None:
        super().__init__(stale_after)
        self.timeout = timeout
        self.frame = sim_start  # the receiver's clock: the newest frame it ticked on
        self.last_tick = -math.inf  # [s, monotonic] when the last tick started
        self.ticked = False
        self.stop: asyncio.Event | None = None  # set by the node's run()
        self._robot_id = robot_id
        self._eps = eps

    def begin_frame(self, t: float, started: float) -> None:
        """The lock-step loop starts the tick of the frame stamped ``t`` at ``started``."""
        self.frame = max(self.frame, t)
        self.last_tick = started
        self.ticked = True

    def now(self) -> float:
        return self.frame

    def starved(self) -> bool:
        """This agent has ticked before but not for ``lockstep_timeout``: the world stopped
        waiting for it (it was late) and its frames may now run more than the window ahead;
        the next one is taken (counted ``lockstep_catch_ups``), not refused for ever."""
        return self.ticked and time.monotonic() - self.last_tick > self.timeout

    def at(self, ref: float | None) -> float:
        assert ref is not None
        return ref

    async def start(self, inbox: Waitable, inputs: Inputs, t: float | None) -> None:
        assert t is not None
        if inbox.advance(t):
            await asyncio.sleep(0)  # let the mailboxes store what was just released
        await self.wait(inbox, inputs, t)

    async def wait(self, inbox: Waitable, inputs: Inputs, t: float) -> bool:
        """Wait until every (class, key) in ``inputs`` that is not late holds the message of
        the tick stamped ``t`` (True), or the timeout or stop (False). On a timeout the inputs
        still missing become late."""
        assert self.stop is not None
        if not inbox.missing(inputs, t):
            return True
        deadline = time.monotonic() + self.timeout
        while not self.stop.is_set():
            inbox.arrived.clear()
            if not inbox.missing(inputs, t):
                return True
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                self.timeouts += 1
                late = inbox.missing(inputs, t)
                inbox.mark_late(late)
                logger.info("%s: tick %.3f: gave up waiting for %s", self._robot_id, t,
                            ", ".join(late))
                return False
            try:
                await asyncio.wait_for(inbox.arrived.wait(), remaining)
            except (TimeoutError, asyncio.TimeoutError):  # distinct classes on 3.10
                pass
        return not inbox.missing(inputs, t)

    def pose_current(self, entry: Entry, t: float | None) -> bool:
        """The pose is fresh and this frame's (not an older one: camera dropout)."""
        assert t is not None
        return self.fresh(entry, t) and entry[0].stamp >= t - self._eps

    def cmd_stamp(self, t: float | None, last: float) -> float:
        assert t is not None
        return t

    def note_pose(self, entry: Entry) -> None:
        pass

    def align(self, states: dict[str, State], stamp: float) -> dict[str, Kin]:
        """Every state as it is (each is this frame's)."""
        return {k: (m.x, m.y, m.ux, m.uy, m.theta) for k, m in states.items()}

    def gone_stale(self, stamp: float) -> bool:
        return False

    def state_before(self, send: Callable[[], None]) -> None:
        send()  # the neighbours and the leader wait for this tick's state

    def state_after(self, send: Callable[[], None]) -> None:
        pass


class RealtimeClock(_Common):
    """The wall clock (module docstring)."""

    lockstep = False

    def __init__(self, stale_after: float, offset: float) -> None:
        super().__init__(stale_after)
        self._offset = offset

    def now(self) -> float:
        return time.time()  # stamps are the camera's time.time()

    def starved(self) -> bool:
        return False

    def at(self, ref: float | None) -> float:
        return time.time()

    async def start(self, inbox: Waitable, inputs: Inputs, t: float | None) -> None:
        pass

    async def wait(self, inbox: Waitable, inputs: Inputs, t: float) -> bool:
        return True

    def pose_current(self, entry: Entry, t: float | None) -> bool:
        return self.fresh(entry, None)

    def cmd_stamp(self, t: float | None, last: float) -> float:
        return last

    def note_pose(self, entry: Entry) -> None:
        self.pose_age_us.append((time.monotonic() - entry[1]) * 1e6)
        # pose stamp -> received, on this machine's wall clock (bench: one clock for all)
        self.pose_in_us.append((time.time() - (time.monotonic() - entry[1])
                                - entry[0].stamp) * 1e6)

    def align(self, states: dict[str, State], stamp: float) -> dict[str, Kin]:
        """Every neighbour's state carried from its stamp to ``stamp`` (this tick's pose) under
        its certified command (:func:`agent.inputs.predict_state`), never further than the
        stale limit, never backwards."""
        out = {}
        limit, offset = self.stale_after, self._offset
        for k, m in states.items():
            age = min(max(0.0, stamp - m.stamp), limit)
            if age > 0.0:
                x, y, th = predict_state(m.x, m.y, m.ux, m.uy, m.theta, age, offset)
                out[k] = (x, y, m.ux, m.uy, th)
            else:
                out[k] = (m.x, m.y, m.ux, m.uy, m.theta)
        return out

    def gone_stale(self, stamp: float) -> bool:
        return time.time() - stamp > self.stale_after  # never send from a pose gone stale

    def state_before(self, send: Callable[[], None]) -> None:
        pass

    def state_after(self, send: Callable[[], None]) -> None:
        send()  # with the velocity just certified, the freshest it can share
