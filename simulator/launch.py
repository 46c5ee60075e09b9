"""``formation run``: the multi-process simulation over Zenoh (docs/cli.md).

:func:`launch` takes a checked :class:`simulator.run_config.RunConfig` and only orchestrates the
run's :class:`Fleet`. It picks a loopback port and starts, each in its own process group
(``start_new_session``) with explicit ``tcp/127.0.0.1:PORT`` endpoints and multicast scouting off:

* a Zenoh router (``python -m runtime.router``), with the run's fresh credentials and access
  control list unless insecure (:mod:`simulator.access`);
* one agent per robot (``python -m agent --config DIR/configs/ROBOT.yaml``, ``--lockstep`` unless
  ``--realtime``), each writing its counters to ``DIR/agents/ROBOT.json`` when it stops. With
  ``--agents-per-process K`` the agents run K to an agent host (``python -m agent.host``, child
  ``host-I``; :mod:`agent.host`), one Zenoh session per host unless ``--session-per-agent`` or
  ``--secure``; each robot keeps its own configuration, keys and counters file. With ``--hosts
  INVENTORY`` the robots it names run their agents on its hosts over SSH (:mod:`deploy.remote`,
  children of the same :class:`Fleet`), the router listening on the inventory's ``zenoh.router``.

The simulated world (:class:`simulator.world.World`) runs in the launcher's own process on a
client session, so progress is shown as it goes; the fault driver (:mod:`simulator.faults`) kills
and restarts agents on its ticks and the status board (:mod:`simulator.status_board`) keeps each
leader's last status. When every goal is reached (or the duration is over) the agents get
SIGTERM, the launcher reads their counters (:mod:`simulator.counters`) and traces, and
:func:`simulator.summary.build_summary` makes ``summary.json`` (``mode: "multiprocess"``), which
the caller writes with the time series and the figures (:func:`simulator.output.write_run`).
A scenario with a fleet (lifelong operation) also runs the fleet manager in the launcher's
process (:func:`simulator.manager.run_manager`): each tick it posts the orders due, and the
world takes every order the book holds (:meth:`simulator.world.World.post_order`) and keeps the
loads (:mod:`simulator.world_loads`). The run ends when every order is done and none is still to
come (or at the duration; ``--hold`` keeps it up); ``orders.csv``, ``loads.csv`` and
``orders.png`` are written into the run's folder, and ``summary.json`` gains ``orders`` and the
loads' collisions, as ``formation sim`` writes them (:func:`simulator.lifelong.write_orders`).
Every child is stopped (SIGTERM to its process group, SIGKILL after a timeout) on every way out:
success, Ctrl-C or SIGTERM, a crashed child, an exception. ``DIR/processes.json`` lists the
children's PIDs; ``DIR/logs/`` holds their output.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import signal
import threading
from collections.abc import Callable
from contextlib import ExitStack
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import zenoh

from agent.config import AgentConfig, build_agent_configs
from leader import orders as lo
from runtime.ports import free_tcp_port, tcp_endpoint
from scenario.lifelong import Lifelong
from wire import acl, keys
from wire.zconf import ZenohSettings

from .access import MANAGER_FILE, RunCredentials, secure_setup, zone_link
from .bases import run_bases, with_rmw_bases
from .counters import agent_stats
from .faults import FAULT_WORLD_TIMEOUT_S, FaultDriver, fault_summary
from .fleet import START_TIMEOUT_S, Child, ChildFailed, Fleet, unique_children
from .fused import merge_estimates
from .goals import goals_sent, judge_by_goals_sent
from .lifelong import judge_orders, write_orders
from .manager import REFUSED, Entry, FleetManager, run_manager
from .run_config import RunConfig
from .series import Series
from .status_board import StatusBoard
from .summary import build_summary, mark_aborted
from .world import World, WorldOptions, WorldResult
from .world_loads import WorldLoads
from .zones import PoseZones

logger = logging.getLogger(__name__)

Observer = Callable[[zenoh.Session], Callable[[], None] | None]


@dataclass(frozen=True)
class _Hooks:
    """The caller's hooks into a run (see :func:`launch`) and the held run's stop flag."""

    progress_factory: Callable[[], Any] | None
    observer: Observer | None
    announce: Callable[[str], None] | None
    stop_requested: threading.Event
    keep: Callable[[WorldLoads], None] | None = None


@dataclass(frozen=True)
class _Outcome:
    """What the world's part of a run left: its result, why it stopped early (None if it did
    not), each leader's last status and the fault driver's events."""

    result: WorldResult
    stopped: BaseException | None
    board: dict[str, dict]
    events: list[dict]
    restarts: dict[str, int]  # robot -> its crashed agents restarted (--restart on-failure)
    sent: dict[str, dict] = field(default_factory=dict)  # the goals leaders took at run time
    loads: WorldLoads | None = None  # a lifelong run's loads and orders
    more: bool = False  # a lifelong run: the fleet manager had orders still to post


class RunAborted(RuntimeError):
    """A run that had started stopped early; ``summary`` (with ``aborted``) and ``series`` hold
    what it measured until then, for :func:`simulator.output.write_run`."""

    def __init__(self, reason: str, summary: dict, series: Series, cause: BaseException) -> None:
        super().__init__(reason)
        self.summary = summary
        self.series = series
        self.cause = cause

    @property
    def interrupted(self) -> bool:
        return isinstance(self.cause, KeyboardInterrupt)


def launch(config: RunConfig, *, progress_factory: Callable[[], Any] | None = None,
           observer: Observer | None = None,
           announce: Callable[[str], None] | None = None,
           keep: Callable[[WorldLoads], None] | None = None) -> tuple[dict, Series]:
    """Run ``config`` as separate processes; returns the summary and the time series.

    ``progress_factory()`` makes the progress display (a context manager with ``update``).
    ``observer(session)``, when given, is called with the world's session before the run (a live
    viewer subscribes on it) and returns what detaches it after. ``announce(endpoint)`` is called
    once every agent is up (the endpoint is also written to ``out/endpoint``). A held run
    (``config.hold``) ends normally, with its summary, on SIGINT/SIGTERM. A run that had started
    and stopped early raises :class:`RunAborted` with what it measured. ``keep(loads)``: a
    lifelong run's world loads and orders (:class:`simulator.world_loads.WorldLoads`) once the
    run is over, stopped early or not (their :meth:`~simulator.world_loads.WorldLoads.board` is
    the recording's)."""
    hooks = _Hooks(progress_factory, observer, announce, threading.Event(), keep)
    _fresh_folders(config.out)
    previous_int = None
    if config.hold and threading.current_thread() is threading.main_thread():
        previous_int = signal.signal(signal.SIGINT, lambda _s, _f: hooks.stop_requested.set())
    try:
        return _launch(config, hooks)
    finally:
        if previous_int is not None:
            signal.signal(signal.SIGINT, previous_int)


def _fresh_folders(out: Path) -> None:
    """``out``'s folders for the agents' configurations, counters and logs, no old counters."""
    for sub in ("configs", "agents", "logs"):
        (out / sub).mkdir(parents=True, exist_ok=True)
    for old in (out / "agents").glob("*.json"):
        old.unlink()


def _launch(cfg: RunConfig, hooks: _Hooks) -> tuple[dict, Series]:
    """:func:`launch` once its folders are made: the router's endpoint, and the remote hosts
    tidied on every way out."""
    if cfg.remote is not None:  # the router listens where the other hosts reach it
        endpoint = cfg.remote.endpoint
        port = int(endpoint.rsplit(":", 1)[1])
    else:
        port = cfg.port or free_tcp_port()
        endpoint = tcp_endpoint(port)
    try:
        return _launch_fleet(cfg, hooks, endpoint, port)
    finally:
        if cfg.remote is not None:
            try:  # an early way out: the agents there have stopped; remove the run's files
                cfg.remote.collect(cfg.out)
            except Exception:  # best effort on a way out that already failed
                logger.warning("could not tidy the run's files on the other hosts", exc_info=True)


def _launch_fleet(cfg: RunConfig, hooks: _Hooks, endpoint: str,
                  port: int) -> tuple[dict, Series]:
    """The run's fleet, from its router to the summary (see :func:`launch`)."""
    with Fleet(cfg.out / "logs") as fleet, ExitStack() as own:
        creds = (secure_setup(cfg.scenario, cfg.out / "secure", endpoint,
                              zone_link(own) if cfg.pose_zones else None, cfg.rmw_base)
                 if cfg.secure else None)
        router = _start_router(fleet, endpoint, port, creds)
        camera = [_start_camera(fleet, cfg, endpoint, creds)] if cfg.camera == "process" else []
        zones, configs = _agent_configs(own, cfg, endpoint, creds)
        agents = _start_agents(fleet, cfg, configs, _agent_args(cfg, creds))
        fleet.write_pids(cfg.out / "processes.json")
        outcome = _run_world(cfg, hooks, fleet, endpoint, creds, zones, agents)
        # the agents write their counters on SIGTERM (also after the router died); router last
        fleet.shut_down(unique_children(agents.values()), router, camera)  # a host once
    if cfg.remote is not None:
        cfg.remote.collect(cfg.out)  # the counters of the agents on other hosts, now stopped
    lost: list[dict[str, str]] = []  # counters a full disk kept from being written
    stats = [agent_stats(cfg.out / "agents" / f"{rid}.json", c, running=rid in agents,
                         lost_ok=outcome.stopped is not None, lost=lost)
             for rid, c in configs.items()]
    # a formation sent a goal at run time is judged at that goal, not the scenario's
    judged = judge_by_goals_sent(cfg.scenario, outcome.result, outcome.sent)
    summary, series = build_summary(judged, outcome.result, stats, cfg.topology,
                                    cfg.realtime, cfg.camera, cfg.safety, cfg.solver)
    if cfg.scenario.controller.localisation == "fused":  # the agents' own estimates
        series.robots, block = merge_estimates(cfg.scenario, series.robots, stats,
                                               outcome.result.stamps)
        summary.update(block)
    if lost:
        summary["lost_files"] = lost  # write_run adds what else does not fit
    if cfg.fault_run:
        summary["faults"] = fault_summary(cfg.faults, outcome.result, stats, outcome.events)
    if outcome.restarts:
        summary["restarts"] = outcome.restarts
    summary["secure"] = False if creds is None else creds.summary()
    summary.update(_run_options(cfg, outcome.board))
    if outcome.sent:
        summary["goals_sent"] = outcome.sent  # the goals the verdict and the figures use
    if outcome.loads is not None:
        _lifelong_outputs(cfg, summary, outcome.loads, outcome.more)
        if hooks.keep is not None:
            hooks.keep(outcome.loads)
    if outcome.stopped is not None:
        mark_aborted(summary, stats, outcome.stopped)
        raise RunAborted(summary["aborted"], summary, series, outcome.stopped)
    return summary, series


def _start_router(fleet: Fleet, endpoint: str, port: int, creds: RunCredentials | None) -> Child:
    """The run's Zenoh router; with credentials, its access control list and the zone link."""
    if creds is None:
        return fleet.start_router(endpoint, port, None, auth=None, also_listen=())
    return fleet.start_router(endpoint, port, creds.router_config, auth=creds.world,
                              also_listen=() if creds.zone is None else (creds.zone.link,))


def _agent_configs(own: ExitStack, cfg: RunConfig, endpoint: str, creds: RunCredentials | None
                   ) -> tuple[PoseZones | None, dict[str, AgentConfig]]:
    """Every robot's agent configuration, connected to the run's router or, with pose zones,
    to its zone's router (the zone routers are closed when ``own`` closes, after the agents
    stopped)."""
    zs = ZenohSettings(mode="client", connect=(endpoint,), multicast_scouting=False)
    configs = build_agent_configs(cfg.scenario, zenoh=zs, topology=cfg.topology,
                                  safety=cfg.safety, solver=cfg.solver)
    life = cfg.scenario.lifelong
    if life is not None:  # each fleet robot's agent knows the warehouse it serves
        configs = {rid: c if c.lifelong is not None else dataclasses.replace(c, lifelong=life)
                   for rid, c in configs.items()}
    if cfg.rmw_base is not None:  # each agent drives its base over rmw_zenoh; the world reads it
        configs = with_rmw_bases(configs, cfg.rmw_base)
    if not cfg.pose_zones:
        return None, configs
    pz = own.enter_context(PoseZones(cfg.scenario, cfg.pose_zones, endpoint,
                                     cfg.agents_per_process,
                                     security=None if creds is None else creds.zone))
    return pz, {rid: dataclasses.replace(c, zenoh=dataclasses.replace(
        c.zenoh, connect=(pz.endpoint_of(rid),))) for rid, c in configs.items()}


def _agent_args(cfg: RunConfig, creds: RunCredentials | None) -> Callable[[str], list[str]]:
    """Each robot's agent's options beyond its configuration: the clock, the faults, its
    credentials."""
    common = ([] if cfg.realtime else ["--lockstep"]) + cfg.faults.agent_args()

    def agent_args(rid: str) -> list[str]:
        return [*common, *([] if creds is None else ["--zenoh-auth", str(creds.files[rid])])]

    return agent_args


def _start_agents(fleet: Fleet, cfg: RunConfig, configs: dict[str, AgentConfig],
                  agent_args: Callable[[str], list[str]]) -> dict[str, Child]:
    """Every robot's agent: here, or on its host when ``cfg.remote`` places it there."""
    remote = cfg.remote
    elsewhere = set() if remote is None else remote.robots
    agents = fleet.start_agents({r: c for r, c in configs.items() if r not in elsewhere},
                                cfg.out, agent_args, per_process=cfg.agents_per_process,
                                shared_session=cfg.shared_session)
    if remote is not None:
        agents.update(remote.start(fleet, {r: c for r, c in configs.items() if r in elsewhere},
                                   cfg.out, agent_args, cfg.agents_per_process,
                                   cfg.shared_session))
    return agents


def world_options(cfg: RunConfig) -> WorldOptions:
    return WorldOptions(
        realtime=cfg.realtime, camera=cfg.camera, prefix=keys.DEFAULT_PREFIX,
        start_timeout=START_TIMEOUT_S,
        cmd_timeout=FAULT_WORLD_TIMEOUT_S if cfg.fault_run else WorldOptions.cmd_timeout,
        camera_dropouts=tuple((c.robot, c.at, c.at + c.duration)
                              for c in cfg.faults.camera_dropouts),
        pose_slots=cfg.pose_slots, clock_offset=cfg.clock_offset, stop_at_goal=not cfg.hold,
        engine=cfg.engine,
        rmw_bases=None if cfg.rmw_base is None else run_bases(cfg.scenario.robot_ids, cfg.rmw_base))


def _restart_limit(cfg: RunConfig) -> int:
    """Crashed agents restarted per robot: local agents one to a process (an agent host's
    argv is not one robot's), with ``--restart on-failure``."""
    return cfg.restart_limit if cfg.restart == "on-failure" and cfg.agents_per_process == 1 else 0


def _run_world(cfg: RunConfig, hooks: _Hooks, fleet: Fleet, endpoint: str,
               creds: RunCredentials | None, zones: PoseZones | None,
               agents: dict[str, Child]) -> _Outcome:
    """The world on the launcher's own session, from the agents' start to its last tick."""
    conf = ZenohSettings(mode="client", connect=(endpoint,), multicast_scouting=False,
                         connect_timeout_s=10.0,
                         auth=None if creds is None else creds.world).to_config()
    manager_auth = None if creds is None else creds.folder / MANAGER_FILE
    with zenoh.open(conf) as session, run_manager(cfg.scenario.lifelong, cfg.out, endpoint,
                                                  manager_auth, cfg.realtime) as manager:
        world = World(cfg.scenario, session, world_options(cfg),
                      () if zones is None else zones.sessions,
                      None if zones is None else zones.zone_of)
        if manager is not None:  # the book's yard as the world's loads: a status at its tick
            world.passed_on = manager.hear
        statuses = StatusBoard(session, keys.DEFAULT_PREFIX)
        detach = hooks.observer(session) if hooks.observer is not None else None
        driver = FaultDriver(cfg.faults, fleet, world, agents, cfg.scenario.dt, cfg.realtime,
                             _restart_limit(cfg))
        try:
            result, stopped = _drive(cfg, hooks, fleet, world, endpoint, driver, manager)
        finally:
            if detach is not None:
                detach()
            world.close()
            board = statuses.latest()  # each leader's last status
            sent = goals_sent(cfg.scenario, statuses.goals())
            statuses.close()
        life = cfg.scenario.lifelong
        more = manager is not None and life is not None and _more_orders(manager, life, cfg.hold)
    return _Outcome(result, stopped, board, driver.log, dict(driver.restarts), sent,
                    world.loads, more)


def _drive(cfg: RunConfig, hooks: _Hooks, fleet: Fleet, world: World, endpoint: str,
           driver: FaultDriver, manager: FleetManager | None
           ) -> tuple[WorldResult, BaseException | None]:
    """Wait for every agent, announce the fleet, run the world (with a fleet, its manager posts
    the orders due each tick); a run that had started and stopped early keeps what it measured
    (and says why)."""
    world.wait_for_agents(abort=fleet.check)

    def started() -> None:
        # inside the world's run: a Ctrl-C once the endpoint is out still leaves what was
        # measured (here, it once fell between this file and the run: exit 130, no summary)
        (cfg.out / "endpoint").write_text(endpoint + "\n", encoding="utf-8")
        if hooks.announce is not None:
            hooks.announce(endpoint)

    def abort() -> None:
        if cfg.hold and fleet.signalled is not None:
            hooks.stop_requested.set()  # SIGTERM ends a held run like Ctrl-C: normally
            return
        try:
            fleet.check()
        except ChildFailed:
            if not driver.recover():  # a crashed agent restarted: the run goes on
                raise

    on_tick: Callable[[int, float], None] | None = (
        driver.on_tick if cfg.fault_run or driver.restart_limit else None)
    life = cfg.scenario.lifelong
    if manager is not None and life is not None:
        on_tick = _order_hook(manager, world, on_tick)
        world.more_orders = lambda: _more_orders(manager, life, cfg.hold)
    try:
        return _world_loop(world, hooks, abort, on_tick, started), None
    except (ChildFailed, KeyboardInterrupt, TimeoutError) as exc:
        if world.result is None:
            raise
        return world.result, exc


def _world_loop(world: World, hooks: _Hooks, abort: Callable[[], None],
                on_tick: Callable[[int, float], None] | None,
                started: Callable[[], None]) -> WorldResult:
    stop = hooks.stop_requested.is_set
    if hooks.progress_factory is None:
        return world.run(abort=abort, on_tick=on_tick, stop=stop, started=started)
    with hooks.progress_factory() as progress:
        if world.loads is not None:  # the bar counts deliveries
            world.tally = getattr(progress, "orders", None)
        return world.run(progress=progress.update, abort=abort, on_tick=on_tick, stop=stop,
                         started=started)


def _order_hook(manager: FleetManager, world: World,
                then: Callable[[int, float], None] | None) -> Callable[[int, float], None]:
    """The world's ``on_tick(k, t)`` of a lifelong run: the fleet manager posts the orders due
    by ``t``, the world takes every order of the book it does not know yet (a client's too; one
    the book refused, failed with the book's reason), then ``then`` runs."""

    def tick(k: int, t: float) -> None:
        manager.tick(t)
        loads = world.loads
        if loads is not None:
            for entry in sorted(manager.entries().values(), key=lambda e: (e.t, e.order.oid)):
                sync_order(world, loads, entry, t)
        if then is not None:
            then(k, t)

    return tick


def sync_order(world: World, loads: WorldLoads, entry: Entry, t: float) -> None:
    """One order of the fleet manager's book into the world at ``t``: posted once (failed at
    once when the book refused it), its priority kept current, and a cancel the book took while
    it waited (no team says so on the wire) heard."""
    oid = entry.order.oid
    known = loads.orders.get(oid)
    if known is None:
        reason = entry.status.reason
        world.post_order(entry.order, t, reason if reason.startswith(REFUSED) else "")
        return
    loads.reprioritise(oid, entry.order.priority)
    if entry.status.state == lo.CANCELLED and known.state == lo.WAITING:
        world.hear(entry.status)


def _more_orders(manager: FleetManager, life: Lifelong, hold: bool) -> bool:
    """Whether the fleet manager has orders of ``life`` still to post: a scenario order not yet
    due, a stream still running, or a held run (clients may post until it is stopped)."""
    book = manager.book
    if hold:
        return True
    if any(o.id not in book.entries for o in life.orders):
        return True
    return life.stream is not None and book.t < life.stream.until


def _lifelong_outputs(cfg: RunConfig, summary: dict, loads: WorldLoads, more: bool) -> None:
    """A lifelong run's verdict and ``orders`` in ``summary``, its loads' collisions counted,
    and its order files written (:func:`simulator.lifelong.write_orders`)."""
    judge_orders(summary, loads.orders, more)
    summary["orders"] = loads.summary(summary["sim_time_s"])
    lost = write_orders(cfg.out, summary, loads.orders, loads.rows, loads.checks.events,
                        cfg.plots)
    if lost:
        summary.setdefault("lost_files", []).extend(lost)


def _run_options(cfg: RunConfig, board: dict[str, dict]) -> dict:
    """The summary fields of the options a run used beyond the defaults; ``hold`` (a held run)
    and ``formations_status`` (each leader's last status)."""
    extra: dict = {}
    if cfg.remote is not None:
        extra["remote"] = cfg.remote.summary()  # which host ran which robots
    if cfg.pose_zones:
        extra["pose_zones"] = cfg.pose_zones
    if cfg.camera == "process":
        extra["camera_process"] = _camera_stats(cfg.out / "logs" / "camera.log")
    if cfg.pose_slots > 1:
        extra["pose_slots"] = cfg.pose_slots  # the world spread each period's poses over these
    if cfg.agents_per_process > 1 or cfg.shared_session:
        extra["agents_per_process"] = cfg.agents_per_process
        extra["shared_session"] = cfg.shared_session
    if cfg.hold:
        extra["hold"] = True
    if board:
        extra["formations_status"] = board
    return extra


def _start_camera(fleet: Fleet, cfg: RunConfig, endpoint: str,
                  creds: RunCredentials | None) -> Child:
    """``--camera process``: write the camera process's files into ``out/camera`` and start it
    (logging in as the camera user when secure)."""
    # lazily: keeps OpenCV (the camera's renderer) off the runs that start no camera process
    from camera_service.simcam import FramePublisher, write_camera_files

    assert cfg.scenario_path is not None  # RunConfig checks it with --camera process
    geometry = FramePublisher(cfg.scenario, None, keys.DEFAULT_PREFIX)
    config = write_camera_files(geometry, cfg.scenario, cfg.scenario_path, cfg.out / "camera",
                                endpoint, keys.DEFAULT_PREFIX)
    argv = ["-m", "camera_service", str(config)]
    if creds is not None:
        path = cfg.out / "secure" / "camera.credentials"
        acl.write_credentials(path, creds.world)
        argv += ["--auth", str(path)]
    return fleet.start("camera", argv)


def _camera_stats(log: Path) -> dict | None:
    """The counters the camera process printed as its last line (None if it printed none)."""
    try:
        lines = log.read_text(encoding="utf-8", errors="replace").strip().splitlines()
        return json.loads(lines[-1])["camera"] if lines else None
    except (OSError, ValueError, KeyError, TypeError):
        return None
