"""Load and validate a scenario file (the contract in docs/scenarios.md).

Every problem is reported as one :class:`ScenarioError` whose message names the culprit by its
path in the file (``formations[1].edges[0]``) and says what is wrong, quoting at most a short
excerpt of the value. Nothing is half-loaded.

Checks, in order: the file (a regular UTF-8 file of bounded size, YAML within the limits of
:mod:`scenario.reader`: depth, aliases, duplicate keys, huge integers); unknown keys; types,
finiteness and the range of every number and count (:mod:`scenario.limits`); names that follow
the one name rule (:func:`wire.keys.name_problem`); unique names; edges naming known robots of the
same formation; generic rigidity of every formation graph (rank of the rigidity matrix at random
positions is 2n - 3); the leader adjacent to every member; a formation band that keeps bodies
apart (Df - epsilon >= 2 radius); and a start that satisfies every constraint (formation band,
obstacle clearance, other formations' ellipses, no two bodies overlapping).

The work grows linearly with the robots: formations have a bounded size, and the checks between
robots of different formations look only at neighbours found through a spatial grid
(:mod:`scenario.spatial`).
"""

from __future__ import annotations

import math
import random
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from geometry.ellipse import (
    Ellipse,
    ReferenceShape,
    centroid,
    derive_axes,
    ellipse_value,
    estimate,
    reference_shape,
)
from geometry.shapes import Shape, shape_distance
from geometry.shapes import box as box_shape
from geometry.shapes import segment as segment_shape
from geometry.unicycle import control_point

from . import limits
from .cargo import LOAD_KEY, load_clearances, load_polygon, parse_load
from .fields import count as _count
from .fields import identifier as _identifier
from .fields import mapping as _mapping
from .fields import positive as _positive
from .fields import string as _string
from .fields import title as _title
from .fields import vector as _vector
from .fields import within as _in
from .lifelong import KEYS as LIFELONG_KEYS
from .lifelong import parse_lifelong
from .lifelong_checks import check_lifelong
from .model import (
    DOUBLE_INTEGRATOR,
    METHODS,
    MODELS,
    SINGLE_INTEGRATOR,
    Bounds,
    ControllerSpec,
    Edge,
    FormationSpec,
    Gammas,
    ObstacleSpec,
    RobotModel,
    RobotSpec,
    Scenario,
    check_model_world,
    model_world_warning,
)
from .reader import ScenarioError, excerpt, load_yaml, read_text
from .shipped import find
from .spatial import Grid
from .world import parse_world

ELLIPSE_MARGIN = 0.02  # [m] extra clearance of a derived ellipse beyond bodies and tolerance
LOAD_TOL = 1e-6  # [m] a load overlapping by less is touching (rounding), not overlapping
TIEBREAKS = ("keep_right", "none")

_TOP_KEYS = {"name", "dt", "duration", "goal_tolerance", "robot", "controller", "formations",
             "obstacles", "world", *LIFELONG_KEYS}
_ROBOT_KEYS = {"model", "max_speed", "max_turn_rate", "lookahead", "radius", "max_accel"}
_CONTROLLER_KEYS = {"kp", "gamma", "epsilon", "tiebreak", "d_af", "planner", "method", "bounds"}
_GAMMA_KEYS = {"formation", "obstacle", "formations"}
_FORMATION_KEYS = {"name", "leader", "robots", "edges", "ellipse", "waypoints", LOAD_KEY}
_MEMBER_KEYS = {"start", "goal"}
_ELLIPSE_KEYS = {"a", "b"}
_OBSTACLE_KEYS = {"name", "center", "safe_distance", "velocity", "stop_at", "segment", "box"}
_BOX_KEYS = {"center", "size", "yaw"}
PLANNERS = ("visibility", "none")


def load_scenario(path: str | Path) -> Scenario:
    """Read, parse and validate the scenario at ``path`` (or the shipped scenario a path that
    does not exist names: :func:`scenario.shipped.find`)."""
    p = find(path)
    text = read_text(p)
    try:
        return parse_scenario(text, source=str(p))
    except ScenarioError as exc:
        msg = str(exc)
        raise ScenarioError(msg if msg.startswith(str(p)) else f"{p}: {msg}") from None


def parse_scenario(text: str, source: str = "<scenario>") -> Scenario:
    """Parse and validate scenario YAML text."""
    return scenario_from_dict(load_yaml(text, source))


