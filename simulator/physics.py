"""MuJoCo as a second opinion: ``formation sim --engine mujoco``.

The kinematic world (:mod:`simulator.inprocess`, :mod:`simulator.lab`) moves each robot exactly
as its model says. Here a physics engine moves them instead, so that what the controller
promises can be checked against bodies with mass, wheels that slip and motors that saturate:

* **Robots.** Each robot is a free body of a TurtleBot3 burger: a chassis (a cylinder of the
  scenario's ``robot.radius``, 0.14 m tall, 1 kg with the wheels, the inertia of ROBOTIS's
  Gazebo model, its mass 3.2 cm behind the axle), two driven wheels (radius ``wheel_radius``,
  0.018 m wide, 28.5 g, ``track`` apart; flat ellipsoids, so each touches the floor at one
  point as a tyre does, not along a cylinder's two rims, which scrub in a turn) on hinges, and
  a frictionless caster ball behind. Each wheel has a velocity actuator
  with the XL430-W250's limits: at most 61 rev/min (6.39 rad/s) and 1.5 N m of torque; its
  gain is set so that a wheel reaches 63 % of a step in :data:`MOTOR_LAG` seconds (the gain is
  the effective inertia at the wheel over the lag). Floor friction: :data:`FLOOR_FRICTION`.
* **Commands.** An agent's command becomes the two wheel targets as in the lab world
  (:func:`simulator.lab.command_rates`: a unicycle's ``(v, omega)``, a single integrator's
  velocity through eq. 6.2, its control point ahead of the body or, driving backwards, behind
  it), held for the control period over :data:`TIMESTEP` steps.
* **Obstacles.** Walls and shelves are static boxes (a wall 2 cm thick), circles are cylinders of
  radius ``safe_distance - robot.radius`` (the ``safe_distance`` of a circle includes the
  robot's own radius), moving circles are kinematic (mocap) bodies that follow their velocity.
* **Poses** are the bodies' own, handed to the agents through the world profile's camera when
  the profile has one (:class:`simulator.lab.Camera`), as they are otherwise.
* **Contacts** between bodies (robot and robot, robot and obstacle; never the floor) are read
  from MuJoCo's contact list after every step and counted once per pair per onset:
  ``summary.json``'s ``physics.collisions``, with the first 100 in ``physics.collision_log``.

``mujoco`` is the optional extra ``formation-cbf[physics]``; it is imported when a physics world
is built, never by anything on the robot side.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from typing import Any

from scenario import Scenario
from scenario.world import PROFILES, TURTLEBOT3_LAB

from .lab import Command, LabWorld, Pose3, command_rates, wheel_targets
from .odometry import wheel_increment
from .summary import COLLISION_LOG_MAX

ENGINES = ("kinematic", "mujoco")
TIMESTEP = 0.002  # [s] MuJoCo's integration step
FLOOR_FRICTION = 1.0  # sliding friction of the wheels' rubber on the floor
MOTOR_LAG = PROFILES[TURTLEBOT3_LAB].motor_lag  # [s] a wheel's time constant (the lab's)
XL430_SPEED = 61.0 * 2.0 * math.pi / 60.0  # [rad/s] no-load speed at 12 V
XL430_TORQUE = 1.5  # [N m] stall torque at 12 V
ROBOT_MASS = 1.0  # [kg] TurtleBot3 burger with SBC, battery and sensors
WHEEL_MASS = 0.0285  # [kg]
WHEEL_WIDTH = 0.018  # [m]
CHASSIS_INERTIA = (2.2124416e-03, 2.1193702e-03, 2.0064271e-03)  # [kg m^2] Gazebo model's base
CHASSIS_HEIGHT = 0.14  # [m]
CHASSIS_COM_X = -0.032  # [m] the mass sits behind the axle, over the caster (Gazebo model)
CASTER_X = -0.081  # [m] behind the axle
CASTER_RADIUS = 0.01  # [m]
WALL_HALF_THICKNESS = 0.01  # [m]
OBSTACLE_HALF_HEIGHT = 0.15  # [m]
MIN_OBSTACLE_RADIUS = 0.01  # [m] a circle whose safe distance leaves less is this thin post


def available() -> bool:
    """True when the physics extra is installed."""
    try:
        import mujoco  # noqa: F401  (the optional extra, imported only to see it is there)
    except ImportError:
        return False
    return True


def wheel_gain(radius: float, track: float, lag: float = MOTOR_LAG) -> float:
    """The velocity actuator's gain [N m s/rad] for a first-order lag ``lag`` in straight
    motion: each wheel carries its own inertia and half the robot's mass at its rim."""
    wheel = 0.5 * WHEEL_MASS * radius**2
    return (wheel + 0.5 * ROBOT_MASS * radius**2) / lag


