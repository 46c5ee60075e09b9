"""``formation run``: the multi-process simulation over Zenoh (DESIGN.md, "Command line").

The launcher validates the scenario, picks a loopback port, and starts, each in its own process
group (``start_new_session``) with explicit ``tcp/127.0.0.1:PORT`` endpoints and multicast
scouting off:

* a Zenoh router (``python -m runtime.router``);
* one agent per robot (``python -m agent --config DIR/configs/ROBOT.yaml``, ``--lockstep`` unless
  ``--realtime``), each writing its counters to ``DIR/agents/ROBOT.json`` when it stops. With
  ``--agents-per-process K`` the agents run K to an agent host (``python -m agent.host``, child
  ``host-I``; :mod:`agent.host`), one Zenoh session per host unless ``--session-per-agent`` or
  ``--secure``; each robot keeps its own configuration, keys and counters file. With ``--hosts
  INVENTORY`` the robots it names run their agents on its hosts over SSH (:mod:`deploy.remote`,
  children of the same :class:`Fleet`), the router listening on the inventory's ``zenoh.router``.

The simulated world (:class:`simulator.world.World`) runs in the launcher's own process on a
client session, so progress is shown as it goes. When every goal is reached (or the duration is
over) the agents get SIGTERM, the launcher collects their counters and traces, and writes
``summary.json`` (``mode: "multiprocess"``), the time series and the figures with
:func:`simulator.output.write_run`. Every child is stopped (SIGTERM to its process group, SIGKILL
after a timeout) on every way out: success, Ctrl-C or SIGTERM, a crashed child, an exception.
``DIR/processes.json`` lists the children's PIDs; ``DIR/logs/`` holds their output.

Faults (:class:`FaultPlan`, docs/faults.md): ``--drop P`` and ``--delay-ms D`` are handed to every
agent, which applies them to the ``state``, ``ellipse`` and ``others`` messages it receives
(seeded by ``--fault-seed``); ``--kill ROBOT@T[:AFTER]`` SIGKILLs that robot's agent at simulated
time ``T`` and, with ``AFTER``, starts a new one ``AFTER`` seconds later (in lock-step the world
waits for it to subscribe, so the restart takes no simulated time beyond ``AFTER``);
``--camera-dropout ROBOT@T:DURATION`` makes the world stop publishing that robot's pose. Fault
runs keep the lock-step clock with short timeouts (agents 0.3 s per input, world 1.5 s per tick of
commands): a loss is known to the receiver's simulation at once, a silent process costs one
timeout and is then not waited for until it speaks again. ``summary.json`` gains ``faults``.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import shutil
import signal
import statistics
import tempfile
import threading
import time
from collections.abc import Callable, Sequence
from contextlib import ExitStack
from dataclasses import dataclass
from pathlib import Path

import zenoh

from agent.config import build_agent_configs
from agent.faults import LinkFaults
from runtime.ports import free_tcp_port, tcp_endpoint
from scenario import Scenario
from scenario.succession import formation_successor
from wire import acl, keys, traffic
from wire.payloads import DecodeError, decode_status
from wire.stamps import merge_counts
from wire.zconf import UsrPwdAuth, ZenohSettings

from .fleet import (
    START_TIMEOUT_S,
    STOP_TIMEOUT_S,
    Child,
    ChildFailed,
    Fleet,
    RemoteAgents,
    signal_group,
    unique_children,
)
from .inprocess import ROBOT_COLUMNS, Series
from .motion import motion_fields
from .output import OutputError
from .summary import qp_fields, run_summary
from .world import World, WorldOptions, WorldResult
from .zones import PoseZones, ZoneSecurity

logger = logging.getLogger(__name__)

# control traffic between robots: the classes the topology decides, and the leader's plans to
# its members (sent only when a goal arrives at run time, and then once a second)
INTER_ROBOT = (keys.STATE, keys.ELLIPSE, keys.OTHERS, keys.PLAN, keys.BEACON)
FAULT_AGENT_TIMEOUT_S = 0.3  # [s] lock-step wait per input of an agent in a fault run
FAULT_WORLD_TIMEOUT_S = 1.5  # [s] lock-step wait for a tick's commands in a fault run


@dataclass(frozen=True)
class Kill:
    """SIGKILL ``robot``'s agent at simulated time ``at``; restart it ``restart_after`` later."""

    robot: str
    at: float  # [s]
    restart_after: float | None = None  # [s]; None: it stays dead


@dataclass(frozen=True)
class CameraDropout:
    """The world publishes no pose of ``robot`` from ``at`` for ``duration`` seconds."""

    robot: str
    at: float  # [s]
    duration: float  # [s]


