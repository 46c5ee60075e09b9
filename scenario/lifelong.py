"""The lifelong part of a scenario: a fleet, stations, load types, resting loads and orders.

Six optional top-level keys (the contract's "Lifelong operation"); a file without any of them
has ``Scenario.lifelong = None`` and reads exactly as before. With ``fleet``, ``formations`` may
be absent. The model, all frozen:

* :class:`Fleet`: ``robots``, one :class:`FleetRobot` (id, start ``(x, y, theta)``; theta 0
  when the file gives ``[x, y]``) per robot bound to no formation, in file order; ``parking``,
  the spots idle robots wait at (empty: where they stand); ``bid_window_s`` (the bidding round,
  1.0 s), ``bid_copies`` (copies of each bid per round, 3) and ``lift_s`` (the time a lift or a
  set-down takes, 2.0 s).
* :class:`Station`: ``name``, ``pose`` ``(x, y, yaw)``, the centre and heading of a load
  resting there; ``kind`` ``source`` (new loads appear), ``sink`` (a delivered load leaves
  after ``dwell_s``) or ``store``; ``dwell_s`` is 0 except at a sink. A bare ``[x, y, yaw]``
  is a store.
* :class:`LoadType`: ``name``, ``size`` ``(L, W)`` (a rectangle, L along the load's x axis),
  ``slots``, the points in the load frame its team's robots stand at, slot 0's robot leading
  and slot 1's succeeding; ``team`` = the number of slots. ``team: 2`` without ``slots``
  puts them at the ends of the long axis, ``team: 4`` at the corners, each inset by the robot
  radius (:func:`default_slots`).
* :class:`Load`: a load resting at t = 0: ``name``, ``type``, ``at`` (a station).
* :class:`Order`: ``id``, ``t`` (when it is posted [s]), either ``type`` (a new load, named by
  the order's id, appears at the source ``from_``) or ``load`` (a resting load, or the load of an
  earlier order named by that order's id, moves from wherever it rests; ``from_`` is optional
  then), ``to`` (a store or a sink) and ``priority`` (higher first).
* :class:`OrderStream`: generated orders (:mod:`scenario.stream`): Poisson arrivals at
  ``rate_per_min`` from ``start`` to ``until`` [s], drawn with ``seed``, of the load ``types``
  (all types when the file names none).
* :class:`Lifelong`: the six together, with lookups by name.

Robots (of formations and of the fleet), formations, loads and orders share one namespace;
station and type names each have their own. Field checks (types, finiteness, ranges, names,
references between the keys) happen here, as the file is read; the checks against the world
(walls, shelves, other stations, the fleet's size) are :mod:`scenario.lifelong_checks`.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from . import limits
from .fields import count, identifier, mapping, number, string, vector, within
from .limits import Range
from .reader import ScenarioError, excerpt

SOURCE, SINK, STORE = "source", "sink", "store"
STATION_KINDS = (SOURCE, SINK, STORE)
KEYS = ("fleet", "stations", "load_types", "loads", "orders", "order_stream")

MAX_FLEET = 1000  # robots in a fleet
MAX_STATIONS = 1024
MAX_LOAD_TYPES = 64
MAX_LOADS = 1024
MAX_ORDERS = 10_000
MAX_SLOTS = 16  # a team's slots (an order's bid carries one cost per slot)
TEAMS = (2, 4)  # the teams with default slots
DWELL = Range(0.0, 86_400.0, "s")
TIME = Range(0.0, 1.0e7, "s")  # order times, the stream's start and until
RATE = Range(0.0, 120.0, "orders/min")  # two a second: far beyond what a fleet serves
PRIORITY = Range(-1.0e6, 1.0e6)
BID_WINDOW = limits.positive(60.0, "s")
BID_COPIES = (1, 10)
LIFT = Range(0.0, 600.0, "s")
SEED = (0, 2**63 - 1)

Point = tuple[float, float]
Pose = tuple[float, float, float]

_FLEET_KEYS = {"robots", "parking", "bid_window_s", "bid_copies", "lift_s"}
_FLEET_ROBOT_KEYS = {"start"}
_STATION_KEYS = {"pose", "kind", "dwell_s"}
_TYPE_KEYS = {"size", "team", "slots"}
_LOAD_KEYS = {"name", "type", "at"}
_ORDER_KEYS = {"id", "t", "type", "load", "from", "to", "priority"}
_STREAM_KEYS = {"rate_per_min", "seed", "types", "until", "start"}


@dataclass(frozen=True)
class FleetRobot:
    id: str
    start: Pose  # x, y [m], theta [rad]


@dataclass(frozen=True)
class Fleet:
    robots: tuple[FleetRobot, ...]
    parking: tuple[Point, ...] = ()  # [m] where idle robots wait; empty: where they stand
    bid_window_s: float = 1.0  # [s] a bidding round's length
    bid_copies: int = 3  # copies of each bid put per round
    lift_s: float = 2.0  # [s] a lift, and a set-down, takes this long

    @property
    def robot_ids(self) -> tuple[str, ...]:
        return tuple(r.id for r in self.robots)

    @functools.cached_property
    def starts(self) -> dict[str, Pose]:
        """Robot id -> start pose."""
        return {r.id: r.start for r in self.robots}


@dataclass(frozen=True)
class Station:
    name: str
    pose: Pose  # x, y [m], yaw [rad]: a resting load's centre and heading
    kind: str  # SOURCE, SINK or STORE
    dwell_s: float = 0.0  # [s] at a sink: a delivered load leaves after this long


@dataclass(frozen=True)
class LoadType:
    name: str
    size: Point  # [m] length along the load's x axis, width along its y axis
    slots: tuple[Point, ...]  # [m] in the load frame; slot 0 leads, slot 1 succeeds

    @property
    def team(self) -> int:
        return len(self.slots)

    @property
    def outline(self) -> tuple[Point, ...]:
        """The rectangle in the load frame, counter-clockwise."""
        hx, hy = 0.5 * self.size[0], 0.5 * self.size[1]
        return ((hx, -hy), (hx, hy), (-hx, hy), (-hx, -hy))

    @property
    def area(self) -> float:
        return self.size[0] * self.size[1]


@dataclass(frozen=True)
class Load:
    name: str
    type: str
    at: str  # station


@dataclass(frozen=True)
class Order:
    id: str
    t: float  # [s] when it is posted
    to: str  # a store or a sink
    type: str | None = None  # a new load of this type appears at ``from_`` (a source)
    load: str | None = None  # or: this load moves from where it rests
    from_: str | None = None  # the source of a new load; optional for a ``load`` order
    priority: float = 0.0  # higher first, then the order posted first

    @property
    def load_name(self) -> str:
        """The load it moves: a new load is named by its order's id."""
        return self.load if self.load is not None else self.id


