"""Keep Python's cyclic garbage collector out of real-time loops.

A full (generation 2) collection walks every object the process holds. In a real-time fleet
(`formation bench --fleets 128@20` on a 2-core machine) the world process, which has every
module, the scenario and the run's records loaded, paused 20-45 ms for such collections in the
middle of runs, and each pause made one or two slots of poses late (8-136 late commands). The
objects made at start-up live for the whole run, so :func:`freeze_startup` moves them out of
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
