"""The warehouse draw of ``formation montecarlo --draw warehouse``.

Each run draws, from its own seed, a hall closed by four walls with 2 or 3 shelf rows (boxes)
running east-west, each row cut by 1 or 2 cross aisles; with probability 1/2 one row is a
partition wall with doors where the cross aisles are. Aisles run between the rows and between
the outer rows and the walls; side aisles at both ends join them. In the hall:

* 1 to 3 pillars (static circles) at the ends of shelf rows, in the side aisles;
* 0 to 2 parked forklifts (static circles) against a shelf in a main aisle, where no formation
  starts or ends (:func:`slots`: one thing per stretch of aisle along a shelf);
* 0 to 2 moving forklifts (moving circles) driving along a side aisle (by its outer wall, clear
  of the pillars), or along a main aisle where no formation starts or ends (a forklift avoids
  nothing, so it never drives where a formation parks);
* 2 to 4 formations of 2 to 6 robots (pair, triangle, rectangle, pentagon, hexagon, a 2 x 3
  pallet), each carrying a declared ``load`` (:mod:`scenario.cargo`), starting in one main aisle
  and with its goal in another, on the far side of at least one shelf row, facing east or west
  at either end (a formation may have to turn round on the way);
* one robot model for the run, single integrator or unicycle; ``controller.method: rigid``.

:func:`warehouse_scenario` is the pure draw (a scenario-file mapping); :func:`warehouse_problem`
is what the draw asks beyond the scenario checks: every load clear of walls, shelves and static
circles by :data:`LOAD_MARGIN` at the start and at the goal, and of the other formations'
robots and loads at the goal, and a route for every formation's footprint at the start (what
``formation check`` asks: a 6-robot formation whose hull does not pass the drawn cross aisles,
or whose only way a parked forklift closes, has no goal to reach; such a layout is not a
deadlock of the controller). :func:`experiments.montecarlo.valid_scenario` redraws from the
next sub-seed on either's refusal.
"""

from __future__ import annotations

import math
import random
from typing import Any, NamedTuple

import numpy as np

from geometry.limits import BURGER_MAX_SPEED, BURGER_RADIUS
from scenario import ScenarioError
from scenario.cargo import load_clearances, load_polygon, loads_now
from scenario.model import Scenario
from scenario.routes import start_plan

WALL_DS = 0.15  # [m] safe distance of walls and shelves (as in scenarios/warehouse.yaml)
PILLAR_DS = 0.3  # [m] a round pillar: 0.39 m across
FORKLIFT_DS = 0.45  # [m] a forklift: 0.69 m across (as in the circle draw)
SLOT_END = 1.0  # [m] a start, goal or parked forklift is this far along a shelf from its ends
LOAD_MARGIN = 0.05  # [m] a load's least clearance to walls, shelves and static circles
DURATION = 300.0  # [s] a route of 30 m at 0.22 m/s with stops
EAST, WEST = 0.0, math.pi


def _ring(n: int, radius: float) -> list[tuple[float, float]]:
    return [(round(radius * math.cos(2 * math.pi * k / n), 4),
             round(radius * math.sin(2 * math.pi * k / n), 4)) for k in range(n)]


# Shapes: body offsets from the centroid [m] (x forward), the leader first, and the load as a
# rectangle {size: [along, across]} or "hull" (the members' outline grown by 15 %). Edges: the
# leader and the second member each to every other member (rigid: each member is a triangle on
# the edge between them, which no third member lies on; both are adjacent to every member, so
# the second takes over if the leader dies).
SHAPES: dict[str, tuple[list[tuple[float, float]], Any]] = {
    "pair": ([(0.0, 0.3), (0.0, -0.3)], {"size": [0.3, 0.8]}),
    "triangle": ([(0.35, 0.0), (-0.175, 0.303), (-0.175, -0.303)], {"size": [0.6, 0.6]}),
    "rectangle": ([(0.35, 0.2), (0.35, -0.2), (-0.35, -0.2), (-0.35, 0.2)], {"size": [0.8, 0.6]}),
    "pentagon": (_ring(5, 0.45), "hull"),
    "hexagon": (_ring(6, 0.5), "hull"),
    "pallet": ([(0.0, 0.25), (0.0, -0.25), (0.5, 0.25), (0.5, -0.25), (-0.5, -0.25),
                (-0.5, 0.25)], {"size": [1.3, 0.8]}),
}


