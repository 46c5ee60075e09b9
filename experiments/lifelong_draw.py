"""The lifelong draw of ``formation montecarlo --draw lifelong``: halls with stations and a stream.

Each run draws, from its own seed, a hall closed by four walls with 1 or 2 shelf rows (boxes)
running east-west, each row cut in two by a cross aisle at x = 0; main aisles run between the
rows and between the outer rows and the walls, side aisles at both ends join them. In the hall:

* floor racks (stores) in a line along one side of every main aisle, against a shelf row's face
  (a load's outline :data:`RACK_GAP` from the shelf), every :data:`RACK_PITCH` along the shelf,
  each kept with probability 3/4; 0 to 1/3 of them hold a resting load at t = 0;
* 1 or 2 inbound docks (sources) in the west side aisle and 1 or 2 outbound docks (sinks, a
  dwell of 5 to 15 s) in the east one, loads lying north-south there;
* load types: pallets (0.8 m x 0.6 m, a team of four), beams (1.4 m x 0.3 m, a team of two), or
  both;
* a fleet of 4 to 12 robots (2 to 12 when only beams are drawn) in a row along the north wall,
  where they also park;
* with probability 1/2 a pillar (a static circle) at a side aisle's corner, and with
  probability 1/3 a forklift that drives from a main aisle into the cross aisle and parks there
  for good (a moving circle with ``stop_at``);
* a seeded order stream of 0.4 to 1.2 orders a minute, at most :data:`RATE_PER_TEAM` for each
  team the fleet can field at once, for :data:`STREAM_S` s (ten minutes of operation: no run
  ends before), in a run of at most :data:`DURATION_S` s (the rest is time to finish the orders
  posted last; the run ends once every order is done); one robot model for the run, single
  integrator or unicycle.

:func:`lifelong_scenario` is the pure draw (a scenario-file mapping); :func:`lifelong_problem`
is what the draw asks beyond the scenario checks: a stream that posts at least
:data:`MIN_ORDERS` servable orders (:func:`scenario.stream.plan`).
:func:`experiments.montecarlo.valid_scenario` redraws from the next sub-seed on either's
refusal.
"""

from __future__ import annotations

import math
import random
from typing import Any, NamedTuple

from geometry.limits import BURGER_MAX_SPEED, BURGER_RADIUS
from scenario.model import Scenario
from scenario.stream import plan

from .warehouse_draw import outer_walls

DURATION_S = 1200.0  # [s] a run at most: the stream's ten minutes, then its last orders served
STREAM_S = 600.0  # [s] orders arrive until then: every run lasts at least 10 simulated minutes
# [orders/min] the stream's rate at most, per team the fleet fields at once: what a team of
# unicycles serves (gathering, lifting, carrying across a hall, setting down: three minutes
# and more an order), so that the orders posted last are served within the run
RATE_PER_TEAM = 0.3
MIN_ORDERS = 2  # a drawn stream posts at least this many orders
WALL_DS = 0.15  # [m] safe distance of walls and shelves
RACK_GAP = 0.25  # [m] between a shelf's face and the outline of a load resting at its rack: a
# slot on the shelf side keeps 10 cm beyond the shelf's safe distance (at 0.15, exactly none, and a
# planner that needs a stated clearance found no way into it)
RACK_PITCH = 1.8  # [m] between racks along a shelf: a beam's length and a gap
DOCK_INSET = 0.9  # [m] from the side wall to a dock's centre
PARK_INSET = 0.5  # [m] from the north wall to the parked row
PARK_PITCH = 0.6  # [m] between parked robots
PALLET: dict[str, Any] = {"size": [0.8, 0.6], "team": 4}
BEAM: dict[str, Any] = {"size": [1.4, 0.3], "team": 2}
LONGEST_HALF = 0.7  # [m] half the longest side of a drawn load type
WIDEST_HALF = 0.3  # [m] half the widest side of a drawn load type
CONTROLLER = {"kp": 2.0, "gamma": {"formation": 1.0, "obstacle": 0.8, "formations": 0.5},
              "epsilon": 0.05}


