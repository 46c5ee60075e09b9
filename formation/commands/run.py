"""``formation run SCENARIO --out DIR``: the multi-process run over Zenoh (see :mod:`simulator.launch`).

``--hosts INVENTORY`` places the agents of the robots a deploy inventory names on its hosts
(:mod:`deploy.remote`), each host checked over SSH before anything starts; ``--dry-run`` prints
the placement and starts nothing."""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
from pathlib import Path

from formation.exits import EXIT_ERROR, EXIT_OK, UsageError
from formation.outdir import begin_output
from formation.progress import Progress, print_summary
from scenario import Scenario, load_scenario
from simulator.launch import FaultPlan, RunAborted, launch, parse_camera_dropout, parse_kill
from simulator.output import write_run
from wire.rmw_zenoh import RmwSettings, check_settings


def _pose_zones(ns: argparse.Namespace) -> int:
    """``--pose-zones Z`` checked (UsageError: exit 2 before anything starts)."""
    zones = getattr(ns, "pose_zones", 0)
    if zones < 0:
        raise UsageError(f"--pose-zones: need an integer >= 0, got {zones}")
    return zones


def _rmw_base(ns: argparse.Namespace, scenario: Scenario) -> RmwSettings | None:
    """``--base rmw_zenoh`` and its options checked (UsageError: exit 2)."""
    if getattr(ns, "base", "world") != "rmw_zenoh":
        return None
    settings = RmwSettings(release=getattr(ns, "rmw_zenoh_release", ""),
                           cmd_type=getattr(ns, "cmd_type", "TwistStamped"),
                           domain=getattr(ns, "ros_domain", 0))
    try:
        check_settings(settings)
    except ValueError as exc:
        raise UsageError(f"--base rmw_zenoh: {exc}") from None
    if not scenario.robot.is_unicycle:
        raise UsageError("--base rmw_zenoh: a ROS base takes (v, omega): needs a unicycle scenario")
    if settings.cmd_type == "Twist" and not ns.realtime:
        raise UsageError("--cmd-type Twist: carries no stamp to match lock-step ticks; "
                         "needs --realtime")
    return settings


def run_command(ns: argparse.Namespace) -> int:
    """``formation run``; see the module docstring. Returns the exit status."""
    try:
        faults = FaultPlan(
            drop=ns.drop, delay_ms=ns.delay_ms, seed=getattr(ns, "fault_seed", 0),
            kills=tuple(parse_kill(k) for k in getattr(ns, "kill", None) or ()),
            camera_dropouts=tuple(parse_camera_dropout(c)
                                  for c in getattr(ns, "camera_dropout", None) or ()),
        )
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    if ns.camera in ("synthetic", "process"):
        try:
            import camera_service.service  # noqa: F401
        except ImportError:
            raise UsageError("--camera synthetic: camera_service.service is not available yet") from None
    if ns.camera == "process" and faults.camera_dropouts:
        raise UsageError("--camera-dropout: not with --camera process (the camera process "
                         "publishes the poses)")
    if not 0 <= ns.port < 65536:
        raise UsageError(f"--port: {ns.port} is not a TCP port")
    slots = _pose_slots(ns)
    zones = _pose_zones(ns)
    if zones and getattr(ns, "hosts", None):
        raise UsageError("--pose-zones: the zone routers listen on loopback only; not with --hosts")
    per_process = getattr(ns, "agents_per_process", 1)
    if per_process < 1:
        raise UsageError(f"--agents-per-process: need an integer >= 1, got {per_process}")
    if per_process > 1 and faults.kills:
        raise UsageError("--kill: needs one agent per process (--agents-per-process 1)")
    # an agent host shares one Zenoh session among its agents (measured cheaper, docs/performance.md)
    # unless asked otherwise or under access control (the default: each robot logs in as itself)
    shared = (per_process > 1 and not getattr(ns, "session_per_agent", False)
              and getattr(ns, "insecure", False))
    scenario, hold = _duration_and_hold(ns, load_scenario(ns.scenario))  # ScenarioError -> exit 2
    solver = getattr(ns, "solver", "exact")
    try:
        from agent.qp import make_solver

        make_solver(solver)  # an unknown or missing backend: exit 2 before any process starts
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    try:
        faults.check_robots(scenario.robot_ids)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    rmw_base = _rmw_base(ns, scenario)
    remote = _placement(ns, scenario, per_process, faults)  # over SSH, before anything starts
    if getattr(ns, "dry_run", False):
        return _dry_run(ns, scenario, remote, shared)
    from formation.commands.view import live_observer

    live, observer = live_observer(ns, scenario)  # --live PORT: the page, fed from the world's session
    try:
        out = begin_output(ns)  # the input is valid (a bad --live port included): replace the output
        summary, series = launch(scenario, out, realtime=ns.realtime, camera=ns.camera,
                                 topology=ns.topology, safety=not ns.no_safety, port=ns.port,
                                 progress_factory=lambda: Progress(f"run {scenario.name}",
                                                                   quiet=ns.quiet),
                                 faults=faults, secure=not getattr(ns, "insecure", False),
                                 pose_slots=slots, observer=observer,
                                 scenario_path=ns.scenario,
                                 clock_offset=getattr(ns, "clock_offset_ms", 0.0) / 1000.0,
                                 agents_per_process=per_process, shared_session=shared,
                                 solver=solver, hold=hold, announce=_announce if hold else None,
                                 remote=remote, pose_zones=zones, rmw_base=rmw_base)
    except RunAborted as stop:  # the run started: its summary says why and what it measured
        write_run(stop.summary, stop.series, scenario, out, plots=not ns.no_plots)
        print(f"formation run: aborted: {stop}; wrote {out / 'summary.json'} with what was "
              f"measured until then ({stop.summary['steps']} ticks)", file=sys.stderr)
        return 130 if stop.interrupted else EXIT_ERROR
    finally:
        if live is not None:
            live.close()
    write_run(summary, series, scenario, out, plots=not ns.no_plots)
    print_summary(summary, out, plots=not ns.no_plots)
    return EXIT_OK


