"""``formation run SCENARIO --out DIR``: the multi-process run over Zenoh (see :mod:`simulator.launch`).

The options become one :class:`simulator.run_config.RunConfig`, checked once (invalid input:
exit 2, one line, before anything starts), which :func:`simulator.launch.launch` runs.
``--hosts INVENTORY`` places the agents of the robots a deploy inventory names on its hosts
(:mod:`deploy.remote`), each host checked over SSH before anything starts; ``--dry-run`` prints
the placement and starts nothing."""

from __future__ import annotations

import argparse
import dataclasses
import functools
import math
import os
import shutil
import signal
import sys
import threading
from pathlib import Path
from typing import Any

from deploy.inventory import InventoryError
from deploy.remote import RemoteError, plan_placement
from formation.commands.view import live_observer
from formation.exits import EXIT_ERROR, EXIT_OK, UsageError
from formation.outdir import begin_output
from formation.progress import Progress, lost_words, print_summary
from scenario import Scenario, load_scenario
from scenario.bounds import with_bounds
from scenario.model import model_world_warning, with_world
from simulator.capacity import machine_has, refusal
from simulator.faults import FaultPlan, parse_camera_dropout, parse_kill
from simulator.fleet import RemoteAgents
from simulator.launch import RunAborted, launch
from simulator.output import write_run
from simulator.run_config import RunConfig
from viewer.orders import OrderBoard
from wire.rmw_zenoh import RmwSettings


def run_config(ns: argparse.Namespace) -> RunConfig:
    """The run's configuration from the command's options, every check done (UsageError: exit 2,
    one line, before anything starts); ``--hosts`` places the agents but reaches no host yet."""
    try:
        faults = FaultPlan(
            drop=ns.drop, delay_ms=ns.delay_ms, seed=getattr(ns, "fault_seed", 0),
            kills=tuple(parse_kill(k) for k in getattr(ns, "kill", None) or ()),
            camera_dropouts=tuple(parse_camera_dropout(c)
                                  for c in getattr(ns, "camera_dropout", None) or ()),
        )
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    # ScenarioError -> exit 2; --world replaces the file's world (scenario.world), --bounds the
    # controller's bounds (scenario.bounds)
    scenario = _with_duration(ns, with_bounds(
        with_world(load_scenario(ns.scenario), getattr(ns, "world", None)),
        getattr(ns, "bounds", None)))
    per_process = getattr(ns, "agents_per_process", 1)
    insecure = getattr(ns, "insecure", False)
    try:
        return RunConfig(
            scenario, Path(ns.out), realtime=ns.realtime, camera=ns.camera, topology=ns.topology,
            safety=not ns.no_safety, port=ns.port, faults=faults, secure=not insecure,
            pose_slots=getattr(ns, "pose_slots", 1), scenario_path=Path(ns.scenario),
            clock_offset=getattr(ns, "clock_offset_ms", 0.0) / 1000.0,
            agents_per_process=per_process,
            # an agent host shares one Zenoh session among its agents (cheaper per tick:
            # docs/performance.md) unless asked otherwise or under access control (the
            # default: each robot logs in as itself)
            shared_session=(per_process > 1 and not getattr(ns, "session_per_agent", False)
                            and insecure),
            solver=getattr(ns, "solver", "exact"), hold=bool(getattr(ns, "hold", False)),
            remote=_placement(ns, scenario, per_process), pose_zones=getattr(ns, "pose_zones", 0),
            rmw_base=_rmw_base(ns), restart=getattr(ns, "restart", "on-failure"),
            restart_limit=getattr(ns, "restart_limit", 3), engine=getattr(ns, "engine", "kinematic"),
            plots=not getattr(ns, "no_plots", False))
    except ValueError as exc:
        raise UsageError(str(exc)) from None


def _rmw_base(ns: argparse.Namespace) -> RmwSettings | None:
    """``--base rmw_zenoh`` and its options (checked where the settings and the run's
    configuration are built: ValueError)."""
    if getattr(ns, "base", "world") != "rmw_zenoh":
        return None
    try:
        return RmwSettings(release=getattr(ns, "rmw_zenoh_release", ""),
                           cmd_type=getattr(ns, "cmd_type", "TwistStamped"),
                           domain=getattr(ns, "ros_domain", 0))
    except ValueError as exc:
        raise ValueError(f"--base rmw_zenoh: {exc}") from None


