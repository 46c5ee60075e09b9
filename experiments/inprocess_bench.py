"""``formation bench --inprocess N,...``: how fast ``formation sim`` runs a fleet of N robots.

Each fleet is a warehouse (:func:`bench_warehouse`): shelf rows of three shelves, formations of
four robots carrying pallets (the remainder of N a pair, a triangle or a pentagon), each parked in
a main aisle with its goal in the next aisle up, behind a shelf row, so every leader plans a
route round a shelf (``controller.method: rigid``, the planner on, as in the warehouse draw of
:mod:`experiments.warehouse_draw`); a hall with more rows for more robots, so the robots per
square metre stay the same. Each runs ``duration`` simulated seconds through
:func:`simulator.inprocess.simulate`, recorded as ``formation sim`` records (planning included:
the first plans are made inside the run), and reports robot-ticks per CPU second and simulated
seconds per CPU second (x real time on one core). CPU time (``time.process_time``), not wall
time: the figure of one core however busy the machine is with other work.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence

from experiments.warehouse_draw import EAST, Hall, formation, structure
from geometry.limits import BURGER_MAX_SPEED, BURGER_RADIUS
from scenario.load import scenario_from_dict

INPROCESS_ROBOTS = (4, 8, 16, 32, 50, 100, 200)  # the curve's fleet sizes
INPROCESS_DURATION = 20.0  # [s] simulated per fleet
SHELVES = 3  # shelves in a row
SHELF_LENGTH = 4.5  # [m]
CROSS = 2.0  # [m] a cross aisle between two shelves of a row
AISLE = 2.2  # [m] a main aisle
DEPTH = 0.8  # [m] a shelf row's depth
SIDE = 2.2  # [m] a side aisle
PLACES = (0.25, 0.75)  # where along a shelf a formation parks (two to a shelf's stretch of aisle)
REMAINDER = {1: "pentagon", 2: "pair", 3: "triangle"}  # the last formation, for N mod 4


def fleet_kinds(n: int) -> list[str]:
    """The formations' shapes for ``n`` robots: rectangles of four, the remainder one last
    formation (a pentagon takes a rectangle's four robots and the one left over)."""
    if n < 2:
        raise ValueError(f"n: need at least 2 robots, got {n}")
    rest = n % 4
    kinds = ["rectangle"] * (n // 4)
    if rest == 1:
        kinds[-1] = "pentagon"
    elif rest:
        kinds.append(REMAINDER[rest])
    return kinds


def bench_hall(formations: int) -> Hall:
    """A hall whose every other main aisle parks formations (:data:`PLACES` per shelf), with
    the aisle above each free for their goals."""
    per_aisle = SHELVES * len(PLACES)
    pairs = math.ceil(formations / per_aisle)
    rows = 2 * pairs - 1  # a shelf row between every two aisles
    span = SHELVES * SHELF_LENGTH + (SHELVES - 1) * CROSS
    height = (rows + 1) * AISLE + rows * DEPTH
    south = -height / 2
    aisles = [south + k * (AISLE + DEPTH) + AISLE / 2 for k in range(rows + 1)]
    centres = [south + (k + 1) * AISLE + k * DEPTH + DEPTH / 2 for k in range(rows)]
    shelves = [(-span / 2 + j * (SHELF_LENGTH + CROSS), -span / 2 + j * (SHELF_LENGTH + CROSS)
                + SHELF_LENGTH) for j in range(SHELVES)]
    return Hall(span + 2 * SIDE, height, AISLE, DEPTH, SIDE, aisles, centres, shelves, None)


def bench_warehouse(n: int, duration: float = INPROCESS_DURATION) -> dict:
    """The scenario-file mapping of the ``n``-robot bench warehouse (module docstring)."""
    kinds = fleet_kinds(n)
    hall = bench_hall(len(kinds))
    per_aisle = SHELVES * len(PLACES)
    drawn = []
    for k, kind in enumerate(kinds):
        a, slot = 2 * (k // per_aisle), k % per_aisle
        x0, _x1 = hall.shelves[slot // len(PLACES)]
        x = round(x0 + SHELF_LENGTH * PLACES[slot % len(PLACES)], 4)
        drawn.append(formation(f"f{k}", kind, (x, round(hall.aisles[a], 4), EAST),
                               (x, round(hall.aisles[a + 1], 4), EAST)))
    return {
        "name": f"bench-warehouse-{n}",
        "dt": 0.05,
        "duration": duration,
        "goal_tolerance": 0.05,
        "robot": {"model": "single_integrator", "max_speed": BURGER_MAX_SPEED,
                  "radius": BURGER_RADIUS},
        "controller": {"kp": 2.0, "gamma": {"formation": 1.0, "obstacle": 0.8, "formations": 0.5},
                       "epsilon": 0.05, "method": "rigid"},
        "formations": drawn,
        "obstacles": structure(hall),
    }


def bench_inprocess_fleet(n: int, duration: float = INPROCESS_DURATION) -> dict:
    """One point of the curve: ``n`` robots for ``duration`` simulated seconds (module
    docstring), with the CPU seconds they took."""
    from simulator.inprocess import SimOptions, simulate

    scenario = scenario_from_dict(bench_warehouse(n, duration))
    cpu0 = time.process_time()
    res = simulate(scenario, SimOptions(stop_at_goal=False))
    cpu = time.process_time() - cpu0
    ticks = res.summary["steps"]
    sim_s = ticks * scenario.dt
    return {"robots": n, "formations": len(scenario.formations), "ticks": ticks,
            "sim_s": round(sim_s, 6), "cpu_s": round(cpu, 3),
            "robot_ticks_per_cpu_s": round(n * ticks / cpu, 1) if cpu > 0 else None,
            "x_real_time": round(sim_s / cpu, 3) if cpu > 0 else None,
            "collisions": res.summary["collisions"]}


def bench_inprocess_curve(sizes: Sequence[int] = INPROCESS_ROBOTS,
                          duration: float = INPROCESS_DURATION) -> dict:
    """The in-process curve: one :func:`bench_inprocess_fleet` per fleet size, one after the
    other in this process."""
    return {"inprocess_curve": {"duration_s": duration,
                                "fleets": [bench_inprocess_fleet(n, duration) for n in sizes]}}


def parse_sizes(text: str) -> list[int]:
    """``N,N,...`` (e.g. ``4,8,50``) -> fleet sizes; ValueError naming the bad item."""
    out = []
    for item in text.split(","):
        try:
            n = int(item.strip())
        except ValueError:
            n = 0
        if n < 2:
            raise ValueError(f"--inprocess: {item.strip()!r} is not a robot count >= 2")
        out.append(n)
    return out


def format_curve(result: dict) -> str:
    """The curve as a table: robots, formations, robot-ticks per CPU second, x real time."""
    curve = result["inprocess_curve"]
    lines = [f"in-process ({curve['duration_s']:g} s simulated per fleet, CPU time of one core)",
             f"{'robots':>7}{'formations':>11}{'ticks/cpu-s':>13}{'x real time':>13}{'cpu s':>8}"]
    for f in curve["fleets"]:
        lines.append(f"{f['robots']:>7}{f['formations']:>11}{f['robot_ticks_per_cpu_s']:>13.0f}"
                     f"{f['x_real_time']:>13.2f}{f['cpu_s']:>8.1f}")
    return "\n".join(lines)
