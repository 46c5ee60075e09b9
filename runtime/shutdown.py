"""Shutdown steps with a time limit: undeclaring a publisher or closing a Zenoh
session blocks on the network, and a router that is gone or a peer that does not answer must
not keep a process from ending. Each step runs on a daemon thread; the caller waits at most
``limit`` seconds, logs a step that did not finish in time and goes on (the thread is left to
finish, or to die with the process)."""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Iterable
from typing import Any

logger = logging.getLogger(__name__)

#: [s] the default limit of one shutdown step (a healthy undeclare or close takes milliseconds)
STEP_LIMIT_S = 2.0
#: [s] an agent process's longest normal shutdown after a signal before its emergency way out
SHUTDOWN_S = 3.0
#: [s] then, the longest it waits for its main path already writing the counters
WRITING_S = 10.0


def undeclare_all(handles: Iterable[Any]) -> None:
    """Undeclare each Zenoh subscriber, publisher or token; one that fails is logged and does
    not stop the others."""
    for h in handles:
        try:
            h.undeclare()
        except Exception:  # closing or letting go: log, keep going
            logger.debug("undeclare failed", exc_info=True)


def within(limit: float, what: str, step: Callable[[], object]) -> bool:
    """Run ``step()`` and wait at most ``limit`` seconds for it. True when it finished (an
    exception it raised is logged, not raised: shutting down goes on); False when it did not
    finish in time (logged as a warning naming ``what``)."""
    failed: list[BaseException] = []

    def run() -> None:
        try:
            step()
        except Exception as exc:  # noqa: BLE001 - shutting down: log, keep closing
            failed.append(exc)

    t = threading.Thread(target=run, name=f"shutdown: {what}", daemon=True)
    t.start()
    t.join(limit)
    if t.is_alive():
        logger.warning("%s did not finish within %.1f s: going on without it", what, limit)
        return False
    if failed:
        logger.warning("%s failed: %s", what, failed[0])
    return True
