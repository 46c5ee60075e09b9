"""Robot base adapters: where an agent's unicycle command ``(v, omega)`` goes.

``make_base(config, ...)`` returns an object with ``send(v, omega, stamp)`` and ``stop()``:

- ``world``: the simulated world (or any consumer of the ``{prefix}/robot/{id}/cmd`` key):
  :class:`WorldBase`, a thin class around a publish callable the agent supplies.
- ``turtlebot3-humble`` / ``turtlebot3-jazzy``: a real TurtleBot3 running ROS 2 bringup behind
  ``zenoh-bridge-ros2dds``, which maps the ROS topic ``/cmd_vel`` to the Zenoh key ``cmd_vel``
  (``{robot}/cmd_vel`` when the bridge's Zenoh session has ``namespace: {robot}``; see
  docs/deploy.md). The payload is the raw CDR of ``geometry_msgs/msg/Twist`` (Humble) or
  ``geometry_msgs/msg/TwistStamped`` (Jazzy): :class:`CdrBase`.
- the same TurtleBot3 bases with ``config.rmw`` set: the robot runs ROS 2 on rmw_zenoh and no
  bridge; the agent is an rmw_zenoh publisher itself (:class:`RmwZenohBase`: its data key,
  attachment and liveliness tokens as :mod:`wire.rmw_zenoh` documents), see docs/deploy.md.

A ROS 2 base also publishes its wheel odometry (``nav_msgs/msg/Odometry`` on its ``odom``
topic): :func:`base_odom_key` is where an agent under ``controller.localisation: fused`` hears it
(the bridge: ``odom`` beside the ``cmd_vel`` key, in the bridge's namespace; rmw_zenoh:
:func:`wire.rmw_zenoh.odom_data_key`), and :func:`base_limits` how fast the base can move.

CDR layout (OMG CDR version 1, little endian, as ROS 2 rmw implementations write it):

- a 4-byte encapsulation header ``00 01 00 00`` (CDR_LE, options 0);
- then the fields, each primitive aligned to its own size *relative to the first byte after the
  header*; a ``string`` is a ``uint32`` length that counts the terminating NUL, the UTF-8 bytes,
  then the NUL.

``Twist`` = 6 float64 (linear x, y, z; angular x, y, z): 4 + 48 bytes.
``TwistStamped`` = ``std_msgs/Header`` (``builtin_interfaces/Time`` {int32 sec, uint32 nanosec},
string frame_id) + ``Twist``: the float64s start at the next multiple of 8 after the string.

The encoders clamp to the TurtleBot3 burger limits (0.22 m/s, 2.84 rad/s) as a last safety net
(the controller already keeps within them), and a non-finite command becomes zero.
"""

from __future__ import annotations

import logging
import math
import struct
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

from geometry.limits import BURGER_MAX_SPEED, BURGER_MAX_TURN_RATE
from wire import rmw_zenoh as rmw
from wire.acl import bridge_odom_key

logger = logging.getLogger(__name__)

CDR_LE_HEADER = b"\x00\x01\x00\x00"  # encapsulation: CDR little endian, options 0
DEFAULT_FRAME_ID = "base_link"
DEFAULT_CMD_VEL_KEY = "cmd_vel"
TWIST_BYTES = 4 + 6 * 8  # header + 6 float64 [bytes]

HUMBLE = "turtlebot3-humble"
JAZZY = "turtlebot3-jazzy"
WORLD = "world"


class Base(Protocol):
    """What the agent drives: one velocity command per tick, and a stop on the way out."""

    def send(self, v: float, omega: float, stamp: float) -> None: ...

    def stop(self) -> None: ...


@dataclass(frozen=True)
class Twist:
    """``geometry_msgs/msg/Twist`` [m/s, rad/s]."""

    linear: tuple[float, float, float] = (0.0, 0.0, 0.0)
    angular: tuple[float, float, float] = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class TwistStamped:
    """``geometry_msgs/msg/TwistStamped``: header stamp (sec, nanosec), frame id and twist."""

    sec: int
    nanosec: int
    frame_id: str
    twist: Twist


