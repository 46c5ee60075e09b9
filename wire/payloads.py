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
``EllipseMsg`` version 3, the same as version 2, then sigma                            varies
``Others``     version, formation:str, stamp, ellipses:list[E], own:list[E] (0 or 1)  varies
``Others``     version 2, the same with every ``E`` followed by its points and headings varies
``Others``     version 3, as version 2 with every ``E`` then followed by sigma:list[f64] (0 or 1)
``EllipseMsg`` version 4, formation:str, ..., stamp, points, headings, sigma:list, parked:u8 varies
``Others``     version 4, as version 3 with every ``E`` then followed by parked:u8              varies
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
byte for byte as before), and their decoders accept both; an ``EllipseMsg`` with a
confidence radius ``sigma``, or an ``Others`` any of whose ellipses has one, is written as
:data:`ELLIPSE_SIGMA_VERSION` (without one: as before, byte for byte); an ``EllipseMsg`` of a
formation parked at its goal, or an ``Others`` any of whose ellipses is, is written as
:data:`ELLIPSE_PARKED_VERSION`: every ellipse as an ``Others`` version 3 writes it (its sigma a
list of 0 or 1), then ``parked`` as a ``u8`` (1 parked, 0 not; any other byte is malformed);
without a parked ellipse: as before, byte for byte. Units: metres,
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
import struct
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
#: ``state`` version 3 adds the sender's confidence radius ``sigma`` (its own estimate under
#: ``controller.localisation: fused``); states without one stay version 2, byte for byte, and
#: both versions decode
STATE_SIGMA_VERSION = 3
CMD_ACCEL_VERSION = 2  # Cmd with a double integrator's acceleration (ax, ay)
#: ``ellipse`` and ``others`` version 2 carry each ellipse's members' control points (
#: a formation keeps its own ellipse off the other formations' members, :mod:`agent.body`).
ELLIPSE_POINTS_VERSION = 2
#: ``ellipse`` and ``others`` version 3 add each ellipse's ``sigma``: the largest confidence
#: radius among its formation's members under ``controller.localisation: fused``, which the
#: other formations' margins hold (:func:`agent.margins.heard_radius`)
ELLIPSE_SIGMA_VERSION = 3
#: ``ellipse`` and ``others`` version 4 add each ellipse's ``parked``: its formation stands at
#: its goal (:func:`agent.control.yield_command` never backs away from it)
ELLIPSE_PARKED_VERSION = 4
MAX_ITEMS = 256  # most ellipses (or obstacles) one payload may carry


def check_finite(obj: object, name: str) -> None:
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


def check_id(value: object, name: str) -> None:
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


def check_sigma(obj: Any) -> None:
    """``obj.sigma``, a confidence radius [m], is a finite float >= 0 (ValueError naming it)."""
    check_floats(obj, ("sigma",))
    if obj.sigma < 0.0:
        raise ValueError(f"sigma: must be >= 0, got {obj.sigma!r}")


def check_floats(obj: object, names: Iterable[str]) -> None:
    """Check the float fields ``names`` of ``obj`` like :func:`check_finite`.

    The fast path accepts a plain finite ``float`` as it is (what every decoder and nearly every
    caller passes: ``float(v)`` of it is ``v``); anything else takes :func:`check_finite`, which
    converts it or raises, so the behaviour is the same either way. The messages' constructors
    try :func:`_plain_finite` first and call this only when it fails."""
    for name in names:
        value = getattr(obj, name)
        if type(value) is not float or not _isfinite(value):
            check_finite(obj, name)


def _plain_points(value: object, limit: int) -> bool:
    """Whether ``value`` is already what :func:`points_field` makes of it: a tuple of at most
    ``limit`` pairs of plain finite floats (what a leader's own ellipse carries each tick)."""
    if type(value) is not tuple or len(value) > limit:
        return False
    total = 0.0
    for p in value:
        if type(p) is not tuple or len(p) != 2:
            return False
        x, y = p
        if type(x) is not float or type(y) is not float:
            return False
        total += x + y
    return _isfinite(total)


