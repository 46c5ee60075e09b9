"""``python -m agent.host --agent CONFIG,STATS[,AUTH] ... [agent options]``: K agents, one process.

For big simulations on few cores (``formation run --agents-per-process K``): each
``--agent`` is one robot's :class:`agent.node.AgentNode` with its own configuration, its own
Zenoh keys and its own counters file, exactly as ``python -m agent --config CONFIG --stats STATS
[--zenoh-auth AUTH]`` would run it; every other option (``--lockstep``, faults, ``--no-trace``,
...) is :mod:`agent.__main__`'s and applies to all of them. The nodes run as tasks of one asyncio
loop. In real time a pose callback only stores the pose (on Zenoh's thread) and queues its node;
the host's one tick thread (:class:`TickWorker`) ticks each queued node on its newest pose, under
the node's own tick lock, with the same tick code as a process of its own: while the host keeps
up every pose gets its tick, and a host that falls behind skips to each robot's newest pose
(``superseded_poses`` in its counters) instead of working through a backlog, so its latency stays
bounded. ``--direct-ticks`` ticks on Zenoh's thread instead, as a single agent does (both measured in
docs/results.md). One process per robot stays the default and what
deploy installs.

Sessions: by default each node opens its own Zenoh session (a client of the router, as a separate
process would). ``--shared-session`` gives every node of the host one session instead: fewer
sessions and links on the router, and the nodes' messages to each other stay in the process. It
is refused with per-robot credentials (``AUTH``), since each robot must log in as itself for the
router's access control list. docs/results.md has both measured.

SIGINT or SIGTERM stops every node: each publishes its zero command, undeclares and closes (its
session, or its share of the common one, closed last), and writes its counters to its STATS file.
A node that fails stops the host (the others get their zero command too); exit status 1 then, 2
for an invalid configuration or ``--agent``. ``cpu_s`` in a node's counters is its share of the
host's CPU time (the host's divided by K; ``host_agents`` says K).
"""

from __future__ import annotations

import signal

# SIGINT/SIGTERM blocked before anything else is imported, as in agent.__main__ (a native thread
# started by an import would otherwise take them with their default action: no zero command)
if __name__ == "__main__":
    signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT, signal.SIGTERM})

import argparse
import asyncio
import gc
import logging
import sys
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from pathlib import Path

import zenoh

from agent.__main__ import SignalWatch, build_parser, node_options, stop_event, write_stats
from agent.config import AgentConfig, load_config
from agent.node import AgentNode, NodeOptions, zenoh_config
from agent.replan import close_plan_pool, start_plan_pool
from agent.schedule import PoseScheduler
from agent.stalls import StallProbe
from agent.stats import AgentStats
from runtime.lifeline import watch_parent
from wire.acl import read_credentials
from wire.zconf import use_zenoh_threads

logger = logging.getLogger("agent.host")


class SharedSession:
    """One Zenoh session lent to several nodes; closed when the last one gives it back."""

    def __init__(self, session: zenoh.Session, users: int) -> None:
        self.session = session
        self.users = users

    def give_back(self) -> None:
        self.users -= 1
        if self.users == 0:
            self.session.close()


IDLE_YOUNG = 700  # tracked allocations after which an idle tick thread collects (Python's default)


def collect_if_due(young: int = IDLE_YOUNG) -> int | None:
    """Between ticks: the collection Python's own rule would have made by now, if any (the
    generation collected, else None). The collector's automatic threshold stays high
    (:func:`runtime.heap.freeze_startup`) as a backstop; this makes its collections small and
    at a moment when no tick waits: a young collection walks every young object still alive, so
    one at 700 allocations takes a fraction of a millisecond where the automatic one, at the high
    threshold, held the host's tick thread (and every tick queued behind it) for milliseconds.
    An older generation is collected when its own count passes Python's threshold, as Python
    does (``gc.get_threshold``). A collector switched off (disabled, or threshold 0) stays
    off."""
    young_count, middle_count, old_count = gc.get_count()
    automatic, middle, old = gc.get_threshold()
    if young <= 0 or young_count < young or automatic == 0 or not gc.isenabled():
        return None  # not due, or a collector switched off stays off
    generation = 2 if old_count >= old else 1 if middle_count >= middle else 0
    gc.collect(generation)
    return generation


