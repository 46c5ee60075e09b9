"""The fleet supervisor: flag-only signal handling, bounded shutdown, failed children named."""

from __future__ import annotations

import logging
import os
import signal
import time
from pathlib import Path

import pytest

from simulator.fleet import ChildFailed, Fleet


def _wait_for_line(path: Path, text: str, timeout_s: float = 10.0) -> None:
    deadline = time.monotonic() + timeout_s
    while text not in path.read_text(encoding="utf-8", errors="replace"):
        assert time.monotonic() < deadline, f"{path} never said {text!r}"
        time.sleep(0.02)


def test_sigterm_to_the_launcher_only_sets_a_flag_and_the_next_check_raises(tmp_path: Path) -> None:
    before = signal.getsignal(signal.SIGTERM)
    with Fleet(tmp_path) as fleet:
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(0.05)  # the handler runs here and must not raise
        assert fleet.signalled == signal.SIGTERM
        with pytest.raises(KeyboardInterrupt, match="SIGTERM"):
            fleet.check()
    assert signal.getsignal(signal.SIGTERM) == before


@pytest.mark.integration
def test_a_child_ignoring_sigterm_is_killed_after_the_time_limit(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    code = ("import signal, time; signal.signal(signal.SIGTERM, signal.SIG_IGN); "
            "print('ready', flush=True); time.sleep(60)")
    with Fleet(tmp_path) as fleet:
        child = fleet.start("stubborn", ["-c", code])
        _wait_for_line(tmp_path / "stubborn.log", "ready")
        with caplog.at_level(logging.WARNING):
            fleet.stop(timeout=0.5)
        # killed, not waited for: it would have slept 60 s, and SIGTERM did nothing
        assert child.proc.poll() == -signal.SIGKILL
        assert "stubborn" in caplog.text and "ignored SIGTERM; killing it" in caplog.text
        assert fleet.children == []


@pytest.mark.integration
def test_every_child_is_stopped_on_the_way_out_of_an_exception(tmp_path: Path) -> None:
    with pytest.raises(RuntimeError, match="boom"), Fleet(tmp_path) as fleet:
        child = fleet.start("sleeper", ["-c", "import time; print('ready', flush=True); time.sleep(60)"])
        _wait_for_line(tmp_path / "sleeper.log", "ready")
        raise RuntimeError("boom")
    assert child.proc.poll() is not None


@pytest.mark.integration
def test_check_names_a_child_that_exited_with_its_status_and_last_words(tmp_path: Path) -> None:
    with Fleet(tmp_path) as fleet:
        child = fleet.start("quitter", ["-c", "import sys; print('bad config'); sys.exit(3)"])
        child.proc.wait(10)
        with pytest.raises(ChildFailed, match=r"quitter exited with status 3 .*bad config"):
            fleet.check()