def points_field(value: object, name: str, limit: int) -> tuple[tuple[float, float], ...]:
    if _plain_points(value, limit):
        return value  # type: ignore[return-value]
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
    if _plain_finite(hs):
        return hs
    for k, h in enumerate(hs):
        if isinstance(h, bool) or not isinstance(h, numbers.Real) or not math.isfinite(h):
            raise ValueError(f"headings[{k}] must be a finite number, got {h!r}")
    return tuple(float(h) for h in hs)


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
            check_floats(self, _POSE_FLOATS)


@dataclass(frozen=True, slots=True)
class State:
    """Position and current single-integrator command of one robot: ``.../state``.

    [m, m, m/s, m/s, s, rad]; neighbours use ``ux, uy`` as the velocity of appendix A.2 and
    of the separation rows, ``theta`` (the body heading, wire version 2: :data:`STATE_VERSION`)
    to place a unicycle's body behind its look-ahead point ``x, y``; ``sigma`` [m], the 95 %
    confidence radius of ``x, y`` when the sender drives on its own estimate (wire version
    :data:`STATE_SIGMA_VERSION`; None: the camera's pose).
    """

    x: float
    y: float
    ux: float
    uy: float
    stamp: float
    theta: float = 0.0
    sigma: float | None = None

    def __post_init__(self) -> None:
        if not _plain_finite((self.x, self.y, self.ux, self.uy, self.stamp, self.theta)):
            check_floats(self, _STATE_FLOATS)
        if self.sigma is not None:
            check_sigma(self)


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
            check_floats(self, _CMD_FLOATS)
        if self.ax is not None or self.ay is not None:
            check_floats(self, ("ax", "ay"))


_ELLIPSE_FLOATS = ("cx", "cy", "alpha", "a", "b", "vx", "vy", "alpha_rate", "stamp")


