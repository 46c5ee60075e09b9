"""Per-robot agent configuration: only what one robot needs, derived from a scenario.

``formation deploy`` writes one of these per robot; ``formation run`` hands one to each agent
process. A robot's file names its neighbours (with Df), its goal, its formation's goal centroid,
the controller parameters and, for the leader, what the leader role needs (members, reference
shape, ellipse axes, the other formations). It holds nothing about robots it never hears from.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import MISSING, dataclass, field, fields
from pathlib import Path
from types import NoneType, UnionType
from typing import Any, Literal, Union, get_args, get_origin, get_type_hints

import yaml

from geometry.ellipse import reference_shape
from geometry.limits import BURGER_RADIUS
from geometry.unicycle import control_point
from leader.settings import LeaderSettings
from leader.team import Point, Pose, TeamPlan
from scenario import Scenario, formation_axes, limits
from scenario.cargo import load_polygon
from scenario.extent import world_extent
from scenario.lifelong import Lifelong
from scenario.model import LOCALISATIONS, Edge, FormationSpec, RobotSpec
from scenario.reader import excerpt
from scenario.routes import start_plan
from scenario.succession import formation_successor
from wire.keys import name_problem, validate_prefix
from wire.rmw_zenoh import RmwSettings
from wire.stamps import CLOCK_TOLERANCE_S
from wire.zconf import ZenohSettings

from .body import Footprint, footprint_of
from .control import ControlParams

CONFIG_VERSION = 1
TOPOLOGIES = ("reduced", "all-to-all")
BASES = ("world", "turtlebot3-humble", "turtlebot3-jazzy")
STALE_PERIODS = 5  # inputs older than this many pose periods (at least control periods) are stale


# What an agent configuration file holds of its Zenoh settings; the agent's session adds its
# connect timeout and credentials (command-line options) when it opens.
AGENT_ZENOH_FIELDS = ("mode", "connect", "listen", "multicast_scouting")
AGENT_ZENOH_MODE = "client"  # an agent's mode where its file names none


def agent_zenoh(**fields: Any) -> ZenohSettings:
    """The :class:`wire.zconf.ZenohSettings` of an agent: ``mode`` defaults to client."""
    return ZenohSettings(**{"mode": AGENT_ZENOH_MODE, **fields})


@dataclass(frozen=True)
class AgentConfig:
    """One robot's agent configuration, as the launcher or deploy writes it and the agent reads it.

    Over 20 fields on purpose: it is the flat, frozen record of one file (``load_config``), each
    field one key of it, so that a file and its record read the same; the parts of the agent
    each take the fields they need."""

    robot_id: str
    formation: str
    leader_id: str
    goal: tuple[float, float]
    formation_goal: tuple[float, float]
    neighbours: tuple[tuple[str, float], ...]  # (robot id, Df [m])
    control: ControlParams
    period: float  # [s] control period (the scenario's dt)
    radius: float = BURGER_RADIUS  # [m]
    start: tuple[float, float, float] | None = None  # initial pose, for simulation only
    prefix: str = "warehouse"
    topology: str = "reduced"
    foreign_robots: tuple[str, ...] = ()  # all-to-all only: robots of other formations
    partners: tuple[str, ...] = ()  # every other member of the formation: separation rows
    # leader, lifelong: the formations of one its routes go round as robots (two radii) where
    # no way keeps off their ellipses: a team's members standing near their slots
    # (agent.errand.mates_at, leader.routing.round_mates)
    mates: tuple[str, ...] = ()
    leader: LeaderSettings | None = None  # set on the leader robot only
    # set on the member that takes the leader role when the leader dies (leader.succession)
    standby: LeaderSettings | None = None
    stale_after: float = 0.25  # [s] inputs older than this are stale: command zero
    clock_tolerance: float = CLOCK_TOLERANCE_S  # [s] real time: a stamp this far ahead of the
    # agent's clock is still accepted (camera PC and robots synchronised by chrony)
    pose_period: float | None = None  # [s] how often poses really come (e.g. 1/15 for a 15 fps
    # camera); None: every control period
    base: str = "world"  # where commands go: the simulated world or a real robot base
    zenoh: ZenohSettings = field(default_factory=agent_zenoh)
    cmd_vel_key: str = "cmd_vel"  # real bases: the zenoh-bridge-ros2dds key for /cmd_vel
    frame_id: str = "base_link"  # real bases (Jazzy TwistStamped): header frame
    # real bases: None = zenoh-bridge-ros2dds on cmd_vel_key; set = rmw_zenoh, no bridge
    rmw: RmwSettings | None = None
    solver: str = "exact"  # QP solver (agent.qp.make_solver): exact or a qpsolvers backend
    # the formation centroid's route (waypoints, the goal centroid last); () = the goal alone
    route: tuple[tuple[float, float], ...] = ()
    # a heading per route point (the goal shape's turn; None: any) or () (method rigid)
    route_headings: tuple[float | None, ...] = ()
    route_by_hand: bool = False  # the route is the scenario's waypoints: never planned again
    # leader only: every member's goal as the scenario gives it (the goal shape at heading 0)
    member_goals: tuple[tuple[str, float, float], ...] = ()
    planner: bool = True  # the leader plans routes around walls and shelves for new goals
    goal_tolerance: float = 0.05  # [m]
    # controller.method rigid: this member's slot in its formation's body (agent.body)
    footprint: Footprint | None = None
    # the world's extent (xmin, ymin, xmax, ymax) [m] (scenario.extent): the leader refuses a
    # goal outside it; None: the scenario's coordinate range
    extent: tuple[float, float, float, float] | None = None
    # controller.localisation: "camera" (drive on the camera's poses) or "fused" (the agent's
    # own filter over its wheel odometry and the camera's poses: agent.odom_in)
    localisation: str = "camera"
    # a fleet robot (scenario ``fleet``): the warehouse it serves (stations, load types,
    # resting loads, parking, bidding), so that it can bid for orders and carry loads; None:
    # a robot of a fixed formation
    lifelong: Lifelong | None = None

    def __post_init__(self) -> None:
        _check_names(self)
        _check_numbers(self)
        _check_leader("leader", self.leader)
        _check_leader("standby", self.standby)
        for name, value, allowed in (("topology", self.topology, TOPOLOGIES),
                                     ("base", self.base, BASES),
                                     ("localisation", self.localisation, LOCALISATIONS)):
            if value not in allowed:
                raise ValueError(f"{name}: {value!r} is not one of {allowed}")

    @property
    def is_leader(self) -> bool:
        return self.leader is not None


#: The range of every number in an :class:`AgentConfig` (every number inside a field: each
#: coordinate of a goal, each Df of the neighbours); a tuple gives one range per position.
#: The scenario's ranges (:mod:`scenario.limits`): a robot's file holds what its scenario did.
CONFIG_RANGES: dict[str, limits.Range | tuple[limits.Range, ...]] = {
    "goal": limits.COORDINATE,
    "formation_goal": limits.COORDINATE,
    "neighbours": limits.DISTANCE,
    "period": limits.DT,
    "radius": limits.RADIUS,
    "start": (limits.COORDINATE, limits.COORDINATE, limits.HEADING),
    "stale_after": limits.STALE_AFTER,
    "clock_tolerance": limits.CLOCK_TOLERANCE,
    "pose_period": limits.POSE_PERIOD,
    "route": limits.COORDINATE,
    "route_headings": limits.HEADING,
    "member_goals": limits.COORDINATE,
    "goal_tolerance": limits.GOAL_TOLERANCE,
    "extent": (limits.COORDINATE,) * 4,
}
LEADER_RANGES: dict[str, limits.Range | tuple[limits.Range, ...]] = {
    "offsets": limits.COORDINATE,
    "alpha0": limits.HEADING,
    "axes": limits.DISTANCE,
}
#: Most entries of a list field (the scenario's counts).
CONFIG_COUNTS = {
    "neighbours": limits.MAX_FORMATION_ROBOTS - 1,
    "partners": limits.MAX_FORMATION_ROBOTS - 1,
    "mates": limits.MAX_FORMATION_ROBOTS - 1,
    "member_goals": limits.MAX_FORMATION_ROBOTS,
    "route": limits.MAX_WAYPOINTS + 1,
    "route_headings": limits.MAX_WAYPOINTS + 1,
    "members": limits.MAX_FORMATION_ROBOTS,
    "other_formations": limits.MAX_FORMATIONS - 1,
}


def _check_names(cfg: AgentConfig) -> None:
    """Every robot and formation name follows the one name rule (:func:`wire.keys.name_problem`)."""
    validate_prefix(cfg.prefix)
    names = [("robot_id", cfg.robot_id), ("formation", cfg.formation),
             ("leader_id", cfg.leader_id)]
    names += [(f"neighbours[{k}]", n) for k, (n, _) in enumerate(cfg.neighbours)]
    names += [(f"member_goals[{k}]", m) for k, (m, _, _) in enumerate(cfg.member_goals)]
    names += [(f"{name}[{k}]", n) for name in ("partners", "mates", "foreign_robots")
              for k, n in enumerate(getattr(cfg, name))]
    for where, name in names:
        problem = name_problem(name)
        if problem is not None:
            raise ValueError(f"{where}: {excerpt(name)} is not a valid name: it {problem}")


def _check_numbers(record: Any, ranges: dict[str, Any] | None = None) -> None:
    """Every number of ``record`` in its range and every list within its count."""
    for name, allowed in (CONFIG_RANGES if ranges is None else ranges).items():
        value = getattr(record, name)
        if isinstance(allowed, tuple):
            # ``start`` may be None; a tuple field's length is its type's
            for k, (v, r) in enumerate(zip(value or (), allowed, strict=False)):
                limits.check(v, f"{name}[{k}]", r)
        else:
            for where, v in _numbers(value, name):
                limits.check(v, where, allowed)
    for name, most in CONFIG_COUNTS.items():
        value = getattr(record, name, ())
        if len(value) > most:
            raise ValueError(f"{name}: {len(value)} entries, more than the {most} allowed")


def _numbers(value: Any, where: str) -> Iterator[tuple[str, Any]]:
    """Every number inside ``value`` (strings, names, are left out) with its path."""
    if isinstance(value, tuple):
        for k, v in enumerate(value):
            yield from _numbers(v, f"{where}[{k}]")
    elif value is not None and not isinstance(value, str):
        yield where, value


def _check_leader(where: str, settings: LeaderSettings | None) -> None:
    if settings is None:
        return
    try:
        _check_numbers(settings, LEADER_RANGES)
        for name in ("members", "other_formations"):
            for k, n in enumerate(getattr(settings, name)):
                problem = name_problem(n)
                if problem is not None:
                    raise ValueError(f"{name}[{k}]: {excerpt(n)} is not a valid name: it {problem}")
    except ValueError as exc:
        raise ValueError(f"{where}.{exc}") from None


#: The fields of an :class:`AgentConfig` that say which formation the robot is in and what it
#: does there (:class:`Membership`); every other field is the robot's own and never changes.
MEMBERSHIP_FIELDS = ("formation", "leader_id", "goal", "formation_goal", "neighbours",
                     "foreign_robots", "partners", "mates", "leader", "standby", "route",
                     "route_headings", "route_by_hand", "member_goals", "footprint")


@dataclass(frozen=True)
class Membership:
    """The agent's formation as one value, which the agent replaces at run time
    (:meth:`agent.node.AgentNode.regroup`): a formation of one, then a team's graph, leader,
    successor and load, then one again. Its fields are :class:`AgentConfig`'s of the same names
    (:data:`MEMBERSHIP_FIELDS`); the listen set, the leader role and the successor are derived
    from it the same way at the start and at every change."""

    formation: str
    leader_id: str
    goal: tuple[float, float]
    formation_goal: tuple[float, float]
    neighbours: tuple[tuple[str, float], ...]
    foreign_robots: tuple[str, ...] = ()
    partners: tuple[str, ...] = ()
    mates: tuple[str, ...] = ()
    leader: LeaderSettings | None = None
    standby: LeaderSettings | None = None
    route: tuple[tuple[float, float], ...] = ()
    route_headings: tuple[float | None, ...] = ()
    route_by_hand: bool = False
    member_goals: tuple[tuple[str, float, float], ...] = ()
    footprint: Footprint | None = None


def membership_of(cfg: AgentConfig) -> Membership:
    """The formation part of ``cfg``."""
    return Membership(**{name: getattr(cfg, name) for name in MEMBERSHIP_FIELDS})


def joined(cfg: AgentConfig, membership: Membership) -> AgentConfig:
    """``cfg`` in the formation ``membership`` (every check of the record runs again)."""
    return dataclasses.replace(cfg, **{name: getattr(membership, name)
                                       for name in MEMBERSHIP_FIELDS})


def memberships(scenario: Scenario, topology: str = "reduced") -> dict[str, Membership]:
    """Each robot's :class:`Membership` in the formations of ``scenario``: the leader's settings
    on the formation's leader, the same settings as ``standby`` on its successor
    (:func:`scenario.succession.formation_successor`), the route each formation starts with.
    The agents' configurations at the start (:func:`build_agent_configs`) and the formation a
    running agent changes to (the scenario of that moment, :func:`regrouped`) are both this
    function's."""
    out: dict[str, Membership] = {}
    for f in scenario.formations:
        out.update(formation_memberships(scenario, f, topology))
    return out