def clamp_command(
    v: float,
    omega: float,
    max_speed: float = BURGER_MAX_SPEED,
    max_turn_rate: float = BURGER_MAX_TURN_RATE,
) -> tuple[float, float]:
    """Clip ``v`` to ``[-max_speed, max_speed]`` and ``omega`` likewise; non-finite -> 0 (stop)."""
    if not (max_speed >= 0 and math.isfinite(max_speed)):
        raise ValueError(f"max_speed must be a finite number >= 0, got {max_speed!r}")
    if not (max_turn_rate >= 0 and math.isfinite(max_turn_rate)):
        raise ValueError(f"max_turn_rate must be a finite number >= 0, got {max_turn_rate!r}")
    v, omega = float(v), float(omega)
    if not (math.isfinite(v) and math.isfinite(omega)):
        return 0.0, 0.0
    return min(max(v, -max_speed), max_speed), min(max(omega, -max_turn_rate), max_turn_rate)


def stamp_to_time(stamp: float) -> tuple[int, int]:
    """Seconds -> ``builtin_interfaces/Time`` (int32 sec, uint32 nanosec); invalid -> (0, 0)."""
    if not math.isfinite(stamp) or not (-(2**31) <= stamp < 2**31 - 1):
        return 0, 0
    sec = math.floor(stamp)
    nanosec = min(round((stamp - sec) * 1e9), 999_999_999)
    return int(sec), int(nanosec)


def _align(n: int, size: int) -> int:
    return (n + size - 1) // size * size


def encode_twist(twist: Twist) -> bytes:
    """CDR of ``geometry_msgs/msg/Twist`` with its encapsulation header (52 bytes)."""
    return CDR_LE_HEADER + struct.pack("<6d", *twist.linear, *twist.angular)


def encode_twist_stamped(msg: TwistStamped) -> bytes:
    """CDR of ``geometry_msgs/msg/TwistStamped`` with its encapsulation header."""
    if not -(2**31) <= msg.sec < 2**31:
        raise ValueError(f"sec must fit an int32, got {msg.sec!r}")
    if not 0 <= msg.nanosec < 2**32:
        raise ValueError(f"nanosec must fit a uint32, got {msg.nanosec!r}")
    frame = msg.frame_id.encode("utf-8")
    if b"\x00" in frame:
        raise ValueError("frame_id must not contain NUL")
    body = bytearray(struct.pack("<iI", msg.sec, msg.nanosec))
    body += struct.pack("<I", len(frame) + 1) + frame + b"\x00"
    body += bytes(_align(len(body), 8) - len(body))  # float64s align to 8 (from the body start)
    body += struct.pack("<6d", *msg.twist.linear, *msg.twist.angular)
    return CDR_LE_HEADER + bytes(body)


def _body(payload: bytes) -> bytes:
    if not isinstance(payload, bytes | bytearray | memoryview):
        raise ValueError(f"payload must be bytes, got {type(payload).__name__}")
    payload = bytes(payload)
    if payload[:4] != CDR_LE_HEADER:
        raise ValueError(f"payload: expected CDR_LE header 00 01 00 00, got {payload[:4].hex(' ')}")
    return payload[4:]


def decode_twist(payload: bytes) -> Twist:
    """Inverse of :func:`encode_twist`; ``ValueError`` on a malformed payload."""
    body = _body(payload)
    if len(body) != 48:
        raise ValueError(f"payload: Twist body must be 48 bytes, got {len(body)}")
    values = struct.unpack("<6d", body)
    return Twist(linear=values[:3], angular=values[3:])


def decode_twist_stamped(payload: bytes) -> TwistStamped:
    """Inverse of :func:`encode_twist_stamped`; ``ValueError`` on a malformed payload."""
    body = _body(payload)
    if len(body) < 12:
        raise ValueError("payload: TwistStamped truncated in its header")
    sec, nanosec, length = struct.unpack_from("<iII", body, 0)
    end = 12 + length
    if length < 1 or end > len(body) or body[end - 1] != 0:
        raise ValueError("payload: TwistStamped frame_id is malformed")
    try:
        frame_id = body[12 : end - 1].decode("utf-8")
    except UnicodeDecodeError:
        raise ValueError("payload: TwistStamped frame_id is not UTF-8") from None
    start = _align(end, 8)
    if len(body) != start + 48:
        raise ValueError(f"payload: TwistStamped must be {4 + start + 48} bytes, got {len(payload)}")
    values = struct.unpack_from("<6d", body, start)
    return TwistStamped(sec, nanosec, frame_id, Twist(linear=values[:3], angular=values[3:]))


