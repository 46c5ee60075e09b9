"""``formation run SCENARIO --out DIR``: the multi-process run over Zenoh (see :mod:`simulator.launch`)."""

from __future__ import annotations

import argparse

from formation.exits import EXIT_OK, UsageError
from formation.outdir import begin_output
from formation.progress import Progress, print_summary
from scenario import load_scenario
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
    if ns.camera == "synthetic":
        try:
            import camera_service.service  # noqa: F401
        except ImportError:
            raise UsageError("--camera synthetic: camera_service.service is not available yet") from None
    if not 0 <= ns.port < 65536:
        raise UsageError(f"--port: {ns.port} is not a TCP port")
    slots = getattr(ns, "pose_slots", 1)
    if slots < 1:
        raise UsageError(f"--pose-slots: need an integer >= 1, got {slots}")
    if slots > 1 and not (ns.realtime and ns.camera == "truth"):
        raise UsageError("--pose-slots: more than one slot needs --realtime and --camera truth")
    scenario = load_scenario(ns.scenario)  # ScenarioError -> exit 2
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
    from formation.commands.view import live_observer

    live, observer = live_observer(ns, scenario)  # --live PORT: the page, fed from the world's session
    try:
        out = begin_output(ns)  # the input is valid (a bad --live port included): replace the output
        summary, series = launch(scenario, out, realtime=ns.realtime, camera=ns.camera,
                                 topology=ns.topology, safety=not ns.no_safety, port=ns.port,
                                 progress_factory=lambda: Progress(f"run {scenario.name}",
                                                                   quiet=ns.quiet),
                                 faults=faults, secure=getattr(ns, "secure", False),
                                 pose_slots=slots, observer=observer, solver=solver)
    finally:
        if live is not None:
            live.close()
    write_run(summary, series, scenario, out, plots=not ns.no_plots)
    print_summary(summary, out, plots=not ns.no_plots)
    return EXIT_OK
