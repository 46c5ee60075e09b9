"""The payloads and keys of lifelong operation: transport orders, the robots' bids and votes, and
an order's status (docs/keys.md), in the wire format of :mod:`wire.payloads`, read with its
defensive reader (:mod:`wire.reader`). Layouts (version 1)::

    ``OrderMsg``        version, oid:str, kind:str, type:str, load:str, source:str, to:str,
                        priority, stamp
    ``BidMsg``          version, oid:str, robot:str, round, phase:str, costs:list[f64],
                        roster:list[str], stamp
    ``OrderStatusMsg``  version, oid:str, state:str, round, roster:list[str], leader:str,
                        reason:str, stamp
    ``LoadsMsg``        version, stamp, loads:list[(name:str, type:str, x, y, yaw, state:str,
                        station:str, order:str)]

Keys, under the fleet's prefix::

    {prefix}/order/{oid}              the fleet manager -> every robot (a queryable: the open orders)
    {prefix}/order/{oid}/bid/{rid}    robot rid -> the other bidders of that order
    {prefix}/order/{oid}/status       the team's leader -> anyone
    {prefix}/world/loads              the simulated world -> robots and viewers, every frame

A bid's ``robot`` must be the robot its key names (:func:`bid_is_forged`), and every message's
``oid`` the order its key names (:func:`is_forged`); :func:`read_order_message` decodes a sample
by its key's class and refuses a forged one as malformed. ``round`` is a whole number carried as
f64, ``priority`` a finite number of at most :data:`MAX_PRIORITY` either way (the
scenario's); ``costs`` holds one cost per slot of the order's load type (a bid) and ``roster``
one robot per slot (a vote, or a decline's order of slots).
Text is bounded: ids at most 64 characters, a reason at most :data:`MAX_REASON`.
``LoadsMsg`` lists every load that exists (a load gone from a sink is not listed), at most
:data:`MAX_LOADS`, each named once; ``station`` and ``order`` are empty between stations and
with no order.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import zenoh
from zenoh.ext import UInt8, z_serialize

from wire import keys
from wire.payloads import check_floats, check_id
from wire.reader import WIRE_VERSION, DecodeError, Reader, decode_payload, decoded_replies

MAX_SLOTS = 16  # most robots one load type's team may have (costs and roster entries)
MAX_REASON = 200  # longest reason [characters]
MAX_ROUND = 2**31 - 1  # a round beyond this is implausible
MAX_PRIORITY = 1.0e6  # an order's priority lies in [-MAX_PRIORITY, MAX_PRIORITY]
ORDER_KINDS = ("new", "load", "cancel", "priority")
BID_PHASES = ("bid", "vote", "decline")
ORDER_STATES = ("waiting", "assigned", "gathering", "carrying", "delivered", "cancelled", "failed")
LOAD_STATES = ("resting", "carried")  # what a listed load does (a gone load is not listed)
MAX_LOADS = 256  # most loads one LoadsMsg lists


def _whole(obj: object, name: str, low: int) -> None:
    """Store the whole-number field ``name`` (carried as f64) as an int in [low, MAX_ROUND]."""
    v = getattr(obj, name)
    if isinstance(v, float) and v.is_integer():
        v = int(v)
    if type(v) is not int or not low <= v <= MAX_ROUND:
        raise ValueError(f"{name} must be a whole number in [{low}, {MAX_ROUND}], got {v!r}")
    object.__setattr__(obj, name, v)


def _one_of(value: object, allowed: tuple[str, ...], name: str) -> None:
    if value not in allowed:
        raise ValueError(f"{name} must be one of {allowed}, got {value!r}")


def _optional_id(value: object, name: str) -> None:
    if value != "":
        check_id(value, name)


def _roster(obj: object, name: str) -> None:
    ids = tuple(getattr(obj, name))
    if len(ids) > MAX_SLOTS:
        raise ValueError(f"{name} must hold at most {MAX_SLOTS} robots, got {len(ids)}")
    for k, rid in enumerate(ids):
        check_id(rid, f"{name}[{k}]")
    if len(set(ids)) != len(ids):
        raise ValueError(f"{name} names a robot twice: {ids!r}")
    object.__setattr__(obj, name, ids)


@dataclass(frozen=True, slots=True)
class OrderMsg:
    """An order as the fleet manager posts it. ``kind`` ``new``: a new load of ``type`` appears
    at station ``source`` and goes to ``to``; ``load``: the resting load ``load`` goes to ``to``;
    ``cancel``: the order ``oid`` is withdrawn; ``priority``: it gets ``priority``. Fields a kind
    does not use are empty."""

    oid: str
    kind: str
    type: str = ""
    load: str = ""
    source: str = ""
    to: str = ""
    priority: float = 0.0
    stamp: float = 0.0

    def __post_init__(self) -> None:
        check_id(self.oid, "oid")
        _one_of(self.kind, ORDER_KINDS, "kind")
        for name in ("type", "load", "source", "to"):
            _optional_id(getattr(self, name), name)
        p = self.priority
        if (isinstance(p, bool) or not isinstance(p, int | float) or not math.isfinite(p)
                or abs(p) > MAX_PRIORITY):
            raise ValueError(f"priority must be a finite number in [-{MAX_PRIORITY:g}, "
                             f"{MAX_PRIORITY:g}], got {p!r}")
        object.__setattr__(self, "priority", float(p))
        check_floats(self, ("stamp",))
        need = {"new": ("type", "source", "to"), "load": ("load", "to")}.get(self.kind, ())
        for name in need:
            if not getattr(self, name):
                raise ValueError(f"a {self.kind!r} order needs {name}")


@dataclass(frozen=True, slots=True)
class BidMsg:
    """A robot's word on one order in one allocation round: ``bid`` (its cost to each slot),
    ``vote`` (the roster it computed, one robot per slot) or ``decline`` (it was named by two
    committed rosters and takes the other)."""

    oid: str
    robot: str
    round: int
    phase: str
    costs: tuple[float, ...] = ()
    roster: tuple[str, ...] = ()
    stamp: float = 0.0

    def __post_init__(self) -> None:
        check_id(self.oid, "oid")
        check_id(self.robot, "robot")
        _whole(self, "round", 0)
        _one_of(self.phase, BID_PHASES, "phase")
        costs = tuple(self.costs)
        if len(costs) > MAX_SLOTS:
            raise ValueError(f"costs must hold at most {MAX_SLOTS} slots, got {len(costs)}")
        for k, c in enumerate(costs):
            if isinstance(c, bool) or not isinstance(c, int | float) or not math.isfinite(c) or c < 0:
                raise ValueError(f"costs[{k}] must be a finite number >= 0, got {c!r}")
        object.__setattr__(self, "costs", tuple(float(c) for c in costs))
        _roster(self, "roster")
        check_floats(self, ("stamp",))
        if self.phase == "bid" and not costs:
            raise ValueError("a bid needs its costs, one per slot")
        if self.phase == "vote" and not self.roster:
            raise ValueError("a vote needs its roster, one robot per slot")


@dataclass(frozen=True, slots=True)
class OrderStatusMsg:
    """An order's state as its team's leader (or, before a team, the fleet manager) reports it:
    the round that committed ``roster`` (one robot per slot, the first leads), ``leader``, and
    ``reason`` for ``failed`` or ``cancelled``."""

    oid: str
    state: str
    round: int = 0
    roster: tuple[str, ...] = ()
    leader: str = ""
    reason: str = ""
    stamp: float = 0.0

    def __post_init__(self) -> None:
        check_id(self.oid, "oid")
        _one_of(self.state, ORDER_STATES, "state")
        _whole(self, "round", 0)
        _roster(self, "roster")
        _optional_id(self.leader, "leader")
        if not isinstance(self.reason, str) or len(self.reason) > MAX_REASON:
            raise ValueError(f"reason must be text of at most {MAX_REASON} characters")
        check_floats(self, ("stamp",))


@dataclass(frozen=True, slots=True)
class LoadEntry:
    """One load as the world sees it: ``name``, its load ``type``, its pose (x, y [m], yaw
    [rad]) in the world frame, ``state`` (one of :data:`LOAD_STATES`), the station it rests at
    ("" between stations) and the order moving it ("" none)."""

    name: str
    type: str
    x: float
    y: float
    yaw: float
    state: str
    station: str = ""
    order: str = ""

    def __post_init__(self) -> None:
        check_id(self.name, "name")
        check_id(self.type, "type")
        check_floats(self, ("x", "y", "yaw"))
        _one_of(self.state, LOAD_STATES, "state")
        _optional_id(self.station, "station")
        _optional_id(self.order, "order")


@dataclass(frozen=True, slots=True)
class LoadsMsg:
    """Every load of the warehouse at ``stamp`` [s], as the world puts it after each frame."""

    stamp: float
    loads: tuple[LoadEntry, ...] = ()

    def __post_init__(self) -> None:
        check_floats(self, ("stamp",))
        loads = tuple(self.loads)
        if len(loads) > MAX_LOADS:
            raise ValueError(f"loads must hold at most {MAX_LOADS} loads, got {len(loads)}")
        for k, entry in enumerate(loads):
            if not isinstance(entry, LoadEntry):
                raise ValueError(f"loads[{k}] must be a LoadEntry, got {type(entry).__name__}")
        names = [entry.name for entry in loads]
        if len(set(names)) != len(names):
            raise ValueError(f"loads names a load twice: {names!r}")
        object.__setattr__(self, "loads", loads)


OrderMessage = OrderMsg | BidMsg | OrderStatusMsg
_V1 = UInt8(WIRE_VERSION)


def encode_order(msg: OrderMessage) -> bytes:
    """Serialize an order, bid or status (layouts above)."""
    if isinstance(msg, OrderMsg):
        t: tuple[Any, ...] = (_V1, msg.oid, msg.kind, msg.type, msg.load, msg.source, msg.to,
                              float(msg.priority), msg.stamp)
    elif isinstance(msg, BidMsg):
        t = (_V1, msg.oid, msg.robot, float(msg.round), msg.phase, list(msg.costs),
             list(msg.roster), msg.stamp)
    elif isinstance(msg, OrderStatusMsg):
        t = (_V1, msg.oid, msg.state, float(msg.round), list(msg.roster), msg.leader, msg.reason,
             msg.stamp)
    else:
        raise ValueError(f"msg must be an OrderMsg, BidMsg or OrderStatusMsg, got {type(msg).__name__}")
    return z_serialize(t).to_bytes()


def encode_loads(msg: LoadsMsg) -> bytes:
    """Serialize the world's loads (layout above)."""
    return z_serialize((_V1, msg.stamp, [(e.name, e.type, e.x, e.y, e.yaw, e.state, e.station,
                                          e.order) for e in msg.loads])).to_bytes()


