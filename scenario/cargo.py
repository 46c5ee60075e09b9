"""A formation's load: the ``load:`` key, its checks, and where the load is.

A formation may declare what it carries, in the start frame (origin at the centroid of the
members' start body positions, axes parallel to the scenario's x and y):

    load: {size: [L, W], center: [dx, dy], yaw: a}     # a rectangle, L along yaw
    load: {polygon: [[x, y], [x, y], [x, y], ...]}     # a convex polygon, 3 to 32 vertices

Without ``load`` the load is the convex hull of the members' body centres (a segment for two
robots; a one-robot formation carries none). Each tick the load moves with the least-squares
rigid motion of the members' start body positions onto the current ones
(:func:`geometry.rigid.rigid_fit`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any, NamedTuple

import numpy as np

from geometry.polygon import (
    area,
    bounding_circle,
    closest_point,
    convex_hull,
    counter_clockwise,
    is_convex,
    points_distance,
    polygon_distance,
    separation_floor,
)
from geometry.rigid import rigid_fit
from geometry.shapes import distance_floor, shape_distance

from . import limits
from .fields import mapping, vector, within
from .model import FormationSpec, Scenario
from .reader import ScenarioError

LOAD_KEY = "load"
MAX_LOAD_VERTICES = 32
_LOAD_KEYS = {"size", "center", "yaw", "polygon"}
_RECTANGLE_KEYS = ("size", "center", "yaw")
MIN_LOAD_AREA = 1e-6  # [m^2] a polygon with less area is a line, not a load

Point = tuple[float, float]


def parse_load(raw: Any, where: str) -> tuple[Point, ...]:
    """The declared load at ``where`` (``formations[k].load``) as a convex counter-clockwise
    polygon in the start frame; one-line :class:`ScenarioError` on anything else."""
    m = mapping(raw, where, _LOAD_KEYS)
    if "polygon" in m:
        extra = [k for k in _RECTANGLE_KEYS if k in m]
        if extra:
            raise ScenarioError(f"{where}.{extra[0]}: not allowed with polygon (a load is either "
                                "{size, center, yaw} or {polygon})")
        return _polygon(m["polygon"], f"{where}.polygon")
    if "size" not in m:
        raise ScenarioError(f"{where}: needs size: [L, W] (with optional center, yaw) or "
                            "polygon: [[x, y], ...]")
    return _rectangle(m, where)


def _rectangle(m: Any, where: str) -> tuple[Point, ...]:
    size = vector(m["size"], f"{where}.size", (2,))
    length = within(size[0], f"{where}.size[0]", limits.DISTANCE)
    width = within(size[1], f"{where}.size[1]", limits.DISTANCE)
    center = vector(m.get("center", [0.0, 0.0]), f"{where}.center", (2,), limits.COORDINATE)
    yaw = within(m.get("yaw", 0.0), f"{where}.yaw", limits.HEADING)
    c, s = math.cos(yaw), math.sin(yaw)
    hx, hy = 0.5 * length, 0.5 * width
    return tuple((center[0] + c * u - s * v, center[1] + s * u + c * v)
                 for u, v in ((hx, -hy), (hx, hy), (-hx, hy), (-hx, -hy)))


def _polygon(raw: Any, where: str) -> tuple[Point, ...]:
    if not isinstance(raw, list) or not 3 <= len(raw) <= MAX_LOAD_VERTICES:
        raise ScenarioError(f"{where}: must be a list of 3 to {MAX_LOAD_VERTICES} points [x, y]")
    pts = [vector(p, f"{where}[{k}]", (2,), limits.COORDINATE) for k, p in enumerate(raw)]
    poly = tuple((p[0], p[1]) for p in pts)
    if not is_convex(poly):
        raise ScenarioError(f"{where}: the polygon must be convex, its vertices in order "
                            "(no straight, repeated or crossing corners)")
    ccw = counter_clockwise(poly)
    if abs(area(ccw)) < MIN_LOAD_AREA:
        raise ScenarioError(f"{where}: the polygon has no area")
    return ccw


def start_bodies(formation: FormationSpec) -> tuple[Point, ...]:
    """The members' start body positions, in member order."""
    return tuple((r.start[0], r.start[1]) for r in formation.robots)