def encode_cmd_vel(
    base: str,
    v: float,
    omega: float,
    stamp: float,
    frame_id: str = DEFAULT_FRAME_ID,
    max_speed: float = BURGER_MAX_SPEED,
    max_turn_rate: float = BURGER_MAX_TURN_RATE,
) -> bytes:
    """The ``cmd_vel`` payload for ``base`` (Humble: Twist, Jazzy: TwistStamped), clamped."""
    if base not in (HUMBLE, JAZZY):
        raise ValueError(f"base: {base!r} is not one of {(HUMBLE, JAZZY)}")
    type_name = rmw.TWIST if base == HUMBLE else rmw.TWIST_STAMPED
    return encode_cmd(type_name, v, omega, stamp, frame_id, max_speed, max_turn_rate)


def encode_cmd(
    type_name: str,
    v: float,
    omega: float,
    stamp: float,
    frame_id: str = DEFAULT_FRAME_ID,
    max_speed: float = BURGER_MAX_SPEED,
    max_turn_rate: float = BURGER_MAX_TURN_RATE,
) -> bytes:
    """The CDR of ``geometry_msgs/msg/Twist`` or ``TwistStamped`` (``type_name``), clamped."""
    v, omega = clamp_command(v, omega, max_speed, max_turn_rate)
    twist = Twist(linear=(v, 0.0, 0.0), angular=(0.0, 0.0, omega))
    if type_name == rmw.TWIST:
        return encode_twist(twist)
    if type_name == rmw.TWIST_STAMPED:
        sec, nanosec = stamp_to_time(stamp)
        return encode_twist_stamped(TwistStamped(sec, nanosec, frame_id, twist))
    raise ValueError(f"type: {type_name!r} is not one of {(rmw.TWIST, rmw.TWIST_STAMPED)}")


def decode_cmd(type_name: str, payload: bytes) -> tuple[float, float, float | None]:
    """``(v, omega, stamp or None)`` of a Twist / TwistStamped payload; ``ValueError``."""
    if type_name == rmw.TWIST:
        t = decode_twist(payload)
        return t.linear[0], t.angular[2], None
    if type_name == rmw.TWIST_STAMPED:
        m = decode_twist_stamped(payload)
        return m.twist.linear[0], m.twist.angular[2], m.sec + m.nanosec * 1e-9
    raise ValueError(f"type: {type_name!r} is not one of {(rmw.TWIST, rmw.TWIST_STAMPED)}")


class WorldBase:
    """The simulated world's base: hands ``(v, omega, stamp)`` to the agent's publish callable.

    The agent encodes and puts the ``{prefix}/robot/{id}/cmd`` message itself (it alone knows
    the certified ``ux, uy``); this class only gives the world the same seam as a real robot.
    """

    def __init__(self, publish: Callable[[float, float, float], None]) -> None:
        if not callable(publish):
            raise ValueError("publish must be callable")
        self._publish = publish
        self._last_stamp = 0.0

    def send(self, v: float, omega: float, stamp: float) -> None:
        self._last_stamp = stamp
        self._publish(v, omega, stamp)

    def stop(self) -> None:
        self._publish(0.0, 0.0, self._last_stamp)


