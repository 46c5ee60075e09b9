"""The world's pacing: sleeping until a wall-clock time while still checking for an abort, and
an abort check called no more often than it needs to be."""

from __future__ import annotations

import math
import time
from collections.abc import Callable

ABORT_EVERY_S = 0.05  # [s] the longest ``abort()`` is not called while the world waits, and the
# shortest between two calls (a launcher's check polls every child process: checking it at
# every pose slot of a large fleet costs the world much of its CPU)


def at_most_every(period: float, fn: Callable[[], None]) -> Callable[[], None]:
    """``fn`` wrapped to run only when ``period`` seconds have passed since it last ran."""
    last = -math.inf

    def call() -> None:
        nonlocal last
        now = time.monotonic()
        if now - last >= period:
            last = now
            fn()

    return call


def sleep_until(wall: float, abort: Callable[[], None]) -> None:
    """Sleep until ``time.monotonic()`` reaches ``wall``, calling ``abort()`` (which may raise)
    at least every 50 ms."""
    while True:
        abort()
        remaining = wall - time.monotonic()
        if remaining <= 0:
            return
        time.sleep(min(remaining, 0.05))