@dataclass(frozen=True)
class FaultPlan:
    """Every fault of one run; the default is none (the run equals ``formation sim``)."""

    drop: float = 0.0  # probability
    delay_ms: float = 0.0  # [ms]
    seed: int = 0
    kills: tuple[Kill, ...] = ()
    camera_dropouts: tuple[CameraDropout, ...] = ()
    ellipse_hold: float = 10.0  # [s] see agent.node.NodeOptions

    def __post_init__(self) -> None:
        LinkFaults(self.drop, self.delay_ms / 1000.0, self.seed)  # ValueError naming the field
        for k in self.kills:
            if not (math.isfinite(k.at) and k.at >= 0):
                raise ValueError(f"kill: {k.robot}: time must be >= 0, got {k.at!r}")
            if k.restart_after is not None and not (math.isfinite(k.restart_after)
                                                    and k.restart_after > 0):
                raise ValueError(f"kill: {k.robot}: restart delay must be > 0, "
                                 f"got {k.restart_after!r}")
        for c in self.camera_dropouts:
            if not (math.isfinite(c.at) and c.at >= 0 and math.isfinite(c.duration)
                    and c.duration > 0):
                raise ValueError(f"camera-dropout: {c.robot}: need time >= 0 and duration > 0")

    @property
    def active(self) -> bool:
        return bool(self.drop or self.delay_ms or self.kills or self.camera_dropouts)

    @property
    def link(self) -> LinkFaults:
        return LinkFaults(self.drop, self.delay_ms / 1000.0, self.seed)

    def check_robots(self, robots: Sequence[str]) -> None:
        """ValueError naming a fault that names an unknown robot."""
        for name, items in (("kill", self.kills), ("camera-dropout", self.camera_dropouts)):
            for item in items:
                if item.robot not in robots:
                    raise ValueError(f"{name}: unknown robot {item.robot!r}")


