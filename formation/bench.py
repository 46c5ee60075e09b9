"""Kept for scripts that import it: the benchmarks live in :mod:`experiments.bench` (and its
parts), the command handler in :mod:`formation.commands.bench`."""

from experiments.agents import bench_agents
from experiments.bench import run_bench
from experiments.central import central_problem, fleet_snapshot
from experiments.fleet_scenario import fleet_scenario
from formation.commands.bench import bench_command

__all__ = ["bench_agents", "bench_command", "central_problem", "fleet_scenario", "fleet_snapshot",
           "run_bench"]