@dataclass(frozen=True)
class OrderStream:
    rate_per_min: float  # [1/min] mean arrivals
    seed: int
    types: tuple[str, ...]  # the load types of storage orders
    until: float  # [s] no arrival after this
    start: float = 0.0  # [s] no arrival before this


@dataclass(frozen=True)
class Lifelong:
    fleet: Fleet
    stations: tuple[Station, ...] = ()
    load_types: tuple[LoadType, ...] = ()
    loads: tuple[Load, ...] = ()
    orders: tuple[Order, ...] = ()
    stream: OrderStream | None = None

    @functools.cached_property
    def station_by_name(self) -> dict[str, Station]:
        return {s.name: s for s in self.stations}

    @functools.cached_property
    def type_by_name(self) -> dict[str, LoadType]:
        return {t.name: t for t in self.load_types}

    @functools.cached_property
    def load_by_name(self) -> dict[str, Load]:
        return {ld.name: ld for ld in self.loads}

    def station(self, name: str) -> Station:
        return self.station_by_name[name]

    def load_type(self, name: str) -> LoadType:
        return self.type_by_name[name]

    def stations_of(self, kind: str) -> tuple[Station, ...]:
        return tuple(s for s in self.stations if s.kind == kind)

    def type_of_load(self, name: str) -> LoadType:
        """The type of a resting load or of the new load an order (named ``name``) brings."""
        if name in self.load_by_name:
            return self.load_type(self.load_by_name[name].type)
        order = next((o for o in self.orders if o.id == name and o.type is not None), None)
        if order is None:
            raise KeyError(f"no resting load and no order bringing a new load named {name!r}")
        return self.load_type(str(order.type))


