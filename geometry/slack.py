"""The smallest common slack that makes a set of rows feasible, by bisection.

Both QPs relax rows by one common slack s >= 0 where they cannot all hold: the per-robot QP
(:func:`agent.qp.solve_cbf_qp`) and the formation's twist QP (:func:`agent.body.solve_twist`).
The feasibility test is the caller's (its own exact solver); the search is this one.
"""

from __future__ import annotations

from collections.abc import Callable


def smallest_slack(feasible: Callable[[float], bool], hi: float, steps: int,
                   stop: tuple[float, float] | None = None) -> float:
    """The upper end of a bisection of [0, ``hi``] for the smallest s with ``feasible(s)``
    (``hi`` must be feasible), after ``steps`` halvings; with ``stop`` = (abs, rel) it ends
    early once the bracket is at most abs + rel hi wide."""
    lo = 0.0
    for _ in range(steps):
        mid = 0.5 * (lo + hi)
        if feasible(mid):
            hi = mid
        else:
            lo = mid
        if stop is not None and hi - lo <= stop[0] + stop[1] * hi:
            break
    return hi