class TickWorker:
    """Real time: the host's one thread that runs its agents' pose ticks (see the module
    docstring). A pose callback only stores the pose and queues its node (once); the worker
    ticks each queued node on its newest pose, so a host that falls behind skips to the newest
    pose of each robot instead of working through a backlog of old ones. When no node is queued
    after a tick, the worker makes the garbage collector's due collection
    (:func:`collect_if_due`), so the collector runs between ticks, not inside one."""

    def __init__(self, idle: Callable[[], object] = collect_if_due,
                 probe: StallProbe | None = None) -> None:
        self._due: deque[HostedNode] = deque()
        self._queued: set[int] = set()
        self._cond = threading.Condition()
        self._stopped = False
        self._idle = idle
        self._probe = probe  # --stalls: every tick timed (agent.stalls)
        self.superseded = 0  # poses stored but never ticked on (a newer one came first)
        self._thread = threading.Thread(target=self._run, name="agent-host-ticks", daemon=True)
        self._thread.start()

    def mark(self, node: HostedNode) -> None:
        with self._cond:
            if id(node) in self._queued:
                node.superseded += 1
                return
            self._queued.add(id(node))
            self._due.append(node)
            self._cond.notify()

    def _run(self) -> None:
        while True:
            with self._cond:
                while not self._due and not self._stopped:
                    self._cond.wait()
                if self._stopped:
                    return
                node = self._due.popleft()
                self._queued.discard(id(node))
            if self._probe is None:
                node.tick_queued()
            else:
                self._probe.tick(node.tick_queued, node.cfg.robot_id, node.ticker.times)
            if not self._due:  # nothing waits (read without the lock: a hint is enough)
                self._idle()

    def stop(self) -> None:
        with self._cond:
            self._stopped = True
            self._cond.notify()
        self._thread.join(5.0)


class HostedNode(AgentNode):
    """An :class:`AgentNode` that may use its host's shared session (never closing it itself)
    and, in real time, its host's :class:`TickWorker`."""

    def __init__(self, cfg: AgentConfig, options: NodeOptions, shared: SharedSession | None = None,
                 host_agents: int = 1, worker: TickWorker | None = None) -> None:
        super().__init__(cfg, options)
        self.shared = shared
        self.host_agents = host_agents
        if worker is not None and isinstance(self.scheduler, PoseScheduler):
            # the pose callback queues this node on the host's tick thread
            self.scheduler.queue = lambda: worker.mark(self)
        self.superseded = 0
        self._host_cpu0 = time.process_time()

    def tick_queued(self) -> None:
        """The host's tick thread: tick on the newest pose, under the tick lock, unless closing
        (:meth:`agent.schedule.PoseScheduler.pose_tick`)."""
        scheduler = self.scheduler
        assert isinstance(scheduler, PoseScheduler)  # a worker only in real time on pose arrival
        with self.gate.lock:
            if not self.gate.closing:
                scheduler.pose_tick(time.monotonic())

    def open_session(self) -> zenoh.Session:
        return super().open_session() if self.shared is None else self.shared.session

    def close_session(self, session: zenoh.Session) -> None:
        if self.shared is None:
            super().close_session(session)
        else:
            self.shared.give_back()

    def stats(self) -> AgentStats:
        s = super().stats()
        s.cpu_s = (time.process_time() - self._host_cpu0) / self.host_agents
        s.host_agents = self.host_agents
        s.superseded_poses = self.superseded
        return s


def parse_agent(text: str) -> tuple[Path, Path, Path | None]:
    """``CONFIG,STATS`` or ``CONFIG,STATS,AUTH``."""
    parts = text.split(",")
    if len(parts) not in (2, 3) or not all(parts):
        raise ValueError(f"--agent: {text!r} is not CONFIG,STATS[,AUTH]")
    return Path(parts[0]), Path(parts[1]), Path(parts[2]) if len(parts) == 3 else None


async def serve_all(nodes: Sequence[AgentNode], watch: SignalWatch | None = None) -> None:
    """Run every node until SIGINT/SIGTERM (through ``watch``, the agent's signal thread, as
    :mod:`agent.__main__` does; else asyncio's handlers) or until one fails; every node closes
    either way."""
    stop = stop_event(watch)
    loop = asyncio.get_running_loop()
    if watch is None:
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(sig, stop.set)

    async def one(node: AgentNode) -> None:
        try:
            await node.run(stop)
        finally:
            stop.set()  # one node ending (a failure) ends the host: the others command zero

    try:
        results = await asyncio.gather(*(one(n) for n in nodes), return_exceptions=True)
    finally:
        if watch is None:
            for sig in (signal.SIGINT, signal.SIGTERM):
                loop.remove_signal_handler(sig)
    for node, res in zip(nodes, results, strict=True):
        if isinstance(res, BaseException):
            raise RuntimeError(f"agent {node.cfg.robot_id}: {type(res).__name__}: {res}") from res