def _robot_xml(k: int, pose: Sequence[float], radius: float, wheel_r: float, track: float) -> str:
    x, y, th = pose
    chassis = ROBOT_MASS - 2.0 * WHEEL_MASS
    ix, iy, iz = CHASSIS_INERTIA
    half_h = 0.5 * CHASSIS_HEIGHT
    wheels = "".join(
        f'<body name="r{k}_{side}" pos="0 {sign * 0.5 * track} {wheel_r}">'
        f'<joint name="r{k}_{side}" type="hinge" axis="0 1 0"/>'
        f'<geom type="ellipsoid" size="{wheel_r} {wheel_r} {0.5 * WHEEL_WIDTH}" '
        f'euler="{0.5 * math.pi} 0 0" '
        f'mass="{WHEEL_MASS}" friction="{FLOOR_FRICTION} 0.005 0.0001"/></body>'
        for side, sign in (("left", 1.0), ("right", -1.0)))
    return (
        f'<body name="r{k}" pos="{x} {y} 0.0005" euler="0 0 {th}">'
        f'<freejoint/>'
        f'<inertial pos="{CHASSIS_COM_X} 0 {0.02 + half_h}" mass="{chassis}" '
        f'diaginertia="{ix} {iy} {iz}"/>'
        f'<geom name="r{k}_body" type="cylinder" size="{radius} {half_h}" '
        f'pos="0 0 {0.02 + half_h}" mass="0"/>'
        f'<geom name="r{k}_caster" type="sphere" size="{CASTER_RADIUS}" '
        f'pos="{CASTER_X} 0 {CASTER_RADIUS}" mass="0" condim="1" priority="1" friction="0 0 0"/>'
        f'{wheels}</body>'
    )


def _shape_xml(s: Any) -> str:
    half_y = max(s.hy, WALL_HALF_THICKNESS)
    return (f'<geom name="o_{s.name}" type="box" size="{s.hx} {half_y} {OBSTACLE_HALF_HEIGHT}" '
            f'pos="{s.cx} {s.cy} {OBSTACLE_HALF_HEIGHT}" euler="0 0 {s.yaw}" '
            f'rgba=".6 .5 .3 1"/>')


def _circle_xml(o: Any, radius: float) -> str:
    size = max(o.safe_distance - radius, MIN_OBSTACLE_RADIUS)
    geom = (f'<geom name="o_{o.name}" type="cylinder" size="{size} {OBSTACLE_HALF_HEIGHT}" '
            f'rgba=".8 .3 .3 1"/>')
    x, y = o.center
    if o.velocity == (0.0, 0.0):
        return f'<body name="o_{o.name}" pos="{x} {y} {OBSTACLE_HALF_HEIGHT}">{geom}</body>'
    return (f'<body name="o_{o.name}" mocap="true" pos="{x} {y} {OBSTACLE_HALF_HEIGHT}">'
            f'{geom}</body>')