def start_origin(formation: FormationSpec) -> Point:
    """The origin of the start frame: the centroid of the members' start body positions."""
    pts = start_bodies(formation)
    return (sum(p[0] for p in pts) / len(pts), sum(p[1] for p in pts) / len(pts))


def carries_load(formation: FormationSpec) -> bool:
    """A declared load, or a default hull of at least two members."""
    return bool(formation.load) or len(formation.robots) >= 2


def load_polygon(formation: FormationSpec) -> tuple[Point, ...]:
    """The load at the start, in world coordinates: the declared polygon moved to the start
    frame's origin, or the convex hull of the start body positions (empty for one robot)."""
    if formation.load:
        ox, oy = start_origin(formation)
        return tuple((ox + x, oy + y) for x, y in formation.load)
    if len(formation.robots) < 2:
        return ()
    return convex_hull(start_bodies(formation))


def placed_load(formation: FormationSpec, start_outline: Sequence[Point],
                bodies: Sequence[Point]) -> tuple[Point, ...]:
    """The load ``start_outline`` (world coordinates at the start) placed by the rigid fit of
    the members' start body positions onto ``bodies`` (their current ones, member order)."""
    return rigid_fit(start_bodies(formation), bodies).apply_all(start_outline)


# ---------------------------------------------------------------------------- clearances

LOAD_REACH = 1.0  # [m] things farther from a load's bounding circle than this are not measured
# [m] overlaps shallower than this are rounding, not contact (1 micrometre): the safety
# monitor's for every contact (simulator.metrics), here so that the viewer's load hits share it
CONTACT_TOL = 1e-6
NEAR_SLACK = 1e-9  # [m] the bounding-circle sort keeps what rounding could put just inside reach


class LoadContact(NamedTuple):
    """The clearance of formation ``formation``'s load (index in the scenario) to ``other``:
    a robot of another formation (its body), an obstacle (its physical disk, radius
    safe_distance - robot radius), a wall or shelf (the shape itself) or another formation's
    load (the formation's name); negative: overlap. (x, y): where, for a figure (for a wall,
    shelf or load only worked out when they overlap; else the load's centre)."""

    formation: int
    other: str
    clearance: float  # [m]
    x: float
    y: float


def load_clearances(s: Scenario, loads: Sequence[Sequence[Point]], bodies: np.ndarray,
                    obstacles: Sequence[Point], reach: float = LOAD_REACH) -> list[LoadContact]:
    """Every load's clearance to everything within ``reach`` of it (see :class:`LoadContact`;
    walls, shelves and other loads are first sorted out by bounding circles).

    ``loads``: each formation's load outline now (world, counter-clockwise; empty: none);
    ``bodies``: (n, 2) body centres in scenario robot order; ``obstacles``: the circles'
    centres now. The one function the start check and the run's safety monitor use."""
    out: list[LoadContact] = []
    fidx = {f.name: k for k, f in enumerate(s.formations)}
    formation_of = np.array([fidx[r.formation] for r in s.robots], dtype=int)
    body_pts = np.asarray(bodies, dtype=float).reshape(-1, 2)
    circles = np.array([max(0.0, o.safe_distance - s.robot.radius) for o in s.obstacles])
    centres = np.asarray(obstacles, dtype=float).reshape(-1, 2)
    rounds = [bounding_circle(p) if p else None for p in loads]
    for k, poly in enumerate(loads):
        bound = rounds[k]
        if bound is None:
            continue
        out += _robot_contacts(s, k, poly, bound, body_pts, formation_of, reach)
        out += _circle_contacts(s, k, poly, bound, centres, circles, reach)
        out += _shape_contacts(s, k, poly, bound, reach)
        out += _load_contacts(s, k, loads, rounds, reach)
    return out