def scenario_from_dict(data: Any) -> Scenario:
    """Validate an already-parsed mapping and build the :class:`Scenario`."""
    top = _mapping(data, "scenario", _TOP_KEYS)
    name = _title(top.get("name", "scenario"), "name")
    dt = _in(top.get("dt", 0.05), "dt", limits.DT)
    duration = _positive(top.get("duration", 120.0), "duration")
    if duration < dt:
        raise ScenarioError(f"duration: {duration} s is shorter than one control period dt={dt} s")
    if math.ceil(duration / dt - 1e-9) > limits.MAX_TICKS:  # Scenario.steps
        raise ScenarioError(
            f"duration: {excerpt(duration)} s is {duration / dt:.3g} control periods of dt={dt} s,"
            f" more than {limits.MAX_TICKS:,} (shorten it or lengthen dt)"
        )
    tol = _in(top.get("goal_tolerance", 0.05), "goal_tolerance", limits.GOAL_TOLERANCE)
    robot = _robot_model(top.get("robot", {}))
    controller = _controller(top.get("controller", {}))

    formations = _formations(top, robot)

    raw_obstacles = top.get("obstacles", []) or []
    if not isinstance(raw_obstacles, list):
        raise ScenarioError("obstacles: must be a list")
    _count(raw_obstacles, "obstacles", limits.MAX_OBSTACLES)
    parsed: list[ObstacleSpec | Shape] = []
    obstacle_names: set[str] = set()
    for k, raw in enumerate(raw_obstacles):
        o = _obstacle(raw, f"obstacles[{k}]")
        if o.name in obstacle_names:
            raise ScenarioError(f"obstacles[{k}].name: duplicate obstacle name {o.name!r}")
        obstacle_names.add(o.name)
        parsed.append(o)
    obstacles = tuple(o for o in parsed if isinstance(o, ObstacleSpec))
    shapes = tuple(o for o in parsed if isinstance(o, Shape))

    world = parse_world(top.get("world"))
    check_model_world(robot, world)
    lifelong = parse_lifelong(top, robot.radius, controller.epsilon)
    scenario = Scenario(name, dt, duration, tol, robot, controller, formations,
                        obstacles, shapes, world, lifelong)
    axes = [formation_axes(scenario, f) for f in scenario.formations]
    _check_bands(scenario)
    _check_start(scenario, axes)
    _check_goals(scenario, axes)
    _check_loads(scenario, axes)
    _check_shapes(scenario, [k for k, o in enumerate(parsed) if isinstance(o, Shape)])
    check_lifelong(scenario)
    return scenario


# ---------------------------------------------------------------------------- sections


def _formations(top: Mapping[str, Any], robot: RobotModel) -> tuple[FormationSpec, ...]:
    """``formations``: at least one, unless a ``fleet`` is given (then none is fine)."""
    fleet_only = top.get("fleet") is not None and top.get("formations") in (None, [])
    if "formations" not in top and not fleet_only:
        raise ScenarioError("formations: missing (at least one formation, or a fleet, is "
                            "needed)")
    raw_formations = [] if fleet_only else top["formations"]
    if not isinstance(raw_formations, list) or not (raw_formations or fleet_only):
        raise ScenarioError("formations: must be a non-empty list")
    _count(raw_formations, "formations", limits.MAX_FORMATIONS)
    seen_robots: dict[str, str] = {}
    formations = []
    formation_names: set[str] = set()
    for k, raw in enumerate(raw_formations):
        f = _formation(raw, f"formations[{k}]", robot, seen_robots)
        if f.name in formation_names:
            raise ScenarioError(f"formations[{k}].name: duplicate formation name {f.name!r}")
        formation_names.add(f.name)
        formations.append(f)
    return tuple(formations)


def _robot_model(raw: Any) -> RobotModel:
    m = _mapping(raw, "robot", _ROBOT_KEYS)
    model = _string(m.get("model", SINGLE_INTEGRATOR), "robot.model")
    if model not in MODELS:
        raise ScenarioError(
            f"robot.model: {excerpt(model)} is not one of {', '.join(repr(x) for x in MODELS)}"
        )
    accel = m.get("max_accel")
    if accel is None and model == DOUBLE_INTEGRATOR:
        raise ScenarioError("robot.max_accel: required for model 'double_integrator' [m/s^2]")
    if accel is not None and model == SINGLE_INTEGRATOR:
        raise ScenarioError("robot.max_accel: only for model 'double_integrator' or 'unicycle'")
    d = RobotModel()
    return RobotModel(
        model=model,
        max_speed=_in(m.get("max_speed", d.max_speed), "robot.max_speed", limits.MAX_SPEED),
        max_turn_rate=_in(m.get("max_turn_rate", d.max_turn_rate), "robot.max_turn_rate",
                          limits.MAX_TURN_RATE),
        lookahead=_in(m.get("lookahead", d.lookahead), "robot.lookahead", limits.LOOKAHEAD),
        radius=_in(m.get("radius", d.radius), "robot.radius", limits.RADIUS),
        max_accel=None if accel is None else _in(accel, "robot.max_accel", limits.MAX_ACCEL),
    )


