"""``formation bench``: how fast the control step and the QP are, measured side by side.

The QP instances are the real ones: every problem the exact solver was handed while the
in-process simulator drove a scenario (default: the warehouse). Each backend solves the same
instances in the same process, interleaved, so machine noise hits them alike; medians are
reported, with the worst disagreement against the exact solution.
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import statistics
import time
from collections.abc import Callable, Sequence
from pathlib import Path

from agent.barriers import Neighbour, Obstacle
from agent.control import ControlParams, FormationView, control_step
from agent.qp import Row, qpsolvers_solver, solve_exact
from leader.ellipse import Ellipse

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_SCENARIO = ROOT / "scenarios" / "warehouse.yaml"
BACKENDS = ("osqp", "daqp", "quadprog", "clarabel")


def collect_instances(scenario_path: Path, limit: int) -> list[tuple[float, float, list[Row]]]:
    """Every full QP (first solve of a tick) the simulator posed, up to ``limit``, evenly spread."""
    from scenario import load_scenario
    from simulator.inprocess import SimOptions, simulate

    seen: list[tuple[float, float, list[Row]]] = []

    def recording(ux: float, uy: float, rows: Sequence[Row], tol: float = 1e-9):
        seen.append((ux, uy, list(rows)))
        return solve_exact(ux, uy, rows, tol)

    simulate(load_scenario(scenario_path), SimOptions(record=False, solve_fn=recording))
    step = max(1, len(seen) // limit)
    return seen[::step][:limit]


def time_solver(solve: Callable, instances, repeat: int) -> tuple[list[float], list]:
    times, results = [], []
    for ux, uy, rows in instances:
        best = math.inf
        for _ in range(repeat):
            t0 = time.perf_counter_ns()
            out = solve(ux, uy, rows)
            best = min(best, time.perf_counter_ns() - t0)
        times.append(best * 1e-3)
        results.append(out)
    return times, results


def bench_solvers(instances, repeat: int, backends: Sequence[str]) -> dict:
    solvers: dict[str, Callable] = {"exact": solve_exact}
    for name in backends:
        try:
            solvers[f"qpsolvers-{name}"] = qpsolvers_solver(name)
        except ValueError:
            continue
    # Interleave: one block of instances per solver in turn, a few rounds.
    rounds = 3
    chunk = max(1, len(instances) // rounds)
    times: dict[str, list[float]] = {k: [] for k in solvers}
    results: dict[str, list] = {k: [] for k in solvers}
    for r in range(rounds):
        block = instances[r * chunk:(r + 1) * chunk] if r < rounds - 1 else instances[r * chunk:]
        for name, solve in solvers.items():
            t, res = time_solver(solve, block, repeat if name == "exact" else 1)
            times[name] += t
            results[name] += res
    out = {}
    for name in solvers:
        diffs = [math.dist(a, b) for a, b in zip(results["exact"], results[name], strict=True)
                 if a is not None and b is not None]
        out[name] = {
            "solve_us_median": statistics.median(times[name]),
            "solve_us_p90": sorted(times[name])[int(0.9 * (len(times[name]) - 1))],
            "max_diff_vs_exact": max(diffs) if diffs else None,
            "infeasible": sum(r is None for r in results[name]),
        }
    exact = out["exact"]["solve_us_median"]
    for name in out:
        out[name]["ratio_vs_exact"] = out[name]["solve_us_median"] / exact
    return out


def step_instance():
    """One robot of a 4-robot formation with 2 obstacles and 3 other formations in view."""
    p = ControlParams()
    pose = (0.0, 0.0, 0.0)
    goal = (5.0, 0.0)
    neighbours = [Neighbour(-0.5, 0.0, 0.2, 0.0, 0.5), Neighbour(0.0, -0.25, 0.2, 0.0, 0.25),
                  Neighbour(-0.5, -0.25, 0.2, 0.01, 0.559)]
    obstacles = [Obstacle(1.2, 0.4, 0.0, 0.0, 0.3), Obstacle(2.0, -0.8, 0.05, 0.0, 0.3)]
    others = [Ellipse(2.5, 0.3, 3.1, 0.6, 0.3, -0.2, 0.0, 0.0),
              Ellipse(1.0, -2.0, 1.5, 0.6, 0.45, 0.0, 0.2, 0.01),
              Ellipse(-2.0, 2.0, 0.0, 0.55, 0.3, 0.1, -0.1, 0.0)]
    view = FormationView(Ellipse(-0.25, -0.125, 0.0, 0.6, 0.45, 0.2, 0.0, 0.0), 4.75, -0.125)
    return p, pose, goal, neighbours, obstacles, others, view


def bench_step(n: int) -> dict:
    p, pose, goal, nb, obs, others, view = step_instance()
    times = []
    for _ in range(n):
        t0 = time.perf_counter_ns()
        control_step(p, pose, goal, nb, obs, others, view)
        times.append((time.perf_counter_ns() - t0) * 1e-3)
    return {"step_us_median": statistics.median(times),
            "step_us_p99": sorted(times)[int(0.99 * (len(times) - 1))]}


def run_bench(quick: bool = False, scenario: Path = DEFAULT_SCENARIO) -> dict:
    n_inst = 200 if quick else 2000
    instances = collect_instances(scenario, n_inst)
    solvers = bench_solvers(instances, repeat=3 if quick else 5, backends=BACKENDS)
    step = bench_step(2000 if quick else 20000)
    return {
        "machine": {"python": platform.python_version(), "processor": platform.processor() or
                    platform.machine(), "quick": quick},
        "instances": {"scenario": scenario.name, "count": len(instances),
                      "rows_median": statistics.median(len(r) for _, _, r in instances)},
        "step_us_median": step["step_us_median"],
        "step": step,
        "solvers": solvers,
    }


def format_table(result: dict) -> str:
    lines = [
        f"control step (4-robot formation, 2 obstacles, 3 other formations): median "
        f"{result['step']['step_us_median']:.1f} us, p99 {result['step']['step_us_p99']:.1f} us",
        f"QP instances: {result['instances']['count']} from {result['instances']['scenario']} "
        f"(median {result['instances']['rows_median']} rows)",
        f"{'solver':<22}{'median us':>11}{'p90 us':>10}{'x exact':>9}{'max |du|':>12}",
    ]
    for name, s in result["solvers"].items():
        diff = "-" if s["max_diff_vs_exact"] is None else f"{s['max_diff_vs_exact']:.1e}"
        lines.append(f"{name:<22}{s['solve_us_median']:>11.1f}{s['solve_us_p90']:>10.1f}"
                     f"{s['ratio_vs_exact']:>9.1f}{diff:>12}")
    return "\n".join(lines)


def bench_command(ns: argparse.Namespace) -> int:
    out = Path(ns.out)
    out.mkdir(parents=True, exist_ok=True)
    result = run_bench(quick=ns.quick)
    (out / "bench.json").write_text(json.dumps(result, indent=2) + "\n", encoding="utf-8")
    table = format_table(result)
    (out / "bench.txt").write_text(table + "\n", encoding="utf-8")
    print(table)
    print(f"wrote {out / 'bench.json'}")
    return 0