@dataclass(frozen=True, slots=True)
class EllipseMsg:
    """One formation's bounding ellipse: ``{prefix}/formation/{fid}/ellipse``.

    Centroid ``cx, cy`` [m], orientation ``alpha`` [rad], semi-axes ``a, b`` [m], centroid
    velocity ``vx, vy`` [m/s], ``alpha_rate`` [rad/s], ``stamp`` [s] (eq. 4.6, appendix A.3);
    ``points`` [m]: the members' control points it was estimated from (none from a sender that
    predates them; wire version :data:`ELLIPSE_POINTS_VERSION`); ``headings`` [rad]: their body
    headings, none or one per point (a formation of unicycles waits for its members to face its
    motion: :func:`agent.body.pace`); ``sigma`` [m]: the largest 95 % confidence radius among
    the members' estimates it was fitted from (wire version :data:`ELLIPSE_SIGMA_VERSION`;
    None: the camera's poses); ``parked``: the formation stands at its goal, holding (its
    leader's :func:`leader.navigation.at_goal`; wire version :data:`ELLIPSE_PARKED_VERSION`).
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
    sigma: float | None = None
    parked: bool = False

    def __post_init__(self) -> None:
        check_id(self.formation, "formation")
        if type(self.parked) is not bool:
            raise ValueError(f"parked must be a bool, got {type(self.parked).__name__}")
        if not _plain_finite((self.cx, self.cy, self.alpha, self.a, self.b, self.vx, self.vy,
                              self.alpha_rate, self.stamp)):
            check_floats(self, _ELLIPSE_FLOATS)
        if self.a <= 0.0:
            raise ValueError(f"a must be > 0, got {self.a!r}")
        if self.b <= 0.0:
            raise ValueError(f"b must be > 0, got {self.b!r}")
        if self.points != ():
            object.__setattr__(self, "points", points_field(self.points, "points", MAX_POINTS))
        if self.headings != ():
            object.__setattr__(self, "headings", _point_headings(self.headings, len(self.points)))
        if self.sigma is not None:
            check_sigma(self)


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
        check_id(self.formation, "formation")
        check_floats(self, _STAMP)
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
        check_id(self.id, "id")
        if not _plain_finite((self.x, self.y, self.vx, self.vy, self.ds)):
            check_floats(self, _OBSTACLE_FLOATS)
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
        check_id(self.id, "id")
        if type(self.kind) is not int or self.kind not in (SHAPE_SEGMENT, SHAPE_BOX):
            raise ValueError(f"kind must be {SHAPE_SEGMENT} (segment) or {SHAPE_BOX} (box), "
                             f"got {self.kind!r}")
        check_floats(self, _SHAPE_FLOATS)
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
        check_floats(self, _STAMP)
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
_ELLIPSE_V1_SETTERS = _ELLIPSE_SETTERS[:10]  # formation to stamp: the version-1 fields
# the later versions' fields, which a trusted build sets itself
_PUT_POINTS, _PUT_HEADINGS, _PUT_SIGMA, _PUT_PARKED = _ELLIPSE_SETTERS[10:]
_OBSTACLE_SETTERS = _slot_setters(ObstacleMsg)
_OTHERS_SETTERS = _slot_setters(Others)
_OBSTACLES_SETTERS = _slot_setters(Obstacles)
_SET_POSE = _slot_setters(Pose)
_SET_STATE = _slot_setters(State)
_SET_CMD = _slot_setters(Cmd)


# --- the messages of every tick, made from plain floats ---------------------------------------
#
# What a tick sends (its state and command) and what it decodes most (poses, states) are plain
# floats already; these build the message with the same check its constructor runs (every
# value a plain finite float, in one sum) and fall back to the constructor for anything else,
# which converts or raises as usual.


def new_pose(x: float, y: float, theta: float, stamp: float) -> Pose:
    """``Pose(x, y, theta, stamp)``."""
    if type(x) is float and type(y) is float and type(theta) is float \
            and type(stamp) is float and _isfinite(x + y + theta + stamp):
        msg = _new(Pose)
        px, py, pth, pst = _SET_POSE
        px(msg, x)
        py(msg, y)
        pth(msg, theta)
        pst(msg, stamp)
        return msg
    return Pose(x, y, theta, stamp)


def new_state(x: float, y: float, ux: float, uy: float, stamp: float, theta: float = 0.0
              ) -> State:
    """``State(x, y, ux, uy, stamp, theta)`` (no sigma)."""
    if type(x) is float and type(y) is float and type(ux) is float and type(uy) is float \
            and type(stamp) is float and type(theta) is float \
            and _isfinite(x + y + ux + uy + stamp + theta):
        msg = _new(State)
        sx, sy, sux, suy, sst, sth, ssg = _SET_STATE
        sx(msg, x)
        sy(msg, y)
        sux(msg, ux)
        suy(msg, uy)
        sst(msg, stamp)
        sth(msg, theta)
        ssg(msg, None)
        return msg
    return State(x, y, ux, uy, stamp, theta)


def new_cmd(v: float, omega: float, ux: float, uy: float, stamp: float) -> Cmd:
    """``Cmd(v, omega, ux, uy, stamp)`` (no acceleration)."""
    if type(v) is float and type(omega) is float and type(ux) is float and type(uy) is float \
            and type(stamp) is float and _isfinite(v + omega + ux + uy + stamp):
        msg = _new(Cmd)
        cv, cw, cux, cuy, cst, cax, cay = _SET_CMD
        cv(msg, v)
        cw(msg, omega)
        cux(msg, ux)
        cuy(msg, uy)
        cst(msg, stamp)
        cax(msg, None)
        cay(msg, None)
        return msg
    return Cmd(v, omega, ux, uy, stamp)


def _ellipses(items: list[Item], points: list[Points] | None = None,
              sigmas: list[float | None] | None = None,
              parked: list[bool] | None = None) -> tuple[EllipseMsg, ...]:
    """The ellipses of decoded items, each with its ``points`` and ``headings`` (version 2;
    read by :meth:`wire.reader.Reader.points`, so already pairs of floats and as many headings as points:
    only their finiteness is checked), its ``sigma`` (version 3; checked here) and whether it
    is ``parked`` (version 4; read by :func:`_read_parked`, so already a bool)."""
    built = _ellipses_without_sigma(items, points)
    if sigmas is None:
        for msg in built:  # a trusted build leaves the slots unset
            _PUT_SIGMA(msg, None)
            _PUT_PARKED(msg, False)
        return built
    for msg, sigma in zip(built, sigmas, strict=True):
        _PUT_SIGMA(msg, sigma)
        if sigma is not None:
            check_sigma(msg)
    for msg, flag in zip(built, parked or [False] * len(built), strict=True):
        _PUT_PARKED(msg, flag)
    return built


def _ellipses_without_sigma(items: list[Item], points: list[Points] | None
                            ) -> tuple[EllipseMsg, ...]:
    put_points, put_headings = _PUT_POINTS, _PUT_HEADINGS
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
_STATE_SIGMA_VERSION = UInt8(STATE_SIGMA_VERSION)
_CMD_ACCEL_VERSION = UInt8(CMD_ACCEL_VERSION)
_ELLIPSE_POINTS_VERSION = UInt8(ELLIPSE_POINTS_VERSION)
_ELLIPSE_SIGMA_VERSION = UInt8(ELLIPSE_SIGMA_VERSION)
_ELLIPSE_PARKED_VERSION = UInt8(ELLIPSE_PARKED_VERSION)
_PARKED = (UInt8(0), UInt8(1))  # parked:u8 by the flag


def _ellipse_fields(e: EllipseMsg) -> tuple[Any, ...]:
    return (e.formation, e.cx, e.cy, e.alpha, e.a, e.b, e.vx, e.vy, e.alpha_rate, e.stamp)


def _ellipse_fields_v2(e: EllipseMsg) -> tuple[Any, ...]:
    return (*_ellipse_fields(e), list(e.points), list(e.headings))


def _ellipse_fields_v3(e: EllipseMsg) -> tuple[Any, ...]:
    """Version 3 in an ``others``: version 2, then sigma as a list of 0 or 1."""
    return (*_ellipse_fields_v2(e), [] if e.sigma is None else [float(e.sigma)])


def _ellipse_fields_v4(e: EllipseMsg) -> tuple[Any, ...]:
    """Version 4 (an ``ellipse`` and an ``others``): version 3 as an ``others`` writes it, then
    parked."""
    return (*_ellipse_fields_v3(e), _PARKED[e.parked])


def _pose_tuple(msg: Pose) -> tuple[Any, ...]:
    return (_VERSION, msg.x, msg.y, msg.theta, msg.stamp)


def _state_tuple(msg: State) -> tuple[Any, ...]:
    if msg.sigma is not None:
        return (_STATE_SIGMA_VERSION, msg.x, msg.y, msg.ux, msg.uy, msg.theta, msg.stamp,
                msg.sigma)
    return (_STATE_VERSION, msg.x, msg.y, msg.ux, msg.uy, msg.theta, msg.stamp)


def _cmd_tuple(msg: Cmd) -> tuple[Any, ...]:
    if msg.ax is not None:
        return (_CMD_ACCEL_VERSION, msg.v, msg.omega, msg.ux, msg.uy, msg.ax, msg.ay, msg.stamp)
    return (_VERSION, msg.v, msg.omega, msg.ux, msg.uy, msg.stamp)


def _ellipse_msg_tuple(msg: EllipseMsg) -> tuple[Any, ...]:
    if msg.parked:
        return (_ELLIPSE_PARKED_VERSION, *_ellipse_fields_v4(msg))
    if msg.sigma is not None:
        return (_ELLIPSE_SIGMA_VERSION, *_ellipse_fields_v2(msg), float(msg.sigma))
    if msg.points:
        return (_ELLIPSE_POINTS_VERSION, *_ellipse_fields_v2(msg))
    return (_VERSION, *_ellipse_fields(msg))


def _others_tuple(msg: Others) -> tuple[Any, ...]:
    every = msg.ellipses if msg.own is None else (*msg.ellipses, msg.own)
    version, fields_of = _VERSION, _ellipse_fields
    if any(e.parked for e in every):
        version, fields_of = _ELLIPSE_PARKED_VERSION, _ellipse_fields_v4
    elif any(e.sigma is not None for e in every):
        version, fields_of = _ELLIPSE_SIGMA_VERSION, _ellipse_fields_v3
    elif any(e.points for e in every):
        version, fields_of = _ELLIPSE_POINTS_VERSION, _ellipse_fields_v2
    own = [] if msg.own is None else [fields_of(msg.own)]
    return (
        version,
        msg.formation,
        msg.stamp,
        [fields_of(e) for e in msg.ellipses],
        own,
    )


#: the messages sent every tick (a leader's ellipse and others among them) -> their wire
#: tuple, found by the exact type (the rest, and subclasses, by :func:`_wire_tuple`'s chain)
_TICK_TUPLES: dict[type, Callable[[Any], tuple[Any, ...]]] = {
    Pose: _pose_tuple, State: _state_tuple, Cmd: _cmd_tuple, EllipseMsg: _ellipse_msg_tuple,
    Others: _others_tuple}


def _wire_tuple(msg: Message) -> tuple[Any, ...]:
    if isinstance(msg, Pose):
        return _pose_tuple(msg)
    if isinstance(msg, State):
        return _state_tuple(msg)
    if isinstance(msg, Cmd):
        return _cmd_tuple(msg)
    if isinstance(msg, EllipseMsg):
        return _ellipse_msg_tuple(msg)
    if isinstance(msg, Others):
        return _others_tuple(msg)
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


# The fixed-size messages of every tick (a u8 version, then f64 little-endian: the layout
# z_serialize gives their tuples) packed with struct, the same bytes at a fraction of the cost
_POSE_BYTES = struct.Struct("<B4d")
_STATE_BYTES = struct.Struct("<B6d")
_STATE_SIGMA_BYTES = struct.Struct("<B7d")
_CMD_BYTES = struct.Struct("<B5d")
_CMD_ACCEL_BYTES = struct.Struct("<B7d")


def _pose_bytes(msg: Pose) -> bytes:
    return _POSE_BYTES.pack(WIRE_VERSION, msg.x, msg.y, msg.theta, msg.stamp)


def _state_bytes(msg: State) -> bytes:
    if msg.sigma is not None:
        return _STATE_SIGMA_BYTES.pack(STATE_SIGMA_VERSION, msg.x, msg.y, msg.ux, msg.uy,
                                       msg.theta, msg.stamp, msg.sigma)
    return _STATE_BYTES.pack(STATE_VERSION, msg.x, msg.y, msg.ux, msg.uy, msg.theta, msg.stamp)


def _cmd_bytes(msg: Cmd) -> bytes:
    if msg.ax is not None:
        return _CMD_ACCEL_BYTES.pack(CMD_ACCEL_VERSION, msg.v, msg.omega, msg.ux, msg.uy, msg.ax,
                                     msg.ay, msg.stamp)
    return _CMD_BYTES.pack(WIRE_VERSION, msg.v, msg.omega, msg.ux, msg.uy, msg.stamp)


#: the fixed-size messages by exact type -> their wire bytes (subclasses take the tuple path)
_FIXED_BYTES: dict[type, Callable[[Any], bytes]] = {
    Pose: _pose_bytes, State: _state_bytes, Cmd: _cmd_bytes}


def encode(msg: Message) -> bytes:
    """Serialize ``msg`` (see the module docstring for the layout)."""
    fixed = _FIXED_BYTES.get(type(msg))
    if fixed is not None:
        return fixed(msg)
    return encode_zbytes(msg).to_bytes()


def encode_zbytes(msg: Message) -> zenoh.ZBytes:
    """Like :func:`encode`, as the ``zenoh.ZBytes`` a publisher puts without another copy."""
    fixed = _FIXED_BYTES.get(type(msg))
    if fixed is not None:
        return zenoh.ZBytes(fixed(msg))
    by_type = _TICK_TUPLES.get(type(msg))
    return z_serialize(by_type(msg) if by_type is not None else _wire_tuple(msg))


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
    return new_pose(*r.floats(4, "pose"))


def _parse_state(r: Reader) -> State:
    x, y, ux, uy, theta, stamp = r.floats(6, "state")
    return new_state(x, y, ux, uy, stamp, theta)


def _parse_state_sigma(r: Reader) -> State:
    """Version 3: a state with its sender's confidence radius."""
    x, y, ux, uy, theta, stamp, sigma = r.floats(7, "state")
    return State(x, y, ux, uy, stamp, theta, sigma)


