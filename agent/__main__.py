"""``python -m agent --config ROBOT.yaml [--lockstep] [--stats PATH]``: one robot's agent.

``--drop P --delay-ms D --fault-seed S`` inject link faults at the agent's subscribers (for
``formation run``; see docs/faults.md and :mod:`agent.faults`).

Runs :class:`agent.node.AgentNode` until SIGINT or SIGTERM, then commands zero velocity, closes
the Zenoh session, writes its counters to ``--stats`` (JSON) and exits 0. Exit status 2 for an
invalid configuration, 1 when the session cannot be opened or the node fails.

Signals (:class:`SignalWatch`): SIGINT and SIGTERM are blocked in every thread before any thread
starts and taken by one thread waiting in ``sigwait``, which only sets the node's stop flag. They
never go through asyncio's wakeup fd: under a flood of messages that fd (the loop's self-pipe,
which every ``call_soon_threadsafe`` also writes to) is full, the signal's byte is lost
("Exception ignored when trying to write to the signal wakeup fd: BlockingIOError") and the agent
never stopped. The way out has a time limit (:data:`runtime.shutdown.SHUTDOWN_S`): if the
normal shutdown (zero command, undeclare, close, counters) has not finished by then, the signal
thread publishes the zero command itself if it was not sent yet, writes the counters and ends
the process.
"""

from __future__ import annotations

import signal

# SIGINT/SIGTERM blocked before anything else is imported: some imports start native threads
# (OpenBLAS's pool under numpy) and a thread that has them unblocked would take a process-directed
# signal with its default action (death, no zero command). SignalWatch waits for them instead.
STOP_SIGNALS = frozenset({signal.SIGINT, signal.SIGTERM})
if __name__ == "__main__":
    signal.pthread_sigmask(signal.SIG_BLOCK, STOP_SIGNALS)

import argparse  # noqa: E402
import asyncio  # noqa: E402
import errno  # noqa: E402
import json  # noqa: E402
import logging  # noqa: E402
import os  # noqa: E402
import sys  # noqa: E402
import threading  # noqa: E402
from collections.abc import Callable, Sequence  # noqa: E402
from pathlib import Path  # noqa: E402

from agent.config import load_config  # noqa: E402
from agent.faults import LinkFaults  # noqa: E402
from agent.node import AgentNode, NodeOptions  # noqa: E402
from agent.replan import close_plan_pool, start_plan_pool  # noqa: E402
from runtime.lifeline import watch_parent  # noqa: E402
from runtime.shutdown import SHUTDOWN_S, WRITING_S  # noqa: E402
from wire.acl import read_credentials  # noqa: E402
from wire.stamps import LOCKSTEP_WAIT_S  # noqa: E402
from wire.zconf import UsrPwdAuth, use_zenoh_threads  # noqa: E402

logger = logging.getLogger("agent")


class SignalWatch:
    """SIGINT/SIGTERM taken by a dedicated thread (module docstring). Construct it before any
    other thread starts (threads inherit the blocked mask); :meth:`on_signal` adds what a signal
    does (called on the signal thread, first signal only: each must only set flags or start a
    thread)."""

    def __init__(self) -> None:
        signal.pthread_sigmask(signal.SIG_BLOCK, STOP_SIGNALS)
        self.received = threading.Event()
        self.signum: int | None = None
        self._actions: list[Callable[[], None]] = []
        self._lock = threading.Lock()
        self._thread = threading.Thread(target=self._wait, name="signals", daemon=True)
        self._thread.start()

    def on_signal(self, action: Callable[[], None]) -> None:
        with self._lock:
            self._actions.append(action)
            if self.received.is_set():  # a signal came before the action was added
                action()

    def _wait(self) -> None:
        while True:
            signum = signal.sigwait(STOP_SIGNALS)
            logger.info("signal %s: stopping", signal.Signals(signum).name)
            with self._lock:
                if self.received.is_set():
                    continue  # already stopping
                self.signum = signum
                self.received.set()
                for action in self._actions:
                    action()


def stop_event(watch: SignalWatch | None) -> asyncio.Event:
    """An event of the running loop that ``watch``'s first signal sets (from the signal thread,
    queued on the loop even when its self-pipe is full)."""
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()

    def set_stop() -> None:
        try:
            loop.call_soon_threadsafe(stop.set)
        except RuntimeError:  # loop closed: nothing left to stop
            pass

    if watch is not None:
        watch.on_signal(set_stop)
    return stop


async def serve(node: AgentNode, watch: SignalWatch | None = None) -> None:
    """Run ``node`` until SIGINT/SIGTERM (through ``watch``) or until it fails."""
    await node.run(stop_event(watch))


def write_stats(node: AgentNode, path: Path) -> None:
    tmp = path.with_suffix(path.suffix + f".{os.getpid()}.tmp")
    try:
        tmp.write_text(json.dumps(node.stats().to_json_dict(), allow_nan=False), encoding="utf-8")
    except OSError:
        tmp.unlink(missing_ok=True)
        raise
    tmp.replace(path)  # the launcher never reads a half-written file


def _emergency_exit(node: AgentNode, stats: Path | None, done: threading.Event,
                    written: threading.Lock) -> None:
    """Signal thread, :data:`SHUTDOWN_S` after a signal, unless the main path is done: zero
    command (if not yet sent), counters, exit."""
    if done.wait(SHUTDOWN_S):
        return
    logger.warning("agent %s: shutdown overran %.1f s: zero command and counters from the "
                   "signal thread", node.cfg.robot_id, SHUTDOWN_S)
    node.emergency_zero()
    if stats is not None and written.acquire(blocking=False):
        try:
            write_stats(node, stats)
        except Exception:  # last resort
            logger.exception("agent %s: writing counters failed", node.cfg.robot_id)
    elif stats is not None and done.wait(WRITING_S):
        return  # the main path was writing the counters (a long run's are megabytes): done
    logging.shutdown()
    os._exit(0)