class Hall(NamedTuple):
    """The drawn layout: its size, the main aisles' and the rows' centres (south to north),
    the aisle width, the row depth, the side aisle's width, each shelf's x interval (the same in
    every row) and the cross aisle's width."""

    width: float
    height: float
    aisles: list[float]
    rows: list[float]
    aisle: float
    depth: float
    side: float
    shelves: list[tuple[float, float]]
    cross: float


def _r(x: float) -> float:
    return round(x, 4)


def draw_hall(rng: random.Random) -> Hall:
    n_rows = rng.randint(1, 2)
    aisle, depth, side = rng.uniform(2.8, 3.4), rng.uniform(0.8, 1.0), rng.uniform(2.6, 3.2)
    length, cross = rng.uniform(4.0, 6.0), rng.uniform(1.8, 2.4)
    height = (n_rows + 1) * aisle + n_rows * depth
    south = -height / 2
    aisles = [south + k * (aisle + depth) + aisle / 2 for k in range(n_rows + 1)]
    rows = [south + (k + 1) * aisle + k * depth + depth / 2 for k in range(n_rows)]
    shelves = [(-cross / 2 - length, -cross / 2), (cross / 2, cross / 2 + length)]
    return Hall(2 * (length + side) + cross, height, aisles, rows, aisle, depth, side, shelves,
                cross)


def structure(hall: Hall) -> list[dict]:
    """The outer walls and each row's two shelves."""
    out = outer_walls(hall.width, hall.height, WALL_DS)
    for k, y in enumerate(hall.rows):
        for j, (x0, x1) in enumerate(hall.shelves):
            out.append({"name": f"shelf-{k}{j}", "safe_distance": WALL_DS,
                        "box": {"center": [_r((x0 + x1) / 2), _r(y)],
                                "size": [_r(x1 - x0), _r(hall.depth)]}})
    return out


def rack_line(hall: Hall, aisle: int) -> float:
    """The y of aisle ``aisle``'s racks: against the row south of it (the first aisle: against
    the row north of it), a load's half width and the gap off the shelf's face."""
    off = hall.depth / 2 + RACK_GAP + WIDEST_HALF
    return hall.rows[aisle - 1] + off if aisle > 0 else hall.rows[0] - off


