"""A lab's imperfections: the world of a :class:`scenario.world.WorldSpec` other than ``ideal``.

Both simulators (:mod:`simulator.inprocess` for ``formation sim``, :mod:`simulator.world` for
``formation run``) hand their robots' true poses and the agents' commands to one
:class:`LabWorld`, so the two see the same world number for number, and a lock-step run writes
the same robots.csv as ``sim`` under any profile. The ideal world never reaches this module.

**Actuators.** Every robot is a differential drive. A unicycle agent's command ``(v, omega)``
goes to the wheels as it is; a single-integrator agent's velocity ``u`` (of its position, the
body centre) goes through eq. 6.2's look-ahead map (:func:`agent.unicycle.to_unicycle`, with
``robot.lookahead`` and the robot's heading), as the robot's own firmware would turn it into
wheel speeds; asked to move well behind its heading, the firmware backs up, its control point
``lookahead`` behind the body (:func:`command_rates`). Each wheel's target rim speed
``v -+ omega track / 2`` is clipped to ``max_wheel_speed`` (the motor saturates), the wheel
approaches it with a first-order lag of time constant ``motor_lag`` and never faster than
``max_wheel_accel``; the body integrates the unicycle (eq. 6.1) from the two wheel speeds,
SUBSTEPS times per control period. A robot that gets no command is told to stop: its wheels ramp
down the same way.

**Sensing.** An overhead camera takes frame ``f`` at ``f / camera_fps`` (every tick when the
rate is ``inf``) and publishes it ``camera_latency`` later; a frame is lost with probability
``drop_rate``. What a robot's agent is handed at time ``t`` is its pose in the newest frame
published by then and not lost, with Gaussian noise (``pose_noise`` on each coordinate,
``heading_noise`` on the heading); moving obstacles are seen in the same frame with the same
position noise (static ones are the map). The true pose at a frame's capture time is
interpolated linearly between the two ticks around it; before the run the robots stood at their
starts. The message still carries the tick's stamp (what a camera driver that stamps on
publication sends): the agent cannot tell how old its pose is. Noise and losses are drawn from
``numpy`` generators seeded by ``(seed, frame)``, so they depend on nothing but the frame's
number: the same in every process and in every order of asking.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from agent.unicycle import integrate, to_unicycle
from scenario import Scenario
from scenario.world import WorldSpec

SUBSTEPS = 10  # integration steps of the wheels and the body per control period
FRAME_OFFSET = 2**40  # frame numbers (negative before the run) shifted to seed a generator
MAX_LOST_FRAMES = 1000  # frames searched back for one that was not lost
_FRAME_CACHE = 64  # frames whose draws are kept

Pose3 = tuple[float, float, float]
Command = tuple[float, float, float, float]  # ux, uy, v, omega as the agent sent them


def wheel_targets(v: float, omega: float, track: float) -> tuple[float, float]:
    """The rim speeds (left, right) of a differential drive moving at ``(v, omega)``."""
    half = 0.5 * omega * track
    return (v - half, v + half)


def body_rates(left: float, right: float, track: float) -> tuple[float, float]:
    """``(v, omega)`` of a differential drive whose wheels' rims move at ``left``, ``right``."""
    return (0.5 * (left + right), (right - left) / track)


def wheel_step(w: float, target: float, spec: WorldSpec, h: float) -> float:
    """One wheel's rim speed after ``h`` seconds: the target clipped to ``max_wheel_speed``,
    approached with the first-order lag ``motor_lag`` (exact over ``h``), the change bounded
    by ``max_wheel_accel * h``."""
    cap = spec.max_wheel_speed
    target = max(-cap, min(cap, target))
    want = target if spec.motor_lag <= 0 else target + (w - target) * math.exp(-h / spec.motor_lag)
    most = spec.max_wheel_accel * h
    return w + max(-most, min(most, want - w))


def drive(pose: Pose3, wheels: tuple[float, float], rates: tuple[float, float], spec: WorldSpec,
          dt: float, substeps: int = SUBSTEPS) -> tuple[Pose3, tuple[float, float]]:
    """The body pose and wheel speeds after ``dt`` with the command ``rates = (v, omega)``."""
    tl, tr = wheel_targets(rates[0], rates[1], spec.track)
    h = dt / substeps
    x, y, th = pose
    left, right = wheels
    for _ in range(substeps):
        left = wheel_step(left, tl, spec, h)
        right = wheel_step(right, tr, spec, h)
        v, omega = body_rates(left, right, spec.track)
        x, y, th = integrate(x, y, th, v, omega, h)
    return (x, y, th), (left, right)