def plan(ns: argparse.Namespace) -> list[tuple[AgentConfig, NodeOptions, Path]]:
    """Every ``--agent``'s configuration, options and counters file; ``ValueError`` naming the
    culprit."""
    if ns.config is not None or ns.stats is not None or ns.zenoh_auth is not None:
        raise ValueError("--config, --stats and --zenoh-auth go in --agent CONFIG,STATS[,AUTH]")
    specs = [parse_agent(a) for a in ns.agent]
    if not specs:
        raise ValueError("--agent: give at least one")
    if ns.shared_session and any(auth is not None for _, _, auth in specs):
        raise ValueError("--shared-session: each robot with credentials needs its own session")
    if ns.shared_session and ns.zenoh_config is not None:
        raise ValueError("--shared-session: not with --zenoh-config")
    planned = []
    for config, stats, auth in specs:
        cfg = load_config(config)
        options = node_options(ns, None if auth is None else read_credentials(auth))
        planned.append((cfg, options, stats))
    ids = [cfg.robot_id for cfg, _, _ in planned]
    dup = next((r for r in ids if ids.count(r) > 1), None)
    if dup is not None:
        raise ValueError(f"--agent: robot {dup!r} given twice")
    return planned


def serve_planned(planned: list[tuple[AgentConfig, NodeOptions, Path]], ns: argparse.Namespace,
                  watch: SignalWatch) -> int:
    """Run the planned agents until a signal or a failure, write every one's counters; the exit
    status (1 if one failed)."""
    k = len(planned)
    shared = None
    status = 0
    nodes: list[HostedNode] = []
    opt0 = planned[0][1]
    probe = None if ns.stalls is None else StallProbe()
    worker = None if (ns.direct_ticks or opt0.lockstep or not opt0.tick_on_pose) \
        else TickWorker(probe=probe)
    try:
        if ns.shared_session:
            shared = SharedSession(zenoh.open(zenoh_config(planned[0][0], opt0.connect_timeout)), k)
        nodes = [HostedNode(cfg, options, shared, k, worker) for cfg, options, _ in planned]
        start_plan_pool([cfg for cfg, _, _ in planned], opt0.lockstep)
        if probe is not None:
            probe.start()
        asyncio.run(serve_all(nodes, watch))
    except Exception as exc:  # a process front end: report and exit 1
        logger.exception("agent host (%s) failed", ", ".join(cfg.robot_id for cfg, _, _ in planned))
        print(f"agent host: {type(exc).__name__}: {exc}", file=sys.stderr)
        status = 1
    finally:
        if worker is not None:
            worker.stop()
        if probe is not None:  # before the plan worker goes: its CPU time is in the report
            write_stalls(probe, ns.stalls, planned[0][0].robot_id)
        close_plan_pool()  # as agent.__main__: not left to Python's exit
    for node, (_, _, stats) in zip(nodes, planned, strict=False):
        write_stats(node, stats)
    return status


def write_stalls(probe: StallProbe, folder: Path, first: str) -> None:
    """``--stalls``: the probe's report as ``FOLDER/FIRST.json`` (``first``: the host's first
    robot); a failure to write is logged, the host's exit status stays its own."""
    probe.stop()
    try:
        folder.mkdir(parents=True, exist_ok=True)
        probe.write(folder / f"{first}.json")
    except OSError as exc:
        logger.error("agent host: --stalls: %s", exc)


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser(prog="python -m agent.host", description=__doc__.split("\n")[0],
                          per_agent=True)
    parser.add_argument("--agent", action="append", default=[], metavar="CONFIG,STATS[,AUTH]",
                        help="one robot's agent configuration, counters file and credentials")
    parser.add_argument("--shared-session", action="store_true",
                        help="one Zenoh session for every agent of the host (not with AUTH)")
    parser.add_argument("--direct-ticks", action="store_true",
                        help="real time: tick on Zenoh's thread as a process of its own does, "
                             "not on the host's tick thread (for comparison)")
    parser.add_argument("--stalls", type=Path, default=None, metavar="DIR",
                        help="record what holds the ticks back (garbage collections, the heap, "
                             "each tick's CPU, the longest ticks' parts: agent.stalls) and write "
                             "it to DIR/FIRST_ROBOT.json on the way out")
    ns = parser.parse_args(argv)
    watch = SignalWatch()  # first: before any thread starts (threads inherit the blocked mask)
    logging.basicConfig(level=ns.log_level.upper(),
                        format="%(asctime)s %(name)s %(levelname)s %(message)s")
    try:
        planned = plan(ns)
    except ValueError as exc:
        print(f"agent host: {exc}", file=sys.stderr)
        return 2
    watch_parent()  # started by formation run: stop (zero commands) if the launcher dies
    use_zenoh_threads("agent")
    return serve_planned(planned, ns, watch)


if __name__ == "__main__":
    sys.exit(main())