def _ids(r: Reader, name: str) -> tuple[str, ...]:
    n = r.count(name, MAX_SLOTS)
    return tuple(r.string(f"{name}[{k}]") for k in range(n))


def _parse_order(r: Reader) -> OrderMsg:
    oid, kind, type_, load, source, to = (r.string(name) for name in
                                          ("oid", "kind", "type", "load", "source", "to"))
    priority, stamp = r.floats(2, "priority, stamp")
    return OrderMsg(oid, kind, type_, load, source, to, priority, stamp)


def _parse_bid(r: Reader) -> BidMsg:
    oid, robot = r.string("oid"), r.string("robot")
    (round_,) = r.floats(1, "round")
    phase = r.string("phase")
    n = r.count("costs", MAX_SLOTS)
    costs = tuple(r.floats(1, f"costs[{k}]")[0] for k in range(n))
    roster = _ids(r, "roster")
    (stamp,) = r.floats(1, "stamp")
    return BidMsg(oid, robot, round_, phase, costs, roster, stamp)  # type: ignore[arg-type]


def _parse_status(r: Reader) -> OrderStatusMsg:
    oid, state = r.string("oid"), r.string("state")
    (round_,) = r.floats(1, "round")
    roster = _ids(r, "roster")
    leader, reason = r.string("leader"), r.string("reason")
    (stamp,) = r.floats(1, "stamp")
    return OrderStatusMsg(oid, state, round_, roster, leader, reason, stamp)  # type: ignore[arg-type]


