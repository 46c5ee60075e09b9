"""Route-planning cost: the footprint planner (geometry.footprint_plan) for a 6-robot
line (1.5 m) in a 40 x 30 m hall with 50 shelves (5 columns x 10 rows, 1.8 m aisles, cross
aisles between the columns), from one aisle to another; prints each plan's time and the median.

    python benchmarks/route_plan.py [--plans N] [--seed S] [--ticks] [--draw N]

``--ticks`` also runs a 20 Hz loop (3 ms of Python work a tick) while the same plans run in a
worker process (as agent.replan runs them), then in a worker thread, and counts the ticks that
ended after their period.

``--draw N`` instead plans every formation's start route (:func:`scenario.routes.start_plan`, as
``formation check`` and the draw's own check do) in the warehouse draw's layouts of sub-seeds
0 .. N-1 (experiments.warehouse_draw), and prints each plan's CPU time, the median, mean, max and
total, and the plans with no route. The same file run with another tree first on the path (a copy
outside this checkout, PYTHONPATH=TREE) times that tree's planner on the same layouts.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import statistics
import sys
import time
from concurrent.futures import Executor, ProcessPoolExecutor, ThreadPoolExecutor
from multiprocessing import get_context
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from agent.replan import PLAN_NICE
from geometry.footprint_plan import Body, plan_footprint
from geometry.shapes import Shape, box, segment

HALL = (40.0, 30.0)
SHELF = (6.0, 0.8)
COLUMNS = (5.0, 12.75, 20.5, 28.25, 36.0)  # shelf centres along x (cross aisles ~1.75 m)
ROWS = tuple(2.5 + 2.6 * k for k in range(10))  # shelf centres along y (aisles 1.8 m)
DS = 0.15  # [m] a shelf's safe distance (from a robot's centre)


def hall() -> list[Shape]:
    """The shelves and the hall's four walls."""
    w, h = HALL
    shapes = [box(f"s{c}-{r}", (x, y), SHELF, 0.0, DS)
              for c, x in enumerate(COLUMNS) for r, y in enumerate(ROWS)]
    corners = [(0.0, 0.0), (w, 0.0), (w, h), (0.0, h)]
    shapes += [segment(f"wall{k}", corners[k], corners[(k + 1) % 4], DS) for k in range(4)]
    return shapes


def line(n: int = 6, spacing: float = 0.3) -> Body:
    """n robots in a row along x, ``spacing`` apart, centred (no declared load: the hull)."""
    half = (n - 1) * spacing / 2
    return Body(tuple((-half + k * spacing, 0.0) for k in range(n)), radius=0.105)


def queries(count: int, seed: int) -> list[tuple[tuple[float, float, float], tuple[float, float, float]]]:
    """Start and goal poses in aisles (lengthwise), in different rows and columns."""
    rng = random.Random(seed)
    aisles = [0.5 * (ROWS[k] + ROWS[k + 1]) for k in range(len(ROWS) - 1)]
    out = []
    for _ in range(count):
        a, b = rng.sample(aisles, 2)
        ca, cb = rng.sample(COLUMNS, 2)
        out.append(((ca + rng.uniform(-2, 2), a, 0.0), (cb + rng.uniform(-2, 2), b, 0.0)))
    return out


def ticks_while_planning(shapes: list[Shape], body: Body, plans: list, period: float = 0.05,
                         work_s: float = 0.003, thread: bool = False) -> dict:
    """A 20 Hz loop (each tick ``work_s`` of Python work, about a member's control step) while
    the plans run one after another in a worker (a ``spawn`` process as a leader's replans do,
    agent.replan; or a thread): how late the ticks ended past their period."""
    pool: Executor = (ThreadPoolExecutor(max_workers=1) if thread
                      else ProcessPoolExecutor(max_workers=1, mp_context=get_context("spawn"),
                                          initializer=os.nice, initargs=(PLAN_NICE,)))
    pool.submit(int).result()  # the worker is up (a process imports the planner once)
    jobs = [pool.submit(plan_footprint, a, b, body, shapes) for a, b in plans]
    out = _tick_loop(lambda k: not all(j.done() for j in jobs), period, work_s)
    pool.shutdown()
    return {"worker": "thread" if thread else "process", **out}