def run_command(ns: argparse.Namespace) -> int:
    """``formation run``; see the module docstring. Returns the exit status."""
    config = run_config(ns)
    drive = model_world_warning(config.scenario.robot, config.scenario.world, config.engine)
    if drive is not None:
        print(f"{ns.scenario}: warning: {drive}", file=sys.stderr)
    if not getattr(ns, "no_capacity_check", False):
        _check_capacity(config)  # before any process starts
    _check_space(config.out)
    if config.remote is not None and not getattr(ns, "dry_run", False):
        _reach_hosts(config.remote)  # over SSH, before anything starts
    if getattr(ns, "dry_run", False):
        return _dry_run(config)
    with LaterInterruptsWait(whole_process=getattr(ns, "whole_process", False)) as interrupts:
        return _run(ns, config, interrupts)


class LaterInterruptsWait:
    """SIGINT in ``formation run``: the first stops the run (``KeyboardInterrupt``, as ever);
    every later one, or one that comes once the run is over, only says the shutdown is under
    way, so summary.json, robots.csv and run.mcap are still written (marked ``aborted``). The
    shutdown's every wait is bounded (:class:`simulator.fleet.Fleet`), so it ends anyway.

    ``whole_process``: the command is the program (``formation run`` from a shell), which ends
    when the command does; then, once interrupted, SIGINT stays ignored on the way out. Called in
    a process that goes on (``main([...])`` from Python), the handler before is put back
    whatever happened: an ignored SIGINT would outlive the run and be inherited by every process
    started later (``formation replay`` from a test then never stopped on Ctrl-C)."""

    def __init__(self, whole_process: bool = False) -> None:
        self.count = 0
        self.whole_process = whole_process
        self._previous: Any = None

    def __enter__(self) -> LaterInterruptsWait:
        if threading.current_thread() is threading.main_thread():
            self._previous = signal.signal(signal.SIGINT, self._on_sigint)
        return self

    def __exit__(self, *_exc: object) -> None:
        # once interrupted, the process is on its way out: a Ctrl-C still coming (one of a
        # hurried operator's several) must not meet the default handler while Python exits,
        # which killed the process by SIGINT after the run was written (exit -2, not 130).
        # Python's own exit puts back the default action for a handler written in Python (this
        # one), so a Ctrl-C in the last teardown still did that on a loaded machine; an
        # ignored signal stays ignored through it.
        if self._previous is None:
            return
        if self.count > 0 and self.whole_process:
            signal.signal(signal.SIGINT, signal.SIG_IGN)
        else:
            signal.signal(signal.SIGINT, self._previous)

    def run_over(self) -> None:
        """From now on no SIGINT interrupts: the run's files are being written."""
        self.count = max(self.count, 1)

    def _on_sigint(self, _signum: int, _frame: object) -> None:
        self.count += 1
        if self.count == 1:
            raise KeyboardInterrupt
        # os.write: a print here could land inside another print to the same stream
        os.write(2, b"formation run: already stopping; writing the run's files first\n")


def _run(ns: argparse.Namespace, config: RunConfig, interrupts: LaterInterruptsWait) -> int:
    """The run itself, once every check passed."""
    live, observer = live_observer(ns, config.scenario)  # --live PORT: fed from the world's session
    boards: list[OrderBoard] = []  # a lifelong run's loads and orders, for run.mcap
    try:
        # the input is valid (a bad --live port included): replace the output
        config = dataclasses.replace(config, out=begin_output(ns))
        summary, series = launch(config, progress_factory=lambda: Progress(
            f"run {config.scenario.name}", quiet=ns.quiet,
            early="stopped (Ctrl-C or SIGTERM)" if config.hold else "every goal reached"),
            observer=observer,
            announce=functools.partial(_announce, config) if config.hold else None,
            keep=lambda loads: boards.append(loads.board()))
    except RunAborted as stop:  # the run started: its summary says why and what it measured
        interrupts.run_over()
        lost = write_run(stop.summary, stop.series, config.scenario, config.out,
                         plots=not ns.no_plots, board=boards[0] if boards else None)
        print(f"formation run: aborted: {stop}; wrote {config.out / 'summary.json'} with what "
              f"was measured until then ({stop.summary['steps']} ticks)"
              + (f"; {lost_words(lost)}" if lost else ""), file=sys.stderr)
        return 130 if stop.interrupted else EXIT_ERROR
    finally:
        if live is not None:
            live.close()
    interrupts.run_over()
    lost = write_run(summary, series, config.scenario, config.out, plots=not ns.no_plots,
                     board=boards[0] if boards else None)
    print_summary(summary, config.out, plots=not ns.no_plots,
                  epsilon=config.scenario.controller.epsilon)
    return EXIT_ERROR if lost else EXIT_OK  # files lost to a full disk: the summary says which


