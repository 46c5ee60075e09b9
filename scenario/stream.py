"""The seeded order stream (``order_stream``): Poisson arrivals that post only servable orders.

Arrivals are a Poisson process of ``rate_per_min`` from ``start`` to ``until``: exponential gaps
of mean ``60 / rate_per_min`` s, drawn in blocks of :data:`BLOCK` from
``numpy.random.default_rng((seed, 0, block))``, so the k-th arrival's time never depends on how
the simulated time is cut into steps. At each arrival the warehouse's state, a :class:`Yard`
(which load rests at which station, which stations open orders hold, which loads they move),
decides what can be served:

* a **storage** order: a new load of one of the stream's ``types`` appears at a free source (no
  load resting there, no open order holding it) and goes to a free store (no load, not held);
* a **retrieval** order: the load resting at a full store (not claimed by an open order) goes
  to a free sink.

When both are possible each is taken with probability 1/2; the stations and the type are then
drawn uniformly, from candidates sorted by name, with ``default_rng((seed, 1, k))`` for the
k-th arrival. An arrival that can serve nothing posts nothing. Posted orders are named ``s1,
s2, ...`` in posting order, hold their stations and claim their load in the yard returned, so
two arrivals of one step never share a destination.

:func:`post` is the step a running warehouse calls with its own yard; :func:`plan` is the whole
stream computed before anything moves, with the ledger of a warehouse that delivers every
order the moment it is posted (explicit orders included, at their times), the list the Monte
Carlo draw checks for servability. Both are pure: the same model, times and yard give the same
orders.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace

import numpy as np

from .lifelong import SINK, SOURCE, STORE, Lifelong, Order, OrderStream

BLOCK = 256  # arrivals drawn per block of the arrival generator
STORAGE, RETRIEVAL = "storage", "retrieval"
STREAM_PREFIX = "s"

_ARRIVALS: dict[OrderStream, list[float]] = {}  # a memo of arrival times drawn so far


@dataclass(frozen=True)
class Yard:
    """The warehouse's state as the stream sees it."""

    resting: Mapping[str, str] = field(default_factory=dict)  # station -> the load resting there
    held: frozenset[str] = frozenset()  # stations an open order goes to, or brings a load from
    claimed: frozenset[str] = frozenset()  # loads an open order moves
    posted: int = 0  # stream orders posted so far: the next is s{posted + 1}
    arrivals: int = 0  # arrivals seen so far (those that posted nothing included)


def initial_yard(life: Lifelong) -> Yard:
    """The yard at t = 0: the resting loads, nothing held or claimed."""
    return Yard(resting={ld.at: ld.name for ld in life.loads})


def arrival_times(stream: OrderStream, t: float) -> tuple[float, ...]:
    """The arrival times of ``stream`` up to ``t`` (and ``until``), in order [s]."""
    end = min(t, stream.until)
    if stream.rate_per_min <= 0.0 or end < stream.start:
        return ()
    times = _ARRIVALS.setdefault(stream, [])
    while not times or times[-1] <= end:
        block = len(times) // BLOCK
        gaps = np.random.default_rng((stream.seed, 0, block)).standard_exponential(BLOCK)
        last = times[-1] if times else stream.start
        for g in gaps * (60.0 / stream.rate_per_min):
            last += float(g)
            times.append(last)
    return tuple(times[:bisect.bisect_right(times, end)])


def post(life: Lifelong, t0: float, t1: float, yard: Yard) -> tuple[tuple[Order, ...], Yard]:
    """The stream's orders arriving in ``(t0, t1]`` for a warehouse in ``yard``, and the yard
    with them posted (their stations held, their loads claimed, the counts advanced)."""
    stream = life.stream
    if stream is None:
        return (), yard
    out: list[Order] = []
    times = arrival_times(stream, t1)
    for k in range(max(yard.arrivals, bisect.bisect_right(times, t0)) + 1, len(times) + 1):
        order = choose(life, yard, k, times[k - 1])
        yard = replace(yard, arrivals=k)
        if order is not None:
            out.append(order)
            yard = hold(yard, order, new=True)
    return tuple(out), yard