def formation_memberships(scenario: Scenario, f: FormationSpec, topology: str = "reduced"
                          ) -> dict[str, Membership]:
    """The :class:`Membership` of each member of ``f``, one of the formations of ``scenario``
    (:func:`memberships`)."""
    off = scenario.robot.control_offset
    first = start_plan(scenario, f)
    route = first.route
    shape = reference_shape([control_point(*r.start, off) for r in f.robots])
    leader = LeaderSettings(
        members=f.robot_ids,
        offsets=tuple((float(x), float(y)) for x, y in shape.offsets),
        alpha0=shape.alpha0,
        axes=formation_axes(scenario, f),
        other_formations=tuple(g.name for g in scenario.formations if g.name != f.name),
    )
    foreign = tuple(r for r in scenario.robot_ids if r not in f.robot_ids)
    heir = formation_successor(f)
    return {r.id: Membership(
        formation=f.name,
        leader_id=f.leader,
        goal=r.goal,
        formation_goal=f.goal_centroid,
        neighbours=f.neighbours(r.id),
        foreign_robots=foreign if topology == "all-to-all" else (),
        partners=tuple(m for m in f.robot_ids if m != r.id),
        leader=leader if r.id == f.leader else None,
        standby=leader if r.id == heir else None,
        route=route if len(route) > 1 else (),
        route_headings=first.headings if len(route) > 1 else (),
        route_by_hand=bool(f.waypoints),
        member_goals=(tuple((m.id, *m.goal) for m in f.robots) if r.id == f.leader else ()),
        footprint=_footprint(scenario, f, r.id),
    ) for r in f.robots}