def _pose_slots(ns: argparse.Namespace) -> int:
    """``--pose-slots`` once checked (and ``--clock-offset-ms``: both need real time)."""
    slots = getattr(ns, "pose_slots", 1)
    if slots < 1:
        raise UsageError(f"--pose-slots: need an integer >= 1, got {slots}")
    if slots > 1 and not (ns.realtime and ns.camera == "truth"):
        raise UsageError("--pose-slots: more than one slot needs --realtime and --camera truth")
    if getattr(ns, "clock_offset_ms", 0.0) and not ns.realtime:
        raise UsageError("--clock-offset-ms: needs --realtime (lock-step runs on simulated time)")
    return slots


def _placement(ns: argparse.Namespace, scenario: Scenario, per_process: int,
               faults: FaultPlan):
    """``--hosts INVENTORY``: the agents placed on its hosts (:mod:`deploy.remote`), every host
    reached and checked over SSH; None without it. Any problem: exit 2, one line."""
    hosts = getattr(ns, "hosts", None)
    if hosts is None:
        return None
    if ns.port:
        raise UsageError("--port: not with --hosts (the router listens on the inventory's "
                         "zenoh.router)")
    from deploy.inventory import InventoryError
    from deploy.remote import RemoteError, plan_placement

    try:
        remote = plan_placement(Path(hosts), scenario.robot_ids, per_process)
        for k in faults.kills:
            if k.robot in remote.robots:
                raise UsageError(f"--kill: {k.robot} runs on another host (--hosts); kills need "
                                 f"an agent on this machine")
        if not getattr(ns, "dry_run", False):
            remote.check()
    except (InventoryError, RemoteError, OSError) as exc:
        raise UsageError(str(exc)) from None
    return remote


def _dry_run(ns: argparse.Namespace, scenario: Scenario, remote, shared: bool) -> int:
    """``--dry-run``: where each robot's agent would run (with ``--hosts``, the SSH commands
    that would start it there); nothing is started, written or reached."""
    common = [] if ns.realtime else ["--lockstep"]
    secure = not getattr(ns, "insecure", False)
    if remote is None:
        print(f"router, world and every agent here: robots {', '.join(scenario.robot_ids)}")
    else:
        here = [r for r in scenario.robot_ids if r not in remote.robots]
        for line in remote.describe(common, secure, shared, here):
            print(line)
    print(f"dry run: {len(scenario.robot_ids)} robots, "
          f"{0 if remote is None else len(remote.robots)} on other hosts; nothing started")
    return EXIT_OK


def _duration_and_hold(ns: argparse.Namespace, scenario: Scenario) -> tuple[Scenario, bool]:
    """``--duration S`` (simulated seconds, instead of the scenario's) and ``--hold``."""
    duration = getattr(ns, "duration", None)
    if duration is not None:
        if not (math.isfinite(duration) and duration >= scenario.dt):
            raise UsageError(f"--duration: need at least one period ({scenario.dt} s), got {duration}")
        scenario = dataclasses.replace(scenario, duration=duration)
    return scenario, bool(getattr(ns, "hold", False))


def _announce(endpoint: str) -> None:
    """``--hold``: where the fleet manager sends goals (also in ``DIR/endpoint``)."""
    print(f"fleet up, goals to: formation goal FID X Y --connect {endpoint}", flush=True)
