"""Keep Python's cyclic garbage collector out of real-time loops.

A full (generation 2) collection walks every object the process holds. In a real-time fleet the
world process holds every module, the scenario and the run's records, and a full collection in
the middle of a run pauses it for tens of milliseconds: long enough to make a slot of poses late.
The objects made at start-up live for the whole run, so :func:`freeze_startup` moves them out of
the collector's sight (``gc.freeze``, which takes no time: it collects nothing, so an agent
host's nodes starting one after another never pause the ones already ticking); what the run
allocates afterwards is collected as before.

It also spaces the young collections out (:data:`YOUNG_THRESHOLD` allocations apart instead of
Python's 700). A tick allocates hundreds of short-lived tuples and messages that reference
counting frees at once; a young collection walks only the young objects still alive, so
collecting less often walks about as many each time and an agent host of 16 agents spends a
fraction of the time collecting (``benchmarks/agent_tick.py`` reports it). The older
generations keep Python's thresholds, so garbage in reference cycles is still collected.
"""

from __future__ import annotations

import gc

YOUNG_THRESHOLD = 10_000  # allocations of tracked objects between two young collections


def freeze_startup() -> None:
    """Exempt every object alive now from later collections and space the young collections
    out (call it when start-up is over, before the real-time loop; calling it again adds what
    came since). A collector switched off (threshold 0) stays off."""
    gc.freeze()
    young, middle, old = gc.get_threshold()
    if 0 < young < YOUNG_THRESHOLD:
        gc.set_threshold(YOUNG_THRESHOLD, middle, old)