def racks(rng: random.Random, hall: Hall) -> dict[str, list[float]]:
    """Every kept rack: name -> [x, y, yaw]."""
    out: dict[str, list[float]] = {}
    for a in range(len(hall.aisles)):
        y = rack_line(hall, a)
        for j, (x0, x1) in enumerate(hall.shelves):
            n = int((x1 - x0 - 2 * LONGEST_HALF) // RACK_PITCH) + 1
            first = (x0 + x1) / 2 - (n - 1) * RACK_PITCH / 2
            for k in range(n):
                if rng.random() < 0.75:
                    out[f"rack-{a}{j}{k}"] = [_r(first + k * RACK_PITCH), _r(y), 0.0]
    return out


def docks(rng: random.Random, hall: Hall) -> dict[str, dict[str, Any]]:
    """1 or 2 sources by the west wall and 1 or 2 sinks by the east wall, at aisles' centres."""
    out: dict[str, dict[str, Any]] = {}
    x = hall.width / 2 - DOCK_INSET
    for kind, sign, prefix in (("source", -1.0, "in"), ("sink", 1.0, "out")):
        for n, a in enumerate(sorted(rng.sample(range(len(hall.aisles)),
                                                min(rng.randint(1, 2), len(hall.aisles))))):
            dock: dict[str, Any] = {"pose": [_r(sign * x), _r(hall.aisles[a]), _r(math.pi / 2)],
                                    "kind": kind}
            if kind == "sink":
                dock["dwell_s"] = float(rng.randint(5, 15))
            out[f"{prefix}-{n + 1}"] = dock
    return out


def fleet(rng: random.Random, hall: Hall, least: int) -> dict[str, Any]:
    """``least`` to 12 robots in a row along the north wall, parked there between orders."""
    n = rng.randint(least, 12)
    y = hall.height / 2 - PARK_INSET
    x0 = -PARK_PITCH * (n - 1) / 2
    spots = [[_r(x0 + k * PARK_PITCH), _r(y)] for k in range(n)]
    return {"robots": {f"r{k + 1}": {"start": [p[0], p[1], 0.0]} for k, p in enumerate(spots)},
            "parking": spots}


def obstacles(rng: random.Random, hall: Hall) -> list[dict]:
    """A pillar at a side aisle's corner (probability 1/2) and a forklift that parks in the
    cross aisle (probability 1/3)."""
    out = []
    w, h = hall.width / 2, hall.height / 2
    if rng.random() < 0.5:
        sx, sy = rng.choice((-1.0, 1.0)), rng.choice((-1.0, 1.0))
        out.append({"name": "pillar", "center": [_r(sx * (w - 0.5)), _r(sy * (h - 0.5))],
                    "safe_distance": 0.35})
    if rng.random() < 1.0 / 3.0:
        row = rng.randrange(len(hall.rows))
        aisle = row if rng.random() < 0.5 else row + 1  # start south or north of the row
        y0, y1 = hall.aisles[aisle], hall.rows[row]
        speed = 0.2
        out.append({"name": "forklift", "center": [0.0, _r(y0)], "safe_distance": _r(
            min(0.6, hall.cross / 2 - 0.2)), "velocity": [0.0, math.copysign(speed, y1 - y0)],
            "stop_at": _r(abs(y1 - y0) / speed)})
    return out


def lifelong_scenario(seed: int) -> dict:
    """The scenario mapping of draw ``seed`` (pure: the same seed, the same mapping)."""
    rng = random.Random(seed)
    hall = draw_hall(rng)
    kinds = rng.choice((("pallet",), ("beam",), ("pallet", "beam"), ("pallet", "beam")))
    types = {k: dict(PALLET if k == "pallet" else BEAM) for k in kinds}
    stores = racks(rng, hall)
    stations: dict[str, Any] = {**docks(rng, hall), **stores}
    loads = [{"name": f"l{n + 1}", "type": rng.choice(kinds), "at": name}
             for n, name in enumerate(sorted(stores)) if rng.random() < 1.0 / 3.0]
    model = rng.choice(("single_integrator", "unicycle"))
    robot: dict[str, Any] = {"model": model, "max_speed": BURGER_MAX_SPEED, "radius": BURGER_RADIUS}
    team = max(int(t["team"]) for t in types.values())
    robots = fleet(rng, hall, team)
    rate = min(rng.uniform(0.4, 1.2), RATE_PER_TEAM * (len(robots["robots"]) // team))
    stream = {"rate_per_min": _r(rate), "seed": rng.randrange(2**31), "types": list(kinds),
              "until": STREAM_S}
    return {
        "name": f"lifelong-{seed}",
        "dt": 0.05,
        "duration": DURATION_S,
        "goal_tolerance": 0.05,
        "robot": robot,
        "controller": dict(CONTROLLER),
        "fleet": robots,
        "stations": stations,
        "load_types": types,
        "loads": loads,
        "order_stream": stream,
        "obstacles": structure(hall) + obstacles(rng, hall),
    }


def lifelong_problem(s: Scenario) -> str | None:
    """What the draw asks beyond the scenario checks (None: nothing): a lifelong part whose
    stream posts at least :data:`MIN_ORDERS` servable orders for at least 10 minutes, in a run
    of at least 10 minutes."""
    if s.lifelong is None:
        return "no lifelong part"
    n = len(plan(s.lifelong))
    if n < MIN_ORDERS:
        return f"the stream posts {n} servable orders, fewer than {MIN_ORDERS}"
    if s.duration < 600.0:
        return f"a run of {s.duration:g} s, shorter than 10 minutes"
    if s.lifelong.stream is not None and s.lifelong.stream.until < 600.0:
        return f"a stream of {s.lifelong.stream.until:g} s, shorter than 10 minutes"
    return None