def _tick_loop(going, period: float, work_s: float) -> dict:
    """Ticks of ``work_s`` busy work every ``period`` while ``going(tick)``: how late they end."""
    late, missed, ticks = [], 0, 0
    start = time.perf_counter()
    while going(ticks):
        ticks += 1
        deadline = start + ticks * period
        t0 = time.perf_counter()
        while time.perf_counter() - t0 < work_s:
            pass
        over = time.perf_counter() - deadline
        late.append(max(0.0, over + period))  # how long after its start the tick ended
        missed += over > 0.0
        time.sleep(max(0.0, deadline - time.perf_counter()))
    return {"ticks": ticks, "missed": missed,
            "tick_end_median_ms": round(1e3 * statistics.median(late), 2),
            "tick_end_max_ms": round(1e3 * max(late), 2)}


def draw_plans(count: int) -> dict:
    """Every formation's start plan in the warehouse draw's layouts 0 .. count-1: CPU times."""
    from experiments.warehouse_draw import warehouse_scenario
    from scenario import ScenarioError
    from scenario.load import scenario_from_dict
    from scenario.routes import start_plan

    cpus, refused = [], []
    for sub in range(count):
        try:
            scenario = scenario_from_dict(warehouse_scenario(sub))
        except ScenarioError:
            continue  # a layout the scenario checks refuse (the draw redraws it)
        for f in scenario.formations:
            c0 = time.process_time()
            plan = start_plan(scenario, f)
            cpus.append(time.process_time() - c0)
            if plan.reason:
                refused.append(f"{sub}/{f.name}: {plan.reason}")
    return {"layouts": count, "plans": len(cpus), "median_cpu_s": round(statistics.median(cpus), 4),
            "mean_cpu_s": round(statistics.mean(cpus), 4), "max_cpu_s": round(max(cpus), 3),
            "total_cpu_s": round(sum(cpus), 2), "no_route": len(refused), "refused": refused}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--plans", type=int, default=9)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--ticks", action="store_true",
                        help="also run a 20 Hz loop while the plans run in a worker thread")
    parser.add_argument("--draw", type=int, default=0, metavar="N",
                        help="time the start plans of the warehouse draw's first N layouts instead")
    args = parser.parse_args(argv)
    if args.draw:
        print(json.dumps(draw_plans(args.draw)))
        return 0
    shapes, body = hall(), line()
    if args.ticks:
        print(json.dumps({"worker": "none (the machine alone)",
                          **_tick_loop(lambda k: k < 300, 0.05, 0.003)}))
        for thread in (False, True):
            print(json.dumps(ticks_while_planning(shapes, body, queries(args.plans, args.seed),
                                                  thread=thread)))
    times, cpus, rows = [], [], []
    for start, goal in queries(args.plans, args.seed):
        t0, c0 = time.perf_counter(), time.process_time()
        plan = plan_footprint(start, goal, body, shapes)
        dt, cpu = time.perf_counter() - t0, time.process_time() - c0
        times.append(dt)
        cpus.append(cpu)
        rows.append({"start": start, "goal": goal, "s": round(dt, 3), "cpu_s": round(cpu, 3),
                     "waypoints": len(plan.route), "expanded": plan.expanded, "reason": plan.reason})
        print(json.dumps(rows[-1]))
    print(json.dumps({"plans": len(times), "median_s": round(statistics.median(times), 3),
                      "max_s": round(max(times), 3), "median_cpu_s": round(statistics.median(cpus), 3),
                      "no_route": sum(1 for r in rows if r["reason"]),
                      "load_average_1min": round(os.getloadavg()[0], 1)}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
