"""Versioned payloads of formation-cbf, one per key class, and their wire format.

Payloads are written with ``zenoh.ext.z_serialize`` (the Zenoh serialization format, readable
with the zenoh-ext deserializers of zenoh-c, zenoh-cpp and zenoh-rust). In that
format a ``u8`` is 1 byte, an ``f64`` is 8 bytes little-endian IEEE 754, a ``str`` is its UTF-8
length as an unsigned LEB128 varint followed by the UTF-8 bytes, a ``list`` is its element count
as a LEB128 varint followed by the elements, and a tuple is its elements back to back with no
header. Every payload is one tuple:

=============  =======================================================================  =====
payload        fields in order (``u8`` version, then ``f64`` unless marked ``str``)      bytes
=============  =======================================================================  =====
``Pose``       version, x, y, theta, stamp                                               33
``State``      version (2), x, y, ux, uy, theta, stamp                                   49
``Cmd``        version, v, omega, ux, uy, stamp                                          41
``Cmd``        version 2, v, omega, ux, uy, ax, ay, stamp                                57
``EllipseMsg`` version, formation:str, cx, cy, alpha, a, b, vx, vy, alpha_rate, stamp   73+n
``EllipseMsg`` version 2, the same, then points:list[P], headings:list[f64]           varies
``Others``     version, formation:str, stamp, ellipses:list[E], own:list[E] (0 or 1)  varies
``Others``     version 2, the same with every ``E`` followed by its points and headings varies
``Obstacles``  version, stamp, obstacles:list[O]                                         varies
``Obstacles``  version 2, stamp, obstacles:list[O], shapes:list[S]                       varies
=============  =======================================================================  =====

where ``E`` is an ellipse without the version, ``(formation:str, cx, cy, alpha, a, b, vx, vy,
alpha_rate, stamp)``, ``O`` is ``(id:str, x, y, vx, vy, ds)``, and ``n`` is the length of the
formation id's varint plus its UTF-8 bytes. ``S`` is a wall or shelf, ``(id:str, kind:u8, cx, cy,
hx, hy, yaw, ds)``: kind 1 a segment (centre, half length ``hx``, ``hy = 0``, direction ``yaw``),
kind 2 a box (centre, half sizes, yaw); see :mod:`geometry.shapes`. ``P`` is a point ``(x, y)``:
an ellipse's ``points`` are its formation's members' control points it was estimated from (at
most :data:`MAX_POINTS`), which the other formations keep out of their own ellipses (the mirror
rows of :mod:`agent.body`), and ``headings`` those members' body headings [rad] (none, or one
per point: a formation of unicycles waits for its members to face its motion). ``Others.own`` (the
leader's own ellipse, or none) is a list of 0 or 1 elements because the format has no
optional type. The version byte is
:data:`WIRE_VERSION` for every kind; a decoder accepts exactly that version, except that an
``Obstacles`` carrying walls or shelves is written as :data:`SHAPES_VERSION` (a decoder that
predates shapes refuses it with "unsupported version 2"; circles alone keep version 1, byte for
byte as before); likewise a ``Cmd`` carrying a double integrator's certified acceleration
``ax, ay`` is written as :data:`CMD_ACCEL_VERSION` and every other ``Cmd`` as version 1, and
:func:`decode_cmd` accepts both; an ``EllipseMsg`` with points, or an ``Others`` any of whose
ellipses has points, is written as :data:`ELLIPSE_POINTS_VERSION` (without points: version 1,
byte for byte as before), and their decoders accept both. Units: metres,
radians, seconds, metres per second, radians per second; ``stamp`` is the sender's clock in
seconds. ``Pose`` and ``State`` carry no id: the key names the robot.

Every message validates itself on construction (``ValueError`` naming the field): all floats
finite, ids valid (see :mod:`wire.keys`), ellipse semi-axes ``a, b > 0``, obstacle ``ds >= 0``,
at most :data:`MAX_ITEMS` ellipses or obstacles, no repeated formation or obstacle id, and the
``Others`` own ellipse belonging to its formation and not repeated among the others.

Decoding is defensive (:mod:`wire.reader`): ``decode_*`` raises nothing but
:class:`DecodeError` (a ``ValueError``), for a payload that is not bytes, empty, longer than
:data:`MAX_PAYLOAD_BYTES`, of another version, truncated, followed by trailing bytes, holding a
non-canonical (over-long) varint, invalid UTF-8, more than :data:`MAX_ITEMS` entries, or a
message that fails validation (non-finite numbers, invalid ids). Decoding is written in Python
over ``struct`` rather than with ``zenoh.ext.z_deserialize``, which can abort the process on a
hostile length (see :mod:`wire.reader`); tests check both agree on valid payloads.
"""

from __future__ import annotations

import functools
import logging
import math
import numbers
from collections.abc import Callable, Iterable
from dataclasses import dataclass, fields
from typing import Any, TypeAlias

import zenoh
from zenoh.ext import UInt8, z_serialize

from wire import keys

# DecodeError and MAX_PAYLOAD_BYTES are this module's interface too (what decode_* raises, the
# size it refuses)
from wire.reader import FLOATS, MAX_POINTS, WIRE_VERSION, Item, Points, Reader, decode_payload
from wire.reader import MAX_PAYLOAD_BYTES as MAX_PAYLOAD_BYTES
from wire.reader import DecodeError as DecodeError

logger = logging.getLogger(__name__)

