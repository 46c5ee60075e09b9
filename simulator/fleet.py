"""One owner for a fleet's processes: a Zenoh router and one agent per robot, here or on other hosts.

:class:`Fleet` starts every child in its own process group (``start_new_session``) with its
output in ``LOG_DIR/NAME.log``, watches them (:meth:`Fleet.check` raises :class:`ChildFailed`
when one has exited), and stops them: SIGTERM to the group, then SIGKILL after a time limit, every
wait bounded. As a context manager it stops every child on every way out, and in the main thread
it installs a SIGTERM handler that only sets a flag; :meth:`Fleet.check`, which the world calls
while it waits, turns the flag into ``KeyboardInterrupt`` in ordinary code.

Agents on other hosts (``formation run --hosts``, :class:`RemoteAgents`) are children too: each is
an ``ssh`` that runs the agent there (:meth:`Fleet.start_command`). Its exit is noticed like any
child's, and it is stopped by closing its stdin, on which the far side sends the agent SIGTERM.

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
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import FrameType, TracebackType
from typing import IO, Any, Protocol

from agent.config import AgentConfig, save_config
from runtime import lifeline
from runtime.router import IN_USE, RouterClash, new_router_id, wait_for_router
from runtime.shutdown import SHUTDOWN_S, WRITING_S
from wire.zconf import UsrPwdAuth

logger = logging.getLogger(__name__)

REPO_ROOT = Path(__file__).resolve().parent.parent
# [s] SIGTERM -> SIGKILL, for all the children together: longer than an agent's way out
# (SHUTDOWN_S, then up to WRITING_S for a long run's counters, megabytes that a busy machine
# writes slowly), so no agent is killed while it writes them
STOP_TIMEOUT_S = SHUTDOWN_S + WRITING_S + 2.0
KILL_WAIT_S = 5.0  # [s] the longest wait for a SIGKILLed child to be reaped
START_TIMEOUT_S = 60.0  # [s] router listening, agents subscribed


class RemoteAgents(Protocol):
    """Agents placed on other hosts (implemented by :class:`deploy.remote.RemotePlacement`)."""

    endpoint: str  # the router's endpoint, reachable from those hosts (it listens there)
    robots: frozenset[str]  # the robots whose agents run elsewhere

    def start(self, fleet: Fleet, configs: Mapping[str, AgentConfig], folder: Path,
              extra_argv: Callable[[str], Sequence[str]], per_process: int,
              shared_session: bool = False) -> dict[str, Child]:
        """Ship each robot its configuration and credentials and start its agent there as a
        child of ``fleet``; every robot maps to its process's child."""
        ...

    def collect(self, folder: Path) -> list[str]:
        """Copy each robot's counters back to ``FOLDER/agents/ROBOT.json`` once its agent has
        stopped, and remove the run's files there; the robots whose counters did not come."""
        ...

    def summary(self) -> dict:
        """``remote`` of summary.json: where each robot ran."""
        ...

    def check(self) -> None:
        """Every host reached over SSH and ready to run the agents (before anything starts)."""
        ...

    def describe(self, common: Sequence[str], secure: bool, shared_session: bool = False,
                 here: Sequence[str] = ()) -> list[str]:
        """The placement as text lines (``--dry-run``); nothing is touched."""
        ...


class ChildFailed(RuntimeError):
    """A child process exited while the run needed it."""