def _read_load(r: Reader, k: int) -> LoadEntry:
    name, type_ = r.string(f"loads[{k}].name"), r.string(f"loads[{k}].type")
    x, y, yaw = r.floats(3, f"loads[{k}].pose")
    state, station, order = (r.string(f"loads[{k}].{f}") for f in ("state", "station", "order"))
    return LoadEntry(name, type_, x, y, yaw, state, station, order)


def _parse_loads(r: Reader) -> LoadsMsg:
    (stamp,) = r.floats(1, "stamp")
    n = r.count("loads", MAX_LOADS)
    return LoadsMsg(stamp, tuple(_read_load(r, k) for k in range(n)))


def decode_loads(payload: bytes | zenoh.ZBytes) -> LoadsMsg:
    """Decode a ``loads`` payload; raises only :class:`wire.reader.DecodeError`."""
    return decode_payload(payload, _parse_loads, "loads")


def decode_order(payload: bytes | zenoh.ZBytes) -> OrderMsg:
    """Decode an ``order`` payload; raises only :class:`wire.reader.DecodeError`."""
    return decode_payload(payload, _parse_order, "order")


def decode_bid(payload: bytes | zenoh.ZBytes) -> BidMsg:
    """Decode a ``bid`` payload; raises only :class:`wire.reader.DecodeError`."""
    return decode_payload(payload, _parse_bid, "bid")


