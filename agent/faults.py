"""Link faults an agent applies to what it receives: seeded message loss and added delay.

``formation run --drop P --delay-ms D`` hands every agent the same :class:`LinkFaults`; the agent
applies them at its subscribers (docs/faults.md), to the inter-robot classes only (``state``,
``ellipse``, ``others``): poses, obstacles and commands travel untouched (a camera dropout and
killed processes are separate faults).

Loss is decided per message and per receiver by a pure function of ``(seed, receiver, key,
stamp)`` (a keyed BLAKE2b hash mapped to [0, 1)), not by a stateful random generator: the same
message is lost in every rerun whatever order Zenoh's threads deliver samples in, so a lock-step
run with losses is reproducible. A receiver never learns of a loss from the network; the
lock-step simulation alone uses :meth:`LinkFaults.dropped` to stop waiting for a message that will
never come (in simulated time a loss and a message that misses its tick are the same thing).

Delay in real time holds each message ``delay`` seconds of wall clock before delivery. In
lock-step, time is the simulated clock of the pose stamps: a message stamped ``s`` becomes visible
at the first tick ``t >= s + delay`` (:class:`DelayLine`), so the delay is rounded up to whole
control periods (:func:`lag`).
"""

from __future__ import annotations

import hashlib
import heapq
import logging
import math
import struct
from collections.abc import Callable
from dataclasses import dataclass

from wire import keys

logger = logging.getLogger(__name__)

FAULT_CLASSES: tuple[str, ...] = (keys.STATE, keys.ELLIPSE, keys.OTHERS)  # what --drop/--delay hit
EPS = 1e-9  # [s] stamps are multiples of dt computed in floating point


@dataclass(frozen=True)
class LinkFaults:
    """Loss probability ``drop``, added delay ``delay`` [s], and the loss seed."""

    drop: float = 0.0
    delay: float = 0.0  # [s]
    seed: int = 0

    def __post_init__(self) -> None:
        if isinstance(self.drop, bool) or not isinstance(self.drop, int | float) \
                or not (0.0 <= self.drop < 1.0):
            raise ValueError(f"drop: must be a probability in [0, 1), got {self.drop!r}")
        if isinstance(self.delay, bool) or not isinstance(self.delay, int | float) \
                or not (math.isfinite(self.delay) and self.delay >= 0.0):
            raise ValueError(f"delay: must be a number of seconds >= 0, got {self.delay!r}")
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or self.seed < 0:
            raise ValueError(f"seed: must be an int >= 0, got {self.seed!r}")

    @property
    def active(self) -> bool:
        return self.drop > 0.0 or self.delay > 0.0

    def applies_to(self, cls: str) -> bool:
        return self.active and cls in FAULT_CLASSES

    def dropped(self, receiver: str, key: str, stamp: float) -> bool:
        """Whether ``receiver`` loses the message stamped ``stamp`` on ``key`` (deterministic)."""
        if self.drop <= 0.0:
            return False
        h = hashlib.blake2b(f"{receiver}|{key}|{stamp!r}".encode(), digest_size=8,
                            key=struct.pack("<Q", self.seed))
        return int.from_bytes(h.digest(), "little") / 2.0 ** 64 < self.drop


def lag(delay: float, period: float) -> float:
    """The lock-step delay: ``delay`` rounded up to whole periods [s] (0 stays 0)."""
    if delay <= 0.0:
        return 0.0
    return math.ceil(delay / period - 1e-6) * period


class DelayLine:
    """Lock-step delay: holds (key, payload) until the simulated clock reaches stamp + delay.

    Used on one thread (the agent's event loop); ``deliver(key, payload)`` is called for each
    message whose time has come, in stamp order.
    """

    def __init__(self, delay: float, deliver: Callable[[str, bytes], None]) -> None:
        self.delay = delay
        self._deliver = deliver
        self._now = -math.inf
        self._heap: list[tuple[float, int, str, bytes]] = []
        self._seq = 0

    def push(self, key: str, payload: bytes, stamp: float) -> None:
        if stamp + self.delay <= self._now + EPS:
            self._deliver(key, payload)
            return
        self._seq += 1
        heapq.heappush(self._heap, (stamp + self.delay, self._seq, key, payload))

    def advance(self, now: float) -> None:
        """Set the clock to ``now`` and deliver everything due."""
        self._now = max(self._now, now)
        while self._heap and self._heap[0][0] <= self._now + EPS:
            _, _, key, payload = heapq.heappop(self._heap)
            self._deliver(key, payload)

    def __len__(self) -> int:
        return len(self._heap)