SHAPES_VERSION = 2  # Obstacles with walls or shelves
SHAPE_SEGMENT = 1  # ShapeMsg.kind
SHAPE_BOX = 2
#: ``state`` is at version 2 (it gained the heading); a version-1 decoder refuses it by its
#: version byte ("unsupported version 2"), and this decoder refuses version-1 states.
STATE_VERSION = 2
#: ``status`` version 2 (the one new status version) adds why the formation is
#: in its state (``reason``: the planner's word for ``unreachable``), how many goals its leader
#: refused (``refused``, a whole number carried as f64), why it refused the last one
#: (``refusal``) and every formation of the leader's scenario, its own included (``fleet``:
#: ``formation goal`` tells an unknown formation from one whose leader has not answered yet by
#: any one leader's answer). A status with nothing of these is written as version 1, byte for
#: byte as before, so an older fleet manager still reads it; one with any of them (or the state
#: ``unreachable``) is version 2, which an older decoder refuses by its version byte.
STATUS_VERSION = 2
CMD_ACCEL_VERSION = 2  # Cmd with a double integrator's acceleration (ax, ay)
#: ``goal`` and ``plan`` version 2 add a heading (0 or 1) per waypoint or route point, after the
#: stamp (the footprint's route turns it; a hand-given waypoint may say how). One
#: without any heading is written as version 1, byte for byte as before.
ROUTE_VERSION = 2
#: ``ellipse`` and ``others`` version 2 carry each ellipse's members' control points (
#: a formation keeps its own ellipse off the other formations' members, :mod:`agent.body`).
ELLIPSE_POINTS_VERSION = 2
MAX_ITEMS = 256  # most ellipses (or obstacles) one payload may carry


def _finite(obj: object, name: str) -> None:
    """Check the float field ``name`` of a frozen dataclass and store it as a plain float."""
    value = getattr(obj, name)
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise ValueError(f"{name} must be a real number, got {type(value).__name__}")
    as_float = float(value)
    if not math.isfinite(as_float):
        raise ValueError(f"{name} must be finite, got {as_float!r}")
    object.__setattr__(obj, name, as_float)


_isfinite = math.isfinite

# Ids already found valid (validity depends on the string alone), so a decoder checks a
# formation or obstacle id it has seen before with one set lookup. Bounded: cleared when full.
_VALID_IDS: set[str] = set()
_VALID_IDS_MAX = 4096


def _check_id(value: object, name: str) -> None:
    """:func:`wire.keys.validate_id`, remembering plain strings that passed."""
    if type(value) is str and value in _VALID_IDS:
        return
    keys.validate_id(value, name)
    if type(value) is str:
        if len(_VALID_IDS) >= _VALID_IDS_MAX:
            _VALID_IDS.clear()
        _VALID_IDS.add(value)


def _plain_finite(values: tuple[Any, ...]) -> bool:
    """Whether every value is a plain ``float`` and all are finite, in one pass: the sum of
    plain floats is finite only if each one is (a sum that overflows to infinity just sends
    the caller to the field-by-field check, which accepts such values)."""
    for v in values:
        if type(v) is not float:
            return False
    return _isfinite(sum(values))


def _check_floats(obj: object, names: Iterable[str]) -> None:
    """Check the float fields ``names`` of ``obj`` like :func:`_finite`.

    The fast path accepts a plain finite ``float`` as it is (what every decoder and nearly every
    caller passes: ``float(v)`` of it is ``v``); anything else takes :func:`_finite`, which
    converts it or raises, so the behaviour is the same either way. The messages' constructors
    try :func:`_plain_finite` first and call this only when it fails."""
    for name in names:
        value = getattr(obj, name)
        if type(value) is not float or not _isfinite(value):
            _finite(obj, name)


_POSE_FLOATS = ("x", "y", "theta", "stamp")
_STATE_FLOATS = ("x", "y", "ux", "uy", "stamp", "theta")
_CMD_FLOATS = ("v", "omega", "ux", "uy", "stamp")
_OBSTACLE_FLOATS = ("x", "y", "vx", "vy", "ds")
_STAMP = ("stamp",)


@dataclass(frozen=True, slots=True)
class Pose:
    """Measured pose of one robot: ``{prefix}/robot/{id}/pose``. [m, m, rad, s]"""

    x: float
    y: float
    theta: float
    stamp: float

    def __post_init__(self) -> None:
        if not _plain_finite((self.x, self.y, self.theta, self.stamp)):
            _check_floats(self, _POSE_FLOATS)


@dataclass(frozen=True, slots=True)
class State:
    """Position and current single-integrator command of one robot: ``.../state``.

    [m, m, m/s, m/s, s, rad]; neighbours use ``ux, uy`` as the velocity of appendix A.2 and
    of the separation rows, ``theta`` (the body heading, wire version 2: :data:`STATE_VERSION`)
    to place a unicycle's body behind its look-ahead point ``x, y``.
    """

    x: float
    y: float
    ux: float
    uy: float
    stamp: float
    theta: float = 0.0

    def __post_init__(self) -> None:
        if not _plain_finite((self.x, self.y, self.ux, self.uy, self.stamp, self.theta)):
            _check_floats(self, _STATE_FLOATS)


@dataclass(frozen=True, slots=True)
class Cmd:
    """Command to a robot base: ``.../cmd``. Unicycle ``v, omega`` and the certified ``ux, uy``;
    a double integrator's certified acceleration ``ax, ay`` (both or neither; then ``ux, uy``
    is the velocity it gives at the end of the tick), wire version :data:`CMD_ACCEL_VERSION`.

    [m/s, rad/s, m/s, m/s, s, m/s^2, m/s^2]
    """

    v: float
    omega: float
    ux: float
    uy: float
    stamp: float
    ax: float | None = None
    ay: float | None = None

    def __post_init__(self) -> None:
        if not _plain_finite((self.v, self.omega, self.ux, self.uy, self.stamp)):
            _check_floats(self, _CMD_FLOATS)
        if self.ax is not None or self.ay is not None:
            _check_floats(self, ("ax", "ay"))


_ELLIPSE_FLOATS = ("cx", "cy", "alpha", "a", "b", "vx", "vy", "alpha_rate", "stamp")


