"""One picture of a fleet at one instant: the ``Frame``, shared by recordings, the page and replay.

A frame is plain JSON-ready data, so the same object is logged on the ``/fleet`` channel of a
recording, sent to the page, and read back by ``formation replay``::

    {"t": 12.35,                       # simulated time (simulations) or wall time (real fleets) [s]
     "radius": 0.105,                  # robot body radius [m]
     "robots": [{"id", "formation", "x", "y", "theta", "px", "py",   # body pose, control point
                 "ux", "uy", "v", "omega",                            # command
                 "status", "slack", "h_formation", "h_obstacle", "h_formations",  # QP, barriers
                 "gx", "gy"}, ...],                                   # goal (None if unknown)
     "ellipses": [{"formation", "cx", "cy", "alpha", "a", "b"}, ...],
     "obstacles": [{"name", "x", "y", "ds"}, ...],   # circles: centre and safe distance Ds
     "shapes": [{"name", "kind", "corners", "ds"}, ...],  # walls and shelves: outline [[x, y], ...]
     "loads": [{"formation", "outline", "declared"}, ...],  # each formation's load at this tick
     "load_hits": [{"formation", "other", "clearance", "line"}, ...],  # its overlaps, as lines
     "formations": [{"name", "status", "qp", "gx", "gy", "distance"}, ...]}

Under ``controller.localisation: fused`` each robot also carries its own filter's estimate and
its 95 % confidence radius (``est_x``, ``est_y``, ``sigma_m``: robots.csv's columns; ``x, y``
stay the true pose), and a scenario with blind floor adds ``"blind": [{"corners": [[x, y],
...]}, ...]``, the boxes where the camera sees no robot. A lifelong run adds ``cargo``,
``orders`` and ``order_counts`` (:mod:`viewer.orders`). Frames of other runs have none of these
keys.

Non-finite numbers become ``None`` (JSON has no NaN). :func:`frames_from_series` turns a run's
time series (in-process or multi-process, :class:`simulator.inprocess.Series`) into one frame
per tick; :func:`formation_status` gives each formation's state from its members. The loads
and their hits: :mod:`viewer.loads`.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Iterator, Sequence
from typing import Any

from geometry.shapes import box

from .loads import LoadView
from .orders import OrderBoard

Frame = dict[str, Any]

ROBOT_FIELDS = ("x", "y", "theta", "px", "py", "ux", "uy", "v", "omega", "status", "slack",
                "h_formation", "h_obstacle", "h_formations")
#: a fused run's robots.csv ends with these (:data:`simulator.series.LOCALISATION_COLUMNS`)
ESTIMATE_FIELDS = ("est_x", "est_y", "sigma_m")
H_KINDS = ("formation", "obstacle", "formations")
# worst first: a formation shows its worst member's QP status
QP_ORDER = ("failed", "stale", "fallback", "relaxed", "nominal", "ok", "")
STOP_SPEED = 1e-4  # [m/s] a command below this is "standing still"


def num(v: Any) -> float | None:
    """``v`` as a float, or ``None`` when missing or not finite."""
    if v is None:
        return None
    try:
        f = float(v)
    except (TypeError, ValueError):
        return None
    return f if math.isfinite(f) else None


def robot_entry(rid: str, formation: str, row: Sequence[Any], goal: tuple[float, float] | None) -> dict:
    """A frame's robot from the 14 values of :data:`ROBOT_FIELDS` (``status`` a string)."""
    out: dict[str, Any] = {"id": rid, "formation": formation}
    for name, v in zip(ROBOT_FIELDS, row, strict=True):
        out[name] = (v or "") if name == "status" else num(v)
    out["gx"], out["gy"] = (num(goal[0]), num(goal[1])) if goal is not None else (None, None)
    return out


def formation_status(name: str, robots: Sequence[dict], tolerance: float,
                     goal: tuple[float, float] | None = None) -> dict:
    """A formation's state from its members: ``reached`` (every member within ``tolerance`` of
    its goal), ``stopped`` (all standing still short of their goals), else ``moving``; ``qp`` is
    the worst member's QP status; ``distance`` from the centroid to the goal centroid [m]."""
    members = [r for r in robots if r["formation"] == name]
    dists = [math.hypot(r["x"] - r["gx"], r["y"] - r["gy"]) for r in members
             if None not in (r["x"], r["y"], r["gx"], r["gy"])]
    if not members:
        state = "unknown"
    elif dists and len(dists) == len(members) and max(dists) <= tolerance:
        state = "reached"
    elif all(math.hypot(r["ux"] or 0.0, r["uy"] or 0.0) < STOP_SPEED
             and abs(r["v"] or 0.0) < STOP_SPEED for r in members):
        state = "stopped"
    else:
        state = "moving"
    qp = min((r["status"] for r in members), key=_qp_rank, default="")
    if goal is None and members and all(r["gx"] is not None for r in members):
        goal = (sum(r["gx"] for r in members) / len(members),
                sum(r["gy"] for r in members) / len(members))
    distance = None
    pts = [(r["x"], r["y"]) for r in members if r["x"] is not None]
    if goal is not None and pts:
        cx = sum(p[0] for p in pts) / len(pts)
        cy = sum(p[1] for p in pts) / len(pts)
        distance = math.hypot(goal[0] - cx, goal[1] - cy)
    return {"name": name, "status": state, "qp": qp,
            "gx": None if goal is None else goal[0], "gy": None if goal is None else goal[1],
            "distance": distance}


