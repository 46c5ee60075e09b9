"""Where an agent applies its :class:`agent.faults.LinkFaults`: at its subscribers
(docs/faults.md). A sample of a faulted class (``state``, ``ellipse``, ``others``) is lost
(counted ``fault_dropped``; in lock-step the wait for it ends, :meth:`agent.inbox.Inbox.current`),
held back (real time: on the wall clock; lock-step: in a :class:`agent.faults.DelayLine` until
the tick it may be seen at; counted ``fault_delayed``) or handed to its mailbox at once.

:class:`FaultInjector` owns the losses, the delays and their counters; it hands what passes to
the inbox through the ``store`` it is given and knows nothing else of the agent.
"""

from __future__ import annotations

import asyncio
import math
import threading
from collections.abc import Callable
from typing import Any

from agent.faults import EPS, DelayLine, LinkFaults, lag
from wire import keys

Store = Callable[[str, bytes], None]  # (key, payload) -> into its mailbox (the caller's lock held)


class FaultInjector:
    """The link faults of one agent's subscribers (module docstring). ``store(key, payload)``
    hands a delayed payload to its mailbox and wakes the tick; it is called under ``lock``."""

    def __init__(self, faults: LinkFaults, robot_id: str, period: float, lockstep: bool,
                 lock: threading.Lock, store: Store) -> None:
        self.faults = faults
        self.robot_id = robot_id
        self.lag = lag(faults.delay, period)  # lock-step: how far behind a delayed input may be
        self._lock = lock
        self._store = store
        self.dropped = {cls: 0 for cls in (keys.STATE, keys.ELLIPSE, keys.OTHERS)}
        self.delayed = 0
        self._lost: dict[str, float] = {}  # key -> newest stamp lost to fault injection
        self.delay_line = DelayLine(faults.delay, self.offer) if faults.delay > 0 and lockstep \
            else None

    def applies_to(self, cls: str) -> bool:
        return self.faults.applies_to(cls)

    def sample(self, loop: asyncio.AbstractEventLoop, cls: str, decode: Callable[[bytes], Any],
               key: str, payload: bytes, direct: Store) -> None:
        """Zenoh thread: apply the faults to one sample of a faulted class; ``direct`` hands a
        payload that passes at once (or does not decode: its mailbox counts it) to its mailbox."""
        try:
            stamp = decode(payload).stamp
        except Exception:  # noqa: BLE001 - malformed: the mailbox decodes it again and counts it
            direct(key, payload)
            return
        faults = self.faults
        try:
            if faults.dropped(self.robot_id, key, stamp):
                loop.call_soon_threadsafe(self.mark_lost, cls, key, stamp)
            elif self.delay_line is not None:
                loop.call_soon_threadsafe(self.delay_line.push, key, payload, stamp)
            elif faults.delay > 0:  # real time: hold it on the wall clock
                loop.call_soon_threadsafe(loop.call_later, faults.delay, self.offer, key, payload)
            else:
                direct(key, payload)
        except RuntimeError:  # loop closed: shutting down
            pass

    def offer(self, key: str, payload: bytes) -> None:
        """Loop thread: hand a (delayed) payload to its mailbox."""
        with self._lock:  # real time: a tick may be reading the mailboxes on Zenoh's thread
            self.delayed += 1
            self._store(key, payload)

    def mark_lost(self, cls: str, key: str, stamp: float) -> None:
        """Loop thread: a message was lost to fault injection (counted; lock-step stops waiting
        for it)."""
        with self._lock:
            self.dropped[cls] += 1
            self._lost[key] = max(stamp, self._lost.get(key, -math.inf))

    def advance(self, t: float) -> None:
        """Lock-step: release what the delay line holds for the frame stamped ``t``."""
        if self.delay_line is not None:
            self.delay_line.advance(t)

    def need(self, cls: str, t: float) -> float:
        """Lock-step: the oldest stamp of ``cls`` that belongs to the tick stamped ``t``."""
        return t - self.lag if self.faults.applies_to(cls) else t

    def lost_since(self, key: str, need: float) -> bool:
        """Lock-step: a message on ``key`` stamped ``need`` or later was lost."""
        lost = self._lost.get(key)
        return lost is not None and lost >= need - EPS
