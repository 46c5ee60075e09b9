"""What a simulated world's robots measure themselves, and what its camera cannot see.

**Wheel odometry.** Each robot integrates its wheels' motion: between two control ticks the
body moved by some increment (dx, dy in the body frame at the first tick, dtheta); its odometry
reports that increment with its own systematic errors: the distance scaled by (1 + scale) and
the heading turned by drift rad per metre driven. Each robot's (scale, drift) is drawn once,
uniformly within the world's bounds (:class:`scenario.world.Odometry`), from a generator seeded
by the world's seed (:func:`odometry_errors`): the same in every process and every run.

**Blind floor.** Inside a box of ``world.camera_blind`` the camera reports no pose of the robot
(:func:`scenario.world.blind_at` on the true position at the frame's capture).

In MuJoCo (:mod:`simulator.physics`) the wheels' own turns are measured instead of the body's
motion (:func:`wheel_increment`): where a wheel slips, the odometry drifts by the slip too.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from scenario.world import WorldSpec, blind_at
from wire.odom import body_increment

ODOMETRY_STREAM = 2**41  # the generator's stream, apart from the camera's frames (simulator.lab)

Increment = tuple[float, float, float]


def odometry_errors(spec: WorldSpec, n: int) -> list[tuple[float, float]]:
    """Each of ``n`` robots' (scale error, heading drift [rad/m]), uniform within the bounds."""
    rng = np.random.default_rng((spec.seed, ODOMETRY_STREAM))
    draws = rng.uniform(-1.0, 1.0, size=(n, 2))
    o = spec.odometry
    return [(float(a) * o.scale_error, float(b) * o.heading_drift_rad_per_m) for a, b in draws]


def wheel_increment(left: float, right: float, track: float) -> Increment:
    """The body-frame increment of a differential drive whose wheels rolled ``left`` and
    ``right`` metres (on an arc): ds = (left + right) / 2, dtheta = (right - left) / track,
    the chord ds sinc(dtheta / 2) at half the turn."""
    ds, dth = 0.5 * (left + right), (right - left) / track
    half = 0.5 * dth
    chord = ds if abs(half) < 1e-9 else ds * math.sin(half) / half
    return (chord * math.cos(half), chord * math.sin(half), dth)


def measured(inc: Increment, scale: float, drift: float) -> Increment:
    """What a robot's odometry reports for the true increment ``inc``: the distance scaled by
    (1 + scale), the heading turned by drift times the distance driven."""
    d = math.hypot(inc[0], inc[1])
    return (inc[0] * (1.0 + scale), inc[1] * (1.0 + scale), inc[2] + drift * d)


class Odometer:
    """Every robot's wheel odometry in one world (see the module docstring)."""

    def __init__(self, spec: WorldSpec, n: int) -> None:
        self.errors = odometry_errors(spec, n)

    def increments(self, before: Sequence[Sequence[float]],
                   after: Sequence[Sequence[float]],
                   wheels: Sequence[Increment] | None = None) -> list[Increment]:
        """Each robot's measured increment between two ticks' true poses, or of what its
        wheels measured (``wheels``: physics bodies, whose wheels slip), with its errors."""
        true = wheels if wheels is not None else [body_increment(b, a)
                                                  for b, a in zip(before, after, strict=True)]
        return [measured(inc, *e) for inc, e in zip(true, self.errors, strict=True)]


def seen_by_camera(spec: WorldSpec, captured: Sequence[Sequence[float]]) -> list[bool]:
    """Whether the camera sees each robot, from its true pose when the frame was captured."""
    return [not blind_at(spec.camera_blind, c[0], c[1]) for c in captured]