# ---------------------------------------------------------------------------- geometry


def default_slots(size: Point, team: int, radius: float) -> tuple[Point, ...]:
    """A team's slots under a ``size`` rectangle: 2 at the ends of its long axis, 4 at its
    corners, each inset by ``radius`` from the outline (the robot's body stays under the load).
    ValueError when the rectangle is too small for the inset."""
    hx, hy = 0.5 * size[0] - radius, 0.5 * size[1] - radius
    if team == 2:
        along_x = size[0] >= size[1]
        half = hx if along_x else hy
        if half <= 0.0:
            raise ValueError(f"its long side {max(size):g} m is not longer than two robot "
                             f"radii ({2 * radius:g} m)")
        return ((half, 0.0), (-half, 0.0)) if along_x else ((0.0, half), (0.0, -half))
    if team == 4:
        if min(hx, hy) <= 0.0:
            raise ValueError(f"its short side {min(size):g} m is not longer than two robot "
                             f"radii ({2 * radius:g} m)")
        return ((hx, hy), (-hx, hy), (-hx, -hy), (hx, -hy))
    raise ValueError(f"team {team} has no default slots (only {TEAMS[0]} or {TEAMS[1]}): give "
                     "slots")


def to_world(pose: Pose, point: Point) -> Point:
    """A point of the load frame at ``pose`` (x, y, yaw) in the world."""
    c, s = math.cos(pose[2]), math.sin(pose[2])
    return (pose[0] + c * point[0] - s * point[1], pose[1] + s * point[0] + c * point[1])


def outline_at(load_type: LoadType, pose: Pose) -> tuple[Point, ...]:
    """The type's outline resting at ``pose``, in the world, counter-clockwise."""
    return tuple(to_world(pose, v) for v in load_type.outline)


def slots_at(load_type: LoadType, pose: Pose) -> tuple[Point, ...]:
    """The type's slots under a load resting at ``pose``, in the world, in slot order."""
    return tuple(to_world(pose, v) for v in load_type.slots)


# ---------------------------------------------------------------------------- parsing


def has_lifelong(top: Mapping[str, Any]) -> bool:
    return any(k in top for k in KEYS)


def parse_lifelong(top: Mapping[str, Any], radius: float, epsilon: float) -> Lifelong | None:
    """The lifelong keys of the scenario mapping ``top`` (None when it has none); ``radius``
    is the robot's, ``epsilon`` the formation tolerance (slots keep bodies apart by it)."""
    if not has_lifelong(top):
        return None
    if top.get("fleet") is None:
        present = next(k for k in KEYS if k in top)
        raise ScenarioError(f"fleet: missing ({present} needs a fleet of robots to serve it)")
    fleet = _fleet(top["fleet"])
    stations = _stations(top.get("stations"))
    types = _load_types(top.get("load_types"), radius, epsilon)
    loads = _loads(top.get("loads"), stations, types)
    orders = _orders(top.get("orders"), stations, types, loads)
    stream = _stream(top.get("order_stream"), types)
    return Lifelong(fleet, tuple(stations.values()), tuple(types.values()), loads, orders, stream)