@dataclass(frozen=True, slots=True)
class EllipseMsg:
    """One formation's bounding ellipse: ``{prefix}/formation/{fid}/ellipse``.

    Centroid ``cx, cy`` [m], orientation ``alpha`` [rad], semi-axes ``a, b`` [m], centroid
    velocity ``vx, vy`` [m/s], ``alpha_rate`` [rad/s], ``stamp`` [s] (eq. 4.6, appendix A.3);
    ``points`` [m]: the members' control points it was estimated from (none from a sender that
    predates them; wire version :data:`ELLIPSE_POINTS_VERSION`); ``headings`` [rad]: their body
    headings, none or one per point (a formation of unicycles waits for its members to face its
    motion: :func:`agent.body.pace`).
    """

    formation: str
    cx: float
    cy: float
    alpha: float
    a: float
    b: float
    vx: float
    vy: float
    alpha_rate: float
    stamp: float
    points: tuple[tuple[float, float], ...] = ()
    headings: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        _check_id(self.formation, "formation")
        if not _plain_finite((self.cx, self.cy, self.alpha, self.a, self.b, self.vx, self.vy,
                              self.alpha_rate, self.stamp)):
            _check_floats(self, _ELLIPSE_FLOATS)
        if self.a <= 0.0:
            raise ValueError(f"a must be > 0, got {self.a!r}")
        if self.b <= 0.0:
            raise ValueError(f"b must be > 0, got {self.b!r}")
        if self.points != ():
            object.__setattr__(self, "points", _points(self.points, "points", MAX_POINTS))
        if self.headings != ():
            object.__setattr__(self, "headings", _point_headings(self.headings, len(self.points)))


def _ellipse_tuple(value: object, name: str) -> tuple[EllipseMsg, ...]:
    items: tuple[Any, ...] = tuple(value)  # type: ignore[arg-type]
    if len(items) > MAX_ITEMS:
        raise ValueError(f"{name} must hold at most {MAX_ITEMS} entries, got {len(items)}")
    for item in items:
        if not isinstance(item, EllipseMsg):
            raise ValueError(f"{name} entries must be EllipseMsg, got {type(item).__name__}")
    return items


@dataclass(frozen=True, slots=True)
class Others:
    """A leader's republication to its members: ``{prefix}/formation/{fid}/others``.

    ``ellipses`` are the other formations' ellipses; ``own`` is the leader's own formation's
    ellipse (or ``None`` before it has one).
    """

    formation: str
    stamp: float
    ellipses: tuple[EllipseMsg, ...] = ()
    own: EllipseMsg | None = None

    def __post_init__(self) -> None:
        _check_id(self.formation, "formation")
        _check_floats(self, _STAMP)
        ellipses = _ellipse_tuple(self.ellipses, "ellipses")
        object.__setattr__(self, "ellipses", ellipses)
        seen: set[str] = set()
        for ellipse in ellipses:
            if ellipse.formation == self.formation:
                raise ValueError(
                    f"ellipses must not contain the own formation {self.formation!r}"
                )
            if ellipse.formation in seen:
                raise ValueError(f"ellipses repeat formation {ellipse.formation!r}")
            seen.add(ellipse.formation)
        if self.own is not None:
            if not isinstance(self.own, EllipseMsg):
                kind = type(self.own).__name__
                raise ValueError(f"own must be an EllipseMsg or None, got {kind}")
            if self.own.formation != self.formation:
                raise ValueError(
                    f"own belongs to formation {self.own.formation!r}, not {self.formation!r}"
                )


@dataclass(frozen=True, slots=True)
class ObstacleMsg:
    """One circular obstacle: centre ``x, y`` [m], velocity ``vx, vy`` [m/s], ``ds`` [m]."""

    id: str
    x: float
    y: float
    vx: float
    vy: float
    ds: float

    def __post_init__(self) -> None:
        _check_id(self.id, "id")
        if not _plain_finite((self.x, self.y, self.vx, self.vy, self.ds)):
            _check_floats(self, _OBSTACLE_FLOATS)
        if self.ds < 0.0:
            raise ValueError(f"ds must be >= 0, got {self.ds!r}")


_SHAPE_FLOATS = ("cx", "cy", "hx", "hy", "yaw", "ds")


@dataclass(frozen=True, slots=True)
class ShapeMsg:
    """One static wall (``kind`` :data:`SHAPE_SEGMENT`: centre, half length ``hx``, ``hy`` 0,
    direction ``yaw``) or shelf (:data:`SHAPE_BOX`: centre, half sizes, yaw) with its ``ds``.
    [m, m, m, m, rad, m]"""

    id: str
    kind: int
    cx: float
    cy: float
    hx: float
    hy: float
    yaw: float
    ds: float

    def __post_init__(self) -> None:
        _check_id(self.id, "id")
        if type(self.kind) is not int or self.kind not in (SHAPE_SEGMENT, SHAPE_BOX):
            raise ValueError(f"kind must be {SHAPE_SEGMENT} (segment) or {SHAPE_BOX} (box), "
                             f"got {self.kind!r}")
        _check_floats(self, _SHAPE_FLOATS)
        if self.hx < 0.0 or self.hy < 0.0 or self.ds < 0.0:
            raise ValueError(f"hx, hy and ds must be >= 0, got {self.hx!r}, {self.hy!r}, {self.ds!r}")
        if self.kind == SHAPE_SEGMENT and self.hy != 0.0:
            raise ValueError(f"a segment has hy = 0, got {self.hy!r}")


@dataclass(frozen=True, slots=True)
class Obstacles:
    """Every obstacle the camera or world sees: ``{prefix}/obstacles``: circles (moving or not)
    and static walls and shelves."""

    stamp: float
    obstacles: tuple[ObstacleMsg, ...] = ()
    shapes: tuple[ShapeMsg, ...] = ()

    def __post_init__(self) -> None:
        _check_floats(self, _STAMP)
        items = tuple(self.obstacles)
        shapes = tuple(self.shapes)
        if len(items) + len(shapes) > MAX_ITEMS:
            raise ValueError(f"obstacles must hold at most {MAX_ITEMS} entries, got "
                             f"{len(items) + len(shapes)}")
        seen: set[str] = set()
        for item in items:
            if not isinstance(item, ObstacleMsg):
                kind = type(item).__name__
                raise ValueError(f"obstacles entries must be ObstacleMsg, got {kind}")
            if item.id in seen:
                raise ValueError(f"obstacles repeat id {item.id!r}")
            seen.add(item.id)
        for sh in shapes:
            if not isinstance(sh, ShapeMsg):
                raise ValueError(f"shapes entries must be ShapeMsg, got {type(sh).__name__}")
            if sh.id in seen:
                raise ValueError(f"obstacles repeat id {sh.id!r}")
            seen.add(sh.id)
        object.__setattr__(self, "obstacles", items)
        object.__setattr__(self, "shapes", shapes)