def build_parser(prog: str = "python -m agent", description: str = "",
                 per_agent: bool = False) -> argparse.ArgumentParser:
    """The options of one agent (shared with the agent host, :mod:`agent.host`, which gives
    ``per_agent``: each agent's configuration comes with ``--agent``, ``--config`` is hidden
    and optional there, only to say so)."""
    parser = argparse.ArgumentParser(prog=prog, description=description or __doc__.split("\n")[0])
    parser.add_argument("--config", required=not per_agent,
                        help=argparse.SUPPRESS if per_agent
                        else "the robot's agent configuration (YAML)")
    parser.add_argument("--lockstep", action="store_true",
                        help="tick on pose arrival (simulated world) instead of the own clock")
    parser.add_argument("--lockstep-timeout", type=float, default=LOCKSTEP_WAIT_S, metavar="SECONDS",
                        help=f"longest wait for one tick's inputs in lock-step (default {LOCKSTEP_WAIT_S:g})")
    parser.add_argument("--drop", type=float, default=0.0, metavar="P",
                        help="lose each received state/ellipse/others message with probability P")
    parser.add_argument("--delay-ms", type=float, default=0.0, metavar="MS",
                        help="deliver received state/ellipse/others messages this much later")
    parser.add_argument("--fault-seed", type=int, default=0, help="seed of the losses")
    parser.add_argument("--sim-start", type=float, default=0.0, metavar="SECONDS",
                        help="lock-step: the simulated time this agent joins the run at (a "
                             "restart); stamps past it plus two periods are refused")
    parser.add_argument("--ellipse-hold", type=float, default=10.0, metavar="SECONDS",
                        help="leader: longest use of another formation's stale ellipse, inflated")
    parser.add_argument("--zenoh-auth", type=Path, default=None, metavar="FILE",
                        help="log in to the router with the user:password in FILE (mode 0600)")
    parser.add_argument("--zenoh-config", type=Path, default=None, metavar="FILE",
                        help="a full Zenoh JSON5 configuration (as deploy writes it: client of the "
                             "router, user/password, TLS); replaces the one in --config")
    parser.add_argument("--stats", type=Path, default=None, help="write counters here (JSON) at exit")
    parser.add_argument("--no-trace", action="store_true", help="do not keep per-tick rows")
    parser.add_argument("--clock-ticks", action="store_true",
                        help="real time: tick on the own clock, not on pose arrival")
    parser.add_argument("--log-level", default="WARNING")
    return parser


def node_options(ns: argparse.Namespace, auth: UsrPwdAuth | None) -> NodeOptions:
    """The :class:`NodeOptions` of parsed agent options (ValueError on a bad value)."""
    faults = LinkFaults(drop=ns.drop, delay=ns.delay_ms / 1000.0, seed=ns.fault_seed)
    if ns.zenoh_config is not None and not ns.zenoh_config.is_file():
        raise ValueError(f"--zenoh-config: no such file {str(ns.zenoh_config)!r}")
    return NodeOptions(lockstep=ns.lockstep, lockstep_timeout=ns.lockstep_timeout,
                       trace=not ns.no_trace, faults=faults, ellipse_hold=ns.ellipse_hold,
                       auth=auth, tick_on_pose=not ns.clock_ticks, sim_start=ns.sim_start,
                       zenoh_config_file=None if ns.zenoh_config is None else str(ns.zenoh_config))


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    ns = parser.parse_args(argv)
    watch = SignalWatch()  # first: before any thread starts
    logging.basicConfig(level=ns.log_level.upper(),
                        format="%(asctime)s %(name)s %(levelname)s %(message)s")
    try:
        cfg = load_config(ns.config)
        auth = None if ns.zenoh_auth is None else read_credentials(ns.zenoh_auth)
        options = node_options(ns, auth)
        node = AgentNode(cfg, options)
    except ValueError as exc:
        print(f"agent: {exc}", file=sys.stderr)
        return 2
    status = 0
    watch_parent()  # started by formation run: stop (zero command) if the launcher dies
    use_zenoh_threads("agent")
    done = threading.Event()
    written = threading.Lock()  # one writer of the counters: the main path or the emergency one
    watch.on_signal(lambda: threading.Thread(
        target=_emergency_exit, args=(node, ns.stats, done, written), name="shutdown-limit",
        daemon=True).start())
    try:
        start_plan_pool([cfg], options.lockstep)
        asyncio.run(serve(node, watch))
    except Exception as exc:  # a process front end: report and exit 1
        logger.exception("agent %s failed", cfg.robot_id)
        print(f"agent {cfg.robot_id}: {type(exc).__name__}: {exc}", file=sys.stderr)
        status = 1
    close_plan_pool()  # not left to Python's exit, which waits for the worker's current plan
    if ns.stats is not None and written.acquire(blocking=False):
        try:
            write_stats(node, ns.stats)
        except OSError as exc:  # a full disk, say: say so, do not die with a traceback
            why = "disk full" if exc.errno in (errno.ENOSPC, errno.EDQUOT) else (exc.strerror or exc)
            print(f"agent {cfg.robot_id}: cannot write counters to {ns.stats}: {why}",
                  file=sys.stderr)
            status = 1
    done.set()
    return status


if __name__ == "__main__":
    sys.exit(main())
