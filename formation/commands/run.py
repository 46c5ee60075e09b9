"""``formation run SCENARIO --out DIR``: the multi-process run over Zenoh (see :mod:`simulator.launch`)."""

from __future__ import annotations

import argparse
import dataclasses
import math
from pathlib import Path

from formation.exits import EXIT_OK, UsageError
from formation.progress import Progress, print_summary
from scenario import Scenario, load_scenario
from simulator.launch import FaultPlan, launch, parse_camera_dropout, parse_kill
from simulator.output import write_run


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
    slots = getattr(ns, "pose_slots", 1)
    if slots < 1:
        raise UsageError(f"--pose-slots: need an integer >= 1, got {slots}")
    if slots > 1 and not (ns.realtime and ns.camera == "truth"):
        raise UsageError("--pose-slots: more than one slot needs --realtime and --camera truth")
    scenario, hold = _duration_and_hold(ns, load_scenario(ns.scenario))  # ScenarioError -> exit 2
    try:
        faults.check_robots(scenario.robot_ids)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    out = Path(ns.out)
    from formation.commands.view import live_observer

    live, observer = live_observer(ns, scenario)  # --live PORT: the page, fed from the world's session
    try:
        summary, series = launch(scenario, out, realtime=ns.realtime, camera=ns.camera,
                                 topology=ns.topology, safety=not ns.no_safety, port=ns.port,
                                 progress_factory=lambda: Progress(f"run {scenario.name}",
                                                                   quiet=ns.quiet),
                                 faults=faults, secure=getattr(ns, "secure", False),
                                 pose_slots=slots, observer=observer,
                                 scenario_path=ns.scenario, hold=hold,
                                 announce=_announce if hold else None)
    finally:
        if live is not None:
            live.close()
    write_run(summary, series, scenario, out, plots=not ns.no_plots)
    print_summary(summary, out)
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
