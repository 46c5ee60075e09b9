"""Keep Python's cyclic garbage collector out of real-time loops.

A full (generation 2) collection walks every object the process holds. In a real-time fleet the
world process holds every module, the scenario and the run's records, and a full collection in
the middle of a run pauses it for tens of milliseconds: long enough to make a slot of poses late.
The objects made at start-up live for the whole run, so :func:`freeze_startup` moves them out of
the collector's sight (``gc.freeze``, which takes no time: it collects nothing, so an agent
host's nodes starting one after another never pause the ones already ticking); what the run
allocates afterwards is collected as before.
"""

from __future__ import annotations

import gc


def freeze_startup() -> None:
    """Exempt every object alive now from later collections (call it when start-up is over,
    before the real-time loop; calling it again adds what came since)."""
    gc.freeze()
