"""Throughput and speed of a lifelong scenario, under the team allocation and the greedy baseline.

    PYTHONPATH=. python benchmarks/lifelong_throughput.py SCENARIO [--duration S]
    PYTHONPATH=. python benchmarks/lifelong_throughput.py SCENARIO --hours H [--allocator NAME]
        [--profile FILE]

Runs the scenario in process on the same order stream (the same seed, the same rounds, every
bid delivered at the close): once with :func:`leader.allocation.allocate` (the exact
minimum-total-travel teams of the orders each round serves) and once with
:func:`leader.allocation.greedy_nearest` (each slot in turn the nearest robot left). One line
each: orders posted and delivered, delivered per robot-hour, the median and p95 service
efficiency (the straight-line bound of gathering plus carrying at top speed over the time from
assignment to delivery), the median latency, collisions, stuck orders, the CPU seconds the run
took and the CPU seconds per simulated hour.

``--hours H`` is the speed measure: the run lasts ``H`` simulated hours and its stream posts
orders throughout (``until`` moved to the run's end), with one allocator (``--allocator``,
default ``allocate``); ``--profile FILE`` writes the run's cProfile statistics there.
"""

from __future__ import annotations

import argparse
import cProfile
import dataclasses
import time
from pathlib import Path

from scenario import Scenario


def stretched(scenario: Scenario, duration: float | None, hours: float | None) -> Scenario:
    """``scenario`` run for ``duration`` seconds, or for ``hours`` with its stream posting
    to the end."""
    if hours is not None:
        seconds = hours * 3600.0
        life = scenario.lifelong
        if life is not None and life.stream is not None:
            life = dataclasses.replace(life, stream=dataclasses.replace(life.stream,
                                                                        until=seconds))
        return dataclasses.replace(scenario, duration=seconds, lifelong=life)
    if duration is not None:
        return dataclasses.replace(scenario, duration=duration)
    return scenario


def measure(scenario: Scenario, allocator: str, profile: Path | None = None) -> dict:
    """One run's throughput and its CPU time (``profile``: cProfile statistics written there)."""
    from simulator.inprocess import SimOptions
    from simulator.lifelong import LifelongOptions, simulate_lifelong

    prof = cProfile.Profile() if profile is not None else None
    start = time.process_time()
    if prof is not None:
        prof.enable()
    result = simulate_lifelong(scenario, SimOptions(record=False),
                               LifelongOptions(allocator=allocator))
    if prof is not None:
        prof.disable()
        prof.dump_stats(str(profile))
    cpu = time.process_time() - start
    s = result.summary
    o = s["orders"]
    eff = o["service_efficiency"] or {}
    lat = o["latency_s"] or {}
    hours = s["sim_time_s"] / 3600.0
    return {"allocator": allocator, "posted": o["posted"], "delivered": o["delivered"],
            "per_robot_hour": o["delivered_per_robot_hour"], "eff_median": eff.get("median"),
            "eff_p95": eff.get("p95"), "latency_median_s": lat.get("median"),
            "collisions": s["collisions"], "stuck": o["stuck"], "sim_s": s["sim_time_s"],
            "cpu_s": round(cpu, 1),
            "cpu_s_per_sim_hour": round(cpu / hours, 1) if hours > 0 else None}


def main() -> None:
    from scenario import load_scenario

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scenario", type=Path)
    ap.add_argument("--duration", type=float, default=None, help="[s] instead of the file's")
    ap.add_argument("--hours", type=float, default=None,
                    help="[h] the speed measure: this long, the stream posting to the end")
    ap.add_argument("--allocator", default=None, choices=["allocate", "greedy"],
                    help="only this allocator (with --hours: default allocate)")
    ap.add_argument("--profile", type=Path, default=None, help="cProfile statistics file")
    ns = ap.parse_args()
    scenario = stretched(load_scenario(ns.scenario), ns.duration, ns.hours)
    allocators = ((ns.allocator,) if ns.allocator else
                  ("allocate",) if ns.hours is not None else ("allocate", "greedy"))
    for allocator in allocators:
        print(measure(scenario, allocator, ns.profile), flush=True)


if __name__ == "__main__":
    main()