class Hall(NamedTuple):
    """The drawn layout: main aisles' centres (south to north), rows' centres, the shelves' x
    intervals (the same in every row), their extent, and which row is a wall (or None)."""

    width: float
    height: float
    aisle: float  # [m] width of a main aisle
    depth: float  # [m] depth of a shelf row
    side: float  # [m] width of a side aisle
    aisles: list[float]
    rows: list[float]
    shelves: list[tuple[float, float]]
    wall_row: int | None


def draw_hall(rng: random.Random) -> Hall:
    n_rows = rng.randint(2, 3)
    aisle, depth, side = rng.uniform(2.0, 2.6), rng.uniform(0.8, 1.0), rng.uniform(2.0, 2.6)
    n_shelves = rng.randint(2, 3)
    length, cross = rng.uniform(3.5, 5.0), rng.uniform(1.6, 2.2)
    span = n_shelves * length + (n_shelves - 1) * cross
    height = (n_rows + 1) * aisle + n_rows * depth
    south = -height / 2
    aisles = [south + k * (aisle + depth) + aisle / 2 for k in range(n_rows + 1)]
    rows = [south + (k + 1) * aisle + k * depth + depth / 2 for k in range(n_rows)]
    shelves = [(-span / 2 + j * (length + cross), -span / 2 + j * (length + cross) + length)
               for j in range(n_shelves)]
    wall_row = rng.randrange(n_rows) if rng.random() < 0.5 else None
    return Hall(span + 2 * side, height, aisle, depth, side, aisles, rows, shelves, wall_row)


def _r(x: float) -> float:
    return round(x, 4)


def outer_walls(width: float, height: float, safe_distance: float = WALL_DS) -> list[dict]:
    """The four walls (segments) closing a ``width`` x ``height`` hall centred on the origin."""
    w, h = width / 2, height / 2
    return [{"name": name, "segment": [[_r(a), _r(b)], [_r(c), _r(d)]],
             "safe_distance": safe_distance}
            for name, a, b, c, d in (("wall-n", -w, h, w, h), ("wall-s", -w, -h, w, -h),
                                     ("wall-w", -w, -h, -w, h), ("wall-e", w, -h, w, h))]


def structure(hall: Hall) -> list[dict]:
    """The outer walls, and each row's shelves (boxes) or wall segments."""
    out = outer_walls(hall.width, hall.height)
    for k, y in enumerate(hall.rows):
        for j, (x0, x1) in enumerate(hall.shelves):
            if k == hall.wall_row:
                out.append({"name": f"partition-{k}{j}", "segment": [[_r(x0), _r(y)], [_r(x1), _r(y)]],
                            "safe_distance": WALL_DS})
            else:
                out.append({"name": f"shelf-{k}{j}", "safe_distance": WALL_DS,
                            "box": {"center": [_r((x0 + x1) / 2), _r(y)],
                                    "size": [_r(x1 - x0), _r(hall.depth)]}})
    return out


def slots(hall: Hall) -> list[tuple[int, int]]:
    """(main aisle, shelf) of every slot: the stretch of a main aisle along one shelf, between
    cross aisles (or a cross aisle and a side aisle). Each holds at most one formation's start or
    goal or one parked forklift, so a formation parked at its goal leaves every other stretch
    open and can be passed by going round its shelf."""
    return [(a, j) for a in range(len(hall.aisles)) for j in range(len(hall.shelves))]


def slot_x(rng: random.Random, hall: Hall, shelf: int) -> float:
    """A point along shelf ``shelf``, at least SLOT_END from its ends."""
    x0, x1 = hall.shelves[shelf]
    return rng.uniform(x0 + SLOT_END, x1 - SLOT_END)


