"""Per-robot agent configuration: only what one robot needs, derived from a scenario.

``formation deploy`` writes one of these per robot; ``formation run`` hands one to each agent
process. A robot's file names its neighbours (with Df), its goal, its formation's goal centroid,
the controller parameters and, for the leader, what the leader role needs (members, reference
shape, ellipse axes, the other formations). It holds nothing about robots it never hears from.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from leader.ellipse import reference_shape
from scenario import Scenario, formation_axes
from scenario.routes import initial_route

from .control import ControlParams
from .unicycle import control_point

CONFIG_VERSION = 1
TOPOLOGIES = ("reduced", "all-to-all")
BASES = ("world", "turtlebot3-humble", "turtlebot3-jazzy")
STALE_PERIODS = 5  # inputs older than this many control periods are stale


@dataclass(frozen=True)
class ZenohSettings:
    mode: str = "client"  # peer | client
    connect: tuple[str, ...] = ()  # e.g. ("tcp/127.0.0.1:7447",)
    listen: tuple[str, ...] = ()
    multicast_scouting: bool = False


@dataclass(frozen=True)
class LeaderSettings:
    """What the leader role needs to estimate and exchange its formation's ellipse."""

    members: tuple[str, ...]  # every member, leader included, in reference order
    offsets: tuple[tuple[float, float], ...]  # reference offsets of the members' control points
    alpha0: float  # [rad] principal-axis angle of the reference shape
    axes: tuple[float, float]  # semi-axes (a, b) [m]
    other_formations: tuple[str, ...]  # formations whose ellipses this leader subscribes to


@dataclass(frozen=True)
class AgentConfig:
    robot_id: str
    formation: str
    leader_id: str
    goal: tuple[float, float]
    formation_goal: tuple[float, float]
    neighbours: tuple[tuple[str, float], ...]  # (robot id, Df [m])
    control: ControlParams
    period: float  # [s] control period (the scenario's dt)
    radius: float = 0.105  # [m]
    start: tuple[float, float, float] | None = None  # initial pose, for simulation only
    prefix: str = "warehouse"
    topology: str = "reduced"
    foreign_robots: tuple[str, ...] = ()  # all-to-all only: robots of other formations
    leader: LeaderSettings | None = None  # set on the leader robot only
    stale_after: float = 0.25  # [s] inputs older than this are stale: command zero
    base: str = "world"  # where commands go: the simulated world or a real robot base
    zenoh: ZenohSettings = field(default_factory=ZenohSettings)
    cmd_vel_key: str = "cmd_vel"  # real bases: the zenoh-bridge-ros2dds key for /cmd_vel
    frame_id: str = "base_link"  # real bases (Jazzy TwistStamped): header frame
    # the formation centroid's route (waypoints, the goal centroid last); () = the goal alone
    route: tuple[tuple[float, float], ...] = ()
    # leader only: every member's goal as the scenario gives it (the goal shape at heading 0)
    member_goals: tuple[tuple[str, float, float], ...] = ()
    planner: bool = True  # the leader plans routes around walls and shelves for new goals
    goal_tolerance: float = 0.05  # [m]

    @property
    def is_leader(self) -> bool:
        return self.leader is not None


def build_agent_configs(
    scenario: Scenario,
    prefix: str = "warehouse",
    zenoh: ZenohSettings | None = None,
    topology: str = "reduced",
    safety: bool = True,
    base: str = "world",
) -> dict[str, AgentConfig]:
    """One :class:`AgentConfig` per robot of ``scenario``."""
    if topology not in TOPOLOGIES:
        raise ValueError(f"topology: {topology!r} is not one of {TOPOLOGIES}")
    if base not in BASES:
        raise ValueError(f"base: {base!r} is not one of {BASES}")
    zenoh = zenoh or ZenohSettings()
    params = ControlParams.from_scenario(scenario, safety=safety)
    off = scenario.robot.control_offset
    out: dict[str, AgentConfig] = {}
    for f in scenario.formations:
        route = initial_route(scenario, f)
        shape = reference_shape([control_point(*r.start, off) for r in f.robots])
        leader = LeaderSettings(
            members=f.robot_ids,
            offsets=tuple((float(x), float(y)) for x, y in shape.offsets),
            alpha0=shape.alpha0,
            axes=formation_axes(scenario, f),
            other_formations=tuple(g.name for g in scenario.formations if g.name != f.name),
        )
        foreign = tuple(r for r in scenario.robot_ids if r not in f.robot_ids)
        for r in f.robots:
            out[r.id] = AgentConfig(
                robot_id=r.id,
                formation=f.name,
                leader_id=f.leader,
                goal=r.goal,
                formation_goal=f.goal_centroid,
                neighbours=f.neighbours(r.id),
                control=params,
                period=scenario.dt,
                radius=scenario.robot.radius,
                start=r.start,
                prefix=prefix,
                topology=topology,
                foreign_robots=foreign if topology == "all-to-all" else (),
                leader=leader if r.id == f.leader else None,
                stale_after=STALE_PERIODS * scenario.dt,
                base=base,
                zenoh=zenoh,
                route=route if len(route) > 1 else (),
                member_goals=(tuple((m.id, *m.goal) for m in f.robots) if r.id == f.leader
                              else ()),
                planner=scenario.controller.planner != "none",
                goal_tolerance=scenario.goal_tolerance,
            )
    return out


