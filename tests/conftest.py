"""What every test shares.

A run a test leaves behind must not hide a tick that raised. An agent catches a failure inside
its tick, answers it with the zero command and counts it (``tick_errors``, summed in
``summary.json``'s ``agents``): the fleet survives, but the failure is a bug. So after each test
that had a ``tmp_path``, every ``summary.json`` under it is read and the test errors when one
counts a tick error; a test that causes them on purpose marks itself ``tick_errors_expected``.

A test leaves SIGINT's handler as it found it: an ignored SIGINT is inherited by every process
the tests start later (a ``formation replay`` then never stopped on Ctrl-C, and three tests of
another file failed far from the cause).

A test that starts a process, opens a Zenoh session, binds a socket or runs a whole scenario is
``integration`` (``make check`` leaves it out): marked here by reading it, and failed when it does
one of these unmarked (tests/heavy.py).
"""

from __future__ import annotations

import json
import signal
from collections.abc import Generator, Iterator
from pathlib import Path

import pytest

from tests.heavy import Guard, heavy_reason


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


# --- integration: marked by reading the test, caught by watching it -----------------------------

GUARD = Guard()


def pytest_configure(config: pytest.Config) -> None:
    GUARD.install()


def pytest_unconfigure(config: pytest.Config) -> None:
    GUARD.uninstall()


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Mark `integration` every test whose source (or a fixture's, or a tests helper's it calls)
    starts a process, opens a Zenoh session or runs a whole scenario (tests/heavy.py), before
    ``-m "not integration"`` picks the tests of ``make check``."""
    for item in items:
        if not isinstance(item, pytest.Function) or item.get_closest_marker("integration"):
            continue
        reason = heavy_reason(item.module, item.function, list(item.fixturenames))
        if reason is not None:
            item.add_marker(pytest.mark.integration(reason=reason))


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_setup(item: pytest.Item) -> None:
    GUARD.clear()  # before the fixtures: a fixture's router counts for the test it serves


@pytest.hookimpl(wrapper=True)
def pytest_runtest_makereport(item: pytest.Item, call: pytest.CallInfo[None],
                              ) -> Generator[None, pytest.TestReport, pytest.TestReport]:
    """A test not marked `integration` that still starts a process, opens a session, binds a
    socket or runs a whole scenario fails, saying what it did: mark it (or make it smaller)."""
    report = yield
    if call.when != "call" or not report.passed or item.get_closest_marker("integration"):
        return report
    events = list(GUARD.report())
    if events:
        report.outcome = "failed"
        report.longrepr = ("not marked `integration`, yet it " + "; ".join(events)
                           + ": mark it @pytest.mark.integration (tests/heavy.py marks the tests "
                           "whose source calls simulate, summary_of, subprocess, zenoh.open, "
                           "RouterProcess or a formation command that runs)")
    return report