def capacity_problem(scenario: Scenario, agents_per_process: int = 1,
                     remote_robots: int = 0) -> str | None:
    """Why this machine cannot hold the run's local agents (:mod:`simulator.capacity`), or None."""
    return refusal(len(scenario.robot_ids), machine_has(), agents_per_process, remote_robots)


def _check_capacity(config: RunConfig) -> None:
    """A fleet that does not fit this machine: exit 2, one line, before anything starts."""
    remote = 0 if config.remote is None else len(config.remote.robots)
    why = capacity_problem(config.scenario, config.agents_per_process, remote)
    if why is not None:
        raise UsageError(f"{why} (--no-capacity-check starts it anyway)")


MIN_FREE_MB = 8.0  # [MB] free space --out needs before a run starts (summary, bulk files, logs)


def free_mb(path: Path) -> float:
    """Free space [MB] where ``path`` is (or would be: its nearest existing folder)."""
    where = path.resolve()
    while not where.exists() and where != where.parent:
        where = where.parent
    return shutil.disk_usage(where).free / 2**20


def _check_space(out: Path) -> None:
    """Too little room for the run's files: exit 2, one line, before anything starts."""
    free = free_mb(out)
    if free < MIN_FREE_MB:
        raise UsageError(f"--out {out}: {free:.1f} MB free, a run needs at least "
                         f"{MIN_FREE_MB:g} MB for its files")


def _placement(ns: argparse.Namespace, scenario: Scenario, per_process: int) -> RemoteAgents | None:
    """``--hosts INVENTORY``: the agents placed on its hosts (:mod:`deploy.remote`); None
    without it. A bad inventory: exit 2, one line."""
    hosts = getattr(ns, "hosts", None)
    if hosts is None:
        return None
    try:
        return plan_placement(Path(hosts), scenario.robot_ids, per_process)
    except (InventoryError, RemoteError, OSError) as exc:
        raise UsageError(str(exc)) from None


def _reach_hosts(remote: RemoteAgents) -> None:
    """Every host of ``--hosts`` reached and checked over SSH; a problem: exit 2, one line."""
    try:
        remote.check()
    except (InventoryError, RemoteError, OSError) as exc:
        raise UsageError(str(exc)) from None


def _dry_run(config: RunConfig) -> int:
    """``--dry-run``: where each robot's agent would run (with ``--hosts``, the SSH commands
    that would start it there); nothing is started, written or reached."""
    common = [] if config.realtime else ["--lockstep"]
    robots = config.scenario.robot_ids
    remote = config.remote
    if remote is None:
        print(f"router, world and every agent here: robots {', '.join(robots)}")
    else:
        here = [r for r in robots if r not in remote.robots]
        for line in remote.describe(common, config.secure, config.shared_session, here):
            print(line)
    print(f"dry run: {len(robots)} robots, "
          f"{0 if remote is None else len(remote.robots)} on other hosts; nothing started")
    return EXIT_OK


def _with_duration(ns: argparse.Namespace, scenario: Scenario) -> Scenario:
    """``--duration S`` (simulated seconds, instead of the scenario's)."""
    duration = getattr(ns, "duration", None)
    if duration is None:
        return scenario
    if not (math.isfinite(duration) and duration >= scenario.dt):
        raise UsageError(f"--duration: need at least one period ({scenario.dt} s), got {duration}")
    return dataclasses.replace(scenario, duration=duration)


def _announce(config: RunConfig, endpoint: str) -> None:
    """``--hold``: where the fleet manager sends goals (also in ``DIR/endpoint``), with the
    credentials it logs in with; ``--run DIR`` finds both."""
    auth = f" --auth {config.out / 'secure' / 'manager.json5'}" if config.secure else ""
    print(f"fleet up, goals to: formation goal FID X Y --connect {endpoint}{auth} "
          f"(or: --run {config.out})", flush=True)