def _number(text: str, what: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise ValueError(f"{what}: {text!r} is not a number") from None
    if not math.isfinite(v):
        raise ValueError(f"{what}: {text!r} is not a finite number")
    return v


def parse_kill(text: str) -> Kill:
    """``ROBOT@T`` or ``ROBOT@T:RESTART_AFTER`` (seconds of simulated time)."""
    robot, sep, rest = text.partition("@")
    if not sep or not robot:
        raise ValueError(f"kill: {text!r} is not ROBOT@T[:RESTART_AFTER]")
    at, sep, after = rest.partition(":")
    return Kill(robot, _number(at, "kill"), _number(after, "kill") if sep else None)


def parse_camera_dropout(text: str) -> CameraDropout:
    """``ROBOT@T:DURATION`` (seconds of simulated time)."""
    robot, sep, rest = text.partition("@")
    at, sep2, duration = rest.partition(":")
    if not (sep and sep2 and robot):
        raise ValueError(f"camera-dropout: {text!r} is not ROBOT@T:DURATION")
    return CameraDropout(robot, _number(at, "camera-dropout"), _number(duration, "camera-dropout"))


def launch(
    scenario: Scenario,
    out: Path,
    *,
    realtime: bool = False,
    camera: str = "truth",
    topology: str = "reduced",
    safety: bool = True,
    port: int = 0,
    progress_factory=None,
    faults: FaultPlan | None = None,
    secure: bool = True,
    pose_slots: int = 1,
    observer=None,
    scenario_path: str | Path | None = None,
    clock_offset: float = 0.0,
    agents_per_process: int = 1,
    shared_session: bool = False,
    solver: str = "exact",
    hold: bool = False,
    announce=None,
    remote: RemoteAgents | None = None,
    pose_zones: int = 0,
) -> tuple[dict, Series]:
    """Run ``scenario`` as separate processes; returns the summary and the time series.

    ``faults`` injects the faults of :class:`FaultPlan`; ``secure`` runs the router with
    user/password authentication and the access control list of :mod:`wire.acl`, every process
    logging in as itself. ``pose_slots`` is the world's (:class:`simulator.world.WorldOptions`:
    real time only). ``solver`` is the agents' QP solver (:func:`agent.qp.make_solver`).
    ``observer(session)``, when given, is called with the world's session
    before the run (a live viewer subscribes on it) and returns what detaches it after.
    ``camera="process"`` also starts the real camera process
    (``python -m camera_service``) on the frames the world renders; it reads the static obstacles
    from ``scenario_path``.

    ``agents_per_process`` K > 1 runs the agents K to an agent host (:mod:`agent.host`;
    ``shared_session``: one Zenoh session per host); killing an agent (``--kill``) then needs K = 1.
    ``hold`` keeps the fleet up after every goal is reached, until the scenario's duration or
    SIGINT/SIGTERM (which then end the run normally, with its summary); ``announce(endpoint)`` is
    called once every agent is up (the endpoint is also written to ``out/endpoint``). The
    summary's ``formations_status`` holds each leader's last status. ``pose_zones`` Z > 0 carries
    the poses and commands through Z zone routers of the world's process
    (:mod:`simulator.zones`; with ``secure`` they hold the run's access control list).

    ``remote`` places the agents of ``remote.robots`` on other hosts (``formation run --hosts``,
    :mod:`deploy.remote`): the router then listens on ``remote.endpoint``, those agents are
    children of the same :class:`Fleet` (started, watched and stopped with the others), their
    counters are copied back before the summary is made, and the summary gains ``remote``."""
    faults = faults or FaultPlan()
    if camera == "process" and scenario_path is None:
        raise ValueError("scenario_path: --camera process needs the scenario file")
    faults.check_robots(scenario.robot_ids)
    _check_hosting(agents_per_process, shared_session, faults, secure)
    if remote is not None:
        for k in faults.kills:
            if k.robot in remote.robots:
                raise ValueError(f"kill: {k.robot} runs on another host (--hosts); kills need "
                                 f"an agent on this machine")
    out = Path(out)
    for sub in ("configs", "agents", "logs"):
        (out / sub).mkdir(parents=True, exist_ok=True)
    for old in (out / "agents").glob("*.json"):
        old.unlink()
    stop_requested = threading.Event()
    previous_int = None
    if hold and threading.current_thread() is threading.main_thread():
        previous_int = signal.signal(signal.SIGINT, lambda _s, _f: stop_requested.set())
    try:
        summary, series = _launch(scenario, out, realtime, camera, topology, safety, port,
                                  progress_factory, faults, secure, pose_slots, observer, hold,
                                  announce, stop_requested, scenario_path,
                                  clock_offset=clock_offset, agents_per_process=agents_per_process,
                                  shared_session=shared_session, solver=solver, remote=remote,
                                  pose_zones=pose_zones)
    finally:
        if previous_int is not None:
            signal.signal(signal.SIGINT, previous_int)
    return summary, series


def _launch(scenario: Scenario, out: Path, realtime: bool, camera: str, topology: str,
            safety: bool, port: int, progress_factory, faults: FaultPlan, secure: bool,
            pose_slots: int, observer, hold: bool, announce,
            stop_requested: threading.Event,
            scenario_path: str | Path | None, *, clock_offset: float, agents_per_process: int,
            shared_session: bool, solver: str,
            remote: RemoteAgents | None = None, pose_zones: int = 0) -> tuple[dict, Series]:
    """:func:`launch` once its arguments are checked and its folders made."""
    if remote is not None:  # the router listens where the other hosts reach it
        endpoint = remote.endpoint
        port = int(endpoint.rsplit(":", 1)[1])
    else:
        port = port or free_tcp_port()
        endpoint = tcp_endpoint(port)
    try:
        return _launch_fleet(scenario, out, realtime, camera, topology, safety, port, endpoint,
                             progress_factory, faults, secure, pose_slots, observer, hold,
                             announce, stop_requested, scenario_path, clock_offset=clock_offset,
                             agents_per_process=agents_per_process, shared_session=shared_session,
                             solver=solver, remote=remote, pose_zones=pose_zones)
    finally:
        if remote is not None:
            try:  # an early way out: the agents there have stopped; remove the run's files
                remote.collect(out)
            except Exception:  # noqa: BLE001 - best effort on a way out that already failed
                logger.warning("could not tidy the run's files on the other hosts", exc_info=True)


def _launch_fleet(scenario: Scenario, out: Path, realtime: bool, camera: str, topology: str,
                  safety: bool, port: int, endpoint: str, progress_factory, faults: FaultPlan,
                  secure: bool, pose_slots: int, observer, hold: bool, announce,
                  stop_requested: threading.Event, scenario_path: str | Path | None, *,
                  clock_offset: float, agents_per_process: int, shared_session: bool,
                  solver: str, remote: RemoteAgents | None,
                  pose_zones: int = 0) -> tuple[dict, Series]:
    """The run's fleet, from its router to the summary (see :func:`launch`)."""
    stopped: BaseException | None = None  # why a started run ended early
    fault_run = faults.active
    with Fleet(out / "logs") as fleet, ExitStack() as own:

        def abort() -> None:
            if hold and fleet.signalled is not None:
                stop_requested.set()  # SIGTERM ends a held run like Ctrl-C: normally
                return
            fleet.check()

        creds = (_secure_setup(scenario, out / "secure", endpoint,
                               _zone_link(own) if pose_zones else None) if secure else None)
        router = fleet.start_router(endpoint, port, None if creds is None else creds.router_config,
                                    auth=None if creds is None else creds.world,
                                    also_listen=() if creds is None or creds.zone is None
                                    else (creds.zone.link,))
        camera_child = None
        if camera == "process" and scenario_path is not None:  # checked above
            camera_child = _start_camera(fleet, scenario, scenario_path, out, endpoint, creds)
        zs = ZenohSettings(mode="client", connect=(endpoint,), multicast_scouting=False)
        configs = build_agent_configs(scenario, zenoh=zs, topology=topology, safety=safety,
                                      solver=solver)
        zones, configs = _open_zones(own, scenario, pose_zones, endpoint, agents_per_process,
                                     creds, configs)

        def agent_args(rid: str) -> list[str]:
            argv = [] if realtime else ["--lockstep"]
            if fault_run:
                argv += ["--drop", repr(faults.drop), "--delay-ms", repr(faults.delay_ms),
                         "--fault-seed", str(faults.seed), "--ellipse-hold", repr(faults.ellipse_hold),
                         "--lockstep-timeout", repr(FAULT_AGENT_TIMEOUT_S)]
            if creds is not None:
                argv += ["--zenoh-auth", str(creds.files[rid])]
            return argv

        agents = _start_agents(fleet, configs, out, agent_args, agents_per_process,
                               shared_session, remote)
        fleet.write_pids(out / "processes.json")
        conf = ZenohSettings(mode="client", connect=(endpoint,), multicast_scouting=False,
                                 connect_timeout_s=10.0,
                                 auth=None if creds is None else creds.world).to_config()
        options = WorldOptions(
            realtime=realtime, camera=camera, prefix=keys.DEFAULT_PREFIX,
            start_timeout=START_TIMEOUT_S,
            cmd_timeout=FAULT_WORLD_TIMEOUT_S if fault_run else WorldOptions.cmd_timeout,
            camera_dropouts=tuple((c.robot, c.at, c.at + c.duration)
                                  for c in faults.camera_dropouts),
            pose_slots=pose_slots, clock_offset=clock_offset, stop_at_goal=not hold)
        with zenoh.open(conf) as session:
            world = World(scenario, session, options, () if zones is None else zones.sessions,
                          None if zones is None else zones.zone_of)
            statuses = StatusBoard(session, keys.DEFAULT_PREFIX)
            detach = observer(session) if observer is not None else None
            driver = _FaultDriver(faults, fleet, world, agents, scenario.dt, realtime)
            try:
                world.wait_for_agents(abort=fleet.check)
                (out / "endpoint").write_text(endpoint + "\n", encoding="utf-8")
                if announce is not None:
                    announce(endpoint)
                try:
                    result = _run_world(world, progress_factory, abort,
                                        driver.on_tick if fault_run else None, stop_requested.is_set)
                except (ChildFailed, KeyboardInterrupt, TimeoutError) as exc:
                    if world.result is None:
                        raise
                    result, stopped = world.result, exc  # the run started: keep what it measured
            finally:
                if detach is not None:
                    detach()
                world.close()
                board = statuses.latest()  # each leader's last status
                statuses.close()
        # the agents write their counters on SIGTERM (also after the router died); router last
        fleet.shut_down(unique_children(agents.values()), router,  # a host once
                        [] if camera_child is None else [camera_child])
    if remote is not None:
        remote.collect(out)  # the counters of the agents on other hosts, now they have stopped
    stats = [_stats_of(out / "agents" / f"{rid}.json", cfg, lost_ok=stopped is not None)
             if rid in agents else _dead_stats(cfg) for rid, cfg in configs.items()]
    summary, series = build_summary(scenario, result, stats, topology, realtime, camera, safety,
                                    solver)
    if fault_run:
        summary["faults"] = fault_summary(faults, result, stats, driver.log)
    summary["secure"] = False if creds is None else creds.summary()
    summary.update(_run_options(out, camera, pose_slots, agents_per_process, shared_session,
                                pose_zones, remote))
    _navigation_fields(summary, hold, board)
    if stopped is not None:
        _mark_aborted(summary, stats, stopped)
        raise RunAborted(summary["aborted"], summary, series, stopped)
    return summary, series


def _start_agents(fleet: Fleet, configs: dict, out: Path, agent_args: Callable[[str], list[str]],
                  per_process: int, shared_session: bool,
                  remote: RemoteAgents | None) -> dict[str, Child]:
    """Every robot's agent: here, or on its host when ``remote`` places it there."""
    elsewhere = set() if remote is None else remote.robots
    agents = fleet.start_agents({r: c for r, c in configs.items() if r not in elsewhere}, out,
                                agent_args, per_process=per_process, shared_session=shared_session)
    if remote is not None:
        agents.update(remote.start(fleet, {r: c for r, c in configs.items() if r in elsewhere},
                                   out, agent_args, per_process, shared_session))
    return agents


def _zone_link(own: ExitStack) -> str:
    """A Unix-socket endpoint in a fresh private folder (mode 0700, removed when ``own``
    closes) for the zone routers' link to the run's router (:data:`wire.acl.ZONE_LINK`)."""
    sockets = Path(tempfile.mkdtemp(prefix="formation-zones-"))
    own.callback(shutil.rmtree, sockets, ignore_errors=True)
    return f"{acl.ZONE_LINK}/{sockets / 'router.sock'}"


def _open_zones(own: ExitStack, scenario: Scenario, zones: int, endpoint: str, per_process: int,
                creds: _Secure | None, configs: dict) -> tuple[PoseZones | None, dict]:
    """``zones`` > 0: the zone routers (closed when ``own`` closes, after the agents stopped)
    and the agent configurations connecting each agent to its zone's; else (None, configs)."""
    if not zones:
        return None, configs
    pz = own.enter_context(PoseZones(scenario, zones, endpoint, per_process,
                                     security=None if creds is None else creds.zone))
    return pz, {rid: dataclasses.replace(c, zenoh=dataclasses.replace(
        c.zenoh, connect=(pz.endpoint_of(rid),))) for rid, c in configs.items()}


def _run_options(out: Path, camera: str, pose_slots: int, agents_per_process: int,
                 shared_session: bool, pose_zones: int = 0,
                 remote: RemoteAgents | None = None) -> dict:
    """The summary fields of the options a run used beyond the defaults."""
    extra: dict = {}
    if remote is not None:
        extra["remote"] = remote.summary()  # which host ran which robots
    if pose_zones:
        extra["pose_zones"] = pose_zones
    if camera == "process":
        extra["camera_process"] = _camera_stats(out / "logs" / "camera.log")
    if pose_slots > 1:
        extra["pose_slots"] = pose_slots  # the world spread each period's poses over this many
    if agents_per_process > 1 or shared_session:
        extra["agents_per_process"] = agents_per_process
        extra["shared_session"] = shared_session
    return extra


def _check_hosting(agents_per_process: int, shared_session: bool, faults: FaultPlan,
                   secure: bool) -> None:
    """ValueError where the agent-host options cannot run together."""
    if agents_per_process < 1:
        raise ValueError(f"agents per process: need an integer >= 1, got {agents_per_process!r}")
    if faults.kills and agents_per_process > 1:
        raise ValueError("kill: an agent host runs several robots; kills need one agent per process")
    if shared_session and secure:
        raise ValueError("shared session: each robot logs in as itself with secure; not both")


def _navigation_fields(summary: dict, hold: bool, board: dict[str, dict]) -> None:
    """``hold`` (a held run) and ``formations_status`` (each leader's last status)."""
    if hold:
        summary["hold"] = True
    if board:
        summary["formations_status"] = board


class StatusBoard:
    """The newest ``status`` of every formation's leader, heard on the launcher's session."""

    def __init__(self, session: zenoh.Session, prefix: str) -> None:
        self._lock = threading.Lock()
        self._latest: dict[str, dict] = {}
        self._sub = session.declare_subscriber(f"{prefix}/formation/*/status", self._on_status)

    def _on_status(self, sample: zenoh.Sample) -> None:
        try:
            s = decode_status(sample.payload.to_bytes())
        except DecodeError:
            return
        with self._lock:
            self._latest[s.formation] = {
                "state": s.state, "goal": [s.gx, s.gy], "heading": s.heading,
                "distance_m": s.distance, "waypoint": s.waypoint, "waypoints": s.waypoints,
                "leader": s.leader, "stamp": s.stamp}

    def latest(self) -> dict[str, dict]:
        with self._lock:
            return {k: dict(v) for k, v in sorted(self._latest.items())}

    def close(self) -> None:
        try:
            self._sub.undeclare()
        except Exception:  # noqa: BLE001 - the session may be closing
            logger.debug("status board undeclare failed", exc_info=True)


def _start_camera(fleet: Fleet, scenario: Scenario, scenario_path: str | Path, out: Path,
                  endpoint: str, creds: _Secure | None) -> Child:
    """``--camera process``: write the camera process's files into ``out/camera`` and start it
    (logging in as the camera user when secure)."""
    from camera_service.simcam import FramePublisher, write_camera_files

    geometry = FramePublisher(scenario, None, keys.DEFAULT_PREFIX)
    config = write_camera_files(geometry, scenario, scenario_path, out / "camera", endpoint,
                                keys.DEFAULT_PREFIX)
    argv = ["-m", "camera_service", str(config)]
    if creds is not None:
        path = out / "secure" / "camera.credentials"
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
def _run_world(world: World, progress_factory, abort: Callable[[], None], on_tick,
               stop: Callable[[], bool]) -> WorldResult:
    if progress_factory is None:
        return world.run(abort=abort, on_tick=on_tick, stop=stop)
    with progress_factory() as progress:
        return world.run(progress=progress.update, abort=abort, on_tick=on_tick, stop=stop)


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


def abort_reason(exc: BaseException) -> str:
    """``aborted`` of summary.json: why the run stopped early, in one line."""
    if isinstance(exc, KeyboardInterrupt):
        return f"interrupted ({exc.args[0] if exc.args else 'Ctrl-C'})"
    return f"{exc}".splitlines()[0] if str(exc) else type(exc).__name__


def _mark_aborted(summary: dict, stats: list[dict], exc: BaseException) -> None:
    summary["aborted"] = abort_reason(exc)
    lost = sorted(s["robot"] for s in stats if s.get("counters_lost"))
    if lost:
        summary["aborted_counters_lost"] = lost


def _stats_of(path: Path, cfg, lost_ok: bool) -> dict:
    """An agent's counters; in an aborted run an agent that wrote none (it died with the run)
    counts as lost instead of failing the summary."""
    if lost_ok and not path.is_file():
        return {**_dead_stats(cfg), "killed": False, "counters_lost": True}
    return _read_stats(path)


@dataclass(frozen=True)
class _Secure:
    router_config: Path
    files: dict[str, Path]  # robot -> its credentials file
    world: UsrPwdAuth
    folder: Path
    zone: ZoneSecurity | None = None  # with pose zones: what the zone routers need

    def summary(self) -> dict:
        """``secure`` of summary.json."""
        return {"auth": "usrpwd", "acl": str(self.router_config),
                "manager": str(self.folder / MANAGER_FILE), "viewer": str(self.folder / VIEWER_FILE)}


MANAGER_FILE = "manager.json5"  # in OUT/secure: the fleet manager's credentials (goals)
VIEWER_FILE = "viewer.json5"  # in OUT/secure: a read-only viewer's credentials


def _secure_setup(scenario: Scenario, folder: Path, endpoint: str,
                  zone_link: str | None = None) -> _Secure:
    """Fresh credentials for the world (as the camera user), every robot, the fleet manager and
    a viewer; the router's dictionary and its configuration with the fleet's access control
    list (:mod:`wire.acl`), all in ``folder`` (mode 0700, files 0600). ``manager.json5`` and
    ``viewer.json5`` are Zenoh configuration fragments (the router's endpoint, the user and
    password) that client commands take with ``--auth FILE`` (``viewer.credentials``, the
    viewer's ``user:password`` line, is kept for older scripts). ``zone_link``: pose zones; the
    router also listens there (a Unix socket in a private folder) for the zone routers, which log
    in as :data:`wire.acl.ZONE_USER`."""
    folder.mkdir(parents=True, exist_ok=True)
    folder.chmod(0o700)
    for old in folder.iterdir():  # a previous run's credentials are void
        if old.is_file():
            old.unlink()
    robots = {rid: scenario.formation_of(rid).name for rid in scenario.robot_ids}
    leaders = {f.name: f.leader for f in scenario.formations}
    successors = {f.name: s for f in scenario.formations
                  if (s := formation_successor(f)) is not None}
    services = [acl.CAMERA_USER, acl.MANAGER_USER, acl.VIEWER_USER]
    creds = acl.new_credentials([*services, *([acl.ZONE_USER] if zone_link else []), *robots])
    dictionary = folder / "users.txt"
    acl.write_dictionary(dictionary, creds)
    acl.write_credentials(folder / "viewer.credentials", creds[acl.VIEWER_USER])
    files = {}
    for rid in robots:
        files[rid] = folder / f"{rid}.credentials"
        acl.write_credentials(files[rid], creds[rid])
    for name, user in ((MANAGER_FILE, acl.MANAGER_USER), (VIEWER_FILE, acl.VIEWER_USER)):
        acl.write_client_file(folder / name, creds[user], [endpoint])
    router_conf = folder / "router.json5"
    rules = acl.fleet_acl(robots, leaders, keys.DEFAULT_PREFIX, successors=successors,
                          zone_user=acl.ZONE_USER if zone_link else None)
    acl.write_router_config(router_conf, acl.router_config(
        [endpoint, *([zone_link] if zone_link else [])], rules, dictionary.resolve()))
    zone = None if zone_link is None else ZoneSecurity(rules, dictionary.resolve(), zone_link,
                                                       creds[acl.ZONE_USER])
    return _Secure(router_conf, files, creds[acl.CAMERA_USER], folder, zone)


class _FaultDriver:
    """Kills and restarts agents at their simulated times (``World.run(on_tick=...)``)."""

    def __init__(self, plan: FaultPlan, fleet: Fleet, world: World, agents: dict[str, Child],
                 dt: float, realtime: bool) -> None:
        self.fleet = fleet
        self.world = world
        self.agents = agents
        self.argv = fleet.agent_argv
        self.realtime = realtime
        self.log: list[dict] = []
        # (tick, order, action, robot): kills before restarts within a tick
        self.events: list[tuple[int, int, str, str]] = []
        for k in plan.kills:
            self.events.append((math.ceil(k.at / dt - 1e-9), 0, "kill", k.robot))
            if k.restart_after is not None:
                self.events.append((math.ceil((k.at + k.restart_after) / dt - 1e-9), 1,
                                    "restart", k.robot))
        self.events.sort()
        self.incarnation = dict.fromkeys(agents, 1)

    def on_tick(self, k: int, t: float) -> None:
        while self.events and self.events[0][0] <= k:
            _, _, action, rid = self.events.pop(0)
            if action == "kill":
                self.kill(rid, t)
            else:
                self.restart(rid, t)

    def kill(self, rid: str, t: float) -> None:
        child = self.agents.pop(rid, None)
        if child is None:
            logger.warning("kill %s at t=%.2f s: its agent is not running", rid, t)
            return
        signal_group(child.proc.pid, signal.SIGKILL)
        self.fleet.stop([child])  # reaps it, closes its log
        gone = self.world.wait_unsubscribed(rid)
        logger.info("killed agent %s at t=%.2f s (router saw it go: %s)", rid, t, gone)
        self.log.append({"event": "kill", "robot": rid, "t_s": round(t, 6)})

    def restart(self, rid: str, t: float) -> None:
        if rid in self.agents:
            logger.warning("restart %s at t=%.2f s: its agent is still running", rid, t)
            return
        self.incarnation[rid] += 1
        wall0 = time.monotonic()
        argv = self.argv[rid] + ([] if self.realtime else ["--sim-start", repr(t)])
        self.agents[rid] = self.fleet.start(f"agent-{rid}-{self.incarnation[rid]}", argv)
        if not self.realtime:  # lock-step: the restart takes no simulated time
            self.world.wait_for_agents(abort=self.fleet.check, robots=[rid], grace=False)
            self.world.inbox.expect(rid)  # and waits for its commands from the first tick
        self.log.append({"event": "restart", "robot": rid, "t_s": round(t, 6),
                         "start_wall_s": round(time.monotonic() - wall0, 3)})


def fault_summary(plan: FaultPlan, result: WorldResult, stats: list[dict], log: list[dict]) -> dict:
    """``faults`` of ``summary.json``: what was injected and what it did."""
    dropped = sum_counts(s.get("fault_dropped", {}) for s in stats)
    return {
        "drop": plan.drop,
        "delay_ms": plan.delay_ms,
        "seed": plan.seed,
        "applies_to": [keys.STATE, keys.ELLIPSE, keys.OTHERS],  # what agent.faults affects
        "dropped_messages": sum(dropped.values()),
        "dropped": dropped,
        "delayed_messages": sum(s.get("fault_delayed", 0) for s in stats),
        "kills": [{"robot": k.robot, "at_s": k.at, "restart_after_s": k.restart_after}
                  for k in plan.kills],
        "camera_dropouts": [{"robot": c.robot, "at_s": c.at, "duration_s": c.duration}
                            for c in plan.camera_dropouts],
        "events": log,
        "camera_dropped_poses": result.camera_dropped,
        "zero_commands_applied": result.missing_cmds,
        "world_cmd_timeouts": result.cmd_timeouts,
        "agent_lockstep_timeouts": sum(s.get("lockstep_timeouts", 0) for s in stats),
        "stale_ticks": sum(s["stale"] for s in stats),
        "stale_ticks_by_input": sum_counts(s.get("stale_why", {}) for s in stats),
        "stale_ticks_by_robot": {s["robot"]: s["stale"] for s in stats},
        "inflated_ellipse_ticks": sum(s.get("inflated", 0) for s in stats),
        "leader_takeovers": {s["robot"]: s["takeovers"] for s in stats if s.get("takeovers")},
        "acting_leader_ticks": sum(s.get("acting_leader_ticks", 0) for s in stats),
        "counters_lost_with_killed_agents": bool(plan.kills),
    }


def _dead_stats(cfg) -> dict:
    """Counters of a robot whose agent was killed and not restarted (it wrote none)."""
    return {
        "robot": cfg.robot_id, "formation": cfg.formation, "leader": cfg.leader is not None,
        "killed": True, "ticks": 0, "overruns": 0, "stale": 0, "waiting": 0,
        "lockstep_timeouts": 0, "solves": 0, "relaxed": 0, "fallback": 0, "failed": 0,
        "solve_us_median": None, "tick_us_median": None, "pose_age_us_median": None,
        "min_h": {"formation": None, "obstacle": None, "formations": None},
        "dropped": {}, "traffic": traffic.empty_snapshot(), "cpu_s": None, "wall_s": 0.0,
        "trace": [], "ellipse_trace": [],
    }


def _read_stats(path: Path) -> dict:
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        if _disk_full(path.parent):
            raise OutputError(f"disk full: {path.parent} has no room for the agents' counters "
                              f"({path.name} missing; run output not saved)") from None
        raise ChildFailed(f"agent counters {path} missing or unreadable: {exc}") from None


def _disk_full(folder: Path, room: int = 256 * 1024) -> bool:
    """Whether the file system of ``folder`` has less than ``room`` bytes free."""
    try:
        return shutil.disk_usage(folder).free < room
    except OSError:
        return False


def build_summary(scenario: Scenario, result: WorldResult, stats: list[dict], topology: str,
                  realtime: bool, camera: str, safety: bool,
                  solver: str = "exact") -> tuple[dict, Series]:
    """``summary.json`` of a multi-process run, and the time series with the agents' traces."""
    series = merge_traces(result, stats, scenario.dt)
    n = len(scenario.robot_ids)
    sim_time = result.sim_time
    solve_us = [row[12] for s in stats for row in s["trace"] if row[12] is not None]
    relaxed = sum(s["relaxed"] for s in stats)
    fallback = sum(s["fallback"] for s in stats)
    failed = sum(s["failed"] for s in stats)
    hard_unmet = sum(s.get("hard_row_unmet_ticks", 0) for s in stats)
    min_h = {}
    for kind in ("formation", "obstacle", "formations"):
        vals = [s["min_h"][kind] for s in stats if s["min_h"][kind] is not None]
        min_h[kind] = min(vals) if vals else None
    snap = traffic.merge([result.traffic, *(s["traffic"] for s in stats)])
    summary = run_summary(
        scenario, "multiprocess", result.steps, sim_time, result.monitor, min_h,
        qp_fields(sum(s["solves"] for s in stats), solve_us, relaxed, fallback, failed,
                  hard_unmet, sum_counts(s.get("hard_row_unmet", {}) for s in stats),
                  escape=sum(s.get("escape_ticks", 0) for s in stats)),
        comm_summary(snap, topology, n, sim_time), safety, solver,
        motion=motion_fields(series.robots, ROBOT_COLUMNS, scenario),
        realtime=realtime,
        camera=camera,
        agents={
            "ticks": sum(s["ticks"] for s in stats),
            "overruns": sum(s["overruns"] for s in stats),
            "stale": sum(s["stale"] for s in stats),
            "waiting_for_pose": sum(s.get("waiting", 0) for s in stats),
            "lockstep_timeouts": sum(s.get("lockstep_timeouts", 0) for s in stats),
            "dropped": sum_counts(s["dropped"] for s in stats),
            "stale_why": sum_counts(s.get("stale_why", {}) for s in stats),
            "stamp_rejected": merge_counts([s.get("stamp_rejected", {}) for s in stats]),
            "lockstep_catch_ups": sum(s.get("lockstep_catch_ups", 0) for s in stats),
            "implausible": sum_counts(s.get("implausible", {}) for s in stats),
            "obstacles_missing": sum(s.get("obstacles_missing", 0) for s in stats),
            "obstacle_held_ticks": sum(s.get("obstacle_held_ticks", 0) for s in stats),
            "obstacles_dropped_after_hold": sum(s.get("obstacles_dropped_after_hold", 0)
                                                for s in stats),
            "cpu_s": {s["robot"]: s["cpu_s"] for s in stats},
            "wall_s": max((s["wall_s"] for s in stats), default=None),
            "tick_us_median": _median([s["tick_us_median"] for s in stats]),
            "pose_age_us_median": _median([s.get("pose_age_us_median") for s in stats]),
        },
        world={
            "missing_cmds": result.missing_cmds,
            "zero_cmds": result.zero_cmds,
            "malformed_cmds": result.malformed_cmds,
            "stamp_rejected": result.stamp_rejected,
            "clock_offset_s": result.clock_offset,  # real time: the camera's clock ahead
            "wall_s": result.wall_s,
            "latency_ms": _latency(result.latency_ms),
        },
        time_to_goal_by_formation_s=formation_goal_times(scenario, series,
                                                         result.monitor.time_to_goal),
    )
    return summary, series


def formation_goal_times(scenario: Scenario, series: Series,
                         all_reached_at: float | None = None) -> dict[str, float | None]:
    """When each formation first had every robot within ``goal_tolerance`` of its goal (None
    if never): with a dead leader one formation stands still while the others go on. The
    series ends with the state the last tick started from, so a formation first seen there
    when every robot reached (``all_reached_at``, the run's end) gets that time."""
    goal = {r.id: r.goal for r in scenario.robots}
    tol = scenario.goal_tolerance
    at: dict[float, set[str]] = {}
    for row in series.robots:
        t, rid, x, y = row[0], row[1], row[3], row[4]
        gx, gy = goal[rid]
        if math.hypot(x - gx, y - gy) <= tol:
            at.setdefault(t, set()).add(rid)
    out: dict[str, float | None] = {}
    for f in scenario.formations:
        ids = set(f.robot_ids)
        first = next((round(t, 6) for t in sorted(at) if ids <= at[t]), None)
        if first is None and all_reached_at is not None:
            first = round(all_reached_at, 6)
        out[f.name] = first
    return out


def comm_summary(snap: dict, topology: str, n: int, sim_time: float) -> dict:
    """``comm`` of the contract, from traffic counted at publishers and subscribers.

    ``messages``/``bytes`` are the deliveries received by agents on the classes the topology
    decides (``state``, ``ellipse``, ``others``), comparable to the in-process model; ``classes``
    breaks every class down into what was put and what was received.
    """
    recv = snap["recv"]
    messages = sum(recv[c]["messages"] for c in INTER_ROBOT)
    nbytes = sum(recv[c]["bytes"] for c in INTER_ROBOT)
    per = n * sim_time
    return {
        "topology": topology,
        "messages": messages,
        "bytes": nbytes,
        "messages_per_robot_per_s": messages / per if per > 0 else 0.0,
        "bytes_per_robot_per_s": nbytes / per if per > 0 else 0.0,
        "source": "counted",
        "counted": "deliveries received of " + "+".join(INTER_ROBOT),
        "classes": {cls: {side: snap[side][cls] for side in traffic.SIDES}
                    for cls in keys.KEY_CLASSES},
    }


def merge_traces(result: WorldResult, stats: list[dict], dt: float) -> Series:
    """The world's rows with ``status``, ``slack`` and ``h_*`` from each agent's trace entry for
    the pose the world published at that tick; leaders' ellipses become ``ellipses`` rows.

    With pose slots each robot's pose of a tick goes out with its own slot's stamp
    (``result.robot_stamps``), which is the stamp its agent's trace is keyed by."""
    by_key: dict[tuple[str, float], list] = {}
    for s in stats:
        for row in s["trace"]:
            by_key[(s["robot"], row[0])] = row
    index: dict[str, int] = {}
    series = Series(obstacles=result.series.obstacles)
    for row in result.series.robots:
        t, rid = row[0], row[1]
        k = round(t / dt) if dt else 0
        i = index.setdefault(rid, len(index))
        stamp = _stamp_of(result, k, i, t)
        tr = by_key.get((rid, stamp))
        if tr is None:
            series.robots.append(row)
            continue
        status, slack, hf, ho, he = tr[7], tr[8], tr[9], tr[10], tr[11]
        series.robots.append((*row[:12], status, _nan(slack), _nan(hf), _nan(ho), _nan(he)))
    t_of = {stamp: k * dt for k, stamp in enumerate(result.stamps)}
    for k, sent in enumerate(result.robot_stamps):
        t_of.update((stamp, k * dt) for stamp in sent if math.isfinite(stamp))
    for s in stats:
        for row in s.get("ellipse_trace", []):
            t = t_of.get(row[0])
            if t is not None:
                series.ellipses.append((t, s["formation"], *row[1:]))
    series.ellipses.sort(key=lambda r: (r[0], r[1]))
    return series


def _stamp_of(result: WorldResult, k: int, i: int, t: float) -> float:
    """The stamp of robot ``i``'s pose at tick ``k`` (the tick's, or its slot's)."""
    if k < len(result.robot_stamps) and i < len(result.robot_stamps[k]):
        return result.robot_stamps[k][i]
    return result.stamps[k] if k < len(result.stamps) else t


def _nan(v):
    return math.nan if v is None else v


def sum_counts(dicts) -> dict:
    """Counters of several agents (dicts of name -> count) added up per name."""
    out: dict[str, int] = {}
    for d in dicts:
        for k, v in d.items():
            out[k] = out.get(k, 0) + v
    return out


def _median(vals):
    vals = [v for v in vals if v is not None]
    return statistics.median(vals) if vals else None


def _latency(ms: list[float]) -> dict | None:
    if not ms:
        return None
    xs = sorted(ms)
    return {"samples": len(xs), "median_ms": statistics.median(xs),
            "p99_ms": xs[min(len(xs) - 1, int(math.ceil(0.99 * len(xs))) - 1)], "max_ms": xs[-1]}


Supervisor = Fleet  # the former name, kept for callers outside this package
__all__ = ["START_TIMEOUT_S", "STOP_TIMEOUT_S", "Child", "ChildFailed", "Fleet", "Supervisor"]