# A single integrator's firmware takes the shorter turn: it drives backwards (its control point
# l BEHIND the body) once the asked velocity lies more than REVERSE_ENTER from its heading, and
# forwards again once it lies within REVERSE_LEAVE. The narrow hysteresis keeps a velocity
# across the heading from switching it every tick; either way the robot then turns away from
# 90 degrees. Of the pairs 120/60, 95/85, 120/85 and 135/90 degrees, tried on single-integrator
# runs (the warehouse in MuJoCo with either camera, in the lab world with and without bounds,
# and the thesis's files in the lab), 95/85 leaves the fewest formation errors over 1.5 eps.
# The choice is each robot's own, so members can still choose apart.
REVERSE_ENTER = math.radians(95.0)
REVERSE_LEAVE = math.radians(85.0)


def command_rates(cmd: Command | None, theta: float, unicycle: bool, lookahead: float,
                  backwards: bool = False) -> tuple[float, float, bool]:
    """The ``(v, omega)`` a command asks of a differential drive, and whether it now drives
    backwards: a unicycle's own; a single integrator's through eq. 6.2 with the control point
    ``lookahead`` ahead of the body, or behind it while it drives ``backwards`` (see
    REVERSE_ENTER); none (no command): stop.

    Under eq. 6.2 alone a point ahead that is asked to move backwards swings the body round it
    (the robot turns round in place, its body moving 2 l), unless the velocity lies exactly
    along the heading: of a formation reversing, members turned round and members backing up
    held their bodies up to 2 l off the shape (warehouse-lab-bounds, 3.1 epsilon)."""
    if cmd is None:
        return (0.0, 0.0, backwards)
    ux, uy, v, omega = cmd
    if unicycle:
        return (v, omega, False)
    speed = math.hypot(ux, uy)
    if speed > 1e-9:
        along = (math.cos(theta) * ux + math.sin(theta) * uy) / speed
        if not backwards and along < math.cos(REVERSE_ENTER):
            backwards = True
        elif backwards and along > math.cos(REVERSE_LEAVE):
            backwards = False
    v, omega = to_unicycle(ux, uy, theta, -lookahead if backwards else lookahead)
    return (v, omega, backwards)


def _lerp_pose(a: Sequence[float], b: Sequence[float], s: float) -> Pose3:
    dth = math.atan2(math.sin(b[2] - a[2]), math.cos(b[2] - a[2]))
    return (a[0] + s * (b[0] - a[0]), a[1] + s * (b[1] - a[1]), a[2] + s * dth)


@dataclass(frozen=True)
class Frame:
    """A camera frame's draws: lost or not, the robots' and the moving obstacles' noise."""

    lost: bool
    robots: np.ndarray  # (n, 3): dx, dy, dtheta
    obstacles: np.ndarray  # (m, 2): dx, dy


class Camera:
    """The overhead camera of a lab world (see the module docstring)."""

    def __init__(self, spec: WorldSpec, dt: float, starts: Sequence[Pose3],
                 obstacles: Sequence) -> None:
        self.spec = spec
        self.dt = dt
        self.period = 1.0 / spec.camera_fps if math.isfinite(spec.camera_fps) else dt
        self.obstacles = tuple(obstacles)
        self.moving = tuple(k for k, o in enumerate(self.obstacles) if o.velocity != (0.0, 0.0))
        self.start = [tuple(s) for s in starts]
        window = (spec.camera_latency + 64 * self.period) / dt + 4
        self.history: deque[list[Pose3]] = deque(maxlen=int(min(window, 1e6)))
        self.first_tick = 0  # the tick of history[0]
        self._frames: dict[int, Frame] = {}

    def frame(self, f: int) -> Frame:
        """Frame ``f``'s draws (from a generator seeded by the seed and ``f``, nothing else)."""
        got = self._frames.get(f)
        if got is None:
            rng = np.random.default_rng((self.spec.seed, f + FRAME_OFFSET))
            lost = bool(rng.random() < self.spec.drop_rate)
            n, m = len(self.start), len(self.moving)
            robots = rng.standard_normal((n, 3)) * (self.spec.pose_noise, self.spec.pose_noise,
                                                    self.spec.heading_noise)
            obstacles = rng.standard_normal((m, 2)) * self.spec.pose_noise
            got = Frame(lost, robots, obstacles)
            if len(self._frames) >= _FRAME_CACHE:
                self._frames.pop(next(iter(self._frames)))
            self._frames[f] = got
        return got

    def latest_frame(self, t: float) -> int:
        """The newest frame published by ``t`` that was not lost."""
        f = math.floor((t - self.spec.camera_latency) / self.period + 1e-9)
        for back in range(MAX_LOST_FRAMES):
            if not self.frame(f - back).lost:
                return f - back
        return f - MAX_LOST_FRAMES

    def record(self, k: int, state: Sequence[Sequence[float]]) -> None:
        """The true poses at tick ``k`` (each tick once, in order; a tick recorded already is
        kept as it was)."""
        if self.history and k <= self.first_tick + len(self.history) - 1:
            return
        if not self.history:
            self.first_tick = k
        elif len(self.history) == self.history.maxlen:
            self.first_tick += 1
        self.history.append([(s[0], s[1], s[2]) for s in state])

    def truth_at(self, tau: float) -> list[Pose3]:
        """Every robot's true pose at time ``tau`` (at most the last recorded tick's)."""
        if tau <= 0.0 or not self.history:
            return list(self.start)  # type: ignore[arg-type]
        x = tau / self.dt - self.first_tick
        j = max(0, min(len(self.history) - 1, math.floor(x + 1e-9)))
        s = min(1.0, max(0.0, x - j))
        if s <= 1e-9 or j + 1 >= len(self.history):
            return list(self.history[j])
        a, b = self.history[j], self.history[j + 1]
        return [_lerp_pose(p, q, s) for p, q in zip(a, b, strict=True)]

    def poses(self, t: float) -> list[Pose3]:
        """What the camera hands every robot at time ``t``."""
        f = self.latest_frame(t)
        noise = self.frame(f).robots
        truth = self.truth_at(f * self.period)
        return [(p[0] + d[0], p[1] + d[1], p[2] + d[2])
                for p, d in zip(truth, noise.tolist(), strict=True)]

    def obstacle_positions(self, t: float) -> list[tuple[float, float]]:
        """Every obstacle's position as published at ``t``: the moving ones as the camera saw
        them, the static ones where the map has them."""
        out = [o.position(t) for o in self.obstacles]
        if not self.moving:
            return out
        f = self.latest_frame(t)
        noise = self.frame(f).obstacles.tolist()
        for k, d in zip(self.moving, noise, strict=True):
            x, y = self.obstacles[k].position(f * self.period)
            out[k] = (x + d[0], y + d[1])
        return out