Message: TypeAlias = Pose | State | Cmd | EllipseMsg | Others | Obstacles


# --- building messages from decoded fields ----------------------------------------------------
#
# A decoder checks a whole list of ellipses or obstacles at once (every float of the list in one
# sum, the ids against the set of ids already found valid, each item's range rule) and, when all
# pass, builds the items without running each one's checks again (an ``Others`` of eight
# ellipses is the message every member decodes each tick). Anything that fails the
# quick check goes through the constructors, which accept it or raise the usual error.

_new = object.__new__


def _slot_setters(cls: type) -> tuple[Callable[[Any, Any], None], ...]:
    """The slot setters of a frozen message class's fields, in field order."""
    return tuple(cls.__dict__[f.name].__set__ for f in fields(cls))


def _build_trusted(cls: type, setters: tuple[Callable[[Any, Any], None], ...],
                   values: Iterable[Any]) -> Any:
    """An instance of the frozen message class ``cls`` holding ``values`` (in field order)
    without running its checks: only for values already checked as its constructor would."""
    obj: Any = _new(cls)
    for put, value in zip(setters, values, strict=True):
        put(obj, value)
    return obj


def _build_items(cls: type, setters: tuple[Callable[[Any, Any], None], ...], items: list[Item],
                 in_range: Callable[[tuple[float, ...]], bool]) -> tuple[Any, ...]:
    """The ``cls`` messages of decoded ``(id, floats)`` items, where ``in_range`` is the
    constructor's rule on the floats beyond finiteness."""
    total = 0.0
    for ident, values in items:
        if ident not in _VALID_IDS or not in_range(values):
            break
        total += sum(values)
    else:
        if _isfinite(total):
            return tuple([_build_trusted(cls, setters, (ident, *values)) for ident, values in items])
    return tuple([cls(ident, *values) for ident, values in items])


def _axes_positive(values: tuple[float, ...]) -> bool:  # cx, cy, alpha, a, b, ...
    return values[3] > 0.0 and values[4] > 0.0


def _ds_not_negative(values: tuple[float, ...]) -> bool:  # x, y, vx, vy, ds
    return values[4] >= 0.0


_ELLIPSE_SETTERS = _slot_setters(EllipseMsg)
_ELLIPSE_V1_SETTERS = _ELLIPSE_SETTERS[:-2]  # every field but points and headings (defaults)
_OBSTACLE_SETTERS = _slot_setters(ObstacleMsg)
_OTHERS_SETTERS = _slot_setters(Others)
_OBSTACLES_SETTERS = _slot_setters(Obstacles)


def _ellipses(items: list[Item], points: list[Points] | None = None) -> tuple[EllipseMsg, ...]:
    """The ellipses of decoded items, each with its ``points`` and ``headings`` (version 2;
    read by :meth:`wire.reader.Reader.points`, so already pairs of floats and as many headings as points:
    only their finiteness is checked)."""
    put_points, put_headings = _ELLIPSE_SETTERS[-2], _ELLIPSE_SETTERS[-1]
    built = _build_items(EllipseMsg, _ELLIPSE_V1_SETTERS, items, _axes_positive)
    if points is None:
        for msg in built:  # a trusted build leaves the slots unset
            put_points(msg, ())
            put_headings(msg, ())
        return built
    total = 0.0
    for pts, hs in points:
        for x, y in pts:
            total += x + y
        total += sum(hs)
    if not _isfinite(total):
        return tuple(EllipseMsg(ident, *values, points=pts, headings=hs)  # type: ignore[misc, arg-type]
                     for (ident, values), (pts, hs) in zip(items, points, strict=True))
    for msg, (pts, hs) in zip(built, points, strict=True):
        put_points(msg, pts)
        put_headings(msg, hs)
    return built


# --- encoding ---------------------------------------------------------------------------------

_VERSION = UInt8(WIRE_VERSION)
_SHAPES_VERSION = UInt8(SHAPES_VERSION)
_STATE_VERSION = UInt8(STATE_VERSION)
_STATUS_VERSION = UInt8(STATUS_VERSION)
_CMD_ACCEL_VERSION = UInt8(CMD_ACCEL_VERSION)
_ROUTE_VERSION = UInt8(ROUTE_VERSION)
_ELLIPSE_POINTS_VERSION = UInt8(ELLIPSE_POINTS_VERSION)


def _ellipse_fields(e: EllipseMsg) -> tuple[Any, ...]:
    return (e.formation, e.cx, e.cy, e.alpha, e.a, e.b, e.vx, e.vy, e.alpha_rate, e.stamp)


def _ellipse_fields_v2(e: EllipseMsg) -> tuple[Any, ...]:
    return (*_ellipse_fields(e), list(e.points), list(e.headings))


