"""What every test shares: a run a test leaves behind must not hide a tick that raised.

An agent catches a failure inside its tick, answers it with the zero command and counts it
(``tick_errors``, summed in ``summary.json``'s ``agents``): the fleet survives, but the failure
is a bug (issue 28). So after each test that had a ``tmp_path``, every ``summary.json`` under
it is read and the test errors when one counts a tick error; a test that causes them on
purpose marks itself ``tick_errors_expected``.

And a test leaves SIGINT's handler as it found it: an ignored SIGINT is inherited by every
process the tests start later (a ``formation replay`` then never stopped on Ctrl-C, and three
tests of another file failed far from the cause).
"""

from __future__ import annotations

import json
import signal
from collections.abc import Iterator
from pathlib import Path

import pytest


def tick_errors_in(folder: Path) -> list[str]:
    """``PATH: N`` for each ``summary.json`` under ``folder`` whose agents counted tick errors."""
    found = []
    for path in sorted(folder.rglob("summary.json")):
        try:
            summary = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            continue  # not a run's summary (or a test's own broken one): not this check's
        agents = summary.get("agents") if isinstance(summary, dict) else None
        n = agents.get("tick_errors", 0) if isinstance(agents, dict) else 0
        if isinstance(n, int) and n > 0:
            found.append(f"{path}: {n}")
    return found


@pytest.fixture(autouse=True)
def _no_hidden_tick_errors(request: pytest.FixtureRequest) -> Iterator[None]:
    yield
    tmp = request.node.funcargs.get("tmp_path") if hasattr(request.node, "funcargs") else None
    if tmp is None or request.node.get_closest_marker("tick_errors_expected") is not None:
        return
    found = tick_errors_in(Path(tmp))
    if found:
        pytest.fail("agents' ticks raised (tick_errors; their logs say where): " + "; ".join(found),
                    pytrace=False)


@pytest.fixture(autouse=True)
def _sigint_left_as_found() -> Iterator[None]:
    before = signal.getsignal(signal.SIGINT)
    yield
    after = signal.getsignal(signal.SIGINT)
    if after is not before:
        signal.signal(signal.SIGINT, before)  # the tests after this one run as they should
        pytest.fail(f"the test left SIGINT's handler changed ({before!r} -> {after!r})",
                    pytrace=False)
