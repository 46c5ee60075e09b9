"""The order state machine and its guards (leader.orders)."""

from __future__ import annotations

import pytest

from leader import orders as lo
from leader.orders import Event, Order, biddable, step


def posted(oid: str = "o1", t: float = 0.0, **kw) -> Order:
    base = {"type": "pallet", "load": oid, "src": "dock", "dst": "rack", "fresh": True}
    base.update(kw)
    return step(Order(oid, **base), Event(lo.POST, t))


def walk(order: Order, kinds: list[str], t0: float = 1.0) -> Order:
    for k, kind in enumerate(kinds):
        robots = ("r1", "r2") if kind == lo.ASSIGN else ()
        order = step(order, Event(kind, t0 + k, robots))
    return order


def test_a_delivered_order_records_each_time_in_turn():
    o = walk(posted(), [lo.ASSIGN, lo.JOIN, lo.GATHERED, lo.LIFTED, lo.ARRIVED, lo.SET_DOWN])
    assert o.state == lo.DELIVERED and o.done
    assert (o.t_posted, o.t_assigned, o.t_gathered, o.t_lifted, o.t_delivered) == (0, 1, 3, 4, 6)
    assert o.robots == ("r1", "r2")


def test_phases_report_the_state_round_them():
    o = walk(posted(), [lo.ASSIGN, lo.JOIN, lo.GATHERED])
    assert o.state == lo.LIFTING and o.reported == lo.GATHERING
    o = walk(o, [lo.LIFTED, lo.ARRIVED])
    assert o.state == lo.SETTING_DOWN and o.reported == lo.CARRYING


def test_a_member_lost_before_the_lift_returns_the_order_to_the_queue():
    o = walk(posted(), [lo.ASSIGN, lo.JOIN])
    o = step(o, Event(lo.LOST, 5.0, who="r2"))
    assert o.state == lo.WAITING and o.robots == () and o.t_assigned is None and not o.reason


def test_a_member_lost_with_the_load_up_fails_the_order_with_its_name():
    o = walk(posted(), [lo.ASSIGN, lo.JOIN, lo.GATHERED, lo.LIFTED])
    o = step(o, Event(lo.LOST, 9.0, who="r2"))
    assert o.state == lo.FAILED and o.reason == "member lost: r2" and o.done
    assert o.t_done == 9.0


@pytest.mark.parametrize("kind", [lo.JOIN, lo.LIFTED, lo.SET_DOWN, lo.LOST])
def test_an_event_out_of_turn_is_refused(kind):
    with pytest.raises(ValueError, match="no transition"):
        step(posted(), Event(kind, 1.0))


def test_a_roster_must_name_distinct_robots():
    with pytest.raises(ValueError, match="distinct"):
        step(posted(), Event(lo.ASSIGN, 1.0, ("r1", "r1")))


def test_a_delivered_order_takes_no_more_events():
    o = walk(posted(), [lo.ASSIGN, lo.JOIN, lo.GATHERED, lo.LIFTED, lo.ARRIVED, lo.SET_DOWN])
    for kind in (lo.CANCEL, lo.LOST, lo.ASSIGN):
        with pytest.raises(ValueError):
            step(o, Event(kind, 9.0, ("r1",)))


def test_a_new_load_appears_only_at_a_free_source():
    o = posted()
    assert lo.appears(o, {})
    assert not lo.appears(o, {"dock": "other"})
    assert not lo.appears(o, {"rack": "o1"})  # already there


def test_biddable_orders_come_in_precedence_and_respect_stations():
    a = posted("a", 0.0, dst="r1")
    b = posted("b", 1.0, dst="r2", src="dock2", priority=1)
    c = posted("c", 2.0, dst="r1", src="dock3")  # same destination as a: only the first
    at = {"a": "dock", "b": "dock2", "c": "dock3"}
    got = biddable([a, b, c], {"dock": "a", "dock2": "b", "dock3": "c"}, at)
    assert [o.oid for o in got] == ["b", "a"]


def test_a_full_or_reserved_destination_holds_an_order_back():
    a = walk(posted("a", 0.0), [lo.ASSIGN])  # reserves "rack"
    b = posted("b", 1.0, src="dock2")
    assert biddable([a, b], {"dock2": "b"}, {"b": "dock2"}) == []
    c = posted("c", 1.0, src="dock2", dst="full")
    assert biddable([c], {"dock2": "c", "full": "x"}, {"c": "dock2", "x": "full"}) == []


def test_an_order_for_a_load_not_resting_waits():
    chained = posted("o2", 1.0, load="o1", src="", fresh=False)
    assert biddable([chained], {}, {}) == []
    assert biddable([chained], {"rack-2": "o1"}, {"o1": "rack-2"}) == [chained]
