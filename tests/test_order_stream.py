"""scenario.stream: the seeded order stream posts only orders the warehouse can serve (storage:
a free source to a free store; retrieval: a full store to a free sink), names them s1, s2, ...,
draws Poisson arrivals at its rate, and gives the same orders for the same inputs however the
simulated time is cut into steps."""

from __future__ import annotations

import math
import statistics

from hypothesis import given, settings
from hypothesis import strategies as st

from scenario.lifelong import (
    SINK,
    SOURCE,
    STORE,
    Fleet,
    FleetRobot,
    Lifelong,
    Load,
    LoadType,
    Order,
    OrderStream,
    Station,
)
from scenario.stream import Yard, arrival_times, deliver, hold, initial_yard, plan, post

PALLET = LoadType("pallet", (0.8, 0.6), ((0.3, 0.2), (-0.3, 0.2), (-0.3, -0.2), (0.3, -0.2)))
BEAM = LoadType("beam", (1.4, 0.3), ((0.6, 0.0), (-0.6, 0.0)))


def hall(sources: int, sinks: int, stores: int, full: int, rate: float, seed: int,
         until: float = 3600.0, start: float = 0.0) -> Lifelong:
    """A hall with the given stations in a row, ``full`` of the stores holding a pallet."""
    stations = ([Station(f"in{k}", (0.0, 2.0 * k, 0.0), SOURCE) for k in range(sources)]
                + [Station(f"out{k}", (4.0, 2.0 * k, 0.0), SINK, 5.0) for k in range(sinks)]
                + [Station(f"rack{k}", (8.0, 2.0 * k, 0.0), STORE) for k in range(stores)])
    loads = tuple(Load(f"p{k}", "pallet", f"rack{k}") for k in range(min(full, stores)))
    fleet = Fleet(tuple(FleetRobot(f"r{k}", (float(k), -2.0, 0.0)) for k in range(4)))
    return Lifelong(fleet, tuple(stations), (PALLET, BEAM), loads, (),
                    OrderStream(rate, seed, ("pallet", "beam"), until, start))


halls = st.builds(hall, sources=st.integers(0, 3), sinks=st.integers(0, 3),
                  stores=st.integers(1, 6), full=st.integers(0, 6),
                  rate=st.floats(0.2, 12.0), seed=st.integers(0, 2**32))


def servable(life: Lifelong, yard: Yard, order: Order) -> str | None:
    """Why ``order`` cannot be served in ``yard``, or None when it can."""
    to = life.station(order.to)
    if order.to in yard.held or order.to in yard.resting:
        return f"{order.id}: destination {order.to} is not free"
    if order.type is not None:
        src = life.station(str(order.from_))
        if src.kind != SOURCE or src.name in yard.resting or src.name in yard.held:
            return f"{order.id}: source {order.from_} is not a free source"
        return None if to.kind == STORE else f"{order.id}: a storage order to a {to.kind}"
    if yard.resting.get(str(order.from_)) != order.load or order.load in yard.claimed:
        return f"{order.id}: load {order.load} does not rest unclaimed at {order.from_}"
    if life.station(str(order.from_)).kind != STORE or to.kind != SINK:
        return f"{order.id}: a retrieval from {order.from_} to {order.to}"
    return None


def run_warehouse(life: Lifelong, dt: float, delay: float, end: float) -> list[str]:
    """Step the stream over a warehouse that delivers each order ``delay`` s after posting;
    the problems found (an unservable order, a bad name, a destination held twice)."""
    yard, open_orders, problems, names = initial_yard(life), [], [], []
    t = 0.0
    while t < end:
        t1 = t + dt
        due = [o for o in open_orders if o.t + delay <= t1]
        for o in due:
            yard = deliver(life, yard, o)
            open_orders.remove(o)
        before = yard
        orders, yard = post(life, t, t1, yard)
        check = before
        for o in orders:
            why = servable(life, check, o)
            if why is not None:
                problems.append(why)
            check = hold(check, o, new=True)
            names.append(o.id)
        open_orders += orders
        targets = [o.to for o in open_orders]
        if len(targets) != len(set(targets)):
            problems.append(f"t={t1}: two open orders go to one station")
        t = t1
    if names != [f"s{k}" for k in range(1, len(names) + 1)]:
        problems.append(f"names {names[:5]}... are not s1, s2, ...")
    return problems


