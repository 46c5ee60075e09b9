"""The benchmark fleet: N/4 four-robot rectangles travelling in parallel lanes (``formation bench``)."""

from __future__ import annotations

import logging

from geometry.limits import BURGER_MAX_SPEED, BURGER_RADIUS
from scenario.load import scenario_from_dict

logger = logging.getLogger(__name__)

# Fleets of the "agents" and "central" parts: N/4 rectangles travelling in parallel lanes.
LANE_SPACING = 2.5  # [m] between the centroids of neighbouring lanes
COLUMN_SPACING = 9.0  # [m] between formations sharing a lane
TRAVEL = 7.0  # [m] goal ahead of the start (not reached within the benchmark's duration)


def fleet_scenario(n: int, dt: float, duration: float):
    """``n`` robots (a multiple of 4) as n/4 rectangles of 0.5 m x 0.25 m, in parallel lanes
    ``LANE_SPACING`` apart (up to 4 formations per lane), all travelling +x towards goals
    ``TRAVEL`` ahead, with 2 static obstacles beside the fleet: every robot has 3 neighbours,
    2 obstacles and n/4 - 1 other formations in view, and nobody is in anybody's way."""
    if n < 4 or n % 4:
        raise ValueError(f"n: need a positive multiple of 4 robots, got {n}")
    k = n // 4
    per_lane = min(4, k)
    shape = ((-0.5, 0.125), (0.0, 0.125), (0.0, -0.125), (-0.5, -0.125))
    formations = []
    for f in range(k):
        x0, y0 = (f % per_lane) * COLUMN_SPACING, (f // per_lane) * LANE_SPACING
        robots = {}
        for i, (dx, dy) in enumerate(shape, start=1):
            robots[f"f{f}r{i}"] = {"start": [x0 + dx, y0 + dy],
                                   "goal": [x0 + dx + TRAVEL, y0 + dy]}
        r = [f"f{f}r{i}" for i in range(1, 5)]
        formations.append({"name": f"f{f}", "leader": r[1], "robots": robots,
                           "edges": [[r[0], r[1]], [r[0], r[3]], [r[1], r[2]], [r[1], r[3]],
                                     [r[2], r[3]]]})
    return scenario_from_dict({
        "name": f"bench-fleet-{n}",
        "dt": dt,
        "duration": duration,
        "robot": {"model": "single_integrator", "max_speed": BURGER_MAX_SPEED, "radius": BURGER_RADIUS},
        "controller": {"kp": 2.0, "gamma": {"formation": 1.0, "obstacle": 0.8, "formations": 0.5},
                       "epsilon": 0.04},
        "formations": formations,
        "obstacles": [{"name": "o1", "center": [2.0, -1.5], "safe_distance": 0.35},
                      {"name": "o2", "center": [5.0, -1.5], "safe_distance": 0.35}],
    })
