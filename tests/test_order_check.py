"""A robot's check of a posted order (agent.order_check) against the fleet manager's
(simulator.manager): the same rule over the same warehouse (scenario.servable), so every order
the manager refuses the robots refuse too, whichever orders a robot missed."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from agent.order_check import acceptable, open_in_book
from scenario.lifelong import Load
from scenario.load import load_scenario
from scenario.servable import WORK_KINDS, movable_loads
from simulator.manager import REFUSED, new_book, take_order
from wire.orders import OrderMsg, OrderStatusMsg

TESTS = Path(__file__).resolve().parent
CHAINED = load_scenario(TESTS / "scenarios" / "lifelong-chained.yaml").lifelong
assert CHAINED is not None
LIFE = replace(CHAINED, loads=(Load("p1", "beam", "rack-2"),))  # one load resting at t = 0

IDS = [f"m{k}" for k in range(8)]
STATIONS = [*LIFE.station_by_name, "dock-9"]
TYPES = [*LIFE.type_by_name, "crate"]
LOADS = ["p1", "p9", *IDS]  # resting, unknown, and loads that new orders may bring


@st.composite
def order(draw, oid: str) -> OrderMsg:
    kind = draw(st.sampled_from(WORK_KINDS))
    to = draw(st.sampled_from(STATIONS))
    if kind == "new":
        return OrderMsg(oid, "new", type=draw(st.sampled_from(TYPES)),
                        source=draw(st.sampled_from(STATIONS)), to=to)
    source = draw(st.sampled_from(["", *STATIONS]))
    return OrderMsg(oid, "load", load=draw(st.sampled_from(LOADS)), source=source, to=to)


@st.composite
def posting(draw) -> list[tuple[OrderMsg, bool]]:
    """Orders under distinct ids, each posted once or twice, each marked heard or missed by
    one robot."""
    oids = draw(st.lists(st.sampled_from(IDS), unique=True, min_size=1, max_size=len(IDS)))
    out = []
    for oid in oids:
        msg = draw(order(oid))
        for _ in range(draw(st.integers(1, 2))):
            out.append((msg, draw(st.booleans())))
    return out


class Robot:
    """What a robot keeps of the orders it hears: the first message under each id, whether it
    accepted it, and so the loads it knows (as an agent's resolve keeps them)."""

    def __init__(self) -> None:
        self.accepted: dict[str, bool] = {}
        self.new: list[str] = []

    def hear(self, msg: OrderMsg) -> str | None:
        problem = acceptable(LIFE, msg, movable_loads(LIFE, self.new))
        if msg.oid not in self.accepted:
            self.accepted[msg.oid] = problem is None
            if problem is None and msg.kind == "new":
                self.new.append(msg.oid)
        return problem


def refused_by_manager(msgs: list[OrderMsg]) -> dict[str, bool]:
    book = new_book(LIFE)
    for msg in msgs:
        book = take_order(LIFE, book, msg, 1.0)
    return {oid: e.status.reason.startswith(REFUSED) for oid, e in book.entries.items()}


@settings(max_examples=300, deadline=None)
@given(posting())
def test_every_order_the_manager_refuses_a_robot_refuses_whatever_it_missed(posted) -> None:
    refused = refused_by_manager([m for m, _ in posted])
    robot = Robot()
    for msg, heard in posted:
        if heard:
            problem = robot.hear(msg)
            if refused[msg.oid]:
                assert problem is not None, msg


@settings(max_examples=200, deadline=None)
@given(posting())
def test_a_robot_that_hears_every_order_refuses_exactly_what_the_manager_refuses(posted) -> None:
    refused = refused_by_manager([m for m, _ in posted])
    robot = Robot()
    for msg, _ in posted:
        robot.hear(msg)
    assert {oid: not ok for oid, ok in robot.accepted.items()} == refused


@pytest.mark.parametrize("msg, why", [
    (OrderMsg("m1", "new", type="crate", source="in-1", to="rack-2"), "type: unknown load type"),
    (OrderMsg("m1", "new", type="pallet", source="rack-3", to="rack-2"), "from: 'rack-3'"),
    (OrderMsg("m1", "new", type="pallet", source="in-1", to="in-2"), "to: 'in-2'"),
    (OrderMsg("m1", "load", load="p9", to="rack-2"), "load: unknown load 'p9'"),
    (OrderMsg("m1", "load", load="p1", source="dock-9", to="out-1"), "from: unknown station"),
])
def test_a_robot_names_the_culprit_of_an_order_it_refuses(msg, why) -> None:
    problem = acceptable(LIFE, msg, movable_loads(LIFE, ()))
    assert problem is not None and why in problem


def test_an_order_the_warehouse_can_serve_is_acceptable_and_its_new_load_movable() -> None:
    new = OrderMsg("m1", "new", type="pallet", source="in-1", to="rack-1")
    assert acceptable(LIFE, new, movable_loads(LIFE, ())) is None
    moved = OrderMsg("m2", "load", load="m1", to="out-2")
    assert acceptable(LIFE, moved, movable_loads(LIFE, ())) is not None  # m1 not heard yet
    assert acceptable(LIFE, moved, movable_loads(LIFE, ["m1"])) is None
    assert acceptable(LIFE, OrderMsg("m1", "cancel"), frozenset()) is None  # no work of its own


def test_a_restarted_robot_keeps_only_the_open_orders_of_the_book() -> None:
    orders = {oid: OrderMsg(oid, "load", load="p1", to="out-1") for oid in ("a", "b", "c", "d", "e")}
    statuses = {"a": OrderStatusMsg("a", "delivered"), "b": OrderStatusMsg("b", "waiting"),
                "c": OrderStatusMsg("c", "failed", reason=REFUSED + "to: 'x'"),
                "d": OrderStatusMsg("d", "carrying", 1, ("f1", "f2"), "f1")}
    assert sorted(open_in_book(orders, statuses)) == ["b", "d", "e"]
