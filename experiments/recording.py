"""What recording and watching cost the fleet (``formation bench``, part ``viewer``).

* :func:`bench_recording`: in-process throughput (robot-steps per second of wall time) of the
  simulator on a scenario three ways, interleaved so machine noise hits them alike: without
  keeping the time series (``record=False``, the loop alone), with it (what ``formation sim``
  does), and with it plus writing ``run.mcap`` afterwards (:func:`viewer.record.write_recording`);
  also the recording's own cost per tick and the file's size.
* Agent latency with a viewer attached is :func:`formation.bench.bench_agents` run twice on the
  same fleet, the second time with ``formation view --connect`` attached to its router (see
  ``agents_viewer`` in ``bench.json``).
"""

from __future__ import annotations

import tempfile
import time
from dataclasses import replace
from pathlib import Path

from scenario import load_scenario
from simulator.inprocess import SimOptions, simulate
from viewer.record import write_recording


def bench_recording(scenario_path: Path, duration: float | None, rounds: int = 2) -> dict:
    scenario = load_scenario(scenario_path)
    if duration is not None:
        scenario = replace(scenario, duration=min(duration, scenario.duration))
    n = len(scenario.robot_ids)
    best = {"loop_only": float("inf"), "with_series": float("inf"), "with_mcap": float("inf")}
    write_s = float("inf")
    size = ticks = 0
    with tempfile.TemporaryDirectory(prefix="bench-rec-") as tmp:
        for _ in range(rounds):
            t0 = time.perf_counter()
            res = simulate(scenario, SimOptions(record=False))
            best["loop_only"] = min(best["loop_only"], time.perf_counter() - t0)
            t0 = time.perf_counter()
            res = simulate(scenario, SimOptions(record=True))
            t1 = time.perf_counter()
            path = write_recording(res.summary, res.series, scenario, Path(tmp))
            t2 = time.perf_counter()
            best["with_series"] = min(best["with_series"], t1 - t0)
            best["with_mcap"] = min(best["with_mcap"], t2 - t0)
            write_s = min(write_s, t2 - t1)
            size = path.stat().st_size
            ticks = res.summary["steps"]
    steps = ticks * n
    return {
        "scenario": scenario.name, "robots": n, "ticks": ticks,
        "robot_steps_per_s": {k: steps / v for k, v in best.items()},
        "record_ms_per_tick": 1e3 * write_s / ticks if ticks else None,
        "mcap_bytes": size,
        "mcap_bytes_per_tick": size / ticks if ticks else None,
    }