@settings(max_examples=60, deadline=None)
@given(halls, st.floats(5.0, 300.0))
def test_a_stream_over_a_working_warehouse_posts_only_servable_orders(life, delay):
    assert run_warehouse(life, 7.0, delay, 1800.0) == []


@settings(max_examples=40, deadline=None)
@given(halls, st.lists(st.floats(0.0, 1800.0), max_size=12))
def test_the_orders_do_not_depend_on_how_time_is_cut_into_steps(life, cuts):
    whole, _ = post(life, 0.0, 1800.0, initial_yard(life))
    yard, pieces = initial_yard(life), []
    edges = [0.0, *sorted(cuts), 1800.0]
    for t0, t1 in zip(edges, edges[1:], strict=False):
        got, yard = post(life, t0, t1, yard)
        pieces += got
    assert pieces == list(whole)
    again, _ = post(life, 0.0, 1800.0, initial_yard(life))
    assert again == whole


@settings(max_examples=60, deadline=None)
@given(halls)
def test_the_planned_stream_is_servable_against_its_ledger(life):
    orders = plan(life)
    assert plan(life) == orders
    yard = initial_yard(life)
    for o in orders:
        assert servable(life, yard, o) is None, o
        yard = deliver(life, hold(yard, o, new=True), o)
    assert [o.id for o in orders] == [f"s{k}" for k in range(1, len(orders) + 1)]
    assert all(a.t < b.t for a, b in zip(orders, orders[1:], strict=False))


def test_a_hall_that_can_serve_something_gets_orders_and_one_that_cannot_gets_none():
    assert len(plan(hall(1, 1, 3, 0, 6.0, 1))) > 100  # storage and retrieval alternate
    kinds = {o.type is None for o in plan(hall(1, 1, 3, 0, 6.0, 1))}
    assert kinds == {True, False}
    assert plan(hall(0, 1, 3, 0, 6.0, 1)) == ()  # no source and nothing stored: nothing to do
    only_out = plan(hall(0, 1, 3, 3, 6.0, 1))  # three pallets stored, no source: three retrievals
    assert [o.load for o in only_out] == ["p0", "p1", "p2"] or sorted(
        str(o.load) for o in only_out) == ["p0", "p1", "p2"]
    assert plan(hall(1, 1, 3, 0, 0.0, 1)) == ()  # rate 0


def test_arrivals_are_poisson_at_the_rate_within_start_and_until():
    rate, hours = 3.0, 20.0
    counts = []
    for seed in range(8):
        stream = OrderStream(rate, seed, ("pallet",), hours * 3600.0)
        times = arrival_times(stream, math.inf)
        counts.append(len(times))
        gaps = [b - a for a, b in zip(times, times[1:], strict=False)]
        assert statistics.mean(gaps) == _within(60.0 / rate, 0.05)
        assert statistics.pstdev(gaps) == _within(60.0 / rate, 0.08)  # exponential: sd = mean
    expected = rate * hours * 60.0
    assert abs(statistics.mean(counts) - expected) < 4.0 * math.sqrt(expected / len(counts))
    window = OrderStream(rate, 3, ("pallet",), 900.0, 300.0)
    times = arrival_times(window, math.inf)
    assert times and 300.0 < times[0] and times[-1] <= 900.0
    assert arrival_times(window, 600.0) == tuple(t for t in times if t <= 600.0)
    assert arrival_times(OrderStream(rate, 4, ("pallet",), 900.0), 600.0) != arrival_times(
        OrderStream(rate, 3, ("pallet",), 900.0), 600.0)


class _within:
    """Equal to any number within ``rel`` of ``value`` (relative)."""

    def __init__(self, value: float, rel: float) -> None:
        self.value, self.rel = value, rel

    def __eq__(self, other: object) -> bool:
        return isinstance(other, float) and abs(other - self.value) <= self.rel * self.value

    def __repr__(self) -> str:
        return f"{self.value} +/- {100 * self.rel:g} %"


def test_explicit_orders_shape_the_planned_stream():
    life = hall(1, 1, 1, 0, 6.0, 2)
    explicit = (Order("o1", 0.0, "rack0", type="pallet", from_="in0"),)
    with_explicit = Lifelong(life.fleet, life.stations, life.load_types, life.loads, explicit,
                             life.stream)
    first = plan(with_explicit)[0]
    assert first.type is None and first.load == "o1"  # the one rack is full: retrieve it first
