"""One in-process run per scenario file for the whole test session.

Several test files hold the same file to different parts of its bar (test_simulation: every
goal, the band; test_rigid_scenarios, test_route_scenarios, test_navigation and
test_double_integrator: their issue's whole bar). Each asked the simulator again, about a fifth
of `make test`'s time. :func:`summary_of` runs a file once, recorded (the motion counters need
the series; nothing else in the summary depends on recording), and hands every test the same
summary; tests that change the scenario run their own.
"""

from __future__ import annotations

import copy
import functools
from pathlib import Path

from scenario import load_scenario
from simulator.inprocess import SimOptions, simulate


@functools.cache
def _summary(path: str) -> dict:
    return simulate(load_scenario(path), SimOptions()).summary


def summary_of(path: Path | str) -> dict:
    """The in-process summary of the scenario file at ``path`` (a copy: a test may change it)."""
    return copy.deepcopy(_summary(str(Path(path).resolve())))