def _wire_tuple(msg: Message) -> tuple[Any, ...]:
    if isinstance(msg, Pose):
        return (_VERSION, msg.x, msg.y, msg.theta, msg.stamp)
    if isinstance(msg, State):
        return (_STATE_VERSION, msg.x, msg.y, msg.ux, msg.uy, msg.theta, msg.stamp)
    if isinstance(msg, Cmd) and msg.ax is not None:
        return (_CMD_ACCEL_VERSION, msg.v, msg.omega, msg.ux, msg.uy, msg.ax, msg.ay, msg.stamp)
    if isinstance(msg, Cmd):
        return (_VERSION, msg.v, msg.omega, msg.ux, msg.uy, msg.stamp)
    if isinstance(msg, EllipseMsg) and msg.points:
        return (_ELLIPSE_POINTS_VERSION, *_ellipse_fields_v2(msg))
    if isinstance(msg, EllipseMsg):
        return (_VERSION, *_ellipse_fields(msg))
    if isinstance(msg, Others):
        v2 = any(e.points for e in msg.ellipses) or (msg.own is not None and bool(msg.own.points))
        fields_of = _ellipse_fields_v2 if v2 else _ellipse_fields
        own = [] if msg.own is None else [fields_of(msg.own)]
        return (
            _ELLIPSE_POINTS_VERSION if v2 else _VERSION,
            msg.formation,
            msg.stamp,
            [fields_of(e) for e in msg.ellipses],
            own,
        )
    if isinstance(msg, Obstacles) and msg.shapes:
        return (
            _SHAPES_VERSION,
            msg.stamp,
            [(o.id, o.x, o.y, o.vx, o.vy, o.ds) for o in msg.obstacles],
            [(sh.id, UInt8(sh.kind), sh.cx, sh.cy, sh.hx, sh.hy, sh.yaw, sh.ds) for sh in msg.shapes],
        )
    if isinstance(msg, Obstacles):
        return (
            _VERSION,
            msg.stamp,
            [(o.id, o.x, o.y, o.vx, o.vy, o.ds) for o in msg.obstacles],
        )
    raise ValueError(f"msg must be one of the wire payload types, got {type(msg).__name__}")


def encode(msg: Message) -> bytes:
    """Serialize ``msg`` (see the module docstring for the layout)."""
    return z_serialize(_wire_tuple(msg)).to_bytes()


def encode_zbytes(msg: Message) -> zenoh.ZBytes:
    """Like :func:`encode`, as the ``zenoh.ZBytes`` a publisher puts without another copy."""
    return z_serialize(_wire_tuple(msg))


# --- decoding (wire.reader: the defensive cursor) ---------------------------------------------


def _read_ellipse(r: Reader, name: str, index: int | None = None) -> Item:
    """An ellipse without the version (``name[index]`` in error messages)."""
    return r.item(FLOATS[9], name, index, "formation")


def _read_obstacle(r: Reader, index: int) -> Item:
    return r.item(FLOATS[5], "obstacles", index, "id")


def _read_shape(r: Reader, index: int) -> ShapeMsg:
    what = f"shapes[{index}]"
    ident = r.string(f"{what}.id")
    kind = r.u8(f"{what}.kind")
    return ShapeMsg(ident, kind, *r.floats(6, what))


def _parse_pose(r: Reader) -> Pose:
    return Pose(*r.floats(4, "pose"))


def _parse_state(r: Reader) -> State:
    x, y, ux, uy, theta, stamp = r.floats(6, "state")
    return State(x, y, ux, uy, stamp, theta)


def _parse_cmd(r: Reader) -> Cmd:
    return Cmd(*r.floats(5, "cmd"))


def _parse_cmd_accel(r: Reader) -> Cmd:
    """Version 2: a double integrator's command with its acceleration."""
    v, omega, ux, uy, ax, ay, stamp = r.floats(7, "cmd")
    return Cmd(v, omega, ux, uy, stamp, ax, ay)


_CMD_PARSERS = {WIRE_VERSION: _parse_cmd, CMD_ACCEL_VERSION: _parse_cmd_accel}


def _parse_ellipse(r: Reader) -> EllipseMsg:
    return _ellipses([_read_ellipse(r, "ellipse")])[0]


def _parse_ellipse_points(r: Reader) -> EllipseMsg:
    """Version 2: the ellipse as in version 1, then its points."""
    item = _read_ellipse(r, "ellipse")
    return _ellipses([item], [r.points("ellipse")])[0]


_ELLIPSE_PARSERS = {WIRE_VERSION: _parse_ellipse, ELLIPSE_POINTS_VERSION: _parse_ellipse_points}


def _parse_others(r: Reader, with_points: bool = False) -> Others:
    formation = r.string("formation")
    (stamp,) = r.floats(1, "stamp")
    n = r.count("ellipses", MAX_ITEMS)
    items: list[Item] = []
    points: list[Points] | None = [] if with_points else None
    for i in range(n):
        items.append(_read_ellipse(r, "ellipses", i))
        if points is not None:
            points.append(r.points("ellipses", i))
    n_own = r.count("own", 1)
    if n_own:
        items.append(_read_ellipse(r, "own"))
        if points is not None:
            points.append(r.points("own"))
    built = _ellipses(items, points)
    ellipses, own = (built[:-1], built[-1]) if n_own else (built, None)
    names = {e.formation for e in ellipses}
    if (formation in _VALID_IDS and _isfinite(stamp) and len(names) == n
            and formation not in names and (own is None or own.formation == formation)):
        return _build_trusted(Others, _OTHERS_SETTERS, (formation, stamp, ellipses, own))
    return Others(formation, stamp, ellipses, own)


def _parse_obstacles(r: Reader) -> Obstacles:
    (stamp,) = r.floats(1, "stamp")
    n = r.count("obstacles", MAX_ITEMS)
    items = [_read_obstacle(r, i) for i in range(n)]
    obstacles = _build_items(ObstacleMsg, _OBSTACLE_SETTERS, items, _ds_not_negative)
    if _isfinite(stamp) and len({o.id for o in obstacles}) == n:
        return _build_trusted(Obstacles, _OBSTACLES_SETTERS, (stamp, obstacles, ()))
    return Obstacles(stamp, obstacles)


def _parse_obstacles_with_shapes(r: Reader) -> Obstacles:
    """Version 2: the circles as in version 1, then the walls and shelves."""
    (stamp,) = r.floats(1, "stamp")
    n = r.count("obstacles", MAX_ITEMS)
    items = [_read_obstacle(r, i) for i in range(n)]
    obstacles = _build_items(ObstacleMsg, _OBSTACLE_SETTERS, items, _ds_not_negative)
    m = r.count("shapes", MAX_ITEMS - n)
    return Obstacles(stamp, obstacles, tuple(_read_shape(r, i) for i in range(m)))