def _fleet(raw: Any) -> Fleet:
    m = mapping(raw, "fleet", _FLEET_KEYS)
    robots_raw = m.get("robots")
    if not isinstance(robots_raw, Mapping) or not robots_raw:
        raise ScenarioError("fleet.robots: must be a non-empty mapping of robot name to {start}")
    count(robots_raw, "fleet.robots", MAX_FLEET)
    robots = []
    for rid, spec in robots_raw.items():
        rid = identifier(rid, "fleet.robots")
        where = f"fleet.robots.{rid}"
        rm = mapping(spec, where, _FLEET_ROBOT_KEYS)
        if "start" not in rm:
            raise ScenarioError(f"{where}.start: missing")
        start = vector(rm["start"], f"{where}.start", (2, 3), limits.COORDINATE)
        theta = within(start[2], f"{where}.start[2] (heading)", limits.HEADING) if len(
            start) == 3 else 0.0
        robots.append(FleetRobot(rid, (start[0], start[1], theta)))
    d = Fleet(())
    return Fleet(
        tuple(robots),
        _points(m.get("parking", []), "fleet.parking"),
        within(m.get("bid_window_s", d.bid_window_s), "fleet.bid_window_s", BID_WINDOW),
        _integer(m.get("bid_copies", d.bid_copies), "fleet.bid_copies", BID_COPIES),
        non_negative(m.get("lift_s", d.lift_s), "fleet.lift_s", LIFT),
    )


def _points(raw: Any, where: str) -> tuple[Point, ...]:
    if not isinstance(raw, list):
        raise ScenarioError(f"{where}: must be a list of [x, y]")
    count(raw, where, MAX_FLEET)
    out = []
    for k, p in enumerate(raw):
        v = vector(p, f"{where}[{k}]", (2,), limits.COORDINATE)
        out.append((v[0], v[1]))
    return tuple(out)


def _integer(raw: Any, where: str, bounds: tuple[int, int]) -> int:
    if isinstance(raw, bool) or not isinstance(raw, int):
        raise ScenarioError(f"{where}: must be a whole number, got {excerpt(raw)}")
    if not bounds[0] <= raw <= bounds[1]:
        raise ScenarioError(f"{where}: out of range, got {excerpt(raw)} (allowed: from "
                            f"{bounds[0]} to {bounds[1]})")
    return raw


def non_negative(raw: Any, where: str, allowed: Range) -> float:
    """A finite number, not negative, in ``allowed`` (which starts at 0)."""
    v = number(raw, where)
    if v < 0.0:
        raise ScenarioError(f"{where}: must not be negative, got {excerpt(raw)}")
    return within(v, where, allowed)


def _named(raw: Any, where: str, most: int) -> Mapping[str, Any]:
    """A mapping of name to spec (None: empty)."""
    if raw is None:
        return {}
    if not isinstance(raw, Mapping):
        raise ScenarioError(f"{where}: must be a mapping of name to its spec")
    count(raw, where, most)
    return raw


def _stations(raw: Any) -> dict[str, Station]:
    out: dict[str, Station] = {}
    for name, spec in _named(raw, "stations", MAX_STATIONS).items():
        name = identifier(name, "stations")
        out[name] = _station(name, spec, f"stations.{name}")
    return out


def _station(name: str, spec: Any, where: str) -> Station:
    if isinstance(spec, list):  # the shorthand: a store
        return Station(name, _pose(spec, where), STORE)
    m = mapping(spec, where, _STATION_KEYS)
    if "pose" not in m:
        raise ScenarioError(f"{where}.pose: missing ([x, y, yaw] of a load resting there)")
    kind = string(m.get("kind", STORE), f"{where}.kind")
    if kind not in STATION_KINDS:
        raise ScenarioError(f"{where}.kind: {excerpt(kind)} is not one of "
                            f"{', '.join(repr(k) for k in STATION_KINDS)}")
    if "dwell_s" in m and kind != SINK:
        raise ScenarioError(f"{where}.dwell_s: only a sink has a dwell (this is a {kind})")
    dwell = non_negative(m.get("dwell_s", 0.0), f"{where}.dwell_s", DWELL)
    return Station(name, _pose(m["pose"], f"{where}.pose"), kind, dwell)


def _pose(raw: Any, where: str) -> Pose:
    v = vector(raw, where, (3,), limits.COORDINATE)
    return (v[0], v[1], within(v[2], f"{where}[2] (yaw)", limits.HEADING))