def behind_a_shelf(hall: Hall, a: int, b: int) -> bool:
    """Whether a shelf row (not the partition wall) lies between main aisles ``a`` and ``b``."""
    return any(k != hall.wall_row for k in range(min(a, b), max(a, b)))


def pillars(rng: random.Random, hall: Hall) -> list[dict]:
    ends = [(sx * (hall.shelves[-1][1] + 0.5), y) for y in hall.rows for sx in (-1, 1)]
    picks = rng.sample(ends, rng.randint(1, 3))
    return [{"name": f"pillar-{k}", "center": [_r(x), _r(y)], "safe_distance": PILLAR_DS}
            for k, (x, y) in enumerate(picks)]


def moving_forklifts(rng: random.Random, hall: Hall, free_aisle: int | None) -> list[dict]:
    """Up to two forklifts, each along a side aisle or the main aisle no formation uses."""
    lanes: list[tuple[str, int]] = [("side", -1), ("side", 1)]
    if free_aisle is not None:
        lanes.append(("main", free_aisle))
    out = []
    for k, (kind, where) in enumerate(rng.sample(lanes, rng.randint(0, 2))):
        speed = rng.choice([0.1, 0.15]) * rng.choice([-1, 1])
        if kind == "side":
            x, y = where * (hall.width / 2 - 0.6), -math.copysign(hall.height / 2 - 0.6, speed)
            vel = [0.0, speed]
        else:
            x, y = -math.copysign(hall.width / 2 - 0.6, speed), hall.aisles[where]
            vel = [speed, 0.0]
        out.append({"name": f"forklift-{k}", "center": [_r(x), _r(y)],
                    "safe_distance": FORKLIFT_DS, "velocity": vel})
    return out


def parked_forklifts(rng: random.Random, hall: Hall, free: list[tuple[int, int]]) -> list[dict]:
    """Up to two forklifts parked against a shelf in slots no formation uses."""
    out = []
    for k, (a, j) in enumerate(rng.sample(free, min(len(free), rng.randint(0, 2)))):
        y = hall.aisles[a] + rng.choice([-1, 1]) * (hall.aisle / 2 - FORKLIFT_DS)
        out.append({"name": f"parked-{k}", "center": [_r(slot_x(rng, hall, j)), _r(y)],
                    "safe_distance": FORKLIFT_DS})
    return out


def _placed(offsets: list[tuple[float, float]], cx: float, cy: float,
            heading: float) -> list[list[float]]:
    c, s = math.cos(heading), math.sin(heading)
    return [[_r(cx + c * ox - s * oy), _r(cy + s * ox + c * oy)] for ox, oy in offsets]


def load_of(kind: str, heading: float) -> dict:
    """The shape's load in the start frame (centred on the members' centroid)."""
    offsets, load = SHAPES[kind]
    if load == "hull":
        return {"polygon": _placed([(1.15 * x, 1.15 * y) for x, y in offsets], 0.0, 0.0, heading)}
    return {"size": list(load["size"]), "yaw": _r(heading)}


def formation(name: str, kind: str, start: tuple[float, float, float],
              goal: tuple[float, float, float]) -> dict:
    """One formation of shape ``kind`` from pose ``start`` (x, y, heading) to pose ``goal``."""
    offsets, _ = SHAPES[kind]
    starts = _placed(offsets, *start)
    goals = _placed(offsets, *goal)
    ids = [f"{name}{j + 1}" for j in range(len(offsets))]
    edges = [[ids[0], ids[j]] for j in range(1, len(ids))]
    edges += [[ids[1], ids[j]] for j in range(2, len(ids))]
    return {
        "name": name,
        "leader": ids[0],
        "robots": {rid: {"start": [*s, _r(start[2])], "goal": g}
                   for rid, s, g in zip(ids, starts, goals, strict=True)},
        "edges": edges,
        "load": load_of(kind, start[2]),
    }


def _pose(rng: random.Random, hall: Hall, slot: tuple[int, int]) -> tuple[float, float, float]:
    a, j = slot
    return (slot_x(rng, hall, j), hall.aisles[a] + rng.uniform(-0.15, 0.15),
            rng.choice([EAST, WEST]))


