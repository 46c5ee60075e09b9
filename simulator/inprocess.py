"""In-process simulation: every robot through :meth:`agent.control.Controller.step`.

The data each robot sees is what the distributed system hands it: its neighbours' control
points and last commands (their ``state``), the obstacles, and the ellipses its leader estimates
from the members' states (:func:`geometry.ellipse.estimate`). Kinematics are integrated exactly
(single integrator, or the unicycle of eq. 6.1 when ``robot.model: unicycle``); in a lab world
(``world:``, :mod:`simulator.lab`) the robots are differential drives seen through a camera,
and with ``engine="mujoco"`` physics bodies (:mod:`simulator.physics`).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import NamedTuple

from agent import accel_limit, unicycle
from agent.barriers import Obstacle
from agent.body import Footprint, footprint_of, motion_of
from agent.control import Controller, ControlParams, Stall, StepResult
from agent.hard_rows import HardRowCounter
from agent.inputs import step_inputs, with_parked, with_waypoint
from agent.qp import STATUS_FAILED, STATUS_FALLBACK, STATUS_RELAXED, make_solver
from geometry.ellipse import Ellipse, ReferenceShape, estimate, reference_shape
from geometry.shapes import Shape
from leader.navigation import Follower, at_goal, heading_tolerance
from scenario import Scenario, formation_axes
from scenario.cargo import load_polygon
from scenario.routes import start_plan

from .fused import FleetLocalisation
from .lab import LabWorld
from .motion import motion_fields
from .physics import world_for
from .replans import Replans
from .series import ROBOT_COLUMNS, Series
from .summary import RunKind, qp_fields, run_summary
from .tick import FleetTick, Pose

__all__ = ["ROBOT_COLUMNS", "FleetModel", "Series", "SimOptions", "SimResult", "simulate"]

TOPOLOGIES = ("reduced", "all-to-all")

@dataclass(frozen=True)
class SimOptions:
    safety: bool = True
    solver: str = "exact"
    topology: str = "reduced"
    stop_at_goal: bool = True
    record: bool = True
    solve_fn: Callable | None = None  # a solve function to use instead of ``solver`` by name
    engine: str = "kinematic"  # or "mujoco": the robots are physics bodies (simulator.physics)


@dataclass
class SimResult:
    summary: dict
    series: Series
    scenario: Scenario


@dataclass(frozen=True)
class FleetModel:
    """Static per-scenario data the control step needs: reference shapes, axes, neighbours."""

    scenario: Scenario
    params: ControlParams
    shapes: dict[str, ReferenceShape]
    axes: dict[str, tuple[float, float]]
    members: dict[str, tuple[int, ...]]  # formation -> robot indices
    neighbours: tuple[tuple[tuple[int, float], ...], ...]  # per robot: (index, Df)
    formation_of: tuple[str, ...]
    partners: tuple[tuple[int, ...], ...] = ()  # per robot: the other members (separation rows)
    footprints: tuple[Footprint, ...] = ()  # per robot: its slot in its formation's body (rigid)

    @classmethod
    def build(cls, scenario: Scenario, safety: bool = True) -> FleetModel:
        ids = scenario.robot_ids
        index = {rid: k for k, rid in enumerate(ids)}
        off = scenario.robot.control_offset
        shapes, axes, members = {}, {}, {}
        for f in scenario.formations:
            pts = [unicycle.control_point(*r.start, off) for r in f.robots]
            shapes[f.name] = reference_shape(pts)
            axes[f.name] = formation_axes(scenario, f)
            members[f.name] = tuple(index[r.id] for r in f.robots)
        nbrs = tuple(
            tuple((index[j], df) for j, df in scenario.formation_of(rid).neighbours(rid))
            for rid in ids
        )
        formation_of = tuple(scenario.formation_of(rid).name for rid in ids)
        partners = tuple(tuple(j for j in members[formation_of[i]] if j != i) for i in range(len(ids)))
        footprints = tuple(
            footprint_of([unicycle.control_point(*r.start, off) for r in f.robots],
                         [r.start[:2] for r in f.robots], [r.goal for r in f.robots], k,
                         load_polygon(f), bool(f.load))
            for f in scenario.formations for k in range(len(f.robots)))
        return cls(
            scenario,
            ControlParams.from_scenario(scenario, safety=safety),
            shapes,
            axes,
            members,
            nbrs,
            formation_of,
            partners,
            footprints,
        )

    def ellipses(self, ctrl: list[tuple[float, float]], vel: list[tuple[float, float]],
                 headings: list[float]):
        """Each formation's ellipse, as its leader estimates it from its members' ``state``
        (control points, velocities and body headings)."""
        out = {}
        for name, idx in self.members.items():
            out[name] = estimate(
                self.shapes[name], self.axes[name], [ctrl[k] for k in idx], [vel[k] for k in idx],
                [headings[k] for k in idx])
        return out


def simulate(
    scenario: Scenario,
    options: SimOptions = SimOptions(),
    progress: Callable[[int, int, float], None] | None = None,
) -> SimResult:
    """Run ``scenario`` with every robot's command computed here (:class:`FleetControl`) and
    applied by the fleet's tick (:class:`simulator.tick.FleetTick`)."""
    if options.topology not in TOPOLOGIES:
        raise ValueError(f"topology: {options.topology!r} is not one of {TOPOLOGIES}")
    control = FleetControl(scenario, options)
    lab = world_for(scenario, options.engine)  # None: the ideal kinematic world
    tick = FleetTick(scenario, lab, options.stop_at_goal, progress)
    control.localisation = loc = FleetLocalisation.build(scenario, lab)  # None: camera sees all
    state: list[Pose] = [(r.start[0], r.start[1], r.start[2]) for r in scenario.robots]
    tick.start(state)
    dt = scenario.dt
    k, t = 0, 0.0
    for k in range(scenario.steps):
        t = k * dt
        # what the agents see: the truth, or in a lab world the camera's view (simulator.lab)
        seen, obs = sensed(lab, k, state, obstacles_at(scenario, t))
        if loc is not None:  # blind floor, camera faults, the agents' own estimates
            seen = loc.sense(k, state, seen)
        results, ellipses = control.commands(t, seen, obs)
        if loc is not None:
            results = loc.true_points(results, state)
        # move every robot with its own command (all computed from the same snapshot)
        before, state = state, tick.move(state, results)
        if options.record:
            record(tick, t, before, results, ellipses, obs)
            if loc is not None:
                loc.annotate(tick.series.robots)
        t = (k + 1) * dt
        if tick.check(k, t, state):
            break
    return SimResult(summarise(scenario, options, control, tick, (k + 1, t)), tick.series,
                     scenario)