def _controller(raw: Any) -> ControllerSpec:
    m = _mapping(raw, "controller", _CONTROLLER_KEYS)
    d = ControllerSpec()
    g = m.get("gamma", 1.0)
    if isinstance(g, Mapping):
        gm = _mapping(g, "controller.gamma", _GAMMA_KEYS)
        gammas = Gammas(**{k: _in(gm.get(k, 1.0), f"controller.gamma.{k}", limits.GAMMA)
                           for k in sorted(_GAMMA_KEYS)})
    else:
        v = _in(g, "controller.gamma", limits.GAMMA)
        gammas = Gammas(v, v, v)
    tiebreak = _string(m.get("tiebreak", d.tiebreak), "controller.tiebreak")
    if tiebreak not in TIEBREAKS:
        raise ScenarioError(f"controller.tiebreak: {excerpt(tiebreak)} is not one of {TIEBREAKS}")
    d_af = m.get("d_af")
    planner = _string(m.get("planner", d.planner), "controller.planner")
    if planner not in PLANNERS:
        raise ScenarioError(f"controller.planner: {planner!r} is not one of {PLANNERS}")
    return ControllerSpec(
        kp=_in(m.get("kp", d.kp), "controller.kp", limits.GAIN),
        gamma=gammas,
        epsilon=_in(m.get("epsilon", d.epsilon), "controller.epsilon", limits.EPSILON),
        tiebreak=tiebreak,
        d_af=None if d_af is None else _in(d_af, "controller.d_af", limits.DISTANCE),
        planner=planner,
        method=_choice(m.get("method", d.method), "controller.method", METHODS),
        bounds=_bounds(m.get("bounds", {})),
    )


def _bounds(raw: Any) -> Bounds:
    """``controller.bounds``: each bound a number in its range (:data:`limits.BOUNDS`); a
    missing one is 0."""
    m = _mapping(raw, "controller.bounds", set(limits.BOUNDS))
    return Bounds(**{k: _in(m.get(k, 0.0), f"controller.bounds.{k}", r)
                     for k, r in limits.BOUNDS.items()})


def _choice(raw: Any, where: str, allowed: tuple[str, ...]) -> str:
    value = _string(raw, where)
    if value not in allowed:
        raise ScenarioError(f"{where}: {excerpt(value)} is not one of {allowed}")
    return value


def _formation(raw: Any, where: str, robot: RobotModel, seen: dict[str, str]) -> FormationSpec:
    m = _mapping(raw, where, _FORMATION_KEYS)
    if "name" not in m:
        raise ScenarioError(f"{where}.name: missing")
    name = _identifier(m["name"], f"{where}.name")
    specs = _members(m.get("robots"), where, name, seen)
    ctrl = {r.id: _control_point(r.start, robot.control_offset) for r in specs}
    edges = _edges(m.get("edges", []), where, name, ctrl, seen)
    order = [r.id for r in specs]
    if len(order) >= 2 and not is_generically_rigid(order, [(e.i, e.j) for e in edges]):
        raise ScenarioError(
            f"{where}.edges: the graph of formation {name!r} is not rigid "
            f"({len(edges)} edges for {len(order)} robots; a rigid graph needs at least "
            f"{2 * len(order) - 3} well-placed edges)"
        )
    leader = _leader(m, where, name, order, edges)
    ellipse = None if m.get("ellipse") is None else _ellipse_axes(m["ellipse"], f"{where}.ellipse")
    load = () if m.get(LOAD_KEY) is None else parse_load(m[LOAD_KEY], f"{where}.{LOAD_KEY}")
    waypoints = _waypoints(m, where)
    return FormationSpec(name, leader, specs, edges, ellipse, tuple((w[0], w[1]) for w in waypoints), load,
                         _waypoint_headings(waypoints, where))


def _members(raw_robots: Any, where: str, name: str,
             seen: dict[str, str]) -> tuple[RobotSpec, ...]:
    """The formation's robots: unique names, a start (x, y[, theta]) and a goal each; the
    default heading faces from the start centroid to the goal centroid."""
    if not isinstance(raw_robots, Mapping) or not raw_robots:
        raise ScenarioError(f"{where}.robots: must be a non-empty mapping of robot name to "
                            "{start, goal}")
    _count(raw_robots, f"{where}.robots", limits.MAX_FORMATION_ROBOTS)
    robots = []
    for rid, spec in raw_robots.items():
        rid = _identifier(rid, f"{where}.robots")
        rwhere = f"{where}.robots.{rid}"
        if rid in seen:
            raise ScenarioError(f"{rwhere}: robot {rid!r} is already in formation {seen[rid]!r}")
        seen[rid] = name
        robots.append((rid, *_member(spec, rwhere)))
    heading = _default_heading([r[1] for r in robots], [r[2] for r in robots])
    return tuple(
        RobotSpec(rid, name, (s[0], s[1], s[2] if len(s) == 3 else heading), (g[0], g[1]))
        for rid, s, g in robots
    )