def _load_types(raw: Any, radius: float, epsilon: float) -> dict[str, LoadType]:
    out: dict[str, LoadType] = {}
    for name, spec in _named(raw, "load_types", MAX_LOAD_TYPES).items():
        name = identifier(name, "load_types")
        out[name] = _load_type(name, spec, f"load_types.{name}", radius, epsilon)
    return out


def _load_type(name: str, spec: Any, where: str, radius: float, epsilon: float) -> LoadType:
    m = mapping(spec, where, _TYPE_KEYS)
    if "size" not in m:
        raise ScenarioError(f"{where}.size: missing ([L, W] of the load)")
    raw_size = vector(m["size"], f"{where}.size", (2,))
    size = (within(raw_size[0], f"{where}.size[0]", limits.DISTANCE),
            within(raw_size[1], f"{where}.size[1]", limits.DISTANCE))
    if "slots" in m:
        slots = _slots(m["slots"], f"{where}.slots", size)
        if "team" in m and _integer(m["team"], f"{where}.team", (1, MAX_SLOTS)) != len(slots):
            raise ScenarioError(f"{where}.team: {m['team']} is not the number of its slots "
                                f"({len(slots)})")
    else:
        team = _integer(m.get("team"), f"{where}.team", (1, MAX_SLOTS)) if "team" in m else None
        if team is None:
            raise ScenarioError(f"{where}: needs team (2 or 4) or slots")
        try:
            slots = default_slots(size, team, radius)
        except ValueError as exc:
            raise ScenarioError(f"{where}.team: {exc}") from None
    _check_slot_gaps(slots, where, 2.0 * radius + epsilon)
    return LoadType(name, size, slots)


def _slots(raw: Any, where: str, size: Point) -> tuple[Point, ...]:
    if not isinstance(raw, list) or not 1 <= len(raw) <= MAX_SLOTS:
        raise ScenarioError(f"{where}: must be a list of 1 to {MAX_SLOTS} points [x, y]")
    out = []
    for k, p in enumerate(raw):
        v = vector(p, f"{where}[{k}]", (2,), limits.COORDINATE)
        if abs(v[0]) > 0.5 * size[0] + 1e-9 or abs(v[1]) > 0.5 * size[1] + 1e-9:
            raise ScenarioError(f"{where}[{k}]: ({v[0]:g}, {v[1]:g}) is outside the load's "
                                f"outline ({size[0]:g} x {size[1]:g} m)")
        out.append((v[0], v[1]))
    return tuple(out)


def _check_slot_gaps(slots: tuple[Point, ...], where: str, least: float) -> None:
    for a in range(len(slots)):
        for b in range(a + 1, len(slots)):
            d = math.dist(slots[a], slots[b])
            if d < least - 1e-9:
                raise ScenarioError(f"{where}: slots {a} and {b} are {d:.3f} m apart, closer "
                                    f"than two robot radii plus epsilon ({least:.3f} m)")


def _reference(raw: Any, where: str, known: Mapping[str, Any], what: str) -> str:
    name = string(raw, where)
    if name not in known:
        raise ScenarioError(f"{where}: unknown {what} {excerpt(name)}")
    return name


def _loads(raw: Any, stations: Mapping[str, Station],
           types: Mapping[str, LoadType]) -> tuple[Load, ...]:
    if raw is None:
        return ()
    if not isinstance(raw, list):
        raise ScenarioError("loads: must be a list of {name, type, at}")
    count(raw, "loads", MAX_LOADS)
    out: list[Load] = []
    held: dict[str, str] = {}
    for k, spec in enumerate(raw):
        where = f"loads[{k}]"
        m = mapping(spec, where, _LOAD_KEYS)
        for key in sorted(_LOAD_KEYS):
            if key not in m:
                raise ScenarioError(f"{where}.{key}: missing")
        load = Load(identifier(m["name"], f"{where}.name"),
                    _reference(m["type"], f"{where}.type", types, "load type"),
                    _reference(m["at"], f"{where}.at", stations, "station"))
        if stations[load.at].kind == SINK:
            raise ScenarioError(f"{where}.at: {load.at!r} is a sink (a load there leaves)")
        if load.at in held:
            raise ScenarioError(f"{where}.at: load {held[load.at]!r} already rests at "
                                f"{load.at!r}")
        held[load.at] = load.name
        out.append(load)
    return tuple(out)


