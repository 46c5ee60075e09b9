"""A transport order's life: one pure transition function, and the guards that say which
waiting orders may be served.

An order moves a load from a station (``src``) to another (``dst``): a new load that appears at a
source, or a load already resting (at a station, or where a failed team set it down). Its states
are the contract's (DESIGN.md, "Lifelong operation"): ``waiting``, ``assigned``, ``gathering``,
``carrying``, ``delivered``, ``cancelled`` and ``failed`` with a reason; lifting and setting down
are phases inside the moves round ``carrying`` (``lifting``, ``setting-down``), each with its
own time. :func:`step` is the one transition function; the in-process simulator's order book,
an agent and a fleet manager's view all apply it, so they agree on what an event does.

The guards are pure too. A new load waits for its source to be free (:func:`appears`); an order
is open for bids only while its load rests where the order expects it, no other order holds
that load, and its destination is free and reserved by no other order (:func:`biddable`), in
precedence: higher ``priority`` first, then the order posted first, then its id
(:func:`leader.allocation.precedence`'s order). The destination is reserved from the assignment
to the delivery (:func:`reserved_stations`).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

WAITING = "waiting"
ASSIGNED = "assigned"
GATHERING = "gathering"
LIFTING = "lifting"
CARRYING = "carrying"
SETTING_DOWN = "setting-down"
DELIVERED = "delivered"
CANCELLED = "cancelled"
FAILED = "failed"

#: the states an order can be in, phases included
STATES = (WAITING, ASSIGNED, GATHERING, LIFTING, CARRYING, SETTING_DOWN, DELIVERED, CANCELLED,
          FAILED)
#: the states after which nothing happens to the order
FINAL = (DELIVERED, CANCELLED, FAILED)
#: the states in which a team holds the order
TEAMED = (ASSIGNED, GATHERING, LIFTING, CARRYING, SETTING_DOWN)
#: the states in which the load is off the ground
UP = (LIFTING, CARRYING, SETTING_DOWN)
#: each phase's state as the contract reports it (orders.csv, status messages)
REPORTED = {LIFTING: GATHERING, SETTING_DOWN: CARRYING}

# events
POST, ASSIGN, JOIN, GATHERED, LIFTED, ARRIVED, SET_DOWN, LOST, CANCEL = (
    "post", "assign", "join", "gathered", "lifted", "arrived", "set-down", "lost", "cancel")

#: (state, event) -> the state after it; anything else is not a transition
TRANSITIONS: dict[tuple[str, str], str] = {
    (WAITING, ASSIGN): ASSIGNED,
    (WAITING, CANCEL): CANCELLED,
    (ASSIGNED, JOIN): GATHERING,
    (GATHERING, GATHERED): LIFTING,
    (LIFTING, LIFTED): CARRYING,
    (CARRYING, ARRIVED): SETTING_DOWN,
    (SETTING_DOWN, SET_DOWN): DELIVERED,
    (ASSIGNED, LOST): WAITING,
    (GATHERING, LOST): WAITING,
    (LIFTING, LOST): FAILED,
    (CARRYING, LOST): FAILED,
    (SETTING_DOWN, LOST): FAILED,
    (ASSIGNED, CANCEL): CANCELLED,
    (GATHERING, CANCEL): CANCELLED,
    (CARRYING, CANCEL): CANCELLED,
}

#: the time each event records, by the field it fills
STAMPS = {POST: "t_posted", ASSIGN: "t_assigned", GATHERED: "t_gathered", LIFTED: "t_lifted",
          SET_DOWN: "t_delivered"}


@dataclass(frozen=True)
class Order:
    """One order and how far it got. ``load`` names the load it moves (a new load is named by
    the order's id); ``src`` is the station it is taken from (empty for a load resting off any
    station); ``fresh``: a new load that appears at ``src`` when the source is free."""

    oid: str
    type: str
    load: str
    src: str
    dst: str
    priority: float = 0.0
    fresh: bool = False
    state: str = WAITING
    t_posted: float | None = None
    t_assigned: float | None = None
    t_gathered: float | None = None
    t_lifted: float | None = None
    t_delivered: float | None = None
    robots: tuple[str, ...] = ()
    reason: str = ""
    t_done: float | None = None  # when it reached a final state (delivered, cancelled, failed)

    @property
    def reported(self) -> str:
        """The state as the contract names it (a phase reports the state round it)."""
        return REPORTED.get(self.state, self.state)

    @property
    def done(self) -> bool:
        """True once nothing more happens to the order."""
        return self.state in FINAL


@dataclass(frozen=True)
class Event:
    """What happened to an order at ``t``: ``kind`` one of the events above; ``robots`` the
    committed roster (``assign``); ``who`` the member lost (``lost``)."""

    kind: str
    t: float
    robots: tuple[str, ...] = ()
    who: str = ""


def step(order: Order, event: Event) -> Order:
    """The order after ``event`` (ValueError naming both when it is no transition of the order's
    state). A member lost before the lift returns the order to ``waiting`` and releases its
    roster; after the lift it fails with ``member lost: RID``."""
    if event.kind == POST:
        if order.t_posted is not None:
            raise ValueError(f"order {order.oid}: posted twice")
        return replace(order, t_posted=event.t)
    after = TRANSITIONS.get((order.state, event.kind))
    if after is None:
        raise ValueError(f"order {order.oid}: {event.kind!r} is no transition from {order.state!r}")
    changes: dict[str, Any] = {"state": after}
    if after in FINAL:
        changes["t_done"] = event.t
    stamp = STAMPS.get(event.kind)
    if stamp is not None:
        changes[stamp] = event.t
    if event.kind == ASSIGN:
        if not event.robots or len(set(event.robots)) != len(event.robots):
            raise ValueError(f"order {order.oid}: a roster needs distinct robots")
        changes["robots"] = event.robots
    elif event.kind == LOST:
        changes.update(_loss(order, after, event.who))
    return replace(order, **changes)


def _loss(order: Order, after: str, who: str) -> dict[str, Any]:
    if after == WAITING:  # nothing has moved: back to the queue, roster released
        return {"robots": (), "t_assigned": None, "t_gathered": None}
    return {"reason": f"member lost: {who}"}


def precedence(order: Order) -> tuple[float, float, str]:
    """The order's place in the queue: higher priority first, then posted first, then by id."""
    return (-order.priority, order.t_posted if order.t_posted is not None else 0.0, order.oid)


