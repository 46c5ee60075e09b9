"""Throughput of a lifelong scenario under the team allocation and the greedy baseline.

    PYTHONPATH=. python benchmarks/lifelong_throughput.py SCENARIO [--duration S]

Runs the scenario in process twice on the same order stream (the same seed, the same rounds,
every bid delivered at the close): once with :func:`leader.allocation.allocate` (the exact
minimum-total-travel teams of the orders each round serves) and once with
:func:`leader.allocation.greedy_nearest` (each slot in turn the nearest robot left). One line
each: orders posted and delivered, delivered per robot-hour, the median and p95 service
efficiency (the straight-line bound of gathering plus carrying at top speed over the time from
assignment to delivery), the median latency, collisions, stuck orders and the CPU seconds the
run took.
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path


def measure(path: Path, allocator: str, duration: float | None) -> dict:
    from scenario import load_scenario
    from simulator.inprocess import SimOptions
    from simulator.lifelong import LifelongOptions, simulate_lifelong

    scenario = load_scenario(path)
    if duration is not None:
        scenario = dataclasses.replace(scenario, duration=duration)
    start = time.process_time()
    result = simulate_lifelong(scenario, SimOptions(record=False),
                               LifelongOptions(allocator=allocator))
    cpu = time.process_time() - start
    s = result.summary
    o = s["orders"]
    eff = o["service_efficiency"] or {}
    lat = o["latency_s"] or {}
    return {"allocator": allocator, "posted": o["posted"], "delivered": o["delivered"],
            "per_robot_hour": o["delivered_per_robot_hour"], "eff_median": eff.get("median"),
            "eff_p95": eff.get("p95"), "latency_median_s": lat.get("median"),
            "collisions": s["collisions"], "stuck": o["stuck"], "sim_s": s["sim_time_s"],
            "cpu_s": round(cpu, 1)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scenario", type=Path)
    ap.add_argument("--duration", type=float, default=None, help="[s] instead of the file's")
    ns = ap.parse_args()
    for allocator in ("allocate", "greedy"):
        print(measure(ns.scenario, allocator, ns.duration), flush=True)


if __name__ == "__main__":
    main()