def _orders(raw: Any, stations: Mapping[str, Station], types: Mapping[str, LoadType],
            loads: tuple[Load, ...]) -> tuple[Order, ...]:
    if raw is None:
        return ()
    if not isinstance(raw, list):
        raise ScenarioError("orders: must be a list of {id, t, type or load, from, to}")
    count(raw, "orders", MAX_ORDERS)
    new_loads = {str(m["id"]) for m in raw if isinstance(m, Mapping) and "type" in m
                 and "id" in m}
    movable = {ld.name for ld in loads} | new_loads
    return tuple(_order(spec, f"orders[{k}]", stations, types, movable)
                 for k, spec in enumerate(raw))


def _order(spec: Any, where: str, stations: Mapping[str, Station],
           types: Mapping[str, LoadType], movable: set[str]) -> Order:
    m = mapping(spec, where, _ORDER_KEYS)
    for key in ("id", "to"):
        if key not in m:
            raise ScenarioError(f"{where}.{key}: missing")
    if ("type" in m) == ("load" in m):
        raise ScenarioError(f"{where}: needs exactly one of type (a new load) or load (a "
                            "resting one)")
    oid = identifier(m["id"], f"{where}.id")
    t = non_negative(m.get("t", 0.0), f"{where}.t", TIME)
    to = _reference(m["to"], f"{where}.to", stations, "station")
    if stations[to].kind == SOURCE:
        raise ScenarioError(f"{where}.to: {to!r} is a source (an order goes to a store or a "
                            "sink)")
    frm = None if m.get("from") is None else _reference(m["from"], f"{where}.from", stations,
                                                        "station")
    priority = within(m.get("priority", 0.0), f"{where}.priority", PRIORITY)
    if "type" in m:
        kind = _reference(m["type"], f"{where}.type", types, "load type")
        if frm is None:
            raise ScenarioError(f"{where}.from: missing (the source a new load appears at)")
        if stations[frm].kind != SOURCE:
            raise ScenarioError(f"{where}.from: {frm!r} is a {stations[frm].kind}, not a source "
                                "(a new load appears at a source)")
        return Order(oid, t, to, type=kind, from_=frm, priority=priority)
    load = string(m["load"], f"{where}.load")
    if load == oid or load not in movable:
        raise ScenarioError(f"{where}.load: unknown load {excerpt(load)} (a resting load or "
                            "the id of an order that brings a new one)")
    return Order(oid, t, to, load=load, from_=frm, priority=priority)


def _stream(raw: Any, types: Mapping[str, LoadType]) -> OrderStream | None:
    if raw is None:
        return None
    m = mapping(raw, "order_stream", _STREAM_KEYS)
    for key in ("rate_per_min", "seed"):
        if key not in m:
            raise ScenarioError(f"order_stream.{key}: missing")
    rate = non_negative(m["rate_per_min"], "order_stream.rate_per_min", RATE)
    raw_types = m.get("types", list(types))
    if not isinstance(raw_types, list):
        raise ScenarioError("order_stream.types: must be a list of load type names")
    names = tuple(_reference(v, f"order_stream.types[{k}]", types, "load type")
                  for k, v in enumerate(raw_types))
    if not names:
        raise ScenarioError("order_stream.types: no load type to post (declare load_types)")
    start = non_negative(m.get("start", 0.0), "order_stream.start", TIME)
    until = non_negative(m.get("until", TIME.hi), "order_stream.until", TIME)
    if until < start:
        raise ScenarioError(f"order_stream.until: {until:g} s is before its start {start:g} s")
    return OrderStream(rate, _integer(m["seed"], "order_stream.seed", SEED), names, until, start)