def _near(pts: np.ndarray, radii: np.ndarray | float, bound: tuple[Point, float],
          reach: float) -> np.ndarray:
    """Which disks (centres ``pts``, radii ``radii``) may come within ``reach`` of a load whose
    bounding circle is ``bound``: the distance to the circle is a lower bound of the distance to
    the load (a sort, not a measure: only these are measured exactly, since measuring every
    robot against every load costs a large fleet tens of milliseconds a tick)."""
    (cx, cy), r = bound
    gap = np.hypot(pts[:, 0] - cx, pts[:, 1] - cy) - r - radii
    return gap <= reach + NEAR_SLACK


def _robot_contacts(s: Scenario, k: int, poly: Sequence[Point], bound: tuple[Point, float],
                    bodies: np.ndarray, formation_of: np.ndarray,
                    reach: float) -> list[LoadContact]:
    others = np.nonzero((formation_of != k) & _near(bodies, s.robot.radius, bound, reach))[0]
    if not len(others):
        return []
    pts = bodies[others]
    d = points_distance(pts, poly) - s.robot.radius
    return [LoadContact(k, s.robot_ids[others[m]], float(d[m]), float(pts[m, 0]),
                        float(pts[m, 1])) for m in np.nonzero(d <= reach)[0]]


def _circle_contacts(s: Scenario, k: int, poly: Sequence[Point], bound: tuple[Point, float],
                     centres: np.ndarray, radii: np.ndarray, reach: float) -> list[LoadContact]:
    if not len(radii):
        return []
    near = np.nonzero(_near(centres, radii, bound, reach))[0]
    if not len(near):
        return []
    pts = centres[near]
    d = points_distance(pts, poly) - radii[near]
    return [LoadContact(k, s.obstacles[near[m]].name, float(d[m]), float(pts[m, 0]),
                        float(pts[m, 1])) for m in np.nonzero(d <= reach)[0]]


def _shape_contacts(s: Scenario, k: int, poly: Sequence[Point], bound: tuple[Point, float],
                    reach: float) -> list[LoadContact]:
    out = []
    for sh in s.shapes:
        if distance_floor(bound[0][0], bound[0][1], sh) - bound[1] > reach:
            continue  # the shape's bounding circle first: a lower bound of the one below
        if shape_distance(bound[0][0], bound[0][1], sh)[0] - bound[1] > reach:
            continue  # a lower bound of the distance from the load to the shape
        outline = sh.corners()
        if separation_floor(poly, outline) - NEAR_SLACK > reach:
            continue  # a lower bound of the distance below
        d = polygon_distance(poly, outline)
        x, y = _mark_point(poly, outline) if d < 0.0 else bound[0]
        out.append(LoadContact(k, sh.name, d, x, y))
    return out


def _load_contacts(s: Scenario, k: int, loads: Sequence[Sequence[Point]],
                   rounds: Sequence[tuple[Point, float] | None], reach: float) -> list[LoadContact]:
    """Against the loads of the formations after ``k`` (each pair once)."""
    out = []
    bound = rounds[k]
    assert bound is not None
    for g in range(k + 1, len(loads)):
        other = rounds[g]
        if other is None or math.dist(other[0], bound[0]) - other[1] - bound[1] > reach:
            continue
        d = polygon_distance(loads[k], loads[g])
        x, y = _mark_point(loads[k], loads[g]) if d < 0.0 else bound[0]
        out.append(LoadContact(k, s.formations[g].name, d, x, y))
    return out


def _mark_point(poly: Sequence[Point], other: Sequence[Point]) -> Point:
    """The point of ``poly`` nearest to the centre of ``other`` (where a figure marks them)."""
    centre, _ = bounding_circle(other)
    return closest_point(poly, centre)


def loads_now(s: Scenario, outlines: Sequence[Sequence[Point]],
              bodies: np.ndarray) -> list[tuple[Point, ...]]:
    """Every formation's load placed at the body positions ``bodies`` ((n, 2), scenario robot
    order) from its start ``outlines`` (:func:`load_polygon`)."""
    index = {rid: m for m, rid in enumerate(s.robot_ids)}
    out: list[tuple[Point, ...]] = []
    for f, outline in zip(s.formations, outlines, strict=True):
        if not outline:
            out.append(())
            continue
        pts = [(float(bodies[index[r.id]][0]), float(bodies[index[r.id]][1])) for r in f.robots]
        out.append(placed_load(f, outline, pts))
    return out