def scene_xml(scenario: Scenario) -> str:
    """The MJCF model of ``scenario``'s floor, robots and obstacles."""
    spec = PROFILES[TURTLEBOT3_LAB]
    r, track, radius = spec.wheel_radius, spec.track, scenario.robot.radius
    kv = wheel_gain(r, track)
    robots = "".join(_robot_xml(k, rs.start, radius, r, track)
                     for k, rs in enumerate(scenario.robots))
    obstacles = "".join(_circle_xml(o, radius) for o in scenario.obstacles)
    shapes = "".join(_shape_xml(s) for s in scenario.shapes)
    actuators = "".join(
        f'<velocity name="r{k}_{side}" joint="r{k}_{side}" kv="{kv}" ctrlrange="'
        f'{-XL430_SPEED} {XL430_SPEED}" forcerange="{-XL430_TORQUE} {XL430_TORQUE}"/>'
        for k in range(len(scenario.robots)) for side in ("left", "right"))
    return (
        f'<mujoco model="{scenario.name}"><compiler angle="radian"/>'
        f'<option timestep="{TIMESTEP}"/>'
        f'<worldbody><geom name="floor" type="plane" size="0 0 1" '
        f'friction="{FLOOR_FRICTION} 0.005 0.0001"/>{shapes}{obstacles}{robots}</worldbody>'
        f'<actuator>{actuators}</actuator></mujoco>'
    )


def _yaw(q: Sequence[float]) -> float:
    w, x, y, z = q
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