def solo(rid: str, pose: Pose, goal: tuple[float, float], still: bool = False) -> FormationSpec:
    """A robot as a formation of one, named by its id; ``still``: one standing at its goal,
    given the goal as its route (nothing to plan)."""
    return FormationSpec(rid, rid, (RobotSpec(rid, rid, pose, goal),), (), None,
                         waypoints=(goal,) if still else ())


def team_formation(plan: TeamPlan, poses: Mapping[str, Pose], outline: Sequence[Point]
                   ) -> FormationSpec:
    """The team's formation starting at ``poses``, carrying the load of world ``outline``
    (placed in the start frame: origin at the members' centroid)."""
    n = len(plan.robots)
    cx = sum(poses[r][0] for r in plan.robots) / n
    cy = sum(poses[r][1] for r in plan.robots) / n
    robots = tuple(RobotSpec(r, plan.oid, poses[r], g) for r, g in zip(plan.robots, plan.goals,
                                                                        strict=True))
    return FormationSpec(plan.oid, plan.leader, robots,
                         tuple(Edge(i, j, df) for i, j, df in plan.edges), None,
                         load=tuple((x - cx, y - cy) for x, y in outline))


def fleet_scenario(scenario: Scenario) -> Scenario:
    """``scenario`` with every fleet robot (``scenario.lifelong``) a formation of one standing at
    its start, after the fixed formations: the lifelong warehouse at t = 0 (a fleet robot already
    in a formation of ``scenario`` stays in it). Unchanged without a fleet."""
    life = scenario.lifelong
    if life is None:
        return scenario
    starts, placed = life.fleet.starts, set(scenario.robot_ids)
    return dataclasses.replace(scenario, formations=scenario.formations + tuple(
        solo(r, starts[r], starts[r][:2]) for r in life.fleet.robot_ids if r not in placed))


