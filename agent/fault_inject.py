"""Where an agent applies its :class:`agent.faults.LinkFaults`: at its subscribers
(docs/faults.md). A sample of a faulted class (``state``, ``ellipse``, ``others``) is lost
(counted ``fault_dropped``; in lock-step the wait for it ends, :func:`agent.schedule.wait_current`),
held back (real time: on the wall clock; lock-step: in the node's :class:`agent.faults.DelayLine`
until the tick it may be seen at; counted ``fault_delayed``) or handed to its mailbox at once.

Each function takes the :class:`agent.node.AgentNode` whose mailboxes receive the samples.
"""

from __future__ import annotations

import asyncio
import math
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from wire import keys

if TYPE_CHECKING:
    from agent.node import AgentNode


def faulty_sample(node: AgentNode, loop: asyncio.AbstractEventLoop, cls: str,
                  decode: Callable[[bytes], Any], key: str, payload: bytes) -> None:
    """Zenoh thread: apply :class:`LinkFaults` to one sample of a faulted class."""
    box = node._boxes[cls]
    try:
        stamp = decode(payload).stamp
    except Exception:  # noqa: BLE001 - malformed: the mailbox decodes it again and counts it
        box.offer(key, payload)
        return
    faults = node.options.faults
    try:
        if faults.dropped(node.cfg.robot_id, key, stamp):
            loop.call_soon_threadsafe(mark_lost, node, cls, key, stamp)
        elif faults.delay > 0 and node._delay_line is not None:
            loop.call_soon_threadsafe(node._delay_line.push, key, payload, stamp)
        elif faults.delay > 0:  # real time: hold it on the wall clock
            loop.call_soon_threadsafe(loop.call_later, faults.delay, offer, node, key, payload)
        else:
            box.offer(key, payload)
    except RuntimeError:  # loop closed: shutting down
        pass


def offer(node: AgentNode, key: str, payload: bytes) -> None:
    """Loop thread: hand a (delayed) payload to its mailbox."""
    cls = node.subscribed_keys.get(key, keys.STATE)  # all-to-all: a wildcard's concrete key
    with node._tick_lock:  # real time: a tick may be reading the mailboxes on Zenoh's thread
        node.fault_delayed += 1
        node._boxes[cls].offer(key, payload)
    node._on_arrival(key)


def mark_lost(node: AgentNode, cls: str, key: str, stamp: float) -> None:
    """Loop thread: a message was lost to fault injection (counted; lock-step stops waiting
    for it)."""
    with node._tick_lock:
        node.fault_dropped[cls] += 1
        node._lost[key] = max(stamp, node._lost.get(key, -math.inf))