def obstacles_at(scenario: Scenario, t: float) -> list[Obstacle]:
    """Every obstacle of ``scenario`` at time ``t``, as the agents' rows take it."""
    return [Obstacle(*o.position(t), *o.velocity_at(t), o.safe_distance)
            for o in scenario.obstacles]


def record(tick: FleetTick, t: float, before: Sequence[Pose], results: Sequence[StepResult],
           ellipses: dict, obs: Sequence[Obstacle]) -> None:
    """The period that began at ``t`` in ``before``: every robot's row with its QP's outcome,
    the ellipses its leader estimated (not their points) and the obstacles as seen."""
    off = tick.scenario.robot.control_offset
    # the control point of the pose computed from; in a lab world the true pose's, as the
    # multi-process world records it (not that of the pose the camera handed the agent)
    points = ([(r.px, r.py) for r in results] if tick.lab is None
              else [unicycle.control_point(s[0], s[1], s[2], off) for s in before])
    tick.record_robots(t, before, results, points,
                       [(r.status, r.slack, r.h_formation, r.h_obstacle, r.h_formations)
                        for r in results])
    for name, e in ellipses.items():
        tick.series.ellipses.append((t, name, *e[:8]))
    tick.record_obstacles(t, [(o.x, o.y) for o in obs])


def summarise(scenario: Scenario, options: SimOptions, control: FleetControl, tick: FleetTick,
              end: tuple[int, float]) -> dict:
    """summary.json of an in-process run that ended after ``end = (ticks, sim_time)``."""
    ticks, t = end
    stats = control.stats
    edges_total = sum(len(f.edges) for f in scenario.formations)
    summary = run_summary(
        scenario, RunKind("inprocess", options.safety, options.solver), ticks, t, tick.monitor,
        stats.min_h_fields(),
        stats.qp_fields(control.params),
        logical_comm(scenario, options.topology, ticks, t, edges_total),
        motion=motion_fields(tick.series.robots, ROBOT_COLUMNS, scenario) if options.record else None,
        **({} if tick.lab is None else tick.lab.summary_fields()))
    routes = control.routes
    if any(len(r) > 1 for r in routes.values()):
        summary["routes"] = {name: [list(p) for p in r] for name, r in routes.items()}
    summary.update(control.replans.summary())
    if control.localisation is not None:
        summary.update(control.localisation.summary())
    return summary