_OBSTACLES_PARSERS = {WIRE_VERSION: _parse_obstacles, SHAPES_VERSION: _parse_obstacles_with_shapes}
_OTHERS_PARSERS: dict[int, Callable[[Reader], Others]] = {
    WIRE_VERSION: _parse_others,
    ELLIPSE_POINTS_VERSION: functools.partial(_parse_others, with_points=True),
}


def decode_pose(payload: bytes | zenoh.ZBytes) -> Pose:
    """Decode a ``pose`` payload; raises only :class:`DecodeError`."""
    return decode_payload(payload, _parse_pose, "pose")


def decode_state(payload: bytes | zenoh.ZBytes) -> State:
    """Decode a ``state`` payload; raises only :class:`DecodeError`."""
    return decode_payload(payload, _parse_state, "state", STATE_VERSION)


def decode_cmd(payload: bytes | zenoh.ZBytes) -> Cmd:
    """Decode a ``cmd`` payload; raises only :class:`DecodeError`."""
    return decode_payload(payload, _parse_cmd, "cmd", parsers=_CMD_PARSERS)


def decode_ellipse(payload: bytes | zenoh.ZBytes) -> EllipseMsg:
    """Decode an ``ellipse`` payload; raises only :class:`DecodeError`."""
    return decode_payload(payload, _parse_ellipse, "ellipse", parsers=_ELLIPSE_PARSERS)


def decode_others(payload: bytes | zenoh.ZBytes) -> Others:
    """Decode an ``others`` payload; raises only :class:`DecodeError`."""
    return decode_payload(payload, _parse_others, "others", parsers=_OTHERS_PARSERS)


def decode_obstacles(payload: bytes | zenoh.ZBytes) -> Obstacles:
    """Decode an ``obstacles`` payload; raises only :class:`DecodeError`."""
    return decode_payload(payload, _parse_obstacles, "obstacles", parsers=_OBSTACLES_PARSERS)


#: The decoder of each key class (see :func:`wire.keys.key_class`).
DECODERS: dict[str, Callable[[bytes | zenoh.ZBytes], Any]] = {
    keys.POSE: decode_pose,
    keys.STATE: decode_state,
    keys.CMD: decode_cmd,
    keys.ELLIPSE: decode_ellipse,
    keys.BEACON: decode_ellipse,
    keys.OTHERS: decode_others,
    keys.OBSTACLES: decode_obstacles,
}


# --- navigation: goal, plan, status (DESIGN.md key space) ------------------------------------
#
# ``GoalMsg``    version, formation:str, x, y, heading:list[f64] (0 or 1), waypoints:list[(x, y)],
#                stamp
# ``PlanMsg``    version, formation:str, goal_stamp, cx, cy, heading:list[f64] (0 or 1),
#                route:list[(x, y)], members:list[(id:str, gx, gy)], stamp
# ``StatusMsg``  version, formation:str, state:str, leader:str, goal_stamp, gx, gy,
#                heading:list[f64] (0 or 1), distance, waypoint, waypoints, wx, wy, stamp
#                version 2 (:data:`STATUS_VERSION`) adds: reason:str, refused, refusal:str,
#                fleet:list[str]
# ``GoalMsg`` and ``PlanMsg`` version 2 (:data:`ROUTE_VERSION`) add, after the stamp:
#                headings:list[list[f64] (0 or 1)], one per waypoint or route point
#
# ``goal_stamp`` names a goal: the stamp the leader gave it when it accepted it (the fleet
# manager's stamp in real time, simulated time on arrival in lock-step). A member adopts a plan
# whose goal_stamp is newer than the one it follows. ``waypoint`` and ``waypoints`` (the index
# of the current waypoint and the route's length; the goal is the last) are whole numbers
# carried as f64.

MAX_WAYPOINTS = 64  # most waypoints in a goal or route
STATUS_STATES = ("moving", "reached", "stalled", "stopped", "unreachable")
MAX_REASON = 200  # longest reason or refusal [characters]; a longer one is cut by the writer
MAX_REFUSED = 2**31 - 1  # the refused-goal count saturates here (the writer clamps it)


def _points(value: object, name: str, limit: int) -> tuple[tuple[float, float], ...]:
    pts = tuple(tuple(p) for p in value)  # type: ignore[attr-defined]
    if len(pts) > limit:
        raise ValueError(f"{name} must hold at most {limit} points, got {len(pts)}")
    out = []
    for k, p in enumerate(pts):
        if len(p) != 2:
            raise ValueError(f"{name}[{k}] must be (x, y), got {p!r}")
        x, y = p
        for v in (x, y):
            if isinstance(v, bool) or not isinstance(v, numbers.Real) or not math.isfinite(v):
                raise ValueError(f"{name}[{k}] must hold finite numbers, got {p!r}")
        out.append((float(x), float(y)))
    return tuple(out)


def _point_headings(value: object, n: int) -> tuple[float, ...]:
    """An ellipse's ``headings``: one finite number per point."""
    hs: tuple[Any, ...] = tuple(value)  # type: ignore[arg-type]
    if len(hs) != n:
        raise ValueError(f"headings: {len(hs)} headings for {n} points")
    for k, h in enumerate(hs):
        if isinstance(h, bool) or not isinstance(h, numbers.Real) or not math.isfinite(h):
            raise ValueError(f"headings[{k}] must be a finite number, got {h!r}")
    return tuple(float(h) for h in hs)


def _headings(value: object, n: int, name: str) -> tuple[float | None, ...]:
    """A heading [rad] or None per point of ``name``; all None is stored as none at all."""
    hs: tuple[Any, ...] = tuple(value)  # type: ignore[arg-type]
    if not hs or all(h is None for h in hs):
        return ()
    if len(hs) != n:
        raise ValueError(f"{name}: {len(hs)} headings for {n} points")
    for k, h in enumerate(hs):
        if h is not None and (isinstance(h, bool) or not isinstance(h, numbers.Real)
                              or not math.isfinite(h)):
            raise ValueError(f"{name}[{k}] heading must be a finite number, got {h!r}")
    return tuple(None if h is None else float(h) for h in hs)