def _member(spec: Any, rwhere: str) -> tuple[tuple[float, ...], tuple[float, ...]]:
    rm = _mapping(spec, rwhere, _MEMBER_KEYS)
    for key in ("start", "goal"):
        if key not in rm:
            raise ScenarioError(f"{rwhere}.{key}: missing")
    start = _vector(rm["start"], f"{rwhere}.start", (2, 3), limits.COORDINATE)
    if len(start) == 3:
        _in(start[2], f"{rwhere}.start[2] (heading)", limits.HEADING)
    return start, _vector(rm["goal"], f"{rwhere}.goal", (2,), limits.COORDINATE)


def _default_heading(starts: list[tuple[float, ...]], goals: list[tuple[float, ...]]) -> float:
    """Every member faces from the formation's start centroid to its goal centroid."""
    n = len(starts)
    scx, scy = sum(p[0] for p in starts) / n, sum(p[1] for p in starts) / n
    gcx, gcy = sum(p[0] for p in goals) / n, sum(p[1] for p in goals) / n
    return math.atan2(gcy - scy, gcx - scx) if math.hypot(gcx - scx, gcy - scy) > 1e-9 else 0.0


def _edges(raw_edges: Any, where: str, name: str, ctrl: dict[str, tuple[float, float]],
           seen: dict[str, str]) -> tuple[Edge, ...]:
    if not isinstance(raw_edges, list):
        raise ScenarioError(f"{where}.edges: must be a list of [i, j] or [i, j, Df]")
    n = len(ctrl)
    pair_count = n * (n - 1) // 2
    if len(raw_edges) > pair_count:
        raise ScenarioError(f"{where}.edges: {len(raw_edges)} edges, more than the {pair_count} "
                            f"pairs of its {n} robots")
    edges: list[Edge] = []
    pairs: set[frozenset[str]] = set()
    for k, raw in enumerate(raw_edges):
        edge = _edge(raw, f"{where}.edges[{k}]", name, ctrl, seen)
        pair = frozenset((edge.i, edge.j))
        if pair in pairs:
            raise ScenarioError(f"{where}.edges[{k}]: duplicate edge between {edge.i!r} and "
                                f"{edge.j!r}")
        pairs.add(pair)
        edges.append(edge)
    return tuple(edges)


def _edge(raw: Any, ew: str, name: str, ctrl: dict[str, tuple[float, float]],
          seen: dict[str, str]) -> Edge:
    if not isinstance(raw, list) or len(raw) not in (2, 3):
        raise ScenarioError(f"{ew}: must be [i, j] or [i, j, Df], got {excerpt(raw)}")
    i, j = (_string(raw[0], f"{ew}[0]"), _string(raw[1], f"{ew}[1]"))
    for endpoint in (i, j):
        if endpoint not in ctrl:
            other = f" (it is in formation {seen[endpoint]!r})" if endpoint in seen else ""
            raise ScenarioError(f"{ew}: unknown robot {excerpt(endpoint)} in formation "
                                f"{name!r}{other}")
    if i == j:
        raise ScenarioError(f"{ew}: an edge joins two different robots, got {i!r} twice")
    if len(raw) == 3:
        return Edge(i, j, _in(raw[2], f"{ew}[2] (Df)", limits.DISTANCE))
    df = math.dist(ctrl[i], ctrl[j])
    if df <= 0.0:
        raise ScenarioError(f"{ew}: Df omitted and {i!r}, {j!r} start at the same point")
    return Edge(i, j, df)


def _leader(m: Mapping[str, Any], where: str, name: str, order: list[str],
            edges: tuple[Edge, ...]) -> str:
    if "leader" not in m:
        raise ScenarioError(f"{where}.leader: missing")
    leader = _string(m["leader"], f"{where}.leader")
    if leader not in order:
        raise ScenarioError(f"{where}.leader: {excerpt(leader)} is not a robot of formation "
                            f"{name!r}")
    adjacent = {e.j for e in edges if e.i == leader} | {e.i for e in edges if e.j == leader}
    missing = [r for r in order if r != leader and r not in adjacent]
    if missing:
        raise ScenarioError(
            f"{where}.leader: {leader!r} is not adjacent to {', '.join(repr(x) for x in missing)}"
            " (the leader must share an edge with every member)"
        )
    return leader


