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

from geometry.ellipse import reference_shape
from geometry.limits import BURGER_RADIUS
from geometry.unicycle import control_point
from leader.settings import LeaderSettings  # noqa: F401  (re-exported)
from scenario import Scenario, formation_axes
from scenario.cargo import load_polygon
from scenario.model import FormationSpec
from scenario.routes import initial_route
from scenario.succession import formation_successor
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
    solver: str = "exact"  # QP solver (agent.qp.make_solver): exact or a qpsolvers backend
    # the formation centroid's route (waypoints, the goal centroid last); () = the goal alone
    route: tuple[tuple[float, float], ...] = ()
    # leader only: every member's goal as the scenario gives it (the goal shape at heading 0)
    member_goals: tuple[tuple[str, float, float], ...] = ()
    planner: bool = True  # the leader plans routes around walls and shelves for new goals
    goal_tolerance: float = 0.05  # [m]
    # controller.method rigid: this member's slot in its formation's body (agent.body)
    footprint: Footprint | None = None

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
    pose_period: float | None = None,
    clock_tolerance: float = CLOCK_TOLERANCE_S,
    solver: str = "exact",
) -> dict[str, AgentConfig]:
    """One :class:`AgentConfig` per robot of ``scenario``. ``pose_period`` [s] is how often the
    camera really delivers a pose (None: every ``dt``); the stale limit is
    :data:`STALE_PERIODS` of the longer of the two, so the margins hold at the camera's rate."""
    if pose_period is not None and not (math.isfinite(pose_period) and pose_period > 0):
        raise ValueError(f"pose_period: must be a positive number, got {pose_period!r}")
    if topology not in TOPOLOGIES:
        raise ValueError(f"topology: {topology!r} is not one of {TOPOLOGIES}")
    if base not in BASES:
        raise ValueError(f"base: {base!r} is not one of {BASES}")
    zenoh = zenoh or agent_zenoh()
    params = ControlParams.from_scenario(scenario, safety=safety)
    if pose_period is not None and pose_period > scenario.dt:
        # ticks come with the poses: the unicycle's sampling margin is sized for their period
        params = dataclasses.replace(params, period=pose_period)
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
        heir = formation_successor(f)
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
                partners=tuple(m for m in f.robot_ids if m != r.id),
                leader=leader if r.id == f.leader else None,
                standby=leader if r.id == heir else None,
                stale_after=STALE_PERIODS * max(scenario.dt, pose_period or scenario.dt),
                clock_tolerance=clock_tolerance,
                pose_period=pose_period,
                base=base,
                zenoh=zenoh,
                solver=solver,
                route=route if len(route) > 1 else (),
                member_goals=(tuple((m.id, *m.goal) for m in f.robots) if r.id == f.leader
                              else ()),
                planner=scenario.controller.planner != "none",
                goal_tolerance=scenario.goal_tolerance,
                footprint=_footprint(scenario, f, r.id),
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


def _footprint_from(d: dict[str, Any] | None) -> Footprint | None:
    if d is None:
        return None
    pts = lambda seq: tuple((float(x), float(y)) for x, y in seq)  # noqa: E731
    return Footprint(pts(d["slots"]), float(d["alpha0"]), int(d["member"]),
                     float(d.get("goal_turn", 0.0)), pts(d.get("load_points", ())),
                     tuple((pts(e)[0], pts(e)[1]) for e in d.get("load_edges", ())))