class CdrBase:
    """A TurtleBot3 behind ``zenoh-bridge-ros2dds``: puts CDR ``cmd_vel`` payloads.

    ``put`` is a callable taking the payload bytes, e.g. a zenoh publisher's ``put``.
    """

    def __init__(
        self,
        base: str,
        put: Callable[[bytes], Any],
        frame_id: str = DEFAULT_FRAME_ID,
        max_speed: float = BURGER_MAX_SPEED,
        max_turn_rate: float = BURGER_MAX_TURN_RATE,
        undeclare: Callable[[], Any] | None = None,
    ) -> None:
        if base not in (HUMBLE, JAZZY):
            raise ValueError(f"base: {base!r} is not one of {(HUMBLE, JAZZY)}")
        if not callable(put):
            raise ValueError("put must be callable")
        clamp_command(0.0, 0.0, max_speed, max_turn_rate)  # validates the limits
        self.base = base
        self._put = put
        self._frame_id = frame_id
        self._limits = (max_speed, max_turn_rate)
        self._undeclare = undeclare
        self._last_stamp = 0.0

    def send(self, v: float, omega: float, stamp: float) -> None:
        self._last_stamp = stamp
        self._put(encode_cmd_vel(self.base, v, omega, stamp, self._frame_id, *self._limits))

    def stop(self) -> None:
        """Command zero velocity (and undeclare the publisher, if this base declared it)."""
        try:
            self._put(encode_cmd_vel(self.base, 0.0, 0.0, self._last_stamp, self._frame_id))
        finally:
            if self._undeclare is not None:
                undeclare, self._undeclare = self._undeclare, None
                undeclare()


class RmwZenohBase:
    """A robot on ROS 2 with rmw_zenoh: the agent publishes ``cmd_vel`` as rmw_zenoh does.

    Each command is the CDR of ``type_name`` put on ``spec.key`` with the attachment of
    ``spec.layout`` (sequence number from 1, the wall clock's ns, ``spec.gid``): rmw_zenoh's
    subscribers drop a sample without one. ``put(payload, attachment)`` sends; ``close``
    (optional) undeclares the publisher and its liveliness tokens after the final stop.
    """

    def __init__(
        self,
        type_name: str,
        spec: rmw.PublisherSpec,
        put: Callable[[bytes, bytes], Any],
        frame_id: str = DEFAULT_FRAME_ID,
        max_speed: float = BURGER_MAX_SPEED,
        max_turn_rate: float = BURGER_MAX_TURN_RATE,
        clock_ns: Callable[[], int] = time.time_ns,
        close: Callable[[], Any] | None = None,
    ) -> None:
        encode_cmd(type_name, 0.0, 0.0, 0.0)  # validates the type
        if not callable(put):
            raise ValueError("put must be callable")
        clamp_command(0.0, 0.0, max_speed, max_turn_rate)  # validates the limits
        self.type_name = type_name
        self.spec = spec
        self._put = put
        self._frame_id = frame_id
        self._limits = (max_speed, max_turn_rate)
        self._clock_ns = clock_ns
        self._close = close
        self._last_stamp = 0.0
        self.sequence_number = 0  # of the last sample sent
        self.publisher: Any = None  # the zenoh publisher, when open_rmw_base declared it

    def _publish(self, v: float, omega: float, stamp: float, limits: tuple[float, float]) -> None:
        payload = encode_cmd(self.type_name, v, omega, stamp, self._frame_id, *limits)
        self.sequence_number += 1
        att = rmw.Attachment(self.sequence_number, int(self._clock_ns()), self.spec.gid)
        self._put(payload, rmw.encode_attachment(att, self.spec.layout))

    def send(self, v: float, omega: float, stamp: float) -> None:
        self._last_stamp = stamp
        self._publish(v, omega, stamp, self._limits)

    def stop(self) -> None:
        """Command zero velocity, then undeclare the publisher and tokens (if this base did)."""
        try:
            self._publish(0.0, 0.0, self._last_stamp, self._limits)
        finally:
            if self._close is not None:
                close, self._close = self._close, None
                close()


def open_rmw_base(config: Any, session: Any, max_speed: float, max_turn: float) -> RmwZenohBase:
    """An :class:`RmwZenohBase` on ``session`` for ``config`` (its ``base`` and ``rmw``):
    declares the node's and the publisher's liveliness tokens, then the publisher."""
    settings: rmw.RmwSettings = config.rmw
    distro = "humble" if config.base == HUMBLE else "jazzy"
    rel, type_name = rmw.resolve(settings, distro)
    spec = rmw.publisher_spec(rel, str(session.zid()), domain=settings.domain,
                              namespace=settings.namespace, topic="cmd_vel", type_name=type_name)
    liveliness = session.liveliness()
    node_token = liveliness.declare_token(spec.node_token)
    pub_token = liveliness.declare_token(spec.publisher_token)
    publisher = session.declare_publisher(spec.key)

    def put(payload: bytes, attachment: bytes) -> None:
        publisher.put(payload, attachment=attachment)

    def close() -> None:
        for entity in (publisher, pub_token, node_token):
            entity.undeclare()

    logger.info("base %s over rmw_zenoh %s: %s on key %r", config.base, rel.name,
                type_name, spec.key)
    base = RmwZenohBase(type_name, spec, put, getattr(config, "frame_id", DEFAULT_FRAME_ID),
                        max_speed, max_turn, close=close)
    base.publisher = publisher
    return base