def _ellipse_axes(raw: Any, where: str) -> tuple[float, float]:
    em = _mapping(raw, where, _ELLIPSE_KEYS)
    for key in ("a", "b"):
        if key not in em:
            raise ScenarioError(f"{where}.{key}: missing")
    a = _in(em["a"], f"{where}.a", limits.DISTANCE)
    b = _in(em["b"], f"{where}.b", limits.DISTANCE)
    if b > a:
        raise ScenarioError(f"{where}: a={a} is the major semi-axis and must be >= b={b}")
    return (a, b)


def _waypoints(m: Mapping[str, Any], where: str) -> tuple[tuple[float, ...], ...]:
    """Each waypoint as [x, y] or [x, y, heading] (the goal shape's turn there, rad)."""
    raw_wp = m.get("waypoints", []) or []
    if not isinstance(raw_wp, list):
        raise ScenarioError(f"{where}.waypoints: must be a list of [x, y] or [x, y, heading]")
    _count(raw_wp, f"{where}.waypoints", limits.MAX_WAYPOINTS)
    return tuple(_vector(w, f"{where}.waypoints[{k}]", (2, 3), limits.COORDINATE)
                 for k, w in enumerate(raw_wp))


def _waypoint_headings(waypoints: tuple[tuple[float, ...], ...], where: str
                       ) -> tuple[float | None, ...]:
    """The waypoints' headings (None where a waypoint has none); () when none has one."""
    if all(len(w) == 2 for w in waypoints):
        return ()
    for k, w in enumerate(waypoints):
        if len(w) == 3:
            _in(w[2], f"{where}.waypoints[{k}][2]", limits.HEADING)
    return tuple(w[2] if len(w) == 3 else None for w in waypoints)


def _obstacle(raw: Any, where: str) -> ObstacleSpec | Shape:
    m = _mapping(raw, where, _OBSTACLE_KEYS)
    if "segment" in m or "box" in m:
        return _shape(m, where)
    for key in ("center", "safe_distance"):
        if key not in m:
            raise ScenarioError(f"{where}.{key}: missing")
    name = _identifier(m.get("name", where.replace("[", "").replace("]", "")), f"{where}.name")
    center = _vector(m["center"], f"{where}.center", (2,), limits.COORDINATE)
    ds = _in(m["safe_distance"], f"{where}.safe_distance", limits.DISTANCE)
    vel = _vector(m.get("velocity", [0.0, 0.0]), f"{where}.velocity", (2,), limits.OBSTACLE_SPEED)
    stop = None
    if "stop_at" in m:
        if tuple(vel) == (0.0, 0.0):
            raise ScenarioError(f"{where}.stop_at: only a moving circle (with a velocity) stops")
        stop = _positive(m["stop_at"], f"{where}.stop_at")
    return ObstacleSpec(name, (center[0], center[1]), ds, (vel[0], vel[1]), stop)


def _shape(m: Mapping[str, Any], where: str) -> Shape:
    """A wall (``segment: [[x, y], [x, y]]``) or a shelf (``box: {center, size, yaw}``)."""
    kind = "segment" if "segment" in m else "box"
    for key in ("center", "velocity", "stop_at", "box" if kind == "segment" else "segment"):
        if key in m:
            raise ScenarioError(f"{where}.{key}: not allowed on a {kind} (only circles have a "
                                "center and move; an obstacle is one of circle, segment, box)")
    if "safe_distance" not in m:
        raise ScenarioError(f"{where}.safe_distance: missing")
    name = _identifier(m.get("name", where.replace("[", "").replace("]", "")), f"{where}.name")
    ds = _in(m["safe_distance"], f"{where}.safe_distance", limits.DISTANCE)
    if kind == "segment":
        raw = m["segment"]
        if not isinstance(raw, list) or len(raw) != 2:
            raise ScenarioError(f"{where}.segment: must be [[x, y], [x, y]], got {raw!r}")
        a = _vector(raw[0], f"{where}.segment[0]", (2,), limits.COORDINATE)
        b = _vector(raw[1], f"{where}.segment[1]", (2,), limits.COORDINATE)
        if math.dist(a, b) <= 0.0:
            raise ScenarioError(f"{where}.segment: both ends are the same point")
        return segment_shape(name, (a[0], a[1]), (b[0], b[1]), ds)
    bm = _mapping(m["box"], f"{where}.box", _BOX_KEYS)
    for key in ("center", "size"):
        if key not in bm:
            raise ScenarioError(f"{where}.box.{key}: missing")
    center = _vector(bm["center"], f"{where}.box.center", (2,), limits.COORDINATE)
    size = _vector(bm["size"], f"{where}.box.size", (2,), limits.COORDINATE)
    for k in (0, 1):
        _in(size[k], f"{where}.box.size[{k}]", limits.DISTANCE)
    yaw = _in(bm.get("yaw", 0.0), f"{where}.box.yaw", limits.HEADING)
    return box_shape(name, (center[0], center[1]), (size[0], size[1]), yaw, ds)