class MujocoWorld(LabWorld):
    """The robots of ``scenario`` as MuJoCo bodies, sensed through its world profile's camera;
    the same interface as :class:`simulator.lab.LabWorld` (``move``, ``sense``,
    ``obstacles``)."""

    def __init__(self, scenario: Scenario) -> None:
        import mujoco  # the optional physics extra: imported only when a physics world is built

        super().__init__(scenario)
        self._mj = mujoco
        self.model = mujoco.MjModel.from_xml_string(scene_xml(scenario))
        self.data = mujoco.MjData(self.model)
        self.scenario = scenario
        n = len(scenario.robots)
        body = self.model.body
        self._bodies = [body(f"r{k}").id for k in range(n)]
        self._mocap = [(o, int(self.model.body_mocapid[body(f"o_{o.name}").id]))
                       for o in scenario.obstacles if o.velocity != (0.0, 0.0)]
        self._thing = self._geom_owners(scenario)
        self.substeps = max(1, round(scenario.dt / TIMESTEP))
        self.time = 0.0
        self._theta = [r.start[2] for r in scenario.robots]
        self._backwards = [False] * n  # a single integrator's firmware (command_rates)
        self._touching: set[tuple[str, str]] = set()
        adr, joint = self.model.jnt_qposadr, self.model.joint
        self._wheels = [(int(adr[joint(f"r{k}_left").id]), int(adr[joint(f"r{k}_right").id]))
                        for k in range(n)]
        self._angles = self.wheel_angles()
        self.collisions = 0
        self.collision_log: list[dict[str, Any]] = []
        self.step_wall = 0.0  # [s] spent in mj_step
        mujoco.mj_forward(self.model, self.data)

    def _geom_owners(self, scenario: Scenario) -> dict[int, str]:
        """geom id -> the robot or obstacle it belongs to (the floor belongs to nothing)."""
        owners: dict[int, str] = {}
        ids = scenario.robot_ids
        for g in range(self.model.ngeom):
            root = int(self.model.body_rootid[self.model.geom_bodyid[g]])
            name = self.model.geom(g).name
            if root in self._bodies:
                owners[g] = ids[self._bodies.index(root)]
            elif name.startswith("o_"):
                owners[g] = name[2:]
        return owners

    def move(self, state: Sequence[Sequence[float]],
             cmds: Sequence[Command | None]) -> list[Pose3]:
        """Set every robot's wheel targets from its command, step the physics one control
        period, and return the bodies' poses (``state`` is the physics' own already)."""
        spec = PROFILES[TURTLEBOT3_LAB]
        ctrl = self.data.ctrl
        for k, (s, c) in enumerate(zip(state, cmds, strict=True)):
            v, omega, self._backwards[k] = command_rates(c, s[2], self.unicycle, self.lookahead,
                                                         self._backwards[k])
            left, right = wheel_targets(v, omega, spec.track)
            ctrl[2 * k] = left / spec.wheel_radius
            ctrl[2 * k + 1] = right / spec.wheel_radius
        for _ in range(self.substeps):
            self.time += TIMESTEP
            for o, m in self._mocap:
                x, y = o.position(self.time)
                self.data.mocap_pos[m] = (x, y, OBSTACLE_HALF_HEIGHT)
            t0 = time.perf_counter()
            self._mj.mj_step(self.model, self.data)
            self.step_wall += time.perf_counter() - t0
            self._count_contacts()
        return self.poses()

    def wheel_angles(self) -> list[tuple[float, float]]:
        """Every robot's (left, right) wheel angle [rad] (forward is positive)."""
        q = self.data.qpos
        return [(float(q[a]), float(q[b])) for a, b in self._wheels]

    def wheel_increments(self) -> list[tuple[float, float, float]]:
        """Every robot's motion since the last call as its wheels measured it (their turns on
        the floor, slip included: :func:`simulator.odometry.wheel_increment`)."""
        now = self.wheel_angles()
        r, track = PROFILES[TURTLEBOT3_LAB].wheel_radius, PROFILES[TURTLEBOT3_LAB].track
        out = [wheel_increment(r * (a[0] - b[0]), r * (a[1] - b[1]), track)
               for a, b in zip(now, self._angles, strict=True)]
        self._angles = now
        return out

    def poses(self) -> list[Pose3]:
        """The robots' body poses; headings continue the previous ones (no jump at +-pi)."""
        out = []
        for k, b in enumerate(self._bodies):
            x, y, _z = self.data.xpos[b]
            yaw = _yaw(self.data.xquat[b])
            prev = self._theta[k]
            th = prev + math.atan2(math.sin(yaw - prev), math.cos(yaw - prev))
            self._theta[k] = th
            out.append((float(x), float(y), th))
        return out

    def _count_contacts(self) -> None:
        """Count each pair of bodies that touches now and did not at the step before."""
        now: set[tuple[str, str]] = set()
        contact = self.data.contact
        for c in range(self.data.ncon):
            a = self._thing.get(int(contact.geom1[c]))
            b = self._thing.get(int(contact.geom2[c]))
            if a is None or b is None or a == b:
                continue
            pair = (a, b) if a < b else (b, a)
            now.add(pair)
            if pair not in self._touching:
                self.collisions += 1
                if len(self.collision_log) < COLLISION_LOG_MAX:
                    self.collision_log.append({"t": round(self.time, 4), "a": pair[0],
                                               "b": pair[1], "depth_m": float(-contact.dist[c])})
        self._touching = now

    def summary_fields(self) -> dict[str, Any]:
        return {"physics": {
            "engine": "mujoco",
            "mujoco": self._mj.__version__,
            "timestep_s": TIMESTEP,
            "collisions": self.collisions,
            "collision_log": self.collision_log,
            "step_wall_s": round(self.step_wall, 4),
            "real_time_factor": round(self.time / self.step_wall, 2) if self.step_wall else None,
        }}


def world_for(scenario: Scenario, engine: str = "kinematic") -> LabWorld | None:
    """The world that moves ``scenario``'s robots: None for the ideal kinematic world (the
    exact kinematics), a :class:`LabWorld` for a lab profile, a :class:`MujocoWorld` for
    ``engine="mujoco"`` (any profile: its camera, if it has one). Double integrators move in
    the ideal kinematic world only (ValueError otherwise)."""
    if scenario.robot.is_double_integrator and (engine != "kinematic" or not scenario.world.ideal):
        raise ValueError("robot.model: double_integrator runs in the ideal kinematic world only "
                         f"(not with world profile {scenario.world.profile!r}, engine {engine!r})")
    if engine == "mujoco":
        return MujocoWorld(scenario)
    if engine != "kinematic":
        raise ValueError(f"engine: {engine!r} is not one of {ENGINES}")
    return LabWorld.build(scenario)
