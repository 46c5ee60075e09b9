"""The ``odom`` payload: a robot's wheel odometry increment, base or world -> its agent, on
``{prefix}/robot/{id}/odom`` (:func:`odom_key`). A ROS 2 base publishes poses instead (its
``odom`` topic's nav_msgs/Odometry): the agent differences consecutive ones into the same
increments (:func:`body_increment`, :class:`agent.odom_in.RosOdom`).

Layout (the Zenoh serialization format of :mod:`wire.payloads`): ``u8`` version 1, then
``f64`` dx, dy, dtheta, since, stamp (41 bytes): the body's motion from ``since`` to ``stamp``
[s], (dx, dy) [m] in the body frame at ``since``, dtheta [rad]. Read defensively
(:func:`wire.reader.decode_payload`): a malformed, non-finite or implausible payload (a step
longer than :data:`MAX_STEP`, a turn beyond :data:`MAX_TURN`, ``stamp`` before ``since``) is a
:class:`wire.reader.DecodeError`, which a receiver drops and counts.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Sequence
from dataclasses import dataclass

import zenoh

from wire import keys
from wire.reader import WIRE_VERSION, Reader, decode_payload

ODOM = "odom"
MAX_STEP = 10.0  # [m] the longest increment one message may carry
MAX_TURN = 2.0 * math.pi  # [rad]
_LAYOUT = struct.Struct("<B5d")


@dataclass(frozen=True, slots=True)
class Odom:
    """One odometry increment (see the module docstring)."""

    dx: float
    dy: float
    dtheta: float
    since: float
    stamp: float

    def __post_init__(self) -> None:
        values = (self.dx, self.dy, self.dtheta, self.since, self.stamp)
        if not all(isinstance(v, float | int) and not isinstance(v, bool) and math.isfinite(v)
                   for v in values):
            raise ValueError(f"odom: every field must be a finite number, got {values!r}")
        if math.hypot(self.dx, self.dy) > MAX_STEP:
            raise ValueError(f"odom: a step of more than {MAX_STEP} m")
        if abs(self.dtheta) > MAX_TURN:
            raise ValueError(f"odom: a turn of more than {MAX_TURN:.4f} rad")
        if self.stamp < self.since:
            raise ValueError("odom: stamp before since")


def odom_key(prefix: str, robot_id: str) -> str:
    """``{prefix}/robot/{robot_id}/odom``: base or world -> that robot's agent."""
    return f"{keys.validate_prefix(prefix)}/robot/{keys.validate_id(robot_id, 'robot_id')}/{ODOM}"


def body_increment(before: Sequence[float], after: Sequence[float]) -> tuple[float, float, float]:
    """The exact motion from pose ``before`` to ``after`` (x, y, theta): (dx, dy) in ``before``'s
    body frame and the heading change (wrapped), the increment an ``odom`` message carries."""
    dx, dy = after[0] - before[0], after[1] - before[1]
    c, s = math.cos(before[2]), math.sin(before[2])
    dth = math.atan2(math.sin(after[2] - before[2]), math.cos(after[2] - before[2]))
    return (c * dx + s * dy, -s * dx + c * dy, dth)


def encode_odom(msg: Odom) -> bytes:
    """The payload of ``msg`` (41 bytes)."""
    return _LAYOUT.pack(WIRE_VERSION, msg.dx, msg.dy, msg.dtheta, msg.since, msg.stamp)


def _parse(r: Reader) -> Odom:
    return Odom(*r.floats(5, "odom"))


def decode_odom(payload: bytes | zenoh.ZBytes) -> Odom:
    """Decode an ``odom`` payload; raises only :class:`wire.reader.DecodeError`."""
    return decode_payload(payload, _parse, ODOM)