def formations(rng: random.Random, hall: Hall, free: list[tuple[int, int]]) -> list[dict]:
    """2 to 4 formations (at most half the free slots); each takes a start slot and a goal
    slot (removed from ``free``) with a shelf row between them. ScenarioError when no goal slot
    is left behind a shelf (the run redraws)."""
    out = []
    for k in range(min(rng.randint(2, 4), len(free) // 2)):
        start = rng.choice(free)
        free.remove(start)
        goals = [s for s in free if behind_a_shelf(hall, start[0], s[0])]
        if not goals:
            raise ScenarioError("warehouse draw: no free slot behind a shelf for a goal")
        goal = rng.choice(goals)
        free.remove(goal)
        kind = rng.choice(list(SHAPES))
        out.append(formation("abcd"[k], kind, _pose(rng, hall, start), _pose(rng, hall, goal)))
    return out


def _free_aisle(rng: random.Random, hall: Hall, free: list[tuple[int, int]]) -> int | None:
    """With probability 0.3, a main aisle kept free of formations for a forklift (its slots
    leave ``free``), when the others have slots enough for three formations."""
    if rng.random() >= 0.3:
        return None
    a = rng.randrange(len(hall.aisles))
    rest = [s for s in free if s[0] != a]
    if len(rest) < 6:
        return None
    free[:] = rest
    return a


def warehouse_scenario(seed: int) -> dict:
    """One random warehouse as a scenario-file mapping (may raise ScenarioError: redraw)."""
    rng = random.Random(seed)
    model = rng.choice(["single_integrator", "unicycle"])
    hall = draw_hall(rng)
    free = slots(hall)
    free_aisle = _free_aisle(rng, hall, free)
    drawn = formations(rng, hall, free)
    obstacles = (structure(hall) + pillars(rng, hall) + parked_forklifts(rng, hall, free)
                 + moving_forklifts(rng, hall, free_aisle))
    return {
        "name": f"warehouse-{seed}",
        "dt": 0.05,
        "duration": DURATION,
        "goal_tolerance": 0.05,
        "robot": {"model": model, "max_speed": BURGER_MAX_SPEED, "radius": BURGER_RADIUS},
        "controller": {"kp": 2.0, "gamma": {"formation": 1.0, "obstacle": 0.8, "formations": 0.5},
                       "epsilon": 0.05, "method": "rigid"},
        "formations": drawn,
        "obstacles": obstacles,
    }


def warehouse_problem(s: Scenario) -> str | None:
    """What the draw refuses beyond the scenario checks (one line), or None: a load closer than
    LOAD_MARGIN to a wall, shelf or static circle at its start or goal, or touching another
    formation's robot or load at the goal (moving circles are not where they were at the goal),
    or a formation with no route for its footprint at the start (:func:`unreachable`)."""
    return _load_problem(s) or unreachable(s)


def unreachable(s: Scenario) -> str | None:
    """The first formation whose goal has no route for its footprint at the start (walls,
    shelves and static circles: :func:`scenario.routes.start_plan`), as one line, or None."""
    for f in s.formations:
        reason = start_plan(s, f).reason
        if reason:
            return f"formation {f.name!r}: {reason}"
    return None


def _load_problem(s: Scenario) -> str | None:
    outlines = [load_polygon(f) for f in s.formations]
    moving = {o.name for o in s.obstacles if o.velocity != (0.0, 0.0)}
    static = {o.name for o in s.obstacles if o.velocity == (0.0, 0.0)} | {sh.name for sh in s.shapes}
    centres = [o.center for o in s.obstacles]
    for when, bodies in (("start", [r.start[:2] for r in s.robots]), ("goal", [r.goal for r in s.robots])):
        pts = np.array(bodies, dtype=float)
        loads = loads_now(s, outlines, pts)
        for c in load_clearances(s, loads, pts, centres):
            least = LOAD_MARGIN if c.other in static else 0.0
            if c.other not in moving and c.clearance < least:
                return (f"formation {s.formations[c.formation].name!r}: its load is {c.clearance:.3f} m"
                        f" from {c.other!r} at the {when}")
    return None
