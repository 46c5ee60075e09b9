"""The agent's three tick schedulers (the module docstring of :mod:`agent.node` describes them):

* lock-step (:func:`lockstep_loop`): tick on each new frame of the simulated world; each phase
  of the tick waits for its inputs (:func:`wait_current`);
* real time on pose arrival (:func:`on_pose_sample`, :func:`pose_tick`, :func:`tick_locked`,
  :func:`drain`): tick on the Zenoh thread that received a due pose (or on an agent host's tick
  thread), with the event loop's deadline tick (:func:`pose_loop`);
* real time on the agent's own clock (:func:`realtime_loop`).

Each function takes the :class:`agent.node.AgentNode` it drives; the node keeps the state they
share with its wiring (mailboxes, tick lock, stop and arrival events) and its tick.
"""

from __future__ import annotations

import asyncio
import logging
import math
import time
from typing import TYPE_CHECKING, Any, Protocol

from agent.faults import EPS
from wire import keys

if TYPE_CHECKING:
    import zenoh

    from agent.node import AgentNode

logger = logging.getLogger(__name__)

DEADLINE_PERIODS = 1.5  # real time: tick without a new pose after this many periods
MIN_SPACING_PERIODS = 0.75  # real time: a pose stamped sooner after the camera's schedule waits
LATE_POSE_PERIODS = 0.5  # real time: a pose stamped up to this much late does not move the schedule


class TickQueue(Protocol):
    """An agent host's tick thread (:class:`agent.host.TickWorker`): ticks a queued node on its
    newest pose, under the node's tick lock, with :func:`pose_tick`."""

    def mark(self, node: Any) -> None: ...  # the host's own node class (agent.host.HostedNode)


def run_now(coro: Any) -> Any:
    """Run a coroutine that does not suspend to its end on the calling thread (a real-time
    tick, see the module docstring of :mod:`agent.node`) and return its result."""
    try:
        coro.send(None)
    except StopIteration as done:
        return done.value
    coro.close()
    raise RuntimeError("a real-time tick tried to suspend")


async def realtime_loop(node: AgentNode) -> None:
    """Real time on the agent's own clock (``NodeOptions(tick_on_pose=False)``): tick against
    deadlines at 1/period, ``next_t += period``, overruns counted."""
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
        except (TimeoutError, asyncio.TimeoutError):  # distinct classes on 3.10
            pass


# --- real time, ticking on pose arrival ---------------------------------------------------


def on_pose_sample(node: AgentNode, sample: zenoh.Sample) -> None:
    """Zenoh thread: store the pose and tick on it (module docstring of :mod:`agent.node`), or,
    under an agent host with a tick thread (``node.tick_worker``), queue the node on it."""
    worker = node.tick_worker
    with node._tick_lock:
        if node._closing:
            return
        node._boxes[keys.POSE].callback(sample)
        if worker is None:
            pose_tick(node, time.monotonic())
            return
    worker.mark(node)


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


def pose_tick(node: AgentNode, now: float) -> bool:
    """Under the tick lock: tick on the newest pose if it is due by :func:`pose_due` (True),
    else nothing (counted ``early_poses``)."""
    entry = node._boxes[keys.POSE].latest(node.pose_key)
    if entry is None:
        return False
    stamp = entry[0].stamp
    anchor = pose_due(node._pose_anchor, stamp, node.cfg.period)
    if anchor is None:
        node.early_poses += 1
        return False
    node._pose_anchor = anchor
    tick_locked(node, now)
    return True


def tick_locked(node: AgentNode, now: float) -> None:
    """Under the tick lock: drain the ring channels, tick, time it."""
    node._last_tick = now
    drain(node)
    run_now(node.tick(None))
    done = time.monotonic()
    node.tick_us.append((done - now) * 1e6)
    if done - now > node.cfg.period:
        node.overruns += 1


async def pose_loop(node: AgentNode) -> None:
    """The loop's part of real time on pose arrival: the deadline tick when no tick has run
    for ``DEADLINE_PERIODS`` periods (module docstring of :mod:`agent.node`)."""
    assert node._stop is not None
    period = max(node.cfg.period, node._pose_period)  # a slower camera: its own rate
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
                tick_locked(node, now)
                wait = span
        await asyncio.sleep(wait)


def drain(node: AgentNode) -> None:
    """Real time: hand every sample waiting in the ring channels to its mailbox (an inline
    one: stored at once)."""
    for sub, take in node._rings:
        while (sample := sub.try_recv()) is not None:
            take(sample)


# --- lock-step -----------------------------------------------------------------------------


async def lockstep_loop(node: AgentNode) -> None:
    """Lock-step: tick on each new frame of the simulated world, the first of its pose or
    obstacles message to arrive (module docstring of :mod:`agent.node`)."""
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
            node._frame = max(node._frame, last)  # the lock-step clock (wire.stamps)
            started = node._last_tick = time.monotonic()
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


async def wait_current(node: AgentNode, inputs: list[tuple[str, str]], t: float) -> bool:
    """Lock-step: wait until every (class, key) in ``inputs`` that is not late holds the
    message of the tick stamped ``t`` (True), or the timeout or stop (False). On a timeout
    the inputs still missing become late: later ticks do not wait for them until a message
    arrives on their key."""
    assert node._arrived is not None and node._stop is not None

    def missing() -> list[str]:
        return [k for cls, k in inputs if k not in node._late and not _current(node, cls, k, t)]

    if not missing():
        return True
    if not node.options.lockstep:
        return False
    deadline = time.monotonic() + node.options.lockstep_timeout
    while not node._stop.is_set():
        node._arrived.clear()
        if not missing():
            return True
        remaining = deadline - time.monotonic()
        if remaining <= 0:
            node.lockstep_timeouts += 1
            late = missing()
            node._late.update(late)
            logger.info("%s: tick %.3f: gave up waiting for %s", node.cfg.robot_id, t,
                        ", ".join(late))
            return False
        try:
            await asyncio.wait_for(node._arrived.wait(), remaining)
        except (TimeoutError, asyncio.TimeoutError):  # distinct classes on 3.10
            pass
    return not missing()


def _current(node: AgentNode, cls: str, key: str, t: float) -> bool:
    """Lock-step: the message on ``key`` belongs to the tick stamped ``t`` (or later), or,
    under added delay, to the newest tick that can have arrived; or it was lost."""
    need = t - node._lag if node.options.faults.applies_to(cls) else t
    entry = node._latest(cls, key)
    if entry is not None and entry[0].stamp >= need - EPS:
        return True
    lost = node._lost.get(key)
    return lost is not None and lost >= need - EPS