def reserved_stations(orders: Iterable[Order]) -> dict[str, str]:
    """Station -> the order that reserved it: every teamed order's destination."""
    return {o.dst: o.oid for o in orders if o.state in TEAMED}


def held_loads(orders: Iterable[Order]) -> dict[str, str]:
    """Load -> the order whose team holds it (assigned to the delivery)."""
    return {o.load: o.oid for o in orders if o.state in TEAMED}


def appears(order: Order, resting_at: Mapping[str, str]) -> bool:
    """True when ``order``'s new load may appear now: it is waiting, its load is not there yet
    and its source holds no load (``resting_at``: station -> the load resting there)."""
    return (order.fresh and order.state == WAITING and order.load not in resting_at.values()
            and order.src not in resting_at)


def biddable(orders: Sequence[Order], resting_at: Mapping[str, str],
             load_station: Mapping[str, str]) -> list[Order]:
    """The waiting orders open for bids, in precedence: the load rests (a new load at the
    order's source; ``load_station``: every resting load -> its station, empty off any one), no
    other order holds it, and the destination holds no load and is reserved by no other order.
    Of two such orders for one destination or one load only the first in precedence is open."""
    reserved = reserved_stations(orders)
    held = held_loads(orders)
    out: list[Order] = []
    claimed: set[str] = set()
    for order in sorted((o for o in orders if o.state == WAITING and o.t_posted is not None),
                        key=precedence):
        if order.load not in load_station or (order.fresh and load_station[order.load] != order.src):
            continue
        if order.load in held or order.dst in resting_at or order.dst in reserved:
            continue
        if order.dst in claimed or order.load in claimed:
            continue
        claimed.update((order.dst, order.load))
        out.append(order)
    return out