def config_to_dict(cfg: AgentConfig) -> dict[str, Any]:
    d = _plain(dataclasses.asdict(cfg))
    d["version"] = CONFIG_VERSION
    return d


def config_from_dict(d: dict[str, Any]) -> AgentConfig:
    """Inverse of :func:`config_to_dict`; ValueError naming the field on bad input."""
    if not isinstance(d, dict):
        raise ValueError("agent config: must be a mapping")
    d = dict(d)
    version = d.pop("version", None)
    if version != CONFIG_VERSION:
        raise ValueError(f"version: expected {CONFIG_VERSION}, got {version!r}")
    try:
        control = ControlParams(**d.pop("control"))
        zenoh = ZenohSettings(**{k: tuple(v) if isinstance(v, list) else v
                                 for k, v in d.pop("zenoh", {}).items()})
        leader = d.pop("leader", None)
        if leader is not None:
            leader = LeaderSettings(
                members=tuple(leader["members"]),
                offsets=tuple(tuple(map(float, o)) for o in leader["offsets"]),
                alpha0=float(leader["alpha0"]),
                axes=tuple(map(float, leader["axes"])),
                other_formations=tuple(leader["other_formations"]),
            )
        cfg = AgentConfig(
            robot_id=str(d.pop("robot_id")),
            formation=str(d.pop("formation")),
            leader_id=str(d.pop("leader_id")),
            goal=tuple(map(float, d.pop("goal"))),
            formation_goal=tuple(map(float, d.pop("formation_goal"))),
            neighbours=tuple((str(n), float(df)) for n, df in d.pop("neighbours")),
            control=control,
            period=float(d.pop("period")),
            radius=float(d.pop("radius", 0.105)),
            start=None if d.get("start") is None else tuple(map(float, d.pop("start"))),
            prefix=str(d.pop("prefix", "warehouse")),
            topology=str(d.pop("topology", "reduced")),
            foreign_robots=tuple(d.pop("foreign_robots", ())),
            leader=leader,
            stale_after=float(d.pop("stale_after", 0.25)),
            base=str(d.pop("base", "world")),
            zenoh=zenoh,
            cmd_vel_key=str(d.pop("cmd_vel_key", "cmd_vel")),
            frame_id=str(d.pop("frame_id", "base_link")),
            route=tuple((float(x), float(y)) for x, y in d.pop("route", ())),
            member_goals=tuple((str(m), float(x), float(y)) for m, x, y in d.pop("member_goals", ())),
            planner=bool(d.pop("planner", True)),
            goal_tolerance=float(d.pop("goal_tolerance", 0.05)),
        )
        d.pop("start", None)
    except KeyError as exc:
        raise ValueError(f"agent config: missing field {exc.args[0]!r}") from None
    except TypeError as exc:
        raise ValueError(f"agent config: {exc}") from None
    if d:
        raise ValueError(f"agent config: unknown field {sorted(d)[0]!r}")
    for name in ("period", "stale_after"):
        v = getattr(cfg, name)
        if not (math.isfinite(v) and v > 0):
            raise ValueError(f"{name}: must be a positive number, got {v!r}")
    if cfg.topology not in TOPOLOGIES:
        raise ValueError(f"topology: {cfg.topology!r} is not one of {TOPOLOGIES}")
    if cfg.base not in BASES:
        raise ValueError(f"base: {cfg.base!r} is not one of {BASES}")
    return cfg


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
