"""tests/heavy.py: the reading that marks a test `integration` before it runs, and the guard that
fails one that starts a process, a session, a socket or a whole run unmarked."""

from __future__ import annotations

import socket
import subprocess
import sys

import pytest

from formation.cli import main
from runtime.ports import free_tcp_port
from runtime.testing import RouterProcess
from simulator.inprocess import simulate
from tests.heavy import Guard, heavy_reason

HERE = sys.modules[__name__]


# Samples for the reading: never called, only read.
def sample_plain():
    assert main(["check", "thesis-5.2.2"]) == 0


def sample_simulates(scenario):
    simulate(scenario)


def sample_calls_a_helper():
    _helper()


def _helper():
    subprocess.run(["true"], check=True)


def sample_opens_a_session_with_a_local_import():
    import zenoh

    zenoh.open(zenoh.Config())


def sample_runs_sim():
    main(["sim", "thesis-5.2.2", "--out", "x"])


def sample_refused_sim():
    assert main(["sim", "nope.yaml", "--out", "x"]) == 2


def sample_asks_for_help():
    main(["run", "--help"])


def sample_command_named_at_run_time(mode):
    main([mode, "thesis-5.2.2"])


def router_fixture():
    with RouterProcess() as router:
        yield router


@pytest.mark.parametrize("sample,reason", [
    (sample_plain, None),
    (sample_simulates, "runs a whole scenario (simulate)"),
    (sample_calls_a_helper, "starts a process (subprocess.run)"),
    (sample_opens_a_session_with_a_local_import, "opens a Zenoh session"),
    (sample_runs_sim, "runs `formation sim`"),
    (sample_refused_sim, None),
    (sample_asks_for_help, None),
    (sample_command_named_at_run_time, "runs a `formation` command named at run time"),
])
def test_the_reading_finds_what_a_test_calls_through_helpers_and_local_imports(sample, reason):
    assert heavy_reason(HERE, sample, []) == reason


def test_the_reading_follows_the_tests_fixtures():
    assert heavy_reason(HERE, sample_plain, ["router_fixture"]) == "starts a Zenoh router process"


def test_the_guard_names_what_happened_and_where():
    guard = Guard()
    guard.note("starts a process (true)")
    assert list(guard.report()) == ["starts a process (true) (test_heavy.py:85)"]
    guard.clear()
    assert list(guard.report()) == []


@pytest.mark.integration  # binds a socket on purpose
def test_the_guard_sees_a_bound_socket_but_not_free_tcp_port():
    guard = Guard()
    guard.install()
    try:
        free_tcp_port()  # binds port 0 only to learn a free port
        assert list(guard.report()) == []
        with socket.socket() as sock:
            sock.bind(("127.0.0.1", 0))
        assert [e.split(" (")[0] for e in guard.report()] == ["binds a socket"]
    finally:
        guard.uninstall()


def test_matplotlib_listing_the_fonts_is_no_process_of_the_test():
    guard = Guard()
    guard.install()
    try:
        with pytest.raises(OSError):  # fc-list under a name no machine has: nothing starts
            subprocess.Popen(["/nonexistent/fc-list", "--help"])
        assert list(guard.report()) == []
    finally:
        guard.uninstall()