def _check_shapes(s: Scenario, where: list[int]) -> None:
    """No start, goal or waypoint inside a wall's or shelf's safe distance (or the shelf)."""
    offset = s.robot.control_offset
    for k, sh in zip(where, s.shapes, strict=True):
        for r in s.robots:
            start = _control_point(r.start, offset)
            for what, p, slack in (("starts", start, offset), ("has its goal", r.goal, 0.0)):
                d = shape_distance(p[0], p[1], sh)[0]
                if d <= 0.0 and sh.kind == "box":
                    raise ScenarioError(f"obstacles[{k}]: robot {r.id!r} {what} inside {sh.kind} "
                                        f"{sh.name!r}")
                if d < sh.ds + slack:
                    raise ScenarioError(
                        f"obstacles[{k}]: robot {r.id!r} {what} {d:.3f} m from {sh.kind} "
                        f"{sh.name!r}, {_inside_safe(sh.ds, slack)}"
                    )
        for fk, f in enumerate(s.formations):
            for wk, w in enumerate(f.waypoints):
                if shape_distance(w[0], w[1], sh)[0] < sh.ds:
                    raise ScenarioError(
                        f"formations[{fk}].waypoints[{wk}]: inside the safe distance of "
                        f"{sh.kind} {sh.name!r} (obstacles[{k}])"
                    )


# ---------------------------------------------------------------------------- cross checks


def is_generically_rigid(nodes: list[str], edges: list[tuple[str, str]], trials: int = 3) -> bool:
    """Generic (infinitesimal) rigidity in the plane: the rigidity matrix at random positions
    has rank 2n - 3 (n >= 2). Random positions avoid the measure-zero degenerate placements."""
    n = len(nodes)
    if n < 2:
        return True
    index = {v: k for k, v in enumerate(nodes)}
    rng = random.Random(12345)
    for _ in range(trials):
        pos = np.array([[rng.uniform(-1, 1), rng.uniform(-1, 1)] for _ in nodes])
        r = np.zeros((len(edges), 2 * n))
        for row, (i, j) in enumerate(edges):
            a, b = index[i], index[j]
            d = pos[a] - pos[b]
            r[row, 2 * a: 2 * a + 2] = d
            r[row, 2 * b: 2 * b + 2] = -d
        if len(edges) and np.linalg.matrix_rank(r) == 2 * n - 3:
            return True
    return False


def formation_axes(scenario: Scenario, formation: FormationSpec) -> tuple[float, float]:
    """Semi-axes the leader publishes: as written in the file, or derived to enclose every
    member with room for another robot's body (both control offsets, the tolerance and a margin)."""
    if formation.ellipse is not None:
        return formation.ellipse
    r = scenario.robot
    clearance = 2.0 * r.radius + 2.0 * r.control_offset + scenario.controller.epsilon
    shape = reference_shape([_control_point(m.start, r.control_offset) for m in formation.robots])
    if formation.load:  # a declared load: the ellipse contains it too (the hull it does anyway)
        cx, cy = centroid([_control_point(m.start, r.control_offset) for m in formation.robots])
        shape = ReferenceShape(shape.offsets + tuple((x - cx, y - cy)
                                                     for x, y in load_polygon(formation)),
                               shape.alpha0)
    return derive_axes(shape, clearance + ELLIPSE_MARGIN)


def start_ellipse(scenario: Scenario, formation: FormationSpec,
                  axes: tuple[float, float] | None = None) -> Ellipse:
    pts = [_control_point(m.start, scenario.robot.control_offset) for m in formation.robots]
    shape = reference_shape(pts)
    if axes is None:
        axes = formation_axes(scenario, formation)
    return estimate(shape, axes, pts, [(0.0, 0.0)] * len(pts))


def _check_bands(s: Scenario) -> None:
    eps, r = s.controller.epsilon, s.robot.radius
    for k, f in enumerate(s.formations):
        for n, e in enumerate(f.edges):
            if e.df - eps < 2.0 * r - 1e-12:
                raise ScenarioError(
                    f"formations[{k}].edges[{n}]: Df - epsilon = {e.df - eps:.3f} m lets the bodies"
                    f" of {e.i!r} and {e.j!r} overlap (two radii are {2 * r:.3f} m)"
                )