_STATE_PARSERS = {STATE_VERSION: _parse_state, STATE_SIGMA_VERSION: _parse_state_sigma}


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


def _parse_ellipse_sigma(r: Reader) -> EllipseMsg:
    """Version 3: the ellipse as in version 2, then its confidence radius."""
    item = _read_ellipse(r, "ellipse")
    points = r.points("ellipse")
    (sigma,) = r.floats(1, "ellipse.sigma")
    return _ellipses([item], [points], [sigma])[0]


def _read_sigma(r: Reader, name: str, index: int | None = None) -> float | None:
    """An ``others`` ellipse's sigma (version 3): a list of 0 or 1 floats."""
    what = (name if index is None else f"{name}[{index}]") + ".sigma"
    return r.floats(1, what)[0] if r.count(what, 1) else None


def _read_parked(r: Reader, name: str, index: int | None = None) -> bool:
    """An ellipse's parked flag (version 4): the byte 0 or 1, anything else malformed."""
    what = (name if index is None else f"{name}[{index}]") + ".parked"
    flag = r.u8(what)
    if flag > 1:
        raise DecodeError(f"{what} must be 0 or 1, got {flag}")
    return flag == 1


def _parse_ellipse_parked(r: Reader) -> EllipseMsg:
    """Version 4: the ellipse as an ``others`` version 3 holds it, then parked."""
    item = _read_ellipse(r, "ellipse")
    points = r.points("ellipse")
    sigma = _read_sigma(r, "ellipse")
    return _ellipses([item], [points], [sigma], [_read_parked(r, "ellipse")])[0]