def decode_order_status(payload: bytes | zenoh.ZBytes) -> OrderStatusMsg:
    """Decode an order ``status`` payload; raises only :class:`wire.reader.DecodeError`."""
    return decode_payload(payload, _parse_status, "order status")


def order_key(prefix: str, oid: str) -> str:
    """``{prefix}/order/{oid}``."""
    keys.validate_id(oid, "order id")
    return f"{prefix}/order/{oid}"


def all_orders_key(prefix: str) -> str:
    """``{prefix}/order/*``: every order (the fleet manager's queryable; a robot's query)."""
    return f"{prefix}/order/*"


def bid_key(prefix: str, oid: str, rid: str) -> str:
    """``{prefix}/order/{oid}/bid/{rid}``: robot ``rid``'s bids and votes on order ``oid``."""
    keys.validate_id(rid, "robot id")
    return f"{order_key(prefix, oid)}/bid/{rid}"


def bids_key(prefix: str, oid: str) -> str:
    """``{prefix}/order/{oid}/bid/*``: every robot's bids on one open order."""
    return f"{order_key(prefix, oid)}/bid/*"


def order_status_key(prefix: str, oid: str) -> str:
    """``{prefix}/order/{oid}/status``."""
    return f"{order_key(prefix, oid)}/status"


def parse_order_key(key: str, prefix: str) -> tuple[str, str, str] | None:
    """``(oid, what, rid)`` of an order key under ``prefix`` (``what``: ``order``, ``bid`` or
    ``status``; ``rid`` only for a bid), or None for any other key (an invalid id included)."""
    head = f"{prefix}/order/"
    if not key.startswith(head):
        return None
    parts = key[len(head):].split("/")
    try:
        for part in parts[::2]:
            keys.validate_id(part, "id")
    except ValueError:
        return None
    if len(parts) == 1:
        return parts[0], "order", ""
    if len(parts) == 2 and parts[1] == "status":
        return parts[0], "status", ""
    if len(parts) == 3 and parts[1] == "bid":
        return parts[0], "bid", parts[2]
    return None


def bid_is_forged(key: str, prefix: str, msg: BidMsg) -> bool:
    """Whether a bid arrived on a key other than its own (``order/{msg.oid}/bid/{msg.robot}``):
    a robot may speak only for itself and only about the order its key names."""
    return parse_order_key(key, prefix) != (msg.oid, "bid", msg.robot)


def is_forged(key: str, prefix: str, msg: OrderMessage) -> bool:
    """Whether ``msg`` arrived on a key other than its own: an order or a status on the key of
    another order (or of another kind), a bid as :func:`bid_is_forged` says."""
    if isinstance(msg, BidMsg):
        return bid_is_forged(key, prefix, msg)
    what = "order" if isinstance(msg, OrderMsg) else "status"
    return parse_order_key(key, prefix) != (msg.oid, what, "")


_BY_WHAT: dict[str, Callable[[bytes | zenoh.ZBytes], OrderMessage]] = {
    "order": decode_order, "bid": decode_bid, "status": decode_order_status}


def read_order_message(prefix: str, key: str, payload: bytes | zenoh.ZBytes) -> OrderMessage:
    """The order, bid or status of a sample on ``key``, decoded by the key's kind; raises only
    :class:`wire.reader.DecodeError`, for a key that is no order key, a malformed payload or a
    forged message (:func:`is_forged`), so a receiver drops and counts all three alike."""
    parsed = parse_order_key(key, prefix)
    if parsed is None:
        raise DecodeError(f"{key}: not an order key")
    msg: OrderMessage = _BY_WHAT[parsed[1]](payload)
    if is_forged(key, prefix, msg):
        raise DecodeError(f"{key}: forged (the message names order {msg.oid!r})")
    return msg


def ask_orders(session: zenoh.Session, selector: str,
               decode: Callable[[bytes | zenoh.ZBytes], Any], timeout: float) -> dict[str, Any]:
    """Every reply to ``selector`` decoded with ``decode``, by order id (a malformed reply is
    skipped; of two for one order, the later kept)."""
    return {msg.oid: msg for msg in decoded_replies(session, selector, decode, timeout)}


def order_book(session: zenoh.Session, prefix: str, timeout: float
               ) -> tuple[dict[str, OrderMsg], dict[str, OrderStatusMsg]]:
    """The fleet manager's order book, asked on its two queryables: every order (as posted,
    priority current) and every order's last status, by id. What a robot that starts late or
    restarts asks first, and what ``formation orders`` prints."""
    orders = all_orders_key(keys.validate_prefix(prefix))
    return (ask_orders(session, orders, decode_order, timeout),
            ask_orders(session, f"{orders}/status", decode_order_status, timeout))