def _inside_safe(safe: float, lookahead: float) -> str:
    """The distance a start broke: the obstacle's safe distance, and apart the look-ahead of a
    unicycle's control point (the distance is the control point's, which must start clear by
    the look-ahead too), never one sum passed off as the safe distance."""
    if lookahead <= 0.0:
        return f"inside its safe distance {safe:.3f} m"
    return (f"inside its safe distance {safe:.3f} m plus the look-ahead {lookahead:.3f} m "
            f"(distances from the robot's control point)")


def _check_start(s: Scenario, axes: list[tuple[float, float]]) -> None:
    eps, offset = s.controller.epsilon, s.robot.control_offset
    ctrl = {r.id: _control_point(r.start, offset) for r in s.robots}
    for k, f in enumerate(s.formations):
        for n, e in enumerate(f.edges):
            d = math.dist(ctrl[e.i], ctrl[e.j])
            if abs(d - e.df) > eps + 1e-9:
                raise ScenarioError(
                    f"formations[{k}].edges[{n}]: start distance {d:.3f} m between {e.i!r} and "
                    f"{e.j!r} is outside Df={e.df:.3f} +/- epsilon={eps:.3f} m"
                )
    for rid, p in ctrl.items():
        for k, o in enumerate(s.obstacles):
            d = math.dist(p, o.center)
            if d < o.safe_distance + offset:
                raise ScenarioError(
                    f"obstacles[{k}]: robot {rid!r} starts {d:.3f} m from obstacle {o.name!r}, "
                    f"{_inside_safe(o.safe_distance, offset)}"
                )
    robots = s.robots
    overlap = _first_overlap([r.start[:2] for r in robots], 2.0 * s.robot.radius)
    if overlap is not None:
        a, b = overlap
        d = math.dist(robots[a].start[:2], robots[b].start[:2])
        raise ScenarioError(
            f"formations: robots {robots[a].id!r} and {robots[b].id!r} start {d:.3f} m apart, "
            f"closer than two body radii ({2 * s.robot.radius:.3f} m)"
        )
    ellipses = [start_ellipse(s, f, ab) for f, ab in zip(s.formations, axes, strict=True)]
    hit = _first_intrusion(s, ellipses, [ctrl[r.id] for r in robots])
    if hit is not None:
        k, m = hit
        raise ScenarioError(
            f"formations[{k}]: robot {robots[m].id!r} of formation {robots[m].formation!r} starts "
            f"inside the ellipse of formation {s.formations[k].name!r}"
        )


def _check_goals(s: Scenario, axes: list[tuple[float, float]]) -> None:
    """A goal configuration that breaks a constraint can never be reached: say so up front."""
    eps, slop = s.controller.epsilon, 2.0 * s.robot.control_offset
    goals = {r.id: r.goal for r in s.robots}
    for k, f in enumerate(s.formations):
        for n, e in enumerate(f.edges):
            d = math.dist(goals[e.i], goals[e.j])
            if abs(d - e.df) > eps + slop + 1e-9:
                raise ScenarioError(
                    f"formations[{k}].edges[{n}]: goal distance {d:.3f} m between {e.i!r} and "
                    f"{e.j!r} is outside Df={e.df:.3f} +/- epsilon={eps:.3f} m: the goal is unreachable"
                )
    for rid, g in goals.items():
        for k, o in enumerate(s.obstacles):
            if o.velocity == (0.0, 0.0) and math.dist(g, o.center) < o.safe_distance:
                raise ScenarioError(
                    f"obstacles[{k}]: the goal of robot {rid!r} is inside the safe distance of "
                    f"obstacle {o.name!r}"
                )
    ellipses = []
    for f, ab in zip(s.formations, axes, strict=True):
        pts = [m.goal for m in f.robots]
        shape = reference_shape([_control_point(m.start, s.robot.control_offset) for m in f.robots])
        ellipses.append(estimate(shape, ab, pts, [(0.0, 0.0)] * len(pts)))
    robots = s.robots
    hit = _first_intrusion(s, ellipses, [r.goal for r in robots])
    if hit is not None:
        k, m = hit
        raise ScenarioError(
            f"formations[{k}]: the goal of robot {robots[m].id!r} (formation "
            f"{robots[m].formation!r}) is inside the ellipse of formation "
            f"{s.formations[k].name!r} at its goal"
        )


