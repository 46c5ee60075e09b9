"""One control period of a fleet, as both simulators run it.

The in-process simulator (:mod:`simulator.inprocess`, ``formation sim``) computes every robot's
command itself; the world (:mod:`simulator.world`, ``formation run``) receives them from the
agents over Zenoh. What happens to the commands from there on is one :class:`FleetTick`: every
robot moves one period under its command (exact kinematics: the single integrator, the unicycle
of eq. 6.1 through :func:`agent.unicycle.integrate`, a double integrator's position and velocity
under its certified acceleration through :func:`agent.double_integrator.integrate`; or a lab's
wheels, :mod:`simulator.lab`), the period is recorded (robots.csv's rows), the state reached is
checked by the :class:`simulator.metrics.SafetyMonitor` on the true positions, progress is
reported and the stop rule is applied.

A command is anything with the fields ``ux, uy, v, omega`` (and ``ax, ay`` for a double
integrator): the agent's :class:`wire.payloads.Cmd` or the in-process
:class:`agent.control.StepResult`. ``None`` is no command: the robot stands still (a double
integrator brakes, :func:`agent.double_integrator.brake`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any, Protocol

import numpy as np

from agent import double_integrator, unicycle
from scenario import Scenario

from .lab import LabWorld
from .metrics import SafetyMonitor
from .series import Series

NAN = math.nan
Pose = tuple[float, float, float]
#: robots.csv's ``status, slack, h_formation, h_obstacle, h_formations`` of a row whose QP the
#: world does not see (the launcher fills them from the agents' traces)
NO_QP: tuple[Any, ...] = ("", NAN, NAN, NAN, NAN)


class Command(Protocol):
    """What a robot is told for one period (see the module docstring)."""

    @property
    def ux(self) -> float: ...
    @property
    def uy(self) -> float: ...
    @property
    def v(self) -> float: ...
    @property
    def omega(self) -> float: ...
    @property
    def ax(self) -> float | None: ...
    @property
    def ay(self) -> float | None: ...


def step_pose(x: float, y: float, th: float, cmd: Command | None, dt: float,
              is_unicycle: bool) -> Pose:
    """The body pose after ``dt`` under ``cmd`` (``None``: stand still)."""
    if cmd is None:
        return x, y, th
    if is_unicycle:
        return unicycle.integrate(x, y, th, cmd.v, cmd.omega, dt)
    return x + cmd.ux * dt, y + cmd.uy * dt, th


def positions(state: Sequence[Sequence[float]]) -> np.ndarray:
    """The body centres of ``state`` as the monitor takes them: an (n, 2) array."""
    return np.array([s[:2] for s in state])


class FleetTick:
    """Moves, records and checks a fleet period by period (see the module docstring).

    ``progress(k + 1, steps, t)`` is called after every period checked; the run stops once every
    robot is at its goal (``stop_at_goal``) or ``stop()`` says so."""

    def __init__(self, scenario: Scenario, lab: LabWorld | None, stop_at_goal: bool = True,
                 progress: Callable[[int, int, float], None] | None = None,
                 stop: Callable[[], bool] = lambda: False) -> None:
        self.scenario = scenario
        self.lab = lab  # None: the ideal kinematic world
        self.stop_at_goal = stop_at_goal
        self.progress = progress
        self.stop = stop
        self.monitor = SafetyMonitor(scenario)
        self.series = Series()
        self.ids = scenario.robot_ids
        self.formation_of = tuple(scenario.formation_of(rid).name for rid in self.ids)
        # double integrators: every robot's velocity and the acceleration it was last given
        self.vel: list[tuple[float, float]] = [(0.0, 0.0)] * len(self.ids)
        self.acc: list[tuple[float, float]] = list(self.vel)

    def start(self, state: Sequence[Sequence[float]]) -> None:
        """The run begins in ``state`` (every robot at rest): the monitor's first look."""
        self.vel = [(0.0, 0.0)] * len(self.ids)
        self.acc = list(self.vel)
        self.monitor.update(0.0, positions(state), self.obstacle_positions(0.0))

    def obstacle_positions(self, t: float) -> list[tuple[float, float]]:
        """Every obstacle's true position at time ``t``."""
        return [o.position(t) for o in self.scenario.obstacles]

    # --- moving ---------------------------------------------------------------------------

    def move(self, state: Sequence[Sequence[float]],
             cmds: Sequence[Command | None]) -> list[Pose]:
        """Every robot's body pose one period on under its command: exact kinematics
        (:meth:`pose_after`), or the lab's wheels (:mod:`simulator.lab`)."""
        if self.lab is None:
            return [self.pose_after(i, s, c) for i, (s, c) in enumerate(zip(state, cmds, strict=True))]
        return self.lab.move(state, [None if c is None else (c.ux, c.uy, c.v, c.omega)
                                     for c in cmds])

    def pose_after(self, i: int, s: Sequence[float], cmd: Command | None) -> Pose:
        """Robot ``i``'s body pose one period on from ``s`` under ``cmd`` (:func:`step_pose`);
        a double integrator's velocity moves on with it."""
        dt, robot = self.scenario.dt, self.scenario.robot
        if not robot.is_double_integrator:
            return step_pose(s[0], s[1], s[2], cmd, dt, robot.is_unicycle)
        vx, vy = self.vel[i]
        if cmd is not None and cmd.ax is not None and cmd.ay is not None:
            a = (cmd.ax, cmd.ay)
        else:  # a zero command (version 1) or none: brake
            a = double_integrator.brake(vx, vy, robot.max_accel or math.inf, dt)
        x, y, vx, vy = double_integrator.integrate(s[0], s[1], vx, vy, a[0], a[1], dt,
                                                   robot.max_speed)
        self.vel[i], self.acc[i] = (vx, vy), a
        return x, y, s[2]

    # --- recording ------------------------------------------------------------------------

    def record_robots(self, t: float, state: Sequence[Sequence[float]],
                      cmds: Sequence[Command | None],
                      points: Sequence[tuple[float, float]] | None = None,
                      qp: Sequence[tuple[Any, ...]] | None = None) -> None:
        """robots.csv's rows of the period that began at ``t`` in ``state`` under ``cmds``
        (after :meth:`move`: a double integrator's row holds the acceleration it was given).
        ``points``: each robot's control point (default: the true pose's); ``qp``: each
        robot's QP cells (default :data:`NO_QP`)."""
        off = self.scenario.robot.control_offset
        for i, (rid, s, c) in enumerate(zip(self.ids, state, cmds, strict=True)):
            px, py = unicycle.control_point(s[0], s[1], s[2], off) if points is None else points[i]
            ux, uy, v, w = (0.0, 0.0, 0.0, 0.0) if c is None else (c.ux, c.uy, c.v, c.omega)
            self.series.robots.append((t, rid, self.formation_of[i], s[0], s[1], s[2], px, py,
                                       ux, uy, v, w) + (NO_QP if qp is None else qp[i])
                                      + self.accel_cells(i))

    def accel_cells(self, i: int) -> tuple[float, ...]:
        """robots.csv's ``ax, ay`` (double integrators only): the acceleration robot ``i`` was
        given over the period just moved."""
        if not self.scenario.robot.is_double_integrator:
            return ()
        return self.acc[i]

    def record_obstacles(self, t: float, seen: Sequence[tuple[float, float]]) -> None:
        """obstacles.csv's rows at ``t``: every obstacle at ``seen``."""
        for o, (x, y) in zip(self.scenario.obstacles, seen, strict=True):
            self.series.obstacles.append((t, o.name, x, y, o.safe_distance))

    # --- checking -------------------------------------------------------------------------

    def check(self, k: int, t: float, state: Sequence[Sequence[float]] | None) -> bool:
        """Tick ``k`` is done: the monitor checks ``state`` at ``t`` (None: no period ended, as
        when the first slot only publishes), progress is reported; True to stop."""
        if state is not None:
            self.monitor.update(t, positions(state), self.obstacle_positions(t))
        if self.progress is not None:
            self.progress(k + 1, self.scenario.steps, t)
        return (self.stop_at_goal and self.monitor.all_reached) or self.stop()
