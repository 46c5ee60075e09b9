"""``formation sim SCENARIO --out DIR``: the in-process simulation."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from agent.qp import make_solver
from formation.exits import EXIT_ERROR, EXIT_OK, UsageError
from formation.outdir import begin_output
from formation.progress import Progress, print_summary
from scenario import Scenario, load_scenario
from scenario.bounds import with_bounds
from scenario.model import model_world_warning, with_world
from simulator.inprocess import SimOptions, simulate
from simulator.lifelong import simulate_lifelong, write_lifelong
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
    if scenario.lifelong is not None:
        return sim_lifelong(ns, scenario, opts, out)
    with Progress(f"sim {scenario.name}", quiet=ns.quiet) as progress:
        result = simulate(scenario, opts, progress=progress.update)
    lost = write_run(result.summary, result.series, scenario, out, plots=not ns.no_plots)
    print_summary(result.summary, out, plots=not ns.no_plots)
    return EXIT_ERROR if lost else EXIT_OK  # files lost to a full disk: the summary says which


def sim_lifelong(ns: argparse.Namespace, scenario: Scenario, opts: SimOptions, out: Path) -> int:
    """A scenario with a fleet: orders served by teams formed at run time
    (:mod:`simulator.lifelong`); the progress bar counts the orders delivered."""
    with Progress(f"sim {scenario.name}", quiet=ns.quiet, early="every order done") as progress:
        try:
            result = simulate_lifelong(scenario, opts, progress=progress.update,
                                       tally=progress.orders)
        except ValueError as exc:
            raise UsageError(str(exc)) from None
    lost = write_lifelong(result, out, plots=not ns.no_plots)
    print_summary(result.summary, out, plots=not ns.no_plots)
    o = result.summary["orders"]
    print(f"orders: {o['delivered']} of {o['posted']} delivered, {o['failed']} failed, "
          f"{o['open']} open, {o['stuck']} stuck")
    return EXIT_ERROR if lost else EXIT_OK
