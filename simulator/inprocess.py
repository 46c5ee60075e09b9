"""In-process simulation: every robot through :func:`agent.control.control_step`.

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
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from agent import accel_limit, double_integrator, unicycle
from agent.barriers import Obstacle
from agent.body import Footprint, footprint_of, motion_of
from agent.control import Controller, ControlParams, Stall, StepResult
from agent.hard_rows import HardRowCounter
from agent.inputs import step_inputs, with_waypoint
from agent.qp import STATUS_FAILED, STATUS_FALLBACK, STATUS_RELAXED, make_solver
from geometry.ellipse import ReferenceShape, estimate, reference_shape
from leader.navigation import Follower, heading_tolerance
from scenario import Scenario, formation_axes
from scenario.cargo import load_polygon
from scenario.routes import start_plan

from .lab import LabWorld
from .metrics import SafetyMonitor
from .motion import motion_fields
from .physics import world_for
from .replans import Replans
from .series import ROBOT_COLUMNS, Series
from .summary import qp_fields, run_summary

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


def simulate(  # noqa: C901 (13: the in-process loop; to split with the world's tick next)
    scenario: Scenario,
    options: SimOptions = SimOptions(),
    progress: Callable[[int, int, float], None] | None = None,
) -> SimResult:
    if options.topology not in TOPOLOGIES:
        raise ValueError(f"topology: {options.topology!r} is not one of {TOPOLOGIES}")
    solve = options.solve_fn or make_solver(options.solver)
    fleet = FleetModel.build(scenario, safety=options.safety)
    params = fleet.params
    controller = Controller(params, solve, time.perf_counter_ns)  # one for every robot
    robots = scenario.robots
    ids = scenario.robot_ids
    n = len(robots)
    off = params.offset
    dt = scenario.dt
    steps = scenario.steps
    starts = {f.name: start_plan(scenario, f) for f in scenario.formations}
    routes = {name: sp.route for name, sp in starts.items()}
    # every member walks its formation's route with the ellipse its leader hands it
    members = [(f, r) for f in scenario.formations for r in f.robots]  # robot order
    followers = [Follower(r.id, r.goal, f.goal_centroid, routes[f.name], starts[f.name].headings,
                          heading_tolerance(params.kp, fleet.footprints[i].rho
                                            if fleet.footprints else None))
                 for i, (f, r) in enumerate(members)]
    replans = Replans(scenario, starts, fleet.footprints, fleet.members)
    shapes = scenario.shapes
    state = [list(r.start) for r in robots]  # body x, y, theta
    vel = [(0.0, 0.0)] * n  # last certified control-point velocity (what `state` carries)
    monitor = SafetyMonitor(scenario)
    lab = world_for(scenario, options.engine)  # None: the ideal kinematic world
    series = Series()
    solve_us: list[float] = []
    counts = {STATUS_RELAXED: 0, STATUS_FALLBACK: 0, STATUS_FAILED: 0, accel_limit.STATUS_ACCEL: 0}
    hard = HardRowCounter()  # ticks on which a hard row was not met (agent.hard_rows)
    min_h = {"formation": math.inf, "obstacle": math.inf, "formations": math.inf}
    all_to_all = options.topology == "all-to-all"
    escape_ticks = 0  # robot-ticks whose nominal was the formation-level escape
    stalls = [Stall()] * n  # each robot's copy of its formation's jam state

    def obstacles_at(t: float) -> list[Obstacle]:
        return [
            Obstacle(*o.position(t), *o.velocity_at(t), o.safe_distance)
            for o in scenario.obstacles
        ]

    monitor.update(0.0, np.array([s[:2] for s in state]), [o[:2] for o in obstacles_at(0.0)])
    k = 0
    t = 0.0
    for k in range(steps):
        t = k * dt
        # what the agents see: the truth, or in a lab world the camera's view (simulator.lab)
        seen, obs = sensed(lab, k, state, obstacles_at(t))
        ctrl = [unicycle.control_point(s[0], s[1], s[2], off) for s in seen]
        ellipses = fleet.ellipses(ctrl, vel, [s[2] for s in seen])
        replans.tick(t, ellipses, obs, followers)
        headings = {name: replans.heading(name, e) for name, e in ellipses.items()}
        results = []
        for i in range(n):
            fname = fleet.formation_of[i]
            # Every other member of the formation (graph neighbour or not: the agent subscribes to
            # their states) gets a hard separation row; in all-to-all every foreign robot too.
            own = ellipses[fname]
            target, waypoint = followers[i].step(own.cx, own.cy, headings[fname],
                                                 motion_of(own, fleet.footprints[i].rho))
            inputs = step_inputs(
                ((ctrl[j][0], ctrl[j][1], vel[j][0], vel[j][1], df, seen[j][2])
                 for j, df in fleet.neighbours[i]),
                own, fname, waypoint,
                [(name, e) for name, e in ellipses.items() if name != fname],
                stalls[i], dt,
                [(ctrl[j][0], ctrl[j][1], vel[j][0], vel[j][1], seen[j][2])
                 for j in range(n) if fleet.formation_of[j] != fname] if all_to_all else None,
                [(ctrl[j][0], ctrl[j][1], vel[j][0], vel[j][1], seen[j][2]) for j in fleet.partners[i]],
            )
            stalls[i] = inputs.stall
            inputs = with_waypoint(inputs, followers[i].heading, followers[i].arriving)
            pose = (seen[i][0], seen[i][1], seen[i][2])
            res = controller.step(inputs._replace(
                pose=pose, goal=target, obstacles=obs, last_u=vel[i], shapes=shapes,
                footprint=fleet.footprints[i]))
            results.append(res)
            hard.add(res)
            solve_us.append(res.solve_us)
            if res.status in counts:
                counts[res.status] += 1
            escape_ticks += res.escape
            min_h["formation"] = min(min_h["formation"], res.h_formation)
            min_h["obstacle"] = min(min_h["obstacle"], res.h_obstacle)
            min_h["formations"] = min(min_h["formations"], res.h_formations)
            if options.record:
                x, y, th = state[i]
                # the true pose's control point, as the multi-process world records it
                px, py = (res.px, res.py) if lab is None else unicycle.control_point(x, y, th, off)
                series.robots.append((
                    t, ids[i], fname, x, y, th, px, py, res.ux, res.uy, res.v, res.omega,
                    res.status, res.slack, res.h_formation, res.h_obstacle, res.h_formations,
                ) + ((res.ax, res.ay) if params.double_integrator else ()))
        if options.record:
            for name, e in ellipses.items():
                series.ellipses.append((t, name, *e[:8]))  # not its points
            for o, spec in zip(obs, scenario.obstacles, strict=True):
                series.obstacles.append((t, spec.name, o.x, o.y, spec.safe_distance))
        # move every robot with its own command (all computed from the same snapshot)
        state = advance(lab, state, results, params.unicycle, dt,
                        (vel, params.max_speed) if params.double_integrator else None)
        vel = [(res.ux, res.uy) for res in results]
        t = (k + 1) * dt
        monitor.update(t, np.array([s[:2] for s in state]), [o[:2] for o in obstacles_at(t)])
        if progress is not None:
            progress(k + 1, steps, t)
        if options.stop_at_goal and monitor.all_reached:
            break

    edges_total = sum(len(f.edges) for f in scenario.formations)
    ticks = k + 1
    summary = run_summary(
        scenario, "inprocess", ticks, t, monitor,
        {key: (v if math.isfinite(v) else None) for key, v in min_h.items()},
        qp_fields(len(solve_us), solve_us, counts[STATUS_RELAXED], counts[STATUS_FALLBACK],
                  counts[STATUS_FAILED], hard.ticks, hard.by_reason, escape=escape_ticks,
                  **accel_limit.summary_fields(params.max_accel, params.double_integrator,
                                               counts[accel_limit.STATUS_ACCEL])),
        logical_comm(scenario, options.topology, ticks, t, edges_total),
        options.safety, options.solver,
        motion=motion_fields(series.robots, ROBOT_COLUMNS, scenario) if options.record else None,
        **({} if lab is None else lab.summary_fields()))
    if any(len(r) > 1 for r in routes.values()):
        summary["routes"] = {name: [list(p) for p in r] for name, r in routes.items()}
    summary.update(replans.summary())
    return SimResult(summary, series, scenario)


def sensed(lab: LabWorld | None, k: int, state: list[list[float]], obs: list[Obstacle],
           ) -> tuple[Sequence[Sequence[float]], list[Obstacle]]:
    """The poses and obstacles the agents are handed at tick ``k``: the truth in the ideal
    world, the lab camera's view otherwise (:mod:`simulator.lab`)."""
    if lab is None:
        return state, obs
    xy = lab.obstacles(k)
    return lab.sense(k, state), [o._replace(x=p[0], y=p[1]) for o, p in zip(obs, xy, strict=True)]


def advance(lab: LabWorld | None, state: list[list[float]], results: Sequence[StepResult],
            is_unicycle: bool, dt: float,
            accel: tuple[Sequence[tuple[float, float]], float] | None = None,
            ) -> list[list[float]]:
    """Every robot's body pose one period on under its command: exact kinematics (single
    integrator, or the unicycle of eq. 6.1) in the ideal world, the lab's wheels otherwise.
    ``accel``: double integrators, (every robot's velocity now, max_speed), moved by
    :func:`agent.double_integrator.integrate` under its certified acceleration."""
    if accel is not None:
        vel, vmax = accel
        return [[*double_integrator.integrate(s[0], s[1], v[0], v[1], r.ax, r.ay, dt, vmax)[:2], s[2]]
                for s, v, r in zip(state, vel, results, strict=True)]
    if lab is not None:
        return [list(p) for p in lab.move(state, [(r.ux, r.uy, r.v, r.omega) for r in results])]
    out = []
    for (x, y, th), res in zip(state, results, strict=True):
        if is_unicycle:
            out.append(list(unicycle.integrate(x, y, th, res.v, res.omega, dt)))
        else:
            out.append([x + res.ux * dt, y + res.uy * dt, th])
    return out


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