def regrouped(scenario: Scenario, formation: FormationSpec, topology: str = "reduced"
              ) -> dict[str, Membership]:
    """Each member's :class:`Membership` when its robots form ``formation`` (a team, or one
    robot alone again) in the world of ``scenario``: the formations that hold any of its robots
    give way to it (the scenario of that moment), and :func:`formation_memberships` derives the
    rest as at the start."""
    mine = set(formation.robot_ids)
    others = tuple(f for f in scenario.formations if not mine & set(f.robot_ids))
    moment = dataclasses.replace(scenario, formations=others + (formation,))
    return formation_memberships(moment, formation, topology)


def build_agent_configs(
    scenario: Scenario,
    prefix: str = "warehouse",
    zenoh: ZenohSettings | None = None,
    topology: str = "reduced",
    safety: bool = True,
    base: str = "world",
    pose_period: float | None = None,
    clock_tolerance: float = CLOCK_TOLERANCE_S,
    solver: str = "exact",
) -> dict[str, AgentConfig]:
    """One :class:`AgentConfig` per robot of ``scenario``: the robot's own settings joined with
    its :class:`Membership` (:func:`memberships`). A fleet robot (``scenario.lifelong``) starts
    as a formation of one named by its id, its goal its start (:func:`fleet_scenario`), and
    carries the warehouse it serves (``lifelong``). ``pose_period`` [s] is how often the
    camera really delivers a pose (None: every ``dt``); the stale limit is
    :data:`STALE_PERIODS` of the longer of the two, so the margins hold at the camera's rate."""
    if pose_period is not None:
        limits.check(pose_period, "pose_period", limits.POSE_PERIOD)
    zenoh = zenoh or agent_zenoh()
    params = ControlParams.from_scenario(scenario, safety=safety)
    if pose_period is not None and pose_period > scenario.dt:
        # ticks come with the poses: the unicycle's sampling margin is sized for their period
        params = dataclasses.replace(params, period=pose_period)
    box = world_extent(scenario)
    extent = (box.xmin, box.ymin, box.xmax, box.ymax)
    scenario = fleet_scenario(scenario)
    fleet = set(scenario.lifelong.fleet.robot_ids) if scenario.lifelong is not None else set()
    member = memberships(scenario, topology)
    out: dict[str, AgentConfig] = {}
    for f in scenario.formations:
        for r in f.robots:
            m = member[r.id]
            out[r.id] = AgentConfig(
                robot_id=r.id,
                control=params,
                period=scenario.dt,
                radius=scenario.robot.radius,
                start=r.start,
                prefix=prefix,
                topology=topology,
                stale_after=STALE_PERIODS * max(scenario.dt, pose_period or scenario.dt),
                clock_tolerance=clock_tolerance,
                pose_period=pose_period,
                base=base,
                zenoh=zenoh,
                solver=solver,
                planner=scenario.controller.planner != "none",
                goal_tolerance=scenario.goal_tolerance,
                extent=extent,
                localisation=scenario.controller.localisation,
                lifelong=scenario.lifelong if r.id in fleet else None,
                **{name: getattr(m, name) for name in MEMBERSHIP_FIELDS},
            )
    return out


