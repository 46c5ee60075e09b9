"""A child process that outlives its launcher stops itself: no orphaned router or agent.

``formation run`` starts every child in its own session (so a Ctrl-C in the terminal reaches the
launcher only, which then stops them in order). The price: when the launcher dies without that
clean-up (SIGKILL, SIGHUP of a closed terminal, a crash), nothing stops the children. This module
ties each child to its launcher twice:

* **parent-death signal** (Linux): ``prctl(PR_SET_PDEATHSIG, SIGTERM)`` makes the kernel send the
  child SIGTERM when the launcher dies. Linux sends it when the *thread* that started the child
  ends, so the launcher starts children from its main thread;
* **lifeline pipe** (any POSIX system, and the fallback where ``prctl`` is missing): the launcher
  keeps the write end of one pipe open for its whole life and hands each child the read end
  (``pass_fds``); a daemon thread in the child blocks in ``read`` and gets end-of-file when the
  launcher is gone, whatever killed it, then sends the child SIGTERM itself.

Either way the child stops through its own SIGTERM handler: an agent commands zero velocity,
writes its counters and closes its session, the router closes. The launcher's side is
:func:`child_env` (environment and file descriptors for ``subprocess.Popen``); the child's is
:func:`watch_parent`, called first thing in its ``main``. A process started without them (an agent
on a robot, started by systemd) watches nothing: there its own watchdog (no fresh pose -> zero)
stays the safety net.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import logging
import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Mapping

logger = logging.getLogger(__name__)

PARENT_ENV = "FORMATION_PARENT_PID"  # the launcher's pid
FD_ENV = "FORMATION_LIFELINE_FD"  # the read end of the launcher's lifeline pipe
PR_SET_PDEATHSIG = 1  # <linux/prctl.h>
POLL_S = 0.5  # [s] fallback without pipe: how often the parent pid is checked

_lock = threading.Lock()
_write_end: int | None = None  # this process's lifeline, open until it exits
_read_end: int | None = None


def _lifeline() -> int:
    """The read end of this process's lifeline pipe, created once (both ends close-on-exec)."""
    global _read_end, _write_end
    with _lock:
        if _read_end is None:
            _read_end, _write_end = os.pipe()
        return _read_end


def child_env(env: Mapping[str, str]) -> tuple[dict[str, str], tuple[int, ...]]:
    """Launcher side: ``env`` plus the lifeline variables, and the ``pass_fds`` for ``Popen``."""
    fd = _lifeline()
    out = dict(env)
    out[PARENT_ENV] = str(os.getpid())
    out[FD_ENV] = str(fd)
    return out, (fd,)


def _terminate_self() -> None:
    os.kill(os.getpid(), signal.SIGTERM)


def set_pdeathsig(sig: int = signal.SIGTERM) -> bool:
    """Ask Linux to send ``sig`` to this process when its parent dies; False where unsupported."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        if libc.prctl(PR_SET_PDEATHSIG, int(sig), 0, 0, 0) != 0:
            logger.warning("prctl(PR_SET_PDEATHSIG) failed: errno %d", ctypes.get_errno())
            return False
    except (OSError, AttributeError):
        return False
    return True


def watch_parent(on_death: Callable[[], None] = _terminate_self) -> bool:
    """Child side: call ``on_death`` (default: SIGTERM to this process) once the launcher that
    set :data:`PARENT_ENV` is gone. False (nothing watched) when no launcher asked for it.

    The variables are removed from this process's environment, so they do not reach its own
    children with a pid that is not their parent's."""
    parent = os.environ.pop(PARENT_ENV, None)
    fd_text = os.environ.pop(FD_ENV, None)
    if parent is None:
        return False
    try:
        parent_pid = int(parent)
    except ValueError:
        logger.warning("%s=%r is not a pid; not watching the parent", PARENT_ENV, parent)
        return False
    signalled = on_death is _terminate_self and set_pdeathsig()
    fd = _open_fd(fd_text)
    if os.getppid() != parent_pid:  # it died before we could ask to be told
        logger.warning("launcher (pid %d) already gone", parent_pid)
        on_death()
        return True
    if signalled and fd is None:
        return True
    if fd is not None:
        threading.Thread(target=_wait_pipe, args=(fd, parent_pid, on_death), name="lifeline",
                         daemon=True).start()
    else:
        threading.Thread(target=_poll_pid, args=(parent_pid, on_death), name="lifeline",
                         daemon=True).start()
    return True


def _open_fd(fd_text: str | None) -> int | None:
    """The pipe's read end named by :data:`FD_ENV`; None when absent or not an open descriptor."""
    if fd_text is None:
        return None
    try:
        fd = int(fd_text)
        os.fstat(fd)
    except (ValueError, OSError):
        logger.warning("%s=%r is not an open descriptor; polling the parent pid", FD_ENV, fd_text)
        return None
    return fd


def _wait_pipe(fd: int, parent_pid: int, on_death: Callable[[], None]) -> None:
    """Block until every write end of the pipe is closed (the launcher is gone), then stop."""
    try:
        while os.read(fd, 1):  # nobody writes: returns b"" once every write end is closed
            pass
    except OSError:
        pass
    logger.warning("launcher (pid %d) gone: stopping", parent_pid)
    on_death()


def _poll_pid(parent_pid: int, on_death: Callable[[], None]) -> None:
    """Poll the parent pid every :data:`POLL_S` until this process is re-parented, then stop."""
    while os.getppid() == parent_pid:
        time.sleep(POLL_S)
    logger.warning("launcher (pid %d) gone: stopping", parent_pid)
    on_death()
