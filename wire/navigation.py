"""The navigation payloads of formation-cbf: ``goal``, ``plan`` and ``status`` (docs/keys.md
key space), in the wire format of :mod:`wire.payloads` and read with its defensive reader
(:mod:`wire.reader`). Layouts::

    ``GoalMsg``    version, formation:str, x, y, heading:list[f64] (0 or 1), waypoints:list[(x, y)],
                   stamp
    ``PlanMsg``    version, formation:str, goal_stamp, cx, cy, heading:list[f64] (0 or 1),
                   route:list[(x, y)], members:list[(id:str, gx, gy)], stamp
    ``StatusMsg``  version, formation:str, state:str, leader:str, goal_stamp, gx, gy,
                   heading:list[f64] (0 or 1), distance, waypoint, waypoints, wx, wy, stamp
                   version 2 (:data:`STATUS_VERSION`) adds: reason:str, refused, refusal:str,
                   fleet:list[str]
    ``GoalMsg`` and ``PlanMsg`` version 2 (:data:`ROUTE_VERSION`) add, after the stamp:
                   headings:list[list[f64] (0 or 1)], one per waypoint or route point

    ``goal_stamp`` names a goal: the stamp the leader gave it when it accepted it (the fleet
    manager's stamp in real time, simulated time on arrival in lock-step). A member adopts a plan
    whose goal_stamp is newer than the one it follows. ``waypoint`` and ``waypoints`` (the index
    of the current waypoint and the route's length; the goal is the last) are whole numbers
    carried as f64.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass
from typing import Any

import zenoh
from zenoh.ext import UInt8, z_serialize

from wire.payloads import MAX_ITEMS, check_finite, check_floats, check_id, points_field
from wire.reader import WIRE_VERSION, Reader, decode_payload

#: ``status`` version 2 (the one new status version) adds why the formation is
#: in its state (``reason``: the planner's word for ``unreachable``), how many goals its leader
#: refused (``refused``, a whole number carried as f64), why it refused the last one
#: (``refusal``) and every formation of the leader's scenario, its own included (``fleet``:
#: ``formation goal`` tells an unknown formation from one whose leader has not answered yet by
#: any one leader's answer). A status with nothing of these is written as version 1, byte for
#: byte as before, so an older fleet manager still reads it; one with any of them (or the state
#: ``unreachable``) is version 2, which an older decoder refuses by its version byte.
STATUS_VERSION = 2
#: ``goal`` and ``plan`` version 2 add a heading (0 or 1) per waypoint or route point, after the
#: stamp (the footprint's route turns it; a hand-given waypoint may say how). One
#: without any heading is written as version 1, byte for byte as before.
ROUTE_VERSION = 2

MAX_WAYPOINTS = 64  # most waypoints in a goal or route
STATUS_STATES = ("moving", "reached", "stalled", "stopped", "unreachable")
MAX_REASON = 200  # longest reason or refusal [characters]; a longer one is cut by the writer
MAX_REFUSED = 2**31 - 1  # the refused-goal count saturates here (the writer clamps it)


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
        check_finite(obj, name)


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
        check_id(self.formation, "formation")
        check_floats(self, ("x", "y", "stamp"))
        _optional_angle(self, "heading")
        object.__setattr__(self, "waypoints", points_field(self.waypoints, "waypoints", MAX_WAYPOINTS))
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
        check_id(self.formation, "formation")
        check_floats(self, ("goal_stamp", "cx", "cy", "stamp"))
        _optional_angle(self, "heading")
        route = points_field(self.route, "route", MAX_WAYPOINTS)
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
            check_id(rid, f"members[{k}].id")
            assert isinstance(rid, str)  # check_id accepts only a str
            if rid in seen:
                raise ValueError(f"members repeat id {rid!r}")
            seen.add(rid)
            out.append((rid, *points_field([m[1:]], f"members[{k}]", 1)[0]))
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
        check_id(self.formation, "formation")
        check_id(self.leader, "leader")
        fleet = tuple(self.fleet)
        if len(fleet) > MAX_ITEMS:
            raise ValueError(f"fleet must name at most {MAX_ITEMS} formations, got {len(fleet)}")
        for k, name in enumerate(fleet):
            check_id(name, f"fleet[{k}]")
        object.__setattr__(self, "fleet", fleet)
        for name in ("reason", "refusal"):
            text = getattr(self, name)
            if not isinstance(text, str) or len(text) > MAX_REASON:
                raise ValueError(f"{name} must be text of at most {MAX_REASON} characters")
        if self.state not in STATUS_STATES:
            raise ValueError(f"state must be one of {STATUS_STATES}, got {self.state!r}")
        check_floats(self, ("goal_stamp", "gx", "gy", "distance", "wx", "wy", "stamp"))
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


_V1 = UInt8(WIRE_VERSION)
_STATUS_VERSION = UInt8(STATUS_VERSION)
_ROUTE_VERSION = UInt8(ROUTE_VERSION)


def _heading_list(h: float | None) -> list[float]:
    return [] if h is None else [h]


def encode_nav(msg: GoalMsg | PlanMsg | StatusMsg) -> bytes:
    """Serialize a goal, plan or status (layouts above)."""
    if isinstance(msg, GoalMsg):
        t: tuple[Any, ...] = (_V1, msg.formation, msg.x, msg.y, _heading_list(msg.heading),
                              list(msg.waypoints), msg.stamp)
        if msg.headings:
            t = (_ROUTE_VERSION, *t[1:], [_heading_list(h) for h in msg.headings])
    elif isinstance(msg, PlanMsg):
        t = (_V1, msg.formation, msg.goal_stamp, msg.cx, msg.cy, _heading_list(msg.heading),
             list(msg.route), list(msg.members), msg.stamp)
        if msg.headings:
            t = (_ROUTE_VERSION, *t[1:], [_heading_list(h) for h in msg.headings])
    elif isinstance(msg, StatusMsg):
        t = (_V1, msg.formation, msg.state, msg.leader, msg.goal_stamp, msg.gx, msg.gy,
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