def _footprint(scenario: Scenario, f: FormationSpec, robot_id: str) -> Footprint | None:
    """A member's footprint under ``method: rigid`` (None otherwise: files stay as they were)."""
    if scenario.controller.method != "rigid":
        return None
    off = scenario.robot.control_offset
    return footprint_of([control_point(m.start[0], m.start[1], m.start[2], off) for m in f.robots],
                        [m.start[:2] for m in f.robots], [m.goal for m in f.robots],
                        f.robot_ids.index(robot_id), load_polygon(f), bool(f.load))


def config_to_dict(cfg: AgentConfig) -> dict[str, Any]:
    """Every field of ``cfg`` (``dataclasses.asdict``: the file's keys are the dataclass's
    fields, in their order), with only the Zenoh settings an agent's file holds."""
    extra = [f.name for f in dataclasses.fields(cfg.zenoh)
             if f.name not in AGENT_ZENOH_FIELDS and getattr(cfg.zenoh, f.name) is not None]
    if extra:
        raise ValueError(f"zenoh.{extra[0]}: not part of an agent configuration file")
    d = _plain(dataclasses.asdict(cfg))
    d["zenoh"] = {k: d["zenoh"][k] for k in AGENT_ZENOH_FIELDS}
    # unset optional parts (the bridge, method thesis, a fixed formation's robot, no
    # headings, a planned route) are left out: files stay as they were before the fields
    for name in ("rmw", "footprint", "lifelong", "route_headings", "route_by_hand", "mates"):
        if not d.get(name):
            d.pop(name, None)
    for name, default in (("double_integrator", False), ("max_accel", None)):
        if d["control"][name] == default:
            del d["control"][name]  # single integrators and unicycles: likewise
    if not cfg.control.bounds.declared:
        del d["control"]["bounds"]  # no bounds (all 0): likewise
    if d["solver"] == "exact":
        del d["solver"]  # the default: files stay as they were before the field existed
    d["version"] = CONFIG_VERSION
    return d