def estimate_entry(row: Sequence[Any]) -> dict[str, float | None]:
    """A robot's ``est_x, est_y, sigma_m`` from the last three values of its fused row."""
    return {name: num(v) for name, v in zip(ESTIMATE_FIELDS, row[-3:], strict=True)}


def blind_entries(boxes: Iterable[Any]) -> list[dict]:
    """Frame entries of ``world.camera_blind`` boxes (:class:`scenario.world.BlindBox`): their
    four corners, counter-clockwise."""
    return [{"corners": [[num(x), num(y)] for x, y in
                         box("blind", b.center, b.size, b.yaw, 0.0).corners()]} for b in boxes]


def shape_entries(shapes: Iterable[Any]) -> list[dict]:
    """Frame entries of walls and shelves (:class:`geometry.shapes.Shape`): their outline's
    corners (2 for a wall, 4 for a shelf) and Ds."""
    return [{"name": sh.name, "kind": sh.kind, "ds": num(sh.ds),
             "corners": [[num(x), num(y)] for x, y in sh.corners()]} for sh in shapes]


def _qp_rank(status: str) -> int:
    return QP_ORDER.index(status) if status in QP_ORDER else 0


def frames_from_series(series: Any, scenario: Any, load_hits: bool = True,
                       board: OrderBoard | None = None) -> Iterator[Frame]:
    """One frame per tick of a run's time series (rows of
    :data:`simulator.inprocess.ROBOT_COLUMNS`, ellipses and obstacles per tick); ``load_hits``
    False: the frames' ``load_hits`` stay empty, unlooked for (a run whose loads never
    overlapped anything has none). A lifelong run's frames (``board``: its loads and orders)
    list the formations of each tick, which change as teams form; its robots' goals are not
    the scenario's."""
    lifelong = board is not None or getattr(scenario, "lifelong", None) is not None
    goals = {} if lifelong else {r.id: r.goal for r in scenario.robots}
    centroids = {f.name: f.goal_centroid for f in scenario.formations}
    names = [f.name for f in scenario.formations]
    radius = scenario.robot.radius
    tol = scenario.goal_tolerance
    ellipses = _by_time(series.ellipses)
    obstacles = _by_time(series.obstacles)
    extra = _extra(scenario)
    fused = scenario.controller.localisation == "fused"
    loads = LoadView(scenario)
    rows = series.robots
    i = 0
    while i < len(rows):
        t = rows[i][0]
        robots = []
        while i < len(rows) and rows[i][0] == t:
            r = rows[i]
            entry = robot_entry(r[1], r[2], r[3:17], goals.get(r[1]))
            if fused:
                entry.update(estimate_entry(r))
            robots.append(entry)
            i += 1
        circles = [{"name": o[1], "x": num(o[2]), "y": num(o[3]), "ds": num(o[4])}
                   for o in obstacles.get(t, ())]
        if lifelong:
            names = list(dict.fromkeys(r["formation"] for r in robots))
        yield {
            "t": float(t),
            "radius": radius,
            "robots": robots,
            "ellipses": [{"formation": e[1], "cx": num(e[2]), "cy": num(e[3]), "alpha": num(e[4]),
                          "a": num(e[5]), "b": num(e[6])} for e in ellipses.get(t, ())],
            "obstacles": circles,
            **extra,
            **loads.fields(robots, circles, load_hits),
            "formations": [formation_status(n, robots, tol, centroids.get(n)) for n in names],
            **(board.fields(float(t)) if board is not None else {}),
        }


def _extra(scenario: Any) -> dict[str, list]:
    """The frames' walls and shelves, and the blind boxes where there are any."""
    out: dict[str, list] = {"shapes": shape_entries(getattr(scenario, "shapes", ()))}
    world = getattr(scenario, "world", None)
    boxes = getattr(world, "camera_blind", ())
    if boxes:
        out["blind"] = blind_entries(boxes)
    return out


def _by_time(rows: Sequence[tuple]) -> dict[float, list[tuple]]:
    out: dict[float, list[tuple]] = {}
    for row in rows:
        out.setdefault(row[0], []).append(row)
    return out


def min_h(robot: dict) -> dict[str, float | None]:
    """A frame robot's smallest barrier value of each kind."""
    return {k: robot.get(f"h_{k}") for k in H_KINDS}
