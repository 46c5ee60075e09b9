"""``formation sim SCENARIO --out DIR``: the in-process simulation."""

from __future__ import annotations

import argparse
import sys

from agent.qp import make_solver
from formation.exits import EXIT_ERROR, EXIT_OK, UsageError
from formation.outdir import begin_output
from formation.progress import Progress, print_summary
from scenario import load_scenario
from scenario.bounds import with_bounds
from scenario.model import model_world_warning, with_world
from simulator.inprocess import SimOptions, simulate
from simulator.output import write_run
from simulator.physics import available as physics_available


def cmd_sim(ns: argparse.Namespace) -> int:
    scenario = with_bounds(with_world(load_scenario(ns.scenario), ns.world), ns.bounds)
    try:
        make_solver(ns.solver)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    if ns.engine == "mujoco" and scenario.robot.is_double_integrator:
        raise UsageError("--engine mujoco: double integrators run in the kinematic world only")
    if ns.engine == "mujoco" and not physics_available():
        raise UsageError("--engine mujoco: MuJoCo is not installed "
                         "(pip install 'formation-cbf[physics]')")
    drive = model_world_warning(scenario.robot, scenario.world, ns.engine)
    if drive is not None:
        print(f"{ns.scenario}: warning: {drive}", file=sys.stderr)
    out = begin_output(ns)
    opts = SimOptions(safety=not ns.no_safety, solver=ns.solver, topology=ns.topology,
                      engine=ns.engine)
    with Progress(f"sim {scenario.name}", quiet=ns.quiet) as progress:
        result = simulate(scenario, opts, progress=progress.update)
    lost = write_run(result.summary, result.series, scenario, out, plots=not ns.no_plots)
    print_summary(result.summary, out, plots=not ns.no_plots)
    return EXIT_ERROR if lost else EXIT_OK  # files lost to a full disk: the summary says which
