"""The agent's three tick schedulers, moved out of :class:`agent.node.AgentNode` (issue 12):
lock-step (tick on each new frame of the simulated world), real time on pose arrival (tick
on the Zenoh thread when a due pose arrives, with the event loop's deadline tick), and real
time on the agent's own clock. The module docstring of :mod:`agent.node` describes them.

Each function takes the node as its first argument; ``AgentNode`` keeps methods of the old
names (``_lockstep_loop``, ``_pose_loop``, ``_realtime_loop``, ``_on_pose_sample``,
``_pose_tick``, ``_tick_locked``, ``_drain``) that call them.
"""

from __future__ import annotations

import asyncio
import math
import time
from typing import TYPE_CHECKING, Any

from wire import keys

if TYPE_CHECKING:
    import zenoh

    from agent.node import AgentNode

DEADLINE_PERIODS = 1.5  # real time: tick without a new pose after this many periods
MIN_SPACING_PERIODS = 0.75  # real time: a pose stamped sooner after the last ticked one waits


def _run_now(coro: Any) -> Any:
    """Run a coroutine that does not suspend to its end on the calling thread (a real-time
    tick, see :mod:`agent.node`) and return its result."""
    try:
        coro.send(None)
    except StopIteration as done:
        return done.value
    coro.close()
    raise RuntimeError("a real-time tick tried to suspend")


async def realtime_loop(node: AgentNode) -> None:
    assert node._stop is not None  # set by run()
    period = node.cfg.period
    next_t = time.monotonic()
    while not node._stop.is_set():
        started = time.monotonic()
        await node.tick(None)
        node.tick_us.append((time.monotonic() - started) * 1e6)
        next_t += period
        now = time.monotonic()
        if now > next_t:
            node.overruns += 1
            next_t = now  # do not try to catch up with a burst of ticks
        try:
            await asyncio.wait_for(node._stop.wait(), max(0.0, next_t - time.monotonic()))
        except TimeoutError:
            pass


def on_pose_sample(node: AgentNode, sample: zenoh.Sample) -> None:
    """Zenoh thread: store the pose and tick on it (module docstring)."""
    with node._tick_lock:
        if node._closing:
            return
        node._boxes[keys.POSE].callback(sample)
        node._pose_tick(time.monotonic())


def pose_tick(node: AgentNode, now: float) -> bool:
    """Under the tick lock: tick on the newest pose if it is due (True), else nothing: due
    when stamped ``MIN_SPACING_PERIODS`` or more after the last ticked pose, or earlier
    than it (the camera's clock went back)."""
    entry = node._boxes[keys.POSE].latest(node.pose_key)
    if entry is None:
        return False
    stamp, last = entry[0].stamp, node._last_pose_stamp
    if last is not None and last <= stamp < last + MIN_SPACING_PERIODS * node.cfg.period:
        return False
    node._last_pose_stamp = stamp
    node._tick_locked(now)
    return True


def tick_locked(node: AgentNode, now: float) -> None:
    """Under the tick lock: drain the ring channels, tick, time it."""
    node._last_tick = now
    node._drain()
    _run_now(node.tick(None))
    done = time.monotonic()
    node.tick_us.append((done - now) * 1e6)
    if done - now > node.cfg.period:
        node.overruns += 1


async def pose_loop(node: AgentNode) -> None:
    """The loop's part of real time on pose arrival: the deadline tick when no tick has run
    for ``DEADLINE_PERIODS`` periods (module docstring)."""
    assert node._stop is not None
    period = node.cfg.period
    span = DEADLINE_PERIODS * period
    watch = max(span, node.cfg.stale_after - span)
    with node._tick_lock:
        node._last_tick = time.monotonic()  # the first deadline counts from the start
    while not node._stop.is_set():
        with node._tick_lock:
            if node._closing:
                return
            now = time.monotonic()
            wait = watch
            if now - node._last_tick >= span:
                node.deadline_ticks += 1
                node._tick_locked(now)
                wait = span
        await asyncio.sleep(wait)


def drain(node: AgentNode) -> None:
    """Real time: hand every sample waiting in the ring channels to its mailbox (an inline
    one: stored at once)."""
    for sub, take in node._rings:
        while (sample := sub.try_recv()) is not None:
            take(sample)


async def lockstep_loop(node: AgentNode) -> None:
    assert node._stop is not None and node._arrived is not None
    last = -math.inf
    frame = [(node._boxes[keys.POSE], node.pose_key),
             (node._boxes[keys.OBSTACLES], node.obstacles_key)]
    while not node._stop.is_set():
        node._arrived.clear()
        newest = max((e[0].stamp for e in (b.latest(k) for b, k in frame) if e is not None),
                     default=-math.inf)
        if newest > last:  # a new frame: its pose or its obstacles arrived
            last = newest
            started = time.monotonic()
            await node.tick(last)
            node.tick_us.append((time.monotonic() - started) * 1e6)
            continue
        stop_wait = asyncio.ensure_future(node._stop.wait())
        arrived_wait = asyncio.ensure_future(node._arrived.wait())
        try:
            await asyncio.wait({stop_wait, arrived_wait}, return_when=asyncio.FIRST_COMPLETED)
        finally:
            stop_wait.cancel()
            arrived_wait.cancel()
