"""End-to-end latency and CPU of the multi-process system (not a test).

Runs ``formation run`` on a scenario twice through :func:`simulator.launch.launch`:

* real time (``--realtime``): the world stamps each pose with ``time.time()`` and records, for
  every command, ``receive time - stamp of the pose it was computed from``: pose published ->
  command received, including the wait for the agent's own tick (agents tick on their own clock,
  so about half a period of it is phase), transport through the router both ways and the solve;
* lock-step: the world waits for every command before the next tick, so wall time per tick is
  the round trip pose -> state -> ellipse -> others -> cmd with no clock phase in it.

CPU per agent is the agent's own ``time.process_time()`` (all its threads, Zenoh's included)
over its lifetime, as a percentage of one core.

    PYTHONPATH=. python3 benchmarks/latency.py [--scenario scenarios/thesis-5.2.2.yaml]
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
from pathlib import Path

from scenario import load_scenario
from simulator.launch import launch
from simulator.run_config import RunConfig


def measure(scenario_path: str, out: Path) -> dict:
    scenario = load_scenario(scenario_path)
    rt, _ = launch(RunConfig(scenario, out / "realtime", realtime=True))
    ls, _ = launch(RunConfig(scenario, out / "lockstep", realtime=False))
    agents = rt["agents"]
    wall = agents["wall_s"]
    cpu_pct = {r: 100.0 * c / wall for r, c in agents["cpu_s"].items()}
    lat = rt["world"]["latency_ms"] or {}
    return {
        "scenario": scenario.name,
        "robots": len(scenario.robot_ids),
        "period_ms": scenario.dt * 1e3,
        "realtime": {
            "latency_ms": lat,
            "agent_tick_us_median": agents["tick_us_median"],
            "pose_age_at_tick_us_median": agents["pose_age_us_median"],
            "overruns": agents["overruns"],
            "stale": agents["stale"],
            "time_to_goal_s": rt["time_to_goal_s"],
            "cpu_percent_per_agent": cpu_pct,
            "cpu_percent_per_agent_median": statistics.median(cpu_pct.values()),
        },
        "lockstep": {
            "steps": ls["steps"],
            "wall_s": ls["world"]["wall_s"],
            "round_trip_ms_per_tick": 1e3 * ls["world"]["wall_s"] / ls["steps"],
            "time_to_goal_s": ls["time_to_goal_s"],
        },
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--scenario", default="scenarios/thesis-5.2.2.yaml")
    parser.add_argument("--out", default=None, help="keep the runs here (default: a temp dir)")
    parser.add_argument("--json", action="store_true", help="print the full result as JSON")
    ns = parser.parse_args(argv)
    if ns.out:
        result = measure(ns.scenario, Path(ns.out))
    else:
        with tempfile.TemporaryDirectory() as tmp:
            result = measure(ns.scenario, Path(tmp))
    rt, ls = result["realtime"], result["lockstep"]
    lat = rt["latency_ms"]
    print(f"{result['scenario']} ({result['robots']} agents, period {result['period_ms']:.0f} ms): "
          f"real time pose->cmd median {lat.get('median_ms', float('nan')):.1f} ms, "
          f"p99 {lat.get('p99_ms', float('nan')):.1f} ms over {lat.get('samples', 0)} commands; "
          f"of which the pose waits {rt['pose_age_at_tick_us_median'] / 1e3:.1f} ms (median) for the "
          f"agent's own tick; agent tick {rt['agent_tick_us_median']:.0f} us median; "
          f"CPU per agent {rt['cpu_percent_per_agent_median']:.1f}% of a core (median); "
          f"lock-step round trip {ls['round_trip_ms_per_tick']:.2f} ms per tick")
    if ns.json:
        print(json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
