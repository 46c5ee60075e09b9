"""``formation sim SCENARIO --out DIR``: the in-process simulation."""

from __future__ import annotations

import argparse

from agent.qp import make_solver
from formation.exits import EXIT_OK, UsageError
from formation.outdir import begin_output
from formation.progress import Progress, print_summary
from scenario import load_scenario
from simulator.inprocess import SimOptions, simulate
from simulator.output import write_run


def cmd_sim(ns: argparse.Namespace) -> int:
    scenario = load_scenario(ns.scenario)
    try:
        make_solver(ns.solver)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    out = begin_output(ns)
    opts = SimOptions(safety=not ns.no_safety, solver=ns.solver, topology=ns.topology)
    with Progress(f"sim {scenario.name}", quiet=ns.quiet) as progress:
        result = simulate(scenario, opts, progress=progress.update)
    write_run(result.summary, result.series, scenario, out, plots=not ns.no_plots)
    print_summary(result.summary, out, plots=not ns.no_plots)
    return EXIT_OK