def make_base(
    config: Any,
    session: Any = None,
    *,
    publish: Callable[[float, float, float], None] | None = None,
    cmd_vel_key: str | None = None,
) -> WorldBase | CdrBase | RmwZenohBase:
    """The base adapter of ``config.base`` (an :class:`agent.config.AgentConfig`).

    ``world`` needs ``publish`` (the agent's cmd publisher); the TurtleBot bases need ``session``
    (a ``zenoh.Session``) and put on ``cmd_vel_key`` (default: ``config.cmd_vel_key`` if the
    config has that field, else ``cmd_vel``), clamped to ``config.control``'s limits if it has
    ``max_speed``/``max_turn_rate``, never beyond the burger's; with ``config.rmw`` set they
    are rmw_zenoh publishers instead (:func:`open_rmw_base`).
    """
    base = getattr(config, "base", None)
    if base == WORLD:
        if publish is None:
            raise ValueError("publish: the world base needs the agent's cmd publish callable")
        return WorldBase(publish)
    if base in (HUMBLE, JAZZY):
        if session is None:
            raise ValueError(f"session: base {base!r} needs a zenoh session")
        key = cmd_vel_key or getattr(config, "cmd_vel_key", None) or DEFAULT_CMD_VEL_KEY
        control = getattr(config, "control", None)
        max_speed = min(BURGER_MAX_SPEED, _limit(control, "max_speed", BURGER_MAX_SPEED))
        max_turn = min(BURGER_MAX_TURN_RATE, _limit(control, "max_turn_rate", BURGER_MAX_TURN_RATE))
        if getattr(config, "rmw", None) is not None:
            return open_rmw_base(config, session, max_speed, max_turn)
        publisher = session.declare_publisher(key)
        logger.info("base %s: cmd_vel on key %r", base, key)
        return CdrBase(base, publisher.put, max_speed=max_speed, max_turn_rate=max_turn,
                       undeclare=publisher.undeclare)
    raise ValueError(f"base: {base!r} is not one of {(WORLD, HUMBLE, JAZZY)}")


def base_odom_key(config: Any) -> str:
    """The key of the ``odom`` topic of ``config``'s ROS 2 base: over zenoh-bridge-ros2dds
    ``{namespace}/odom``, the namespace being the ``cmd_vel`` key's (``a1/cmd_vel`` ->
    ``a1/odom``; ``cmd_vel`` -> ``odom``); over rmw_zenoh its data key."""
    base = getattr(config, "base", None)
    if base not in (HUMBLE, JAZZY):
        raise ValueError(f"base: {base!r} has no odom topic (one of {(HUMBLE, JAZZY)})")
    if getattr(config, "rmw", None) is not None:
        return rmw.odom_data_key(config.rmw, "humble" if base == HUMBLE else "jazzy")
    return bridge_odom_key(getattr(config, "cmd_vel_key", None) or DEFAULT_CMD_VEL_KEY)


def base_limits(config: Any) -> tuple[float, float]:
    """[m/s], [rad/s] The fastest the base can move and turn: the burger's limits, or the
    controller's where it allows more (what physics lets the base's odometry report)."""
    control = getattr(config, "control", None)
    return (max(BURGER_MAX_SPEED, _limit(control, "max_speed", BURGER_MAX_SPEED)),
            max(BURGER_MAX_TURN_RATE, _limit(control, "max_turn_rate", BURGER_MAX_TURN_RATE)))


def _limit(control: Any, name: str, default: float) -> float:
    value = getattr(control, name, None)
    if isinstance(value, int | float) and math.isfinite(value) and value > 0:
        return float(value)
    return default