@dataclass
class Child:
    name: str
    proc: subprocess.Popen
    log: IO[bytes]
    stop_by_stdin: bool = False  # stopped by closing its stdin (an ssh to another host)
    where: str = ""  # another host's address ("" here)


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
        self._previous_hup: Any = None
        self._installed = False

    # ------------------------------------------------------------------ lifecycle

    def __enter__(self) -> Fleet:
        if threading.current_thread() is threading.main_thread():
            self._previous = signal.signal(signal.SIGTERM, self._on_signal)
            self._previous_hup = signal.signal(signal.SIGHUP, self._on_signal)  # terminal closed
            self._installed = True
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        try:
            self.stop()
        finally:
            if self._installed:
                signal.signal(signal.SIGTERM, self._previous)
                signal.signal(signal.SIGHUP, self._previous_hup)
                self._installed = False

    def _on_signal(self, signum: int, _frame: FrameType | None) -> None:
        """Flag only: :meth:`check` raises in ordinary code."""
        self.signalled = signum

    # ------------------------------------------------------------------ processes

    def start(self, name: str, argv: Sequence[str]) -> Child:
        """``python ARGV`` as child ``name`` in its own process group."""
        log = (self.log_dir / f"{name}.log").open("wb")
        try:
            env, fds = lifeline.child_env(self.env)  # it stops itself if we die (no orphans)
            proc = subprocess.Popen([sys.executable, *argv], env=env, stdin=subprocess.DEVNULL,
                                    stdout=log, stderr=subprocess.STDOUT, start_new_session=True,
                                    pass_fds=fds)
        except BaseException:
            log.close()
            raise
        child = Child(name, proc, log)
        self.children.append(child)
        return child

    def start_command(self, name: str, argv: Sequence[str], where: str = "") -> Child:
        """``ARGV`` (any program: ``ssh`` to another host, say) as child ``name`` in its own
        process group, its stdin a pipe that only this process holds. It is stopped by closing
        that pipe (:meth:`stop`): the program on the other end, seeing end-of-file, stops what it
        runs in order and exits. If this process dies the pipe closes too (no orphans there)."""
        log = (self.log_dir / f"{name}.log").open("wb")
        try:
            proc = subprocess.Popen(list(argv), env=self.env, stdin=subprocess.PIPE, stdout=log,
                                    stderr=subprocess.STDOUT, start_new_session=True)
        except BaseException:
            log.close()
            raise
        child = Child(name, proc, log, stop_by_stdin=True, where=where)
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
                on = f" on {c.where}" if c.where else ""
                raise ChildFailed(f"{c.name}{on} exited with status {code} (see {path})"
                                  + (": " + " | ".join(tail) if tail else ""))

    def stop(self, children: Sequence[Child] | None = None, timeout: float = STOP_TIMEOUT_S) -> None:
        """SIGTERM to each child's process group, wait up to ``timeout`` in all, SIGKILL what is
        left, and reap it (at most :data:`KILL_WAIT_S` each)."""
        targets = list(self.children if children is None else children)
        for c in targets:
            if c.stop_by_stdin:
                _close_stdin(c)  # also of one that is gone: the pipe is ours to close
            elif c.proc.poll() is None:
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
                     timeout: float = START_TIMEOUT_S, auth: UsrPwdAuth | None = None,
                     also_listen: Sequence[str] = ()) -> Child:
        """``python -m runtime.router`` listening on ``endpoint`` with a fresh per-run id; returns
        once that very router answers there (:func:`runtime.router.wait_for_router`, logging in as
        ``auth``; ``TimeoutError`` after ``timeout``, :meth:`check` meanwhile). A port that
        another process (another run's router, say) holds is :class:`RouterClash`, naming it."""
        router_id = new_router_id()
        argv = ["-m", "runtime.router", "--listen", endpoint, "--log-level", "WARNING",
                "--id", router_id]
        for extra in also_listen:  # e.g. the pose zones' private socket (simulator.zones)
            argv += ["--listen", extra]
        if config is not None:
            argv += ["--config", str(config)]
        router = self.start("router", argv)
        try:
            wait_for_router(endpoint, router_id, timeout_s=timeout, alive=self.check, auth=auth)
        except ChildFailed as exc:
            if IN_USE in str(exc):
                raise RouterClash(f"port {port} on 127.0.0.1 is in use by another process: "
                                  f"choose another --port (or 0 for a free one)") from None
            raise
        except RouterClash:
            raise RouterClash(f"port {port} on 127.0.0.1 is served by another run's Zenoh router, "
                              f"not this run's: choose another --port (or 0 for a free one)"
                              ) from None
        return router

    def start_agents(self, configs: Mapping[str, AgentConfig], folder: Path,
                     extra_argv: Callable[[str], Sequence[str]] = lambda _rid: (),
                     per_process: int = 1, shared_session: bool = False) -> dict[str, Child]:
        """One ``python -m agent`` per robot: its configuration saved as
        ``FOLDER/configs/ROBOT.yaml``, its counters written to ``FOLDER/agents/ROBOT.json`` when
        it stops, ``extra_argv(robot)`` appended to its arguments.

        ``per_process`` K > 1: the robots, in order, K at a time in one agent host
        (``python -m agent.host``, child ``host-I``), each with its own configuration, counters
        and credentials (``--zenoh-auth`` of ``extra_argv``); the rest of ``extra_argv`` must
        be the same for every robot of a host. ``shared_session``: one Zenoh session per host.
        Every robot of a host maps to the same :class:`Child`."""
        if per_process < 1:
            raise ValueError(f"per_process: need an integer >= 1, got {per_process!r}")
        agents: dict[str, Child] = {}
        ids = list(configs)
        for rid, cfg in configs.items():
            save_config(cfg, folder / "configs" / f"{rid}.yaml")
        if per_process == 1 and not shared_session:
            for rid in ids:
                argv = ["-m", "agent", "--config", str(folder / "configs" / f"{rid}.yaml"),
                        "--stats", str(folder / "agents" / f"{rid}.json"), *extra_argv(rid)]
                self.agent_argv[rid] = argv
                agents[rid] = self.start(f"agent-{rid}", argv)
            return agents
        for i in range(0, len(ids), per_process):
            group = ids[i:i + per_process]
            argv = ["-m", "agent.host"] + (["--shared-session"] if shared_session else [])
            common: list[str] | None = None
            for rid in group:
                rest, auth = split_auth(list(extra_argv(rid)))
                if common is None:
                    common = rest
                elif rest != common:
                    raise ValueError(f"per_process: robot {rid} has options of its own: {rest}")
                spec = f"{folder / 'configs' / f'{rid}.yaml'},{folder / 'agents' / f'{rid}.json'}"
                argv += ["--agent", spec + ("" if auth is None else f",{auth}")]
            argv += common or []
            host = self.start(f"host-{i // per_process}", argv)
            for rid in group:
                self.agent_argv[rid] = argv
                agents[rid] = host
        return agents

    def write_pids(self, path: Path) -> None:
        """Every running child's PID by name, as JSON, written whole then renamed."""
        tmp = path.with_name(path.name + ".tmp")
        tmp.write_text(json.dumps({c.name: c.proc.pid for c in self.children}, indent=2) + "\n",
                       encoding="utf-8")
        tmp.replace(path)

    def shut_down(self, agents: Sequence[Child], router: Child, services: Sequence[Child] = ()) -> None:
        """The orderly end of a run: the agents first (they write their counters on SIGTERM),
        then ``services`` (e.g. the camera process, which prints its counters on SIGTERM), then
        the router."""
        self.stop(agents)
        if services:
            self.stop(services)
        self.stop([router])


def _close_stdin(child: Child) -> None:
    """End-of-file on ``child``'s stdin (its stop request)."""
    if child.proc.stdin is not None:
        try:
            child.proc.stdin.close()
        except OSError:  # it is gone already (broken pipe)
            pass


def split_auth(argv: list[str]) -> tuple[list[str], str | None]:
    """``argv`` without its ``--zenoh-auth FILE``, and FILE (None if absent)."""
    if "--zenoh-auth" not in argv:
        return argv, None
    i = argv.index("--zenoh-auth")
    return argv[:i] + argv[i + 2:], argv[i + 1]


def unique_children(children: Iterable[Child]) -> list[Child]:
    """``children`` without repeats (an agent host appears once per robot it runs), in order."""
    seen: dict[int, Child] = {}
    for c in children:
        seen.setdefault(id(c), c)
    return list(seen.values())