def _optional_angle(obj: object, name: str) -> None:
    value = getattr(obj, name)
    if value is not None:
        _finite(obj, name)


@dataclass(frozen=True, slots=True)
class GoalMsg:
    """A new goal for a formation: ``{prefix}/formation/{fid}/goal`` (fleet manager -> leader).

    Centroid ``x, y`` [m]; ``heading`` [rad] turns the formation's goal shape (the shape as
    written in the scenario's goals is heading 0), ``None`` keeps the current one; the centroid
    passes ``waypoints`` in order first (none: the leader plans a route); ``stamp`` [s]."""

    formation: str
    x: float
    y: float
    heading: float | None = None
    waypoints: tuple[tuple[float, float], ...] = ()
    stamp: float = 0.0
    headings: tuple[float | None, ...] = ()  # none, or one per waypoint (version 2)

    def __post_init__(self) -> None:
        _check_id(self.formation, "formation")
        _check_floats(self, ("x", "y", "stamp"))
        _optional_angle(self, "heading")
        object.__setattr__(self, "waypoints", _points(self.waypoints, "waypoints", MAX_WAYPOINTS))
        object.__setattr__(self, "headings", _headings(self.headings, len(self.waypoints),
                                                       "waypoints"))


@dataclass(frozen=True, slots=True)
class PlanMsg:
    """A leader's plan for its members: ``{prefix}/formation/{fid}/plan``: the goal it follows
    (``goal_stamp``, centroid, heading), the centroid's route (the goal last) and each member's
    goal ``(id, x, y)``."""

    formation: str
    goal_stamp: float
    cx: float
    cy: float
    heading: float | None
    route: tuple[tuple[float, float], ...]
    members: tuple[tuple[str, float, float], ...]
    stamp: float
    headings: tuple[float | None, ...] = ()  # none, or one per route point (version 2)

    def __post_init__(self) -> None:
        _check_id(self.formation, "formation")
        _check_floats(self, ("goal_stamp", "cx", "cy", "stamp"))
        _optional_angle(self, "heading")
        route = _points(self.route, "route", MAX_WAYPOINTS)
        if not route:
            raise ValueError("route must hold at least the goal")
        object.__setattr__(self, "route", route)
        object.__setattr__(self, "headings", _headings(self.headings, len(route), "route"))
        members = tuple(tuple(m) for m in self.members)
        if len(members) > MAX_ITEMS:
            raise ValueError(f"members must hold at most {MAX_ITEMS} entries, got {len(members)}")
        seen: set[str] = set()
        out = []
        for k, m in enumerate(members):
            if len(m) != 3:
                raise ValueError(f"members[{k}] must be (id, x, y), got {m!r}")
            rid = m[0]
            _check_id(rid, f"members[{k}].id")
            assert isinstance(rid, str)  # _check_id accepts only a str
            if rid in seen:
                raise ValueError(f"members repeat id {rid!r}")
            seen.add(rid)
            out.append((rid, *_points([m[1:]], f"members[{k}]", 1)[0]))
        object.__setattr__(self, "members", tuple(out))

    def goal_of(self, robot_id: str) -> tuple[float, float] | None:
        for rid, x, y in self.members:
            if rid == robot_id:
                return (x, y)
        return None


@dataclass(frozen=True, slots=True)
class StatusMsg:
    """A leader's report: ``{prefix}/formation/{fid}/status`` (published about once a second
    and answered as a queryable). ``state`` is one of :data:`STATUS_STATES`; the goal it
    follows (``goal_stamp``, centroid, heading), the centroid's ``distance`` to go along the
    route [m], the current waypoint (index, route length, position) and the leader's id.
    Version 2 (:data:`STATUS_VERSION`): ``reason`` why the state (``unreachable``: why no route
    reaches the goal), ``refused`` goals the leader refused since it started and ``refusal``, why
    it refused the last one, and ``fleet``, every formation of the leader's scenario (its own
    included; () where not said)."""

    formation: str
    state: str
    leader: str
    goal_stamp: float
    gx: float
    gy: float
    heading: float | None
    distance: float
    waypoint: int
    waypoints: int
    wx: float
    wy: float
    stamp: float
    reason: str = ""
    refused: int = 0
    refusal: str = ""
    fleet: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        _check_id(self.formation, "formation")
        _check_id(self.leader, "leader")
        fleet = tuple(self.fleet)
        if len(fleet) > MAX_ITEMS:
            raise ValueError(f"fleet must name at most {MAX_ITEMS} formations, got {len(fleet)}")
        for k, name in enumerate(fleet):
            _check_id(name, f"fleet[{k}]")
        object.__setattr__(self, "fleet", fleet)
        for name in ("reason", "refusal"):
            text = getattr(self, name)
            if not isinstance(text, str) or len(text) > MAX_REASON:
                raise ValueError(f"{name} must be text of at most {MAX_REASON} characters")
        if self.state not in STATUS_STATES:
            raise ValueError(f"state must be one of {STATUS_STATES}, got {self.state!r}")
        _check_floats(self, ("goal_stamp", "gx", "gy", "distance", "wx", "wy", "stamp"))
        _optional_angle(self, "heading")
        for name in ("waypoint", "waypoints", "refused"):
            v = getattr(self, name)
            if isinstance(v, float) and v.is_integer():
                v = int(v)
                object.__setattr__(self, name, v)
            limit = MAX_REFUSED if name == "refused" else MAX_WAYPOINTS
            if type(v) is not int or not 0 <= v <= limit:
                raise ValueError(f"{name} must be a whole number in [0, {limit}], got {v!r}")
        if self.distance < 0.0:
            raise ValueError(f"distance must be >= 0, got {self.distance!r}")


def _heading_list(h: float | None) -> list[float]:
    return [] if h is None else [h]


