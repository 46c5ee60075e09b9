"""MuJoCo's real-time factor for N TurtleBot3 bodies (simulator.physics), without the controller.

    PYTHONPATH=. python benchmarks/physics_rtf.py 4 16 40 [--repeat 5]

N robots stand on a grid 1 m apart, each driving a circle (v 0.15 m/s, omega 0.5 rad/s) for
SECONDS simulated seconds at dt 0.05 (25 MuJoCo steps of 2 ms per period). Printed per N: the
real-time factor of MuJoCo's steps alone (simulated time over the time spent in ``mj_step``)
and of the whole world step (wheel targets, steps, contact scan, poses), each the median of
``--repeat`` runs (3 by default; the range in brackets), and the contacts counted (0: the
circles never meet).
"""

from __future__ import annotations

import argparse
import math
import statistics
import time

from scenario.load import scenario_from_dict
from simulator.physics import MujocoWorld

SECONDS = 20.0


def grid_scenario(n: int) -> dict:
    side = math.ceil(math.sqrt(n))
    robots = {f"r{k}": {"start": [float(k % side), float(k // side), 0.0],
                        "goal": [float(k % side), float(k // side)]} for k in range(n)}
    # one formation per robot: single robots need no edges
    formations = [{"name": f"f{k}", "leader": rid, "robots": {rid: spec}}
                  for k, (rid, spec) in enumerate(robots.items())]
    return {"name": f"rtf-{n}", "dt": 0.05, "duration": SECONDS,
            "robot": {"model": "unicycle"}, "formations": formations}


def measure(n: int) -> tuple[float, float, int]:
    sc = scenario_from_dict(grid_scenario(n))
    world = MujocoWorld(sc)
    state = [r.start for r in sc.robots]
    cmds = [(0.0, 0.0, 0.15, 0.5)] * n
    t0 = time.perf_counter()
    for _ in range(sc.steps):
        state = world.move(state, cmds)
    wall = time.perf_counter() - t0
    return world.time / world.step_wall, world.time / wall, world.collisions


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description="MuJoCo's real-time factor for N robots")
    p.add_argument("n", nargs="*", type=int, default=[4, 16, 40])
    p.add_argument("--repeat", type=int, default=3)
    a = p.parse_args(argv)
    for n in a.n:
        runs = [measure(n) for _ in range(a.repeat)]
        mj = [r[0] for r in runs]
        whole = [r[1] for r in runs]
        print(f"{n:3d} robots: real-time factor {statistics.median(mj):7.1f} "
              f"[{min(mj):.1f}-{max(mj):.1f}] (mj_step) {statistics.median(whole):7.1f} "
              f"[{min(whole):.1f}-{max(whole):.1f}] (world step), "
              f"contacts {max(r[2] for r in runs)}", flush=True)


if __name__ == "__main__":
    main()
