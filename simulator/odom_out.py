"""The world process's wheel odometry under ``controller.localisation: fused``.

Each tick the world (:mod:`simulator.world`) publishes every robot's odometry increment since
the last tick on ``robot/{id}/odom`` (:mod:`wire.odom`), after the tick's poses: the robot's
motion between the two ticks' true poses (or what its wheels measured, in MuJoCo), with its
own seeded errors (:class:`simulator.odometry.Odometer`, the one model the in-process
simulator uses). The first tick's increment is zero (nothing moved yet). Stamps are the
world's: ``since`` the last tick's, ``stamp`` this one's (lock-step ``k dt``, real time the
frame's wall-clock stamp), so the agent's filter lines them up with the camera's capture
stamps.

The camera's poses under ``fused`` carry their capture stamp (:func:`capture_stamp`): a lab
camera hands over a frame taken ``camera_latency`` ago, and the filter fuses it there.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from scenario import Scenario
from wire.odom import Odom, encode_odom

from .lab import LabWorld
from .odometry import Odometer


def capture_stamp(lab: LabWorld | None, k: int, t: float, stamp: float) -> float:
    """The capture stamp of the poses published at tick ``k`` (simulated time ``t``, stamped
    ``stamp`` on the world's clock): the lab camera's frame time on that clock, else ``stamp``."""
    if lab is None:
        return stamp
    return stamp - (t - lab.captured(k)[0])


class OdomOut:
    """Every robot's odometry out of one world (module docstring); ``publishers``: one per
    robot, in the scenario's robot order (anything with ``put(bytes)``)."""

    def __init__(self, scenario: Scenario, publishers: Sequence[Any]) -> None:
        self.odometer = Odometer(scenario.world, len(scenario.robots))
        self.publishers = list(publishers)
        self.before: list[tuple[float, float, float]] | None = None  # the last tick's truth
        self.since = 0.0  # [s] its stamp

    def publish(self, stamp: float, state: Sequence[Sequence[float]],
                lab: LabWorld | None) -> None:
        """Tick ``stamp``'s increments (true poses ``state``) out, one message per robot."""
        wheels = lab.wheel_increments() if lab is not None else None
        truth = [(s[0], s[1], s[2]) for s in state]
        if self.before is None:
            incs = [(0.0, 0.0, 0.0)] * len(truth)
            self.since = stamp
        else:
            incs = self.odometer.increments(self.before, truth, wheels)
        for pub, inc in zip(self.publishers, incs, strict=True):
            pub.put(encode_odom(Odom(inc[0], inc[1], inc[2], self.since, stamp)))
        self.before, self.since = truth, stamp

    def undeclare(self) -> None:
        for pub in self.publishers:
            pub.undeclare()
        self.publishers.clear()