def config_to_dict(cfg: AgentConfig) -> dict[str, Any]:
    extra = [f.name for f in dataclasses.fields(cfg.zenoh)
             if f.name not in AGENT_ZENOH_FIELDS and getattr(cfg.zenoh, f.name) is not None]
    if extra:
        raise ValueError(f"zenoh.{extra[0]}: not part of an agent configuration file")
    d = _plain(dataclasses.asdict(cfg))
    d["zenoh"] = {k: d["zenoh"][k] for k in AGENT_ZENOH_FIELDS}
    if d["solver"] == "exact":
        del d["solver"]  # the default: files stay as they were before the field existed
    if cfg.footprint is None:
        del d["footprint"]  # likewise (method rules or thesis)
    else:
        d["footprint"] = _plain(cfg.footprint._asdict())
    if d["control"]["method"] == "rules":
        del d["control"]["method"]
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
        zd = dict(d.pop("zenoh", {}))
        unknown = sorted(set(zd) - set(AGENT_ZENOH_FIELDS))
        if unknown:
            raise TypeError(f"zenoh: unexpected field {unknown[0]!r}")
        zenoh = agent_zenoh(**{k: tuple(v) if isinstance(v, list) else v for k, v in zd.items()})
        leader = _leader_settings(d.pop("leader", None))
        standby = _leader_settings(d.pop("standby", None))
        cfg = AgentConfig(
            robot_id=str(d.pop("robot_id")),
            formation=str(d.pop("formation")),
            leader_id=str(d.pop("leader_id")),
            goal=tuple(map(float, d.pop("goal"))),  # type: ignore[arg-type]
            formation_goal=tuple(map(float, d.pop("formation_goal"))),  # type: ignore[arg-type]
            neighbours=tuple((str(n), float(df)) for n, df in d.pop("neighbours")),
            control=control,
            period=float(d.pop("period")),
            radius=float(d.pop("radius", BURGER_RADIUS)),
            start=None if d.get("start") is None else tuple(map(float, d.pop("start"))),  # type: ignore[arg-type]
            prefix=str(d.pop("prefix", "warehouse")),
            topology=str(d.pop("topology", "reduced")),
            foreign_robots=tuple(d.pop("foreign_robots", ())),
            partners=tuple(str(m) for m in d.pop("partners", ())),
            leader=leader,
            standby=standby,
            stale_after=float(d.pop("stale_after", 0.25)),
            clock_tolerance=float(d.pop("clock_tolerance", CLOCK_TOLERANCE_S)),
            pose_period=None if d.get("pose_period") is None else float(d.pop("pose_period")),
            base=str(d.pop("base", "world")),
            zenoh=zenoh,
            cmd_vel_key=str(d.pop("cmd_vel_key", "cmd_vel")),
            frame_id=str(d.pop("frame_id", "base_link")),
            solver=str(d.pop("solver", "exact")),
            route=tuple((float(x), float(y)) for x, y in d.pop("route", ())),
            member_goals=tuple((str(m), float(x), float(y)) for m, x, y in d.pop("member_goals", ())),
            planner=bool(d.pop("planner", True)),
            goal_tolerance=float(d.pop("goal_tolerance", 0.05)),
            footprint=_footprint_from(d.pop("footprint", None)),
        )
        d.pop("start", None)
        d.pop("pose_period", None)
    except KeyError as exc:
        raise ValueError(f"agent config: missing field {exc.args[0]!r}") from None
    except TypeError as exc:
        raise ValueError(f"agent config: {exc}") from None
    if d:
        raise ValueError(f"agent config: unknown field {sorted(d)[0]!r}")
    for name, v in (("period", cfg.period), ("stale_after", cfg.stale_after),
                    ("clock_tolerance", cfg.clock_tolerance), ("pose_period", cfg.pose_period)):
        if v is not None and not (math.isfinite(v) and v > 0):
            raise ValueError(f"{name}: must be a positive number, got {v!r}")
    if cfg.topology not in TOPOLOGIES:
        raise ValueError(f"topology: {cfg.topology!r} is not one of {TOPOLOGIES}")
    if cfg.base not in BASES:
        raise ValueError(f"base: {cfg.base!r} is not one of {BASES}")
    return cfg


def _leader_settings(d: dict[str, Any] | None) -> LeaderSettings | None:
    if d is None:
        return None
    return LeaderSettings(
        members=tuple(d["members"]),
        offsets=tuple(tuple(map(float, o)) for o in d["offsets"]),  # type: ignore[misc]
        alpha0=float(d["alpha0"]),
        axes=tuple(map(float, d["axes"])),  # type: ignore[arg-type]
        other_formations=tuple(d["other_formations"]),
    )


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
