"""Typed, frozen view of a scenario file (the contract in docs/scenarios.md).

Every number here is already validated by :mod:`scenario.load`; code that receives a
:class:`Scenario` may rely on it: finite values, known robot names, rigid graphs, a leader
adjacent to every member and a start that satisfies every constraint.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from dataclasses import dataclass

from geometry.limits import BURGER_MAX_SPEED, BURGER_MAX_TURN_RATE, BURGER_RADIUS
from geometry.shapes import Shape

from . import limits
from .lifelong import Lifelong
from .reader import ScenarioError
from .world import WorldSpec, with_profile

SINGLE_INTEGRATOR = "single_integrator"
UNICYCLE = "unicycle"
DOUBLE_INTEGRATOR = "double_integrator"  # state position and velocity, input acceleration
MODELS = (SINGLE_INTEGRATOR, UNICYCLE, DOUBLE_INTEGRATOR)
# controller.method: "rigid" (the formation's rigid motion: agent.body; the default), "thesis"
# (eq. 4.2 and the thesis's rows only, for comparison)
METHODS = ("rigid", "thesis")


@dataclass(frozen=True)
class RobotModel:
    model: str = SINGLE_INTEGRATOR
    max_speed: float = BURGER_MAX_SPEED  # [m/s]
    max_turn_rate: float = BURGER_MAX_TURN_RATE  # [rad/s], unicycle only
    lookahead: float = 0.05  # [m], l of chapter 6.2, unicycle only
    radius: float = BURGER_RADIUS  # [m] body radius, for collision checks
    # [m/s^2] acceleration limit: needed by double_integrator (agent.double_integrator); None: none
    max_accel: float | None = None

    @property
    def is_unicycle(self) -> bool:
        return self.model == UNICYCLE

    @property
    def is_double_integrator(self) -> bool:
        return self.model == DOUBLE_INTEGRATOR

    @property
    def control_offset(self) -> float:
        """Distance from the body centre to the point the barriers hold for [m]."""
        return self.lookahead if self.is_unicycle else 0.0


@dataclass(frozen=True)
class Gammas:
    """Class-K gains per barrier kind (eq. 4.8-4.11 use one gamma; the scenario may split it)."""

    formation: float = 1.0
    obstacle: float = 1.0
    formations: float = 1.0


@dataclass(frozen=True)
class Bounds:
    """``controller.bounds``: what a robot's controller assumes of its own sensing and motors,
    each a bound it keeps margins for (:mod:`agent.margins`); all 0 (the default): a perfect
    robot, the controller as it always was. The agent never reads the world's profile: these
    are the robot's declared numbers, right or wrong. Checked against
    :data:`scenario.limits.BOUNDS` (ValueError naming the field)."""

    pose_noise: float = 0.0  # [m] standard deviation of each measured position coordinate
    heading_noise: float = 0.0  # [rad] standard deviation of the measured heading
    latency: float = 0.0  # [s] the most a pose can be old when the robot acts on it
    motor_lag: float = 0.0  # [s] first-order time constant from command to wheel speed

    def __post_init__(self) -> None:
        for name, allowed in limits.BOUNDS.items():
            limits.check(getattr(self, name), name, allowed)

    @property
    def declared(self) -> bool:
        """True when any bound is above 0 (the controller keeps margins)."""
        return any(getattr(self, name) > 0.0 for name in limits.BOUNDS)


@dataclass(frozen=True)
class ControllerSpec:
    kp: float = 2.0  # eq. 4.2
    gamma: Gammas = Gammas()
    epsilon: float = 0.05  # [m] formation distance tolerance, eq. 3.3
    tiebreak: str = "keep_right"  # formation-level deadlock rule, or "none"
    d_af: float | None = None  # [m] pairwise distance of eq. 3.5 (all-to-all topology only)
    planner: str = "visibility"  # route around walls and boxes, or "none"
    method: str = "rigid"  # how nominal commands are made: one of METHODS (agent.control)
    bounds: Bounds = Bounds()  # the sensing and motor bounds the controller keeps margins for


@dataclass(frozen=True)
class RobotSpec:
    id: str
    formation: str
    start: tuple[float, float, float]  # x, y [m], theta [rad]
    goal: tuple[float, float]  # [m]


@dataclass(frozen=True)
class Edge:
    i: str
    j: str
    df: float  # [m] desired distance Df_ij


@dataclass(frozen=True)
class FormationSpec:
    name: str
    leader: str
    robots: tuple[RobotSpec, ...]
    edges: tuple[Edge, ...]
    ellipse: tuple[float, float] | None  # semi-axes (a, b) [m] as written, or None
    waypoints: tuple[tuple[float, float], ...] = ()  # [m] the centroid passes these in order
    # [m] the load it carries as declared: a convex polygon, counter-clockwise, in the start
    # frame (origin at the centroid of the members' start body positions, the scenario's axes);
    # empty: the convex hull of the members' body centres (scenario.cargo)
    load: tuple[tuple[float, float], ...] = ()
    # [rad] a heading per waypoint (the goal shape's turn there; None: any), or () for none
    waypoint_headings: tuple[float | None, ...] = ()

    @property
    def robot_ids(self) -> tuple[str, ...]:
        return tuple(r.id for r in self.robots)

    def neighbours(self, robot_id: str) -> tuple[tuple[str, float], ...]:
        """(neighbour id, Df) for every edge at ``robot_id``, in file order."""
        out = []
        for e in self.edges:
            if e.i == robot_id:
                out.append((e.j, e.df))
            elif e.j == robot_id:
                out.append((e.i, e.df))
        return tuple(out)

    @property
    def goal_centroid(self) -> tuple[float, float]:
        n = len(self.robots)
        return (sum(r.goal[0] for r in self.robots) / n, sum(r.goal[1] for r in self.robots) / n)

    @property
    def start_centroid(self) -> tuple[float, float]:
        n = len(self.robots)
        return (
            sum(r.start[0] for r in self.robots) / n,
            sum(r.start[1] for r in self.robots) / n,
        )


@dataclass(frozen=True)
class ObstacleSpec:
    name: str
    center: tuple[float, float]  # [m] at t = 0
    safe_distance: float  # [m] Ds of eq. 3.4, measured from the robot's centre
    velocity: tuple[float, float] = (0.0, 0.0)  # [m/s], constant
    stop_at: float | None = None  # [s] a moving circle stops here for good (a forklift parks)

    def position(self, t: float) -> tuple[float, float]:
        if self.stop_at is not None:
            t = min(t, self.stop_at)
        return (self.center[0] + self.velocity[0] * t, self.center[1] + self.velocity[1] * t)

    def velocity_at(self, t: float) -> tuple[float, float]:
        """[m/s] its velocity at ``t``: zero once it has stopped."""
        return (0.0, 0.0) if self.stop_at is not None and t >= self.stop_at else self.velocity


@dataclass(frozen=True)
class Scenario:
    name: str
    dt: float  # [s] control period
    duration: float  # [s] simulated time limit
    goal_tolerance: float  # [m]
    robot: RobotModel
    controller: ControllerSpec
    formations: tuple[FormationSpec, ...]
    obstacles: tuple[ObstacleSpec, ...]
    shapes: tuple[Shape, ...] = ()  # static walls (segments) and shelves (boxes)
    world: WorldSpec = WorldSpec()  # the simulated robots and camera (scenario.world)
    # the fleet, stations, loads and orders (scenario.lifelong); None: a file without them
    lifelong: Lifelong | None = None

    # Derived once per instance (the fields are frozen; dataclasses.replace makes a new one):
    # lookups by robot id are dict lookups, not scans of every robot.
    @functools.cached_property
    def robots(self) -> tuple[RobotSpec, ...]:
        return tuple(r for f in self.formations for r in f.robots)

    @functools.cached_property
    def robot_ids(self) -> tuple[str, ...]:
        return tuple(r.id for r in self.robots)

    @functools.cached_property
    def _by_id(self) -> dict[str, tuple[RobotSpec, FormationSpec]]:
        return {r.id: (r, f) for f in self.formations for r in f.robots}

    def formation_of(self, robot_id: str) -> FormationSpec:
        return self._by_id[robot_id][1]

    def robot_spec(self, robot_id: str) -> RobotSpec:
        return self._by_id[robot_id][0]

    @property
    def steps(self) -> int:
        return int(math.ceil(self.duration / self.dt - 1e-9))


def with_world(scenario: Scenario, name: str | None) -> Scenario:
    """``scenario`` in the world ``--world NAME`` chose (None: as its file says)."""
    if name is None:
        return scenario
    out = dataclasses.replace(scenario, world=with_profile(scenario.world, name))
    check_model_world(out.robot, out.world)
    return out


def model_world_warning(robot: RobotModel, world: WorldSpec, engine: str = "kinematic"
                        ) -> str | None:
    """A single integrator on differential drives (a world profile other than ideal, or the
    MuJoCo engine), said in one line, or None. Each body centre then moves only along its
    heading (eq. 6.2), which the single integrator's rows do not know: on a sharp turn or a
    reversal a member lags its slot and bodies can meet (docs/physics.md: the warehouse at 3.15
    epsilon in MuJoCo, 2.47 in the lab world, against 0.92 and 1.10 as unicycles)."""
    if robot.model != SINGLE_INTEGRATOR or (world.ideal and engine == "kinematic"):
        return None
    where = f"world profile {world.profile!r}" if not world.ideal else f"the {engine} engine"
    return (f"robot.model: single_integrator on the differential drives of {where}: a body "
            f"centre moves only along its heading (eq. 6.2), which its rows do not know, so on "
            f"a turn or a reversal bodies can meet; model: unicycle steers each look-ahead "
            f"point (docs/physics.md)")


def check_model_world(robot: RobotModel, world: WorldSpec) -> None:
    """Double integrators move in the ideal world only (ScenarioError otherwise)."""
    if robot.is_double_integrator and not world.ideal:
        raise ScenarioError(f"robot.model: double_integrator runs in the ideal world only, not "
                            f"in world profile {world.profile!r}")