@dataclass
class QPStats:
    """What an in-process run counts about its QPs."""

    solve_us: list[float] = field(default_factory=list)
    counts: dict[str, int] = field(default_factory=lambda: {
        STATUS_RELAXED: 0, STATUS_FALLBACK: 0, STATUS_FAILED: 0, accel_limit.STATUS_ACCEL: 0})
    hard: HardRowCounter = field(default_factory=HardRowCounter)  # ticks a hard row was unmet
    min_h: dict[str, float] = field(default_factory=lambda: {
        "formation": math.inf, "obstacle": math.inf, "formations": math.inf})
    escape_ticks: int = 0  # robot-ticks whose nominal was the formation-level escape

    def add(self, res: StepResult) -> None:
        self.hard.add(res)
        self.solve_us.append(res.solve_us)
        if res.status in self.counts:
            self.counts[res.status] += 1
        self.escape_ticks += res.escape
        self.min_h["formation"] = min(self.min_h["formation"], res.h_formation)
        self.min_h["obstacle"] = min(self.min_h["obstacle"], res.h_obstacle)
        self.min_h["formations"] = min(self.min_h["formations"], res.h_formations)

    def min_h_fields(self) -> dict[str, float | None]:
        return {key: (v if math.isfinite(v) else None) for key, v in self.min_h.items()}

    def qp_fields(self, params: ControlParams) -> dict:
        counts = self.counts
        return qp_fields(len(self.solve_us), self.solve_us, counts[STATUS_RELAXED],
                         counts[STATUS_FALLBACK], counts[STATUS_FAILED], self.hard.ticks,
                         self.hard.by_reason, escape=self.escape_ticks,
                         **accel_limit.summary_fields(params.max_accel, params.double_integrator,
                                                      counts[accel_limit.STATUS_ACCEL]))


class FleetControl:
    """Every robot's agent, in process: each computes its command with
    :meth:`agent.control.Controller.step` from what the distributed system hands it."""

    def __init__(self, scenario: Scenario, options: SimOptions,
                 views: Mapping[str, tuple[Shape, ...]] | None = None) -> None:
        """``views``: the walls and shelves a formation (by name) keeps clear of instead of the
        scenario's (its start plan, its replanning and its members' rows)."""
        views = views or {}
        self.scenario = scenario
        self.solve = options.solve_fn or make_solver(options.solver)
        self.fleet = fleet = FleetModel.build(scenario, safety=options.safety)
        self.params = params = fleet.params
        self.controller = Controller(params, self.solve, time.perf_counter_ns)  # one, every robot
        self.n = n = len(scenario.robots)
        starts = {f.name: start_plan(replace(scenario, shapes=views[f.name])
                                     if f.name in views else scenario, f)
                  for f in scenario.formations}
        self.routes = {name: sp.route for name, sp in starts.items()}
        # every member walks its formation's route with the ellipse its leader hands it
        members = [(f, r) for f in scenario.formations for r in f.robots]  # robot order
        self.followers = [
            Follower(r.id, r.goal, f.goal_centroid, self.routes[f.name], starts[f.name].headings,
                     heading_tolerance(params.kp, fleet.footprints[i].rho
                                       if fleet.footprints else None))
            for i, (f, r) in enumerate(members)]
        self.replans = Replans(scenario, starts, fleet.footprints, fleet.members, views)
        self.all_to_all = options.topology == "all-to-all"
        self.vel = [(0.0, 0.0)] * n  # last certified control-point velocity (what `state` carries)
        self.stalls = [Stall()] * n  # each robot's copy of its formation's jam state
        self.stats = QPStats()
        self.localisation: FleetLocalisation | None = None  # simulator.fused, set by simulate
        # the walls and shelves each robot keeps clear of (a lifelong run's resting loads too)
        self.shapes = [views.get(name, scenario.shapes) for name in fleet.formation_of]
        # the formations whose ellipses each robot does not keep out of: a lifelong team's members
        # on their way to its slots, kept apart by separation rows instead (``fleet.partners``)
        self.allies: list[frozenset[str]] = [frozenset()] * n

    def commands(self, t: float, seen: Sequence[Sequence[float]], obs: list[Obstacle],
                 ) -> tuple[list[StepResult], dict]:
        """Every robot's command at ``t`` from the poses and obstacles it is handed (all from
        the same snapshot), and the ellipses the leaders estimated."""
        off = self.params.offset
        ctrl = [unicycle.control_point(s[0], s[1], s[2], off) for s in seen]
        ellipses = self.fleet.ellipses(ctrl, self.vel, [s[2] for s in seen])
        parked = self.parked(ellipses)  # as each leader's ellipse says, before its route step
        self.replans.tick(t, ellipses, obs, self.followers)
        headings = {name: self.replans.heading(name, e) for name, e in ellipses.items()}
        results = [self.command(i, View(seen, ctrl, ellipses, headings, obs, parked))
                   for i in range(self.n)]
        for res in results:
            self.stats.add(res)
        self.vel = [(res.ux, res.uy) for res in results]
        return results, ellipses

    def parked(self, ellipses: Mapping[str, Ellipse]) -> frozenset[str]:
        """The formations parked at their goals, as their leaders put it on their ellipses
        (:func:`leader.navigation.at_goal` on the leader's follower, the goal tolerance of its
        status)."""
        tol = self.scenario.goal_tolerance + self.scenario.robot.control_offset
        lead, followers = self.replans.leader, self.followers
        return frozenset(name for name, e in ellipses.items()
                         if name in lead and at_goal(followers[lead[name]], (e.cx, e.cy), tol))

    def command(self, i: int, view: View) -> StepResult:
        """Robot ``i``'s command. Every other member of its formation (graph neighbour or not:
        the agent subscribes to their states) gets a hard separation row; in all-to-all every
        foreign robot too."""
        fleet, vel, seen, ctrl = self.fleet, self.vel, view.seen, view.ctrl
        fname = fleet.formation_of[i]
        own = view.ellipses[fname]
        target, waypoint = self.followers[i].step(own.cx, own.cy, view.headings[fname],
                                                  motion_of(own, fleet.footprints[i].rho))
        inputs = step_inputs(
            ((ctrl[j][0], ctrl[j][1], vel[j][0], vel[j][1], df, seen[j][2])
             for j, df in fleet.neighbours[i]),
            own, fname, waypoint,
            [(name, e) for name, e in view.ellipses.items()
             if name != fname and name not in self.allies[i]],
            self.stalls[i], self.scenario.dt,
            [(ctrl[j][0], ctrl[j][1], vel[j][0], vel[j][1], seen[j][2])
             for j in range(self.n) if fleet.formation_of[j] != fname] if self.all_to_all else None,
            [(ctrl[j][0], ctrl[j][1], vel[j][0], vel[j][1], seen[j][2]) for j in fleet.partners[i]],
        )
        self.stalls[i] = inputs.stall
        inputs = with_parked(with_waypoint(inputs, self.followers[i].heading,
                                           self.followers[i].arriving), view.parked)
        pose = (seen[i][0], seen[i][1], seen[i][2])
        loc, controller = self.localisation, self.controller
        if loc is not None:  # no pose: zero, counted; fused: the margins of the estimates
            held = loc.hold(i, pose, self.params.offset)
            if held is not None:
                return held
            controller = loc.controller(i, controller, inputs.view.other_names
                                        if inputs.view is not None else ())
        return controller.step(inputs._replace(
            pose=pose, goal=target, obstacles=view.obs, last_u=vel[i], shapes=self.shapes[i],
            footprint=fleet.footprints[i]))