def config_from_dict(d: Any) -> AgentConfig:
    """Inverse of :func:`config_to_dict`, read from :class:`AgentConfig`'s fields and their types:
    a missing field takes the dataclass's default, unknown fields are refused, and every value
    is checked (its type here, its range where the dataclass is built); ValueError naming the
    field."""
    if not isinstance(d, dict):
        raise ValueError("agent config: must be a mapping")
    d = dict(d)
    version = d.pop("version", None)
    if version != CONFIG_VERSION:
        raise ValueError(f"version: expected {CONFIG_VERSION}, got {version!r}")
    return _record(AgentConfig, d, "")


#: Records whose files hold only some of their fields, and how to build them from those.
_PARTIAL: dict[type, tuple[tuple[str, ...], Callable[..., Any]]] = {
    ZenohSettings: (AGENT_ZENOH_FIELDS, agent_zenoh),
}


def _record(cls: type, raw: Any, where: str) -> Any:
    """The dataclass ``cls`` read from the mapping ``raw`` (``where``: its path in the file)."""
    if not isinstance(raw, dict):
        raise ValueError(f"{where}: must be a mapping, got {excerpt(raw)}")
    names, make = _PARTIAL.get(cls, (tuple(f.name for f in fields(cls)), cls))
    unknown = sorted((k for k in raw if k not in names), key=str)
    if unknown:
        raise ValueError(f"agent config: unknown field {_path(where, unknown[0])!r}")
    hints = get_type_hints(cls)
    values = {}
    for f in fields(cls):
        if f.name in raw:
            values[f.name] = _value(hints[f.name], raw[f.name], _path(where, f.name))
        elif f.name in names and f.default is MISSING and f.default_factory is MISSING:
            raise ValueError(f"agent config: missing field {_path(where, f.name)!r}")
    try:
        return make(**values)
    except ValueError as exc:
        raise ValueError(f"{where}.{exc}" if where else str(exc)) from None


