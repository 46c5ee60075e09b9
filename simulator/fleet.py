"""One owner for a fleet's processes: a Zenoh router and one agent per robot on this machine.

:class:`Fleet` starts every child in its own process group (``start_new_session``) with its
output in ``LOG_DIR/NAME.log``, watches them (:meth:`Fleet.check` raises :class:`ChildFailed`
when one has exited), and stops them: SIGTERM to the group, then SIGKILL after a time limit, every
wait bounded. As a context manager it stops every child on every way out, and in the main thread
it installs a SIGTERM handler that only sets a flag; :meth:`Fleet.check`, which the world calls
while it waits, turns the flag into ``KeyboardInterrupt`` in ordinary code.

Used by ``formation run`` and ``formation commcost`` (:func:`simulator.launch.launch`) and by the
agent fleets of ``formation bench`` (:mod:`experiments.agents`).
"""

from __future__ import annotations

import json
import logging
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import FrameType, TracebackType
from typing import IO, Any

from agent.config import AgentConfig, save_config
from wire.ports import wait_for_tcp_port

logger = logging.getLogger(__name__)

REPO_ROOT = Path(__file__).resolve().parent.parent
STOP_TIMEOUT_S = 5.0  # [s] SIGTERM -> SIGKILL
KILL_WAIT_S = 5.0  # [s] the longest wait for a SIGKILLed child to be reaped
START_TIMEOUT_S = 60.0  # [s] router listening, agents subscribed


class ChildFailed(RuntimeError):
    """A child process exited while the run needed it."""


@dataclass
class Child:
    name: str
    proc: subprocess.Popen
    log: IO[bytes]


def signal_group(pid: int, sig: int) -> None:
    """``sig`` to the process group ``pid`` leads; nothing if it is gone."""
    try:
        os.killpg(pid, sig)
    except (ProcessLookupError, PermissionError):
        pass


class Fleet:
    """Starts, watches and stops the children of one run (see the module docstring)."""

    def __init__(self, log_dir: Path) -> None:
        self.log_dir = Path(log_dir)
        self.children: list[Child] = []
        self.agent_argv: dict[str, list[str]] = {}  # robot -> its agent's argv (for restarts)
        self.env = dict(os.environ)
        self.env["PYTHONPATH"] = os.pathsep.join(
            p for p in (str(REPO_ROOT), self.env.get("PYTHONPATH", "")) if p)
        self.signalled: int | None = None  # the stop signal received, if any
        self._previous: Any = None
        self._installed = False

    # ------------------------------------------------------------------ lifecycle

    def __enter__(self) -> Fleet:
        if threading.current_thread() is threading.main_thread():
            self._previous = signal.signal(signal.SIGTERM, self._on_signal)
            self._installed = True
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        try:
            self.stop()
        finally:
            if self._installed:
                signal.signal(signal.SIGTERM, self._previous)
                self._installed = False

    def _on_signal(self, signum: int, _frame: FrameType | None) -> None:
        """Flag only: :meth:`check` raises in ordinary code."""
        self.signalled = signum

    # ------------------------------------------------------------------ processes

    def start(self, name: str, argv: Sequence[str]) -> Child:
        """``python ARGV`` as child ``name`` in its own process group."""
        log = (self.log_dir / f"{name}.log").open("wb")
        try:
            proc = subprocess.Popen([sys.executable, *argv], env=self.env, stdin=subprocess.DEVNULL,
                                    stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
        except BaseException:
            log.close()
            raise
        child = Child(name, proc, log)
        self.children.append(child)
        return child

    def check(self) -> None:
        """``KeyboardInterrupt`` if a stop signal came; :class:`ChildFailed` if a child exited."""
        if self.signalled is not None:
            raise KeyboardInterrupt(f"signal {signal.Signals(self.signalled).name}")
        for c in self.children:
            code = c.proc.poll()
            if code is not None:
                path = self.log_dir / f"{c.name}.log"
                c.log.flush()
                try:
                    tail = path.read_text(encoding="utf-8", errors="replace").strip().splitlines()[-3:]
                except OSError:
                    tail = []
                raise ChildFailed(f"{c.name} exited with status {code} (see {path})"
                                  + (": " + " | ".join(tail) if tail else ""))

    def stop(self, children: Sequence[Child] | None = None, timeout: float = STOP_TIMEOUT_S) -> None:
        """SIGTERM to each child's process group, wait up to ``timeout`` in all, SIGKILL what is
        left, and reap it (at most :data:`KILL_WAIT_S` each)."""
        targets = list(self.children if children is None else children)
        for c in targets:
            if c.proc.poll() is None:
                signal_group(c.proc.pid, signal.SIGTERM)
        deadline = time.monotonic() + timeout
        for c in targets:
            try:
                c.proc.wait(max(0.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                logger.warning("%s (pid %d) ignored SIGTERM; killing it", c.name, c.proc.pid)
            signal_group(c.proc.pid, signal.SIGKILL)  # whatever is left in its group
            if c.proc.poll() is None:
                try:
                    c.proc.wait(KILL_WAIT_S)
                except subprocess.TimeoutExpired:
                    logger.error("%s (pid %d) outlived SIGKILL for %.0f s", c.name, c.proc.pid,
                                 KILL_WAIT_S)
            c.log.close()
        if children is None:
            self.children.clear()
        else:
            self.children = [c for c in self.children if c not in targets]

    # ------------------------------------------------------------------ the fleet's parts

    def start_router(self, endpoint: str, port: int, config: Path | None = None,
                     timeout: float = START_TIMEOUT_S) -> Child:
        """``python -m wire.router`` listening on ``endpoint``; returns once ``port`` accepts
        connections (``TimeoutError`` after ``timeout``, :meth:`check` meanwhile)."""
        argv = ["-m", "wire.router", "--listen", endpoint, "--log-level", "WARNING"]
        if config is not None:
            argv += ["--config", str(config)]
        router = self.start("router", argv)
        deadline = time.monotonic() + timeout
        while True:
            self.check()
            try:
                wait_for_tcp_port(port, timeout_s=0.2)
                return router
            except TimeoutError:
                if time.monotonic() > deadline:
                    raise

    def start_agents(self, configs: Mapping[str, AgentConfig], folder: Path,
                     extra_argv: Callable[[str], Sequence[str]] = lambda _rid: ()) -> dict[str, Child]:
        """One ``python -m agent`` per robot: its configuration saved as
        ``FOLDER/configs/ROBOT.yaml``, its counters written to ``FOLDER/agents/ROBOT.json`` when
        it stops, ``extra_argv(robot)`` appended to its arguments."""
        agents: dict[str, Child] = {}
        for rid, cfg in configs.items():
            path = folder / "configs" / f"{rid}.yaml"
            save_config(cfg, path)
            argv = ["-m", "agent", "--config", str(path),
                    "--stats", str(folder / "agents" / f"{rid}.json"), *extra_argv(rid)]
            self.agent_argv[rid] = argv
            agents[rid] = self.start(f"agent-{rid}", argv)
        return agents

    def write_pids(self, path: Path) -> None:
        """Every running child's PID by name, as JSON, written whole then renamed."""
        tmp = path.with_name(path.name + ".tmp")
        tmp.write_text(json.dumps({c.name: c.proc.pid for c in self.children}, indent=2) + "\n",
                       encoding="utf-8")
        tmp.replace(path)

    def shut_down(self, agents: Sequence[Child], router: Child) -> None:
        """The orderly end of a run: the agents first (they write their counters on SIGTERM),
        then the router."""
        self.stop(agents)
        self.stop([router])