_ELLIPSE_PARSERS = {WIRE_VERSION: _parse_ellipse, ELLIPSE_POINTS_VERSION: _parse_ellipse_points,
                    ELLIPSE_SIGMA_VERSION: _parse_ellipse_sigma,
                    ELLIPSE_PARKED_VERSION: _parse_ellipse_parked}


def _parse_others(r: Reader, version: int = WIRE_VERSION) -> Others:
    formation = r.string("formation")
    (stamp,) = r.floats(1, "stamp")
    n = r.count("ellipses", MAX_ITEMS)
    items: list[Item] = []
    points: list[Points] | None = [] if version >= ELLIPSE_POINTS_VERSION else None
    sigmas: list[float | None] | None = [] if version >= ELLIPSE_SIGMA_VERSION else None
    parked: list[bool] | None = [] if version >= ELLIPSE_PARKED_VERSION else None
    for i in range(n):
        _read_others_ellipse(r, ("ellipses", i), items, points, (sigmas, parked))
    n_own = r.count("own", 1)
    if n_own:
        _read_others_ellipse(r, ("own", None), items, points, (sigmas, parked))
    built = _ellipses(items, points, sigmas, parked)
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


def _read_others_ellipse(r: Reader, where: tuple[str, int | None], items: list[Item],
                         points: list[Points] | None,
                         later: tuple[list[float | None] | None, list[bool] | None]) -> None:
    """One ellipse of an ``others`` (``where``: its name and index) into ``items``, with its
    points (version 2 on), its sigma (version 3 on) and its parked flag (version 4): ``later``
    holds the lists of those two, None before their version."""
    items.append(_read_ellipse(r, *where))
    if points is not None:
        points.append(r.points(*where))
    sigmas, parked = later
    if sigmas is not None:
        sigmas.append(_read_sigma(r, *where))
    if parked is not None:
        parked.append(_read_parked(r, *where))


_OBSTACLES_PARSERS = {WIRE_VERSION: _parse_obstacles, SHAPES_VERSION: _parse_obstacles_with_shapes}
_OTHERS_PARSERS: dict[int, Callable[[Reader], Others]] = {
    WIRE_VERSION: _parse_others,
    ELLIPSE_POINTS_VERSION: functools.partial(_parse_others, version=ELLIPSE_POINTS_VERSION),
    ELLIPSE_SIGMA_VERSION: functools.partial(_parse_others, version=ELLIPSE_SIGMA_VERSION),
    ELLIPSE_PARKED_VERSION: functools.partial(_parse_others, version=ELLIPSE_PARKED_VERSION),
}


def decode_pose(payload: bytes | zenoh.ZBytes) -> Pose:
    """Decode a ``pose`` payload; raises only :class:`DecodeError`."""
    return decode_payload(payload, _parse_pose, "pose")


def decode_state(payload: bytes | zenoh.ZBytes) -> State:
    """Decode a ``state`` payload; raises only :class:`DecodeError`."""
    return decode_payload(payload, _parse_state, "state", STATE_VERSION, _STATE_PARSERS)


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