def hold(yard: Yard, order: Order, new: bool = False) -> Yard:
    """``yard`` with ``order`` open: its destination held, and its source too for a new load
    (until lifted), its load claimed; ``new``: a stream order (the count advances)."""
    held = {order.to} | ({order.from_} if order.type is not None and order.from_ else set())
    return replace(yard, held=yard.held | held, claimed=yard.claimed | {order.load_name},
                   posted=yard.posted + (1 if new else 0))


def choose(life: Lifelong, yard: Yard, k: int, t: float) -> Order | None:
    """The order the k-th arrival, at ``t``, posts in ``yard``, or None when nothing is
    servable."""
    stream = life.stream
    assert stream is not None
    free = [s.name for s in life.stations if s.name not in yard.resting and s.name not in yard.held]
    sources = sorted(n for n in free if life.station(n).kind == SOURCE)
    stores = sorted(n for n in free if life.station(n).kind == STORE)
    sinks = sorted(n for n in free if life.station(n).kind == SINK)
    full = sorted(st for st, load in yard.resting.items()
                  if life.station(st).kind == STORE and load not in yard.claimed
                  and st not in yard.held)
    kinds = ([STORAGE] if sources and stores else []) + ([RETRIEVAL] if full and sinks else [])
    if not kinds:
        return None
    rng = np.random.default_rng((stream.seed, 1, k))
    kind = kinds[int(rng.integers(len(kinds)))]
    oid = f"{STREAM_PREFIX}{yard.posted + 1}"
    if kind == STORAGE:
        return Order(oid, t, _pick(rng, stores), type=_pick(rng, list(stream.types)),
                     from_=_pick(rng, sources))
    store = _pick(rng, full)
    return Order(oid, t, _pick(rng, sinks), load=yard.resting[store], from_=store)


def _pick(rng: np.random.Generator, names: list[str]) -> str:
    return names[int(rng.integers(len(names)))]


def deliver(life: Lifelong, yard: Yard, order: Order) -> Yard:
    """``yard`` once ``order`` is delivered: its load rests at ``to`` (at a sink it leaves), its
    source (if any) is free, its stations and load released."""
    resting = {st: ld for st, ld in yard.resting.items() if ld != order.load_name}
    if life.station(order.to).kind != SINK:
        resting[order.to] = order.load_name
    released = {order.to} | ({order.from_} if order.from_ else set())
    return replace(yard, resting=resting, held=yard.held - released,
                   claimed=yard.claimed - {order.load_name})


def plan(life: Lifelong, until: float = math.inf) -> tuple[Order, ...]:
    """Every stream order up to ``until`` (and the stream's own end), posted against the ledger
    of a warehouse that delivers each order, explicit ones included, the moment it is posted."""
    stream = life.stream
    if stream is None:
        return ()
    yard = initial_yard(life)
    explicit = sorted(life.orders, key=lambda o: (o.t, o.id))
    out: list[Order] = []
    times = arrival_times(stream, min(until, stream.until))
    k, e = 0, 0
    while k < len(times) or e < len(explicit):
        if e < len(explicit) and (k >= len(times) or explicit[e].t <= times[k]):
            yard = _deliver_explicit(life, yard, explicit[e])
            e += 1
            continue
        order = choose(life, yard, k + 1, times[k])
        k += 1
        yard = replace(yard, arrivals=k)
        if order is not None:
            out.append(order)
            yard = deliver(life, hold(yard, order, new=True), order)
    return tuple(out)


def _deliver_explicit(life: Lifelong, yard: Yard, order: Order) -> Yard:
    """The ledger after an explicit order: delivered at once when its load can move (a new
    load, or one that rests somewhere) and its destination is free; left out otherwise."""
    rests = order.type is not None or order.load_name in yard.resting.values()
    if not rests or order.to in yard.resting:
        return yard
    return deliver(life, yard, order)