def _value(tp: Any, raw: Any, where: str) -> Any:
    """``raw`` read as the type ``tp`` (a field's annotation)."""
    scalar = _SCALARS.get(tp)
    if scalar is not None:
        return scalar(raw, where)
    origin, args = get_origin(tp), get_args(tp)
    if origin is Literal:
        if raw not in args:
            raise ValueError(f"{where}: {excerpt(raw)} is not one of {args}")
        return raw
    if origin in (Union, UnionType):
        return None if raw is None and NoneType in args else _value(
            next(a for a in args if a is not NoneType), raw, where)
    if origin is tuple:
        return _tuple(args, raw, where)
    return _record(tp, raw, where)


def _tuple(args: tuple[Any, ...], raw: Any, where: str) -> tuple[Any, ...]:
    """A ``tuple[X, ...]`` or ``tuple[X, Y]`` from a list."""
    if not isinstance(raw, list | tuple):
        raise ValueError(f"{where}: must be a list, got {excerpt(raw)}")
    if len(args) == 2 and args[1] is Ellipsis:
        return tuple(_value(args[0], v, f"{where}[{k}]") for k, v in enumerate(raw))
    if len(raw) != len(args):
        raise ValueError(f"{where}: must be a list of {len(args)}, got {excerpt(raw)}")
    return tuple(_value(a, v, f"{where}[{k}]") for k, (a, v) in enumerate(zip(args, raw, strict=True)))


def _float(raw: Any, where: str) -> float:
    if isinstance(raw, bool) or not isinstance(raw, int | float):
        raise ValueError(f"{where}: must be a number, got {excerpt(raw)}")
    return float(raw)


def _str(raw: Any, where: str) -> str:
    if not isinstance(raw, str):
        raise ValueError(f"{where}: must be a string, got {excerpt(raw)}")
    return raw


def _bool(raw: Any, where: str) -> bool:
    if not isinstance(raw, bool):
        raise ValueError(f"{where}: must be true or false, got {excerpt(raw)}")
    return raw


def _int(raw: Any, where: str) -> int:
    if isinstance(raw, bool) or not isinstance(raw, int):
        raise ValueError(f"{where}: must be a whole number, got {excerpt(raw)}")
    return raw


_SCALARS: dict[Any, Callable[[Any, str], Any]] = {float: _float, str: _str, bool: _bool, int: _int}


def _path(where: str, name: str) -> str:
    return f"{where}.{name}" if where else name


def save_config(cfg: AgentConfig, path: str | Path) -> None:
    Path(path).write_text(yaml.safe_dump(config_to_dict(cfg), sort_keys=False), encoding="utf-8")


def load_config(path: str | Path) -> AgentConfig:
    try:
        data = yaml.safe_load(Path(path).read_text(encoding="utf-8"))
    except (OSError, yaml.YAMLError) as exc:
        raise ValueError(f"{path}: cannot read agent config: {exc}") from None
    try:
        return config_from_dict(data)
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from None


def _plain(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {k: _plain(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_plain(v) for v in obj]
    if isinstance(obj, float):
        return float(obj)
    return obj