class View(NamedTuple):
    """What the robots are handed at one tick: poses, control points, the leaders' ellipses
    and headings, obstacles."""

    seen: Sequence[Sequence[float]]
    ctrl: list[tuple[float, float]]
    ellipses: dict
    headings: dict[str, float | None]
    obs: list[Obstacle]
    parked: frozenset[str] = frozenset()  # formations parked at their goals (FleetControl.parked)


def sensed(lab: LabWorld | None, k: int, state: Sequence[Pose], obs: list[Obstacle],
           ) -> tuple[Sequence[Sequence[float]], list[Obstacle]]:
    """The poses and obstacles the agents are handed at tick ``k``: the truth in the ideal
    world, the lab camera's view otherwise (:mod:`simulator.lab`)."""
    if lab is None:
        return state, obs
    xy = lab.obstacles(k)
    return lab.sense(k, state), [o._replace(x=p[0], y=p[1]) for o, p in zip(obs, xy, strict=True)]


def logical_comm(scenario: Scenario, topology: str, ticks: int, sim_time: float, edges: int):
    """In-process runs exchange nothing on a network: this is the message count the topology
    implies (deliveries per tick), marked ``"source": "model"``; bytes are not modelled."""
    n = len(scenario.robot_ids)
    leaders = len(scenario.formations)
    exchange = leaders * (leaders - 1)  # leaders' ellipses: both topologies (tie-break, jam rule)
    if topology == "reduced":
        # every robot hears every other member of its formation (formation and separation rows)
        per_tick = sum(len(f.robots) * (len(f.robots) - 1) for f in scenario.formations)
        per_tick += exchange + (n - leaders)
    else:
        per_tick = n * (n - 1) + exchange + (n - leaders)
    messages = per_tick * ticks
    rate = messages / n / sim_time if sim_time > 0 and n else 0.0
    return {
        "topology": topology,
        "messages": messages,
        "bytes": None,
        "messages_per_robot_per_s": rate,
        "bytes_per_robot_per_s": None,
        "source": "model",
    }
