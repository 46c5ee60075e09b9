"""``formation bench --method M,...``: one member's whole control step on a scenario under each
``controller.method``, side by side (what the rigid method costs: the median per-member step on
the warehouse, the formation-level QP included, against ``method: thesis``).

Each method runs the scenario in process (:func:`simulator.inprocess.simulate`, no recording)
from start to end; every call of :meth:`agent.control.Controller.step` in that run is timed whole
(nominal command, under ``rigid`` the formation's twist QP of :func:`agent.body.formation_twist`,
the robot's rows and its QP), and under ``rigid`` the formation QP alone as well. Under ``rigid``
every member computes the formation QP itself (:mod:`agent.body`): there is no leader-only part.
The timers wrap the two functions for the run only (a benchmark harness: the product's loop reads
no extra clock). The load average is recorded beside the timings: this is a shared machine.
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import replace
from pathlib import Path
from typing import Any

import agent.body
import agent.control
import simulator.inprocess
from experiments.machine import load_avg, percentile
from scenario import load_scenario
from scenario.model import METHODS


def parse_methods(text: str) -> list[str]:
    """``rigid,thesis`` -> ['rigid', 'thesis']; ValueError naming the culprit."""
    methods = [m.strip() for m in text.split(",") if m.strip()]
    bad = [m for m in methods if m not in METHODS]
    if not methods or bad:
        raise ValueError(f"--method: {bad[0] if bad else text!r} is not one of {', '.join(METHODS)}")
    return methods


@contextmanager
def _timing(module: Any, name: str, into: list[float]) -> Iterator[None]:
    """Time every call of ``module.name`` into ``into`` [us] while the context is open."""
    real: Callable[..., Any] = getattr(module, name)

    def timed(*args: Any, **kwargs: Any) -> Any:
        t0 = time.perf_counter_ns()
        out = real(*args, **kwargs)
        into.append((time.perf_counter_ns() - t0) * 1e-3)
        return out

    setattr(module, name, timed)
    try:
        yield
    finally:
        setattr(module, name, real)


def _stats(us: Sequence[float]) -> dict[str, float | None]:
    if not us:
        return {"median_us": None, "p99_us": None}
    return {"median_us": statistics.median(us), "p99_us": percentile(list(us), 0.99)}


def bench_method(scenario_path: Path, method: str, duration: float | None = None) -> dict:
    """The per-member step timings of one method on the scenario (module docstring)."""
    scenario = load_scenario(scenario_path)
    scenario = replace(scenario, controller=replace(scenario.controller, method=method))
    if duration is not None:
        scenario = replace(scenario, duration=min(duration, scenario.duration))
    steps: list[float] = []
    twist: list[float] = []
    load0 = load_avg()
    with _timing(agent.control.Controller, "step", steps), \
            _timing(agent.body, "formation_twist", twist):
        summary = simulator.inprocess.simulate(
            scenario, simulator.inprocess.SimOptions(record=False)).summary
    return {"method": method, "scenario": scenario.name, "steps": len(steps),
            "step": _stats(steps), "formation_qp": _stats(twist),
            "all_reached": summary["all_reached"], "collisions": summary["collisions"],
            "load_avg_1min_at_start": load0}


def bench_methods(scenario_path: Path, methods: Sequence[str], duration: float | None = None
                  ) -> dict:
    """:func:`bench_method` for each of ``methods``, in order."""
    return {"scenario": str(scenario_path), "methods": [bench_method(scenario_path, m, duration)
                                                        for m in methods]}


def _load(x: float | None) -> str:
    return "-" if x is None else f"{x:.2f}"


def format_methods(result: dict) -> str:
    """The table of a :func:`bench_methods` result."""
    lines = [f"per-member control step on {Path(result['scenario']).name} (in process, whole run)",
             f"{'method':<8}{'steps':>8}{'median us':>11}{'p99 us':>9}{'formation QP us':>17}"
             f"{'load':>7}"]
    for m in result["methods"]:
        fq = m["formation_qp"]["median_us"]
        lines.append(f"{m['method']:<8}{m['steps']:>8}{m['step']['median_us']:>11.1f}"
                     f"{m['step']['p99_us']:>9.1f}{'-' if fq is None else f'{fq:.1f}':>17}"
                     f"{_load(m['load_avg_1min_at_start']):>7}")
    return "\n".join(lines)