class LabWorld:
    """The robots' wheels and the camera of one run in a lab world."""

    def __init__(self, scenario: Scenario) -> None:
        self.spec = scenario.world
        self.dt = scenario.dt
        self.unicycle = scenario.robot.is_unicycle
        self.lookahead = scenario.robot.lookahead
        starts = [r.start for r in scenario.robots]
        self.wheels = [(0.0, 0.0)] * len(starts)
        self.backwards = [False] * len(starts)  # a single integrator's firmware (command_rates)
        self.camera = Camera(self.spec, scenario.dt, starts, scenario.obstacles)

    @classmethod
    def build(cls, scenario: Scenario) -> LabWorld | None:
        """The lab world of ``scenario``; None in the ideal world (nothing changes)."""
        return None if scenario.world.ideal else cls(scenario)

    def move(self, state: Sequence[Sequence[float]],
             cmds: Sequence[Command | None]) -> list[Pose3]:
        """Every robot's true pose after one control period under its command."""
        out = []
        for i, (s, c) in enumerate(zip(state, cmds, strict=True)):
            v, omega, self.backwards[i] = command_rates(c, s[2], self.unicycle, self.lookahead,
                                                        self.backwards[i])
            pose, self.wheels[i] = drive((s[0], s[1], s[2]), self.wheels[i], (v, omega), self.spec,
                                         self.dt)
            out.append(pose)
        return out

    def sense(self, k: int, state: Sequence[Sequence[float]]) -> list[Pose3]:
        """The poses the camera hands the robots at tick ``k`` (true poses ``state``)."""
        self.camera.record(k, state)
        if not self.spec.senses:
            return [(s[0], s[1], s[2]) for s in state]
        return self.camera.poses(k * self.dt)

    def wheel_increments(self) -> list[tuple[float, float, float]] | None:
        """Every robot's motion since the last call as its wheels measured it; None where the
        wheels do not slip (the body's own motion is then what they measure)."""
        return None

    def captured(self, k: int) -> tuple[float, list[Pose3]]:
        """When the poses handed at tick ``k`` (after :meth:`sense`) were captured, and every
        robot's true pose then: what a camera stamping at capture sends, and where blind
        floor is judged (:mod:`simulator.odometry`)."""
        t = k * self.dt
        if not self.spec.senses:
            return t, self.camera.truth_at(t)
        stamp = self.camera.latest_frame(t) * self.camera.period
        return stamp, self.camera.truth_at(stamp)

    def summary_fields(self) -> dict[str, Any]:
        """What this world adds to summary.json (the kinematic lab: nothing)."""
        return {}

    def obstacles(self, k: int) -> list[tuple[float, float]]:
        """Every obstacle's published position at tick ``k``."""
        if not self.spec.senses:
            return [o.position(k * self.dt) for o in self.camera.obstacles]
        return self.camera.obstacle_positions(k * self.dt)
