"""The checks of a scenario's lifelong part against the rest of it (:mod:`scenario.lifelong`).

Each refusal is one :class:`scenario.reader.ScenarioError` naming the culprit by its path in the
file. In order:

* one namespace: robots (of formations and of the fleet), formations, loads and orders; an
  explicit order may not take a name of the stream's form (``s1``, ``s2``, ...) while a stream
  is declared;
* no fixed formations beside the fleet (a run serves one or the other);
* a load type needing more robots than the fleet has;
* every load type's outline resting at every station clear of walls and shelves (their shapes),
  of standing circles (a circle's safe distance less the robot radius is its body) and of every
  other station's outlines; and each slot under it outside every shape's and circle's safe
  distance (the team must be able to stand there);
* a fleet robot's start clear of walls, shelves and circles as a formation robot's must be,
  no robot's body (of a fleet or a formation) inside a load resting at t = 0, no two bodies
  overlapping; a parking spot outside every safe distance and every station's outline;
* an order that gives ``from`` for a resting load names the station it rests at;
* a stream with a store to fill or empty, and a source or a sink to serve it.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterator

import numpy as np

from geometry.polygon import points_distance, polygon_distance
from geometry.shapes import shape_distance
from geometry.unicycle import control_point

from .lifelong import SINK, SOURCE, STORE, Lifelong, LoadType, Point, Station, outline_at, slots_at
from .model import ObstacleSpec, Scenario
from .reader import ScenarioError
from .stream import plan

OVERLAP_TOL = 1e-6  # [m] outlines closer than this overlap; touching is allowed
STREAM_NAME = re.compile(r"^s[0-9]+$")


def check_lifelong(s: Scenario) -> None:
    """All the checks of the module docstring (nothing when the scenario has no lifelong part)."""
    life = s.lifelong
    if life is None:
        return
    _check_names(s, life)
    if s.formations:
        raise ScenarioError(f"formations: {s.formations[0].name!r} beside a fleet: fixed "
                            f"formations and a fleet in one scenario are not run yet (give the "
                            f"formations a scenario of their own)")
    _check_teams(life)
    _check_stations(s, life)
    _check_fleet(s, life)
    _check_orders(life)
    _check_stream(life)


def _check_names(s: Scenario, life: Lifelong) -> None:
    seen: dict[str, str] = {}
    for name, where, what in _names(s, life):
        if name in seen:
            raise ScenarioError(f"{where}: {name!r} is already the name of {seen[name]} (robots, "
                                f"formations, loads and orders share one namespace)")
        seen[name] = what
    if life.stream is not None:
        for k, o in enumerate(life.orders):
            if STREAM_NAME.match(o.id):
                raise ScenarioError(f"orders[{k}].id: {o.id!r} is a name the order stream gives "
                                    "its orders (s1, s2, ...)")


def _names(s: Scenario, life: Lifelong) -> Iterator[tuple[str, str, str]]:
    for k, f in enumerate(s.formations):
        yield f.name, f"formations[{k}].name", f"formation {k}"
    for k, f in enumerate(s.formations):
        for r in f.robots:
            if r.id != f.name:  # a one-robot formation may bear its robot's name
                yield r.id, f"formations[{k}].robots.{r.id}", f"a robot of formation {f.name!r}"
    for fr in life.fleet.robots:
        yield fr.id, f"fleet.robots.{fr.id}", "a robot of the fleet"
    for k, ld in enumerate(life.loads):
        yield ld.name, f"loads[{k}].name", "a resting load"
    for k, o in enumerate(life.orders):
        yield o.id, f"orders[{k}].id", f"orders[{k}]"


def _check_teams(life: Lifelong) -> None:
    n = len(life.fleet.robots)
    for t in life.load_types:
        if t.team > n:
            raise ScenarioError(f"load_types.{t.name}: needs a team of {t.team} robots, more "
                                f"than the fleet's {n}")


def _circles(s: Scenario) -> list[tuple[ObstacleSpec, Point]]:
    """Circles that stand somewhere for good: still ones, and moving ones where they stop."""
    out = []
    for o in s.obstacles:
        if o.velocity == (0.0, 0.0):
            out.append((o, o.center))
        elif o.stop_at is not None:
            out.append((o, o.position(o.stop_at)))
    return out


def by_size(life: Lifelong) -> list[LoadType]:
    """The load types, the largest (by area) first: a refusal names the largest that fails."""
    return sorted(life.load_types, key=lambda t: -t.area)


def _check_stations(s: Scenario, life: Lifelong) -> None:
    for st in life.stations:
        for t in by_size(life):
            _check_station_world(s, st, t)
    _check_station_pairs(life)


def _check_station_world(s: Scenario, st: Station, t: LoadType) -> None:
    where = f"stations.{st.name}"
    outline = outline_at(t, st.pose)
    r = s.robot.radius
    for sh in s.shapes:
        if polygon_distance(outline, sh.corners()) < -OVERLAP_TOL:
            raise ScenarioError(f"{where}: a {t.name!r} load resting there overlaps {sh.kind} "
                                f"{sh.name!r}")
    for o, c in _circles(s):
        if points_distance(np.array([c]), outline)[0] < o.safe_distance - r - OVERLAP_TOL:
            raise ScenarioError(f"{where}: a {t.name!r} load resting there overlaps obstacle "
                                f"{o.name!r}")
    for k, p in enumerate(slots_at(t, st.pose)):
        for sh in s.shapes:
            if shape_distance(p[0], p[1], sh)[0] < sh.ds:
                raise ScenarioError(f"{where}: slot {k} of a {t.name!r} load there is inside "
                                    f"the safe distance of {sh.kind} {sh.name!r}")
        for o, c in _circles(s):
            if math.dist(p, c) < o.safe_distance:
                raise ScenarioError(f"{where}: slot {k} of a {t.name!r} load there is inside "
                                    f"the safe distance of obstacle {o.name!r}")


def _bounding_radius(life: Lifelong) -> float:
    return max((0.5 * math.hypot(*t.size) for t in life.load_types), default=0.0)


def _check_station_pairs(life: Lifelong) -> None:
    reach = 2.0 * _bounding_radius(life)
    stations = sorted(life.stations, key=lambda st: st.pose[0])
    for a, sa in enumerate(stations):
        for sb in stations[a + 1:]:
            if sb.pose[0] - sa.pose[0] > reach:
                break  # sorted by x: every later station is farther still
            if math.dist(sa.pose[:2], sb.pose[:2]) > reach:
                continue
            _check_pair(life, sa, sb)


def _check_pair(life: Lifelong, sa: Station, sb: Station) -> None:
    first, second = sorted((sa, sb), key=lambda st: st.name)
    for ta in by_size(life):
        for tb in by_size(life):
            if polygon_distance(outline_at(ta, first.pose), outline_at(tb, second.pose)) < \
                    -OVERLAP_TOL:
                raise ScenarioError(f"stations.{first.name}: a {ta.name!r} load resting there "
                                    f"overlaps a {tb.name!r} load resting at station "
                                    f"{second.name!r}")


def _check_fleet(s: Scenario, life: Lifelong) -> None:
    r, offset = s.robot.radius, s.robot.control_offset
    for fr in life.fleet.robots:
        where = f"fleet.robots.{fr.id}.start"
        p = control_point(fr.start[0], fr.start[1], fr.start[2], offset)
        _check_point(s, p, where, offset)
    bodies: list[tuple[str, tuple[float, ...]]] = [
        (f"fleet.robots.{fr.id}", fr.start[:2]) for fr in life.fleet.robots]
    bodies += [(f"robot {rs.id!r}", rs.start[:2]) for rs in s.robots]
    _check_bodies(bodies, 2.0 * r)
    for ld in life.loads:
        outline = outline_at(life.load_type(ld.type), life.station(ld.at).pose)
        for where, body in bodies:
            if points_distance(np.array([body[:2]]), outline)[0] < r - OVERLAP_TOL:
                raise ScenarioError(f"{where}: starts under load {ld.name!r} resting at "
                                    f"{ld.at!r} (its body overlaps the load)")
    for k, spot in enumerate(life.fleet.parking):
        _check_point(s, spot, f"fleet.parking[{k}]", 0.0)
        for st in life.stations:
            for t in by_size(life):
                if points_distance(np.array([spot]), outline_at(t, st.pose))[0] < r:
                    raise ScenarioError(f"fleet.parking[{k}]: a robot parked there overlaps "
                                        f"a {t.name!r} load at station {st.name!r}")


def _check_point(s: Scenario, p: Point, where: str, slack: float) -> None:
    """A robot's control point ``p`` outside every shape's and circle's safe distance (plus
    ``slack``, a unicycle's look-ahead, as for a formation's start)."""
    for sh in s.shapes:
        d = shape_distance(p[0], p[1], sh)[0]
        if d < sh.ds + slack:
            raise ScenarioError(f"{where}: {d:.3f} m from {sh.kind} {sh.name!r}, inside its safe "
                                f"distance {sh.ds:.3f} m" + (f" plus the look-ahead {slack:.3f} m"
                                                            if slack else ""))
    for o in s.obstacles:
        d = math.dist(p, o.center)
        if d < o.safe_distance + slack:
            raise ScenarioError(f"{where}: {d:.3f} m from obstacle {o.name!r}, inside its safe "
                                f"distance {o.safe_distance:.3f} m")


def _check_bodies(bodies: list[tuple[str, tuple[float, ...]]], least: float) -> None:
    """No two bodies closer than ``least`` (sorted by x: each is compared with the ones within
    ``least`` along x only)."""
    order = sorted(range(len(bodies)), key=lambda k: bodies[k][1][0])
    for n, a in enumerate(order):
        for b in order[n + 1:]:
            pa, pb = bodies[a][1], bodies[b][1]
            if pb[0] - pa[0] >= least:
                break
            if math.dist(pa[:2], pb[:2]) < least:
                first, second = sorted((a, b))
                raise ScenarioError(f"{bodies[second][0]}: starts {math.dist(pa[:2], pb[:2]):.3f}"
                                    f" m from {bodies[first][0]}, closer than two body radii "
                                    f"({least:.3f} m)")


def _check_orders(life: Lifelong) -> None:
    for k, o in enumerate(life.orders):
        if o.load is None or o.from_ is None or o.load not in life.load_by_name:
            continue
        at = life.load_by_name[o.load].at
        if o.from_ != at:
            raise ScenarioError(f"orders[{k}].from: load {o.load!r} rests at {at!r}, not at "
                                f"{o.from_!r}")


def _check_stream(life: Lifelong) -> None:
    if life.stream is None:
        return
    kinds = {st.kind for st in life.stations}
    if STORE not in kinds:
        raise ScenarioError("order_stream: no store to fill or empty (declare a station of kind "
                            "store)")
    if SOURCE not in kinds and SINK not in kinds:
        raise ScenarioError("order_stream: no source and no sink to serve (declare a station "
                            "of kind source or sink)")


def lifelong_warnings(s: Scenario) -> list[str]:
    """What a valid lifelong part allows that the user should know, one line each: an order
    posted after the run ends, a stream whose orders can never be served in this hall."""
    life = s.lifelong
    if life is None:
        return []
    out = [f"orders[{k}].t: posted at {o.t:g} s, after the run ends (duration {s.duration:g} s)"
           for k, o in enumerate(life.orders) if o.t > s.duration]
    stream = life.stream
    if stream is not None and stream.rate_per_min > 0.0 and not plan(life, s.duration):
        out.append("order_stream: posts no order in this run: no free source with a free store, "
                   "and no full store with a free sink, whenever an order arrives")
    return out