def _check_loads(s: Scenario, axes: list[tuple[float, float]]) -> None:
    """A declared load fits in its formation's ellipse and overlaps nothing at the start."""
    for k, (f, ab) in enumerate(zip(s.formations, axes, strict=True)):
        if not f.load:
            continue
        e = start_ellipse(s, f, ab)
        outside = [v for v in load_polygon(f) if ellipse_value(e, *v) > 1e-9]
        if outside:
            x, y = outside[0]
            raise ScenarioError(
                f"formations[{k}].ellipse: a={ab[0]:.3f}, b={ab[1]:.3f} m does not contain the "
                f"load (its corner ({x:.3f}, {y:.3f}) is outside); enlarge the ellipse or omit it")
    for c in start_load_contacts(s):
        if s.formations[c.formation].load:
            raise ScenarioError(
                f"formations[{c.formation}].load: overlaps {c.other!r} at the start by "
                f"{-c.clearance:.3f} m")


def start_load_contacts(s: Scenario) -> list:
    """The loads' overlaps at the start (:func:`scenario.cargo.load_clearances` below 0)."""
    loads = [load_polygon(f) for f in s.formations]
    bodies = np.array([r.start[:2] for r in s.robots], dtype=float)
    return [c for c in load_clearances(s, loads, bodies, [o.center for o in s.obstacles])
            if c.clearance < -LOAD_TOL]


def _first_overlap(points: list[tuple[float, ...]], min_distance: float) -> tuple[int, int] | None:
    """The first pair (a, b), a < b, of ``points`` closer than ``min_distance``: the smallest b,
    then the smallest a. A grid of ``min_distance`` cells: each point is compared only with
    the earlier points of its 3 x 3 block of cells, and those not closer than ``min_distance``
    to each other are at most a few per cell, so the work is linear in the points."""
    grid = Grid(min_distance)
    for b, (x, y) in enumerate(points):
        close = [a for a in grid.near(x, y) if closer(points[a], (x, y), min_distance)]
        if close:
            return min(close), b
        grid.add(b, x, y)
    return None


def closer(p: tuple[float, ...], q: tuple[float, ...], distance: float) -> bool:
    """Whether the points ``p`` and ``q`` are closer than ``distance`` (the inner pair check)."""
    return math.dist(p[:2], q[:2]) < distance


def _first_intrusion(s: Scenario, ellipses: list[Ellipse],
                     points: list[tuple[float, float]]) -> tuple[int, int] | None:
    """The first (formation k, robot index m) with robot m, of another formation, inside
    ``ellipses[k]`` at ``points[m]``: the smallest k, then the smallest m. Only the robots in the
    grid cells under each ellipse's bounding box are tested."""
    robots = s.robots
    if not ellipses:
        return None
    cell = max(2.0 * s.robot.radius, float(np.median([e.a for e in ellipses])))
    grid = Grid(cell)
    for m, (x, y) in enumerate(points):
        grid.add(m, x, y)
    for k, (f, e) in enumerate(zip(s.formations, ellipses, strict=True)):
        c, sn = math.cos(e.alpha), math.sin(e.alpha)
        hx, hy = math.hypot(e.a * c, e.b * sn), math.hypot(e.a * sn, e.b * c)
        inside = [m for m in grid.in_box(e.cx - hx, e.cy - hy, e.cx + hx, e.cy + hy)
                  if robots[m].formation != f.name and ellipse_value(e, *points[m]) < 0.0]
        if inside:
            return k, min(inside)
    return None


# ---------------------------------------------------------------------------- primitives


def _control_point(start: tuple[float, ...], offset: float) -> tuple[float, float]:
    """The control point (eq. 6.2) of a start pose (x, y[, theta]); theta defaults to 0."""
    return control_point(start[0], start[1], start[2] if len(start) > 2 else 0.0, offset)


def scenario_warnings(s: Scenario) -> list[str]:
    """Things a valid file allows that the user should know: one line each, naming the culprit.

    An edge whose band reaches two body radii (Df - epsilon = 2 r, e.g. a 0.25 m edge with
    epsilon 0.04 and r 0.105) lets the formation rows alone bring the bodies into contact;
    the controller's hard separation rows (:func:`agent.barriers.separation_row`) keep them apart."""
    eps, r = s.controller.epsilon, s.robot.radius
    out = [f"formations[{c.formation}]: its load (the hull of its members) overlaps "
           f"{c.other!r} at the start by {-c.clearance:.3f} m"
           for c in start_load_contacts(s) if not s.formations[c.formation].load]
    drive = model_world_warning(s.robot, s.world)
    if drive is not None:
        out.append(drive)
    for k, f in enumerate(s.formations):
        for n, e in enumerate(f.edges):
            if e.df - eps < 2.0 * r + 1e-6:
                out.append(
                    f"formations[{k}].edges[{n}]: Df - epsilon = {e.df - eps:.3f} m lets the bodies of "
                    f"{e.i!r} and {e.j!r} touch (two radii are {2 * r:.3f} m); the separation rows "
                    f"keep them apart")
    return out
