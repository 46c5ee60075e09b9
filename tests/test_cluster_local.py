"""experiments.cluster.run_local: results in input order, progress counted as runs finish."""

from __future__ import annotations

import multiprocessing
from functools import partial

import pytest

from experiments.cluster import run_local

WAIT_S = 120.0  # a bound on the wait below: only a broken count reaches it


def first_waits(seen, k: int) -> str:
    """Run 0 waits until the progress has counted another run; the others finish at once."""
    if k == 0:
        return "after another" if seen.wait(WAIT_S) else "first"
    return f"run {k}"


@pytest.mark.integration  # starts worker processes
def test_a_long_first_run_does_not_hold_back_the_count_of_the_others():
    with multiprocessing.Manager() as manager:
        seen = manager.Event()
        counts = []

        def progress(done: int, total: int, _t: float) -> None:
            counts.append((done, total))
            seen.set()

        results = run_local(partial(first_waits, seen), [0, 1, 2], 2, progress)
    assert results == ["after another", "run 1", "run 2"]  # input order, whatever the finish
    assert counts == [(1, 3), (2, 3), (3, 3)]