def encode_nav(msg: GoalMsg | PlanMsg | StatusMsg) -> bytes:
    """Serialize a goal, plan or status (layouts above)."""
    if isinstance(msg, GoalMsg):
        t: tuple[Any, ...] = (_VERSION, msg.formation, msg.x, msg.y, _heading_list(msg.heading),
                              list(msg.waypoints), msg.stamp)
        if msg.headings:
            t = (_ROUTE_VERSION, *t[1:], [_heading_list(h) for h in msg.headings])
    elif isinstance(msg, PlanMsg):
        t = (_VERSION, msg.formation, msg.goal_stamp, msg.cx, msg.cy, _heading_list(msg.heading),
             list(msg.route), list(msg.members), msg.stamp)
        if msg.headings:
            t = (_ROUTE_VERSION, *t[1:], [_heading_list(h) for h in msg.headings])
    elif isinstance(msg, StatusMsg):
        t = (_VERSION, msg.formation, msg.state, msg.leader, msg.goal_stamp, msg.gx, msg.gy,
             _heading_list(msg.heading), msg.distance, float(msg.waypoint), float(msg.waypoints),
             msg.wx, msg.wy, msg.stamp)
        if msg.state == "unreachable" or msg.reason or msg.refused or msg.refusal or msg.fleet:
            t = (_STATUS_VERSION, *t[1:], msg.reason, float(msg.refused), msg.refusal,
                 list(msg.fleet))
    else:
        raise ValueError(f"msg must be a GoalMsg, PlanMsg or StatusMsg, got {type(msg).__name__}")
    return z_serialize(t).to_bytes()


def _read_heading(r: Reader) -> float | None:
    n = r.count("heading", 1)
    return r.floats(1, "heading")[0] if n else None


def _read_points(r: Reader, name: str) -> list[tuple[float, float]]:
    n = r.count(name, MAX_WAYPOINTS)
    return [r.floats(2, f"{name}[{k}]") for k in range(n)]  # type: ignore[misc]


def _read_headings(r: Reader, name: str) -> tuple[float | None, ...]:
    n = r.count(name, MAX_WAYPOINTS)
    return tuple(_read_heading(r) for _ in range(n))


def _parse_goal(r: Reader, version: int = WIRE_VERSION) -> GoalMsg:
    formation = r.string("formation")
    x, y = r.floats(2, "x, y")
    heading = _read_heading(r)
    waypoints = _read_points(r, "waypoints")
    (stamp,) = r.floats(1, "stamp")
    headings = _read_headings(r, "headings") if version >= ROUTE_VERSION else ()
    return GoalMsg(formation, x, y, heading, tuple(waypoints), stamp, headings)


def _parse_goal_v2(r: Reader) -> GoalMsg:
    return _parse_goal(r, ROUTE_VERSION)


def _parse_plan_v2(r: Reader) -> PlanMsg:
    return _parse_plan(r, ROUTE_VERSION)


def _parse_plan(r: Reader, version: int = WIRE_VERSION) -> PlanMsg:
    formation = r.string("formation")
    goal_stamp, cx, cy = r.floats(3, "goal_stamp, cx, cy")
    heading = _read_heading(r)
    route = _read_points(r, "route")
    n = r.count("members", MAX_ITEMS)
    members: list[tuple[str, float, float]] = []
    for k in range(n):
        rid = r.string(f"members[{k}].id")
        x, y = r.floats(2, f"members[{k}]")
        members.append((rid, x, y))
    (stamp,) = r.floats(1, "stamp")
    headings = _read_headings(r, "headings") if version >= ROUTE_VERSION else ()
    return PlanMsg(formation, goal_stamp, cx, cy, heading, tuple(route), tuple(members), stamp,
                   headings)


def _parse_status(r: Reader, version: int = WIRE_VERSION) -> StatusMsg:
    formation = r.string("formation")
    state = r.string("state")
    leader = r.string("leader")
    goal_stamp, gx, gy = r.floats(3, "goal_stamp, gx, gy")
    heading = _read_heading(r)
    distance, waypoint, waypoints, wx, wy, stamp = r.floats(6, "distance .. stamp")
    reason, refused, refusal = "", 0.0, ""
    fleet: tuple[str, ...] = ()
    if version >= STATUS_VERSION:
        reason = r.string("reason")
        (refused,) = r.floats(1, "refused")
        refusal = r.string("refusal")
        n = r.count("fleet", MAX_ITEMS)
        fleet = tuple(r.string(f"fleet[{k}]") for k in range(n))
    # whole numbers carried as f64: StatusMsg checks them and makes them ints
    return StatusMsg(formation, state, leader, goal_stamp, gx, gy, heading, distance,
                     waypoint, waypoints, wx, wy, stamp, reason, refused, refusal,  # type: ignore[arg-type]
                     fleet)


def _parse_status_v2(r: Reader) -> StatusMsg:
    return _parse_status(r, STATUS_VERSION)


def decode_goal(payload: bytes | zenoh.ZBytes) -> GoalMsg:
    """Decode a ``goal`` payload; raises only :class:`DecodeError`."""
    return decode_payload(payload, _parse_goal, "goal",
                   parsers={WIRE_VERSION: _parse_goal, ROUTE_VERSION: _parse_goal_v2})


def decode_plan(payload: bytes | zenoh.ZBytes) -> PlanMsg:
    """Decode a ``plan`` payload; raises only :class:`DecodeError`."""
    return decode_payload(payload, _parse_plan, "plan",
                   parsers={WIRE_VERSION: _parse_plan, ROUTE_VERSION: _parse_plan_v2})


def decode_status(payload: bytes | zenoh.ZBytes) -> StatusMsg:
    """Decode a ``status`` payload; raises only :class:`DecodeError`."""
    return decode_payload(payload, _parse_status, "status",
                   parsers={WIRE_VERSION: _parse_status, STATUS_VERSION: _parse_status_v2})


DECODERS.update({keys.GOAL: decode_goal, keys.PLAN: decode_plan, keys.STATUS: decode_status})
