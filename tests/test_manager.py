"""The fleet manager (simulator/manager.py): its pure order book (posting due orders, refusing
what the scenario cannot serve, statuses, cancels, the stream's yard), its journal, and the
Zenoh part on a real router: it answers the order queryables, drops forged and malformed
samples, and a manager restarted mid-way answers the same queries."""

from __future__ import annotations

import os
import queue
import subprocess
import sys
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest
import zenoh

from runtime.testing import RouterProcess
from scenario.load import load_scenario
from simulator.manager import (
    JOURNAL,
    REFUSED,
    FleetManager,
    due,
    journal_line,
    message_fields,
    new_book,
    replay,
    run_manager,
    take_order,
    take_status,
)
from wire import keys
from wire.orders import (
    BidMsg,
    OrderMsg,
    OrderStatusMsg,
    decode_order,
    decode_order_status,
    encode_order,
    order_key,
    order_status_key,
)
from wire.zconf import ZenohSettings

TESTS = Path(__file__).resolve().parent
P = keys.DEFAULT_PREFIX
LIFE = load_scenario(TESTS / "scenarios" / "lifelong-chained.yaml").lifelong
STREAM = load_scenario(TESTS / "scenarios" / "lifelong-stream-unicycle.yaml").lifelong
assert LIFE is not None and STREAM is not None


def posted(t: float, book=None):
    """The book after posting (and taking) every order due by ``t``."""
    book = new_book(LIFE) if book is None else book
    msgs, book = due(LIFE, book, t, stamp=t)
    for m in msgs:
        book = take_order(LIFE, book, m, t)
    return msgs, book


def test_scenario_orders_are_posted_once_when_due_and_wait():
    msgs, book = posted(0.0)
    assert [m.oid for m in msgs] == ["o1", "o2"]
    assert msgs[0] == OrderMsg("o1", "new", type="pallet", source="in-1", to="rack-1", stamp=0.0)
    assert msgs[1].kind == "load" and msgs[1].load == "o1"
    assert {oid: e.status.state for oid, e in book.entries.items()} == {"o1": "waiting",
                                                                         "o2": "waiting"}
    again, book = posted(5.0, book)
    assert again == ()
    later, book = posted(10.0, book)
    assert [m.oid for m in later] == ["o3"]


@pytest.mark.parametrize("msg, why", [
    (OrderMsg("m1", "new", type="crate", source="in-1", to="rack-2"), "type: unknown load type"),
    (OrderMsg("m1", "new", type="pallet", source="rack-3", to="rack-2"), "no source"),
    (OrderMsg("m1", "new", type="pallet", source="in-1", to="in-2"), "no store or sink"),
    (OrderMsg("m1", "load", load="p9", to="rack-2"), "unknown load 'p9'"),
])
def test_an_order_the_scenario_cannot_serve_is_kept_as_refused(msg, why):
    book = take_order(LIFE, new_book(LIFE), msg, 1.0)
    status = book.entries["m1"].status
    assert status.state == "failed" and status.reason.startswith(REFUSED) and why in status.reason


def test_statuses_move_an_order_and_a_final_state_sticks():
    _, book = posted(0.0)
    book = take_status(LIFE, book, OrderStatusMsg("o1", "assigned", 3, ("f1", "f2", "f3", "f4"),
                                                  "f1", stamp=4.0))
    assert book.entries["o1"].status.roster == ("f1", "f2", "f3", "f4")
    book = take_status(LIFE, book, OrderStatusMsg("o1", "delivered", 3, ("f1",), "f1", stamp=9.0))
    assert book.yard.resting == {"rack-1": "o1"} and "rack-1" not in book.yard.held
    same = take_status(LIFE, book, OrderStatusMsg("o1", "carrying", 3, ("f1",), "f1", stamp=9.5))
    assert same is book
    unknown = take_status(LIFE, book, OrderStatusMsg("zz", "assigned", stamp=1.0))
    assert unknown is book


def test_a_waiting_order_is_cancelled_by_the_book_a_teamed_one_by_its_leader():
    _, book = posted(0.0)
    book = take_order(LIFE, book, OrderMsg("o2", "cancel", stamp=1.0), 1.0)
    assert book.entries["o2"].status.state == "cancelled"
    book = take_status(LIFE, book, OrderStatusMsg("o1", "gathering", 1, ("f1", "f2"), "f1"))
    kept = take_order(LIFE, book, OrderMsg("o1", "cancel", stamp=2.0), 2.0)
    assert kept is book  # the team's leader says when it is cancelled
    raised = take_order(LIFE, book, OrderMsg("o1", "priority", priority=5, stamp=2.0), 2.0)
    assert raised.entries["o1"].order.priority == 5.0
    assert raised.entries["o1"].order.to == "rack-1"  # the order itself is kept


def test_the_stream_posts_only_servable_orders_and_holds_their_stations():
    book = new_book(STREAM)
    names: list[str] = []
    for t in range(0, 600, 10):
        msgs, book = due(STREAM, book, float(t), stamp=float(t))
        for m in msgs:
            book = take_order(STREAM, book, m, float(t))
            names.append(m.oid)
    assert names == [f"s{k}" for k in range(1, len(names) + 1)] and len(names) >= 2
    assert all(not e.status.reason for e in book.entries.values())  # none refused
    open_dst = [e.order.to for e in book.entries.values()]
    assert len(set(open_dst)) == len(open_dst)  # never two open orders for one destination


def test_replaying_the_journal_gives_the_same_book():
    lines = []
    book = new_book(LIFE)
    for t in (0.0, 10.0):
        msgs, book = due(LIFE, book, t, stamp=t)
        for m in msgs:
            book = take_order(LIFE, book, m, t)
            lines.append(journal_line(t, "order", message_fields(m)))
    status = OrderStatusMsg("o1", "assigned", 2, ("f1", "f2", "f3", "f4"), "f1", stamp=3.0)
    book = take_status(LIFE, book, status)
    lines.append(journal_line(10.0, "status", message_fields(status)))
    lines.append("{\"t\": 11.0, \"order\": {\"oid\": ")  # torn by a crash mid-write
    again = replay(LIFE, lines)
    assert again.entries == book.entries
    assert again.yard == book.yard and again.t == book.t


# ---------------------------------------------------------------------------- over Zenoh


@pytest.fixture(scope="module")
def router() -> Iterator[RouterProcess]:
    with RouterProcess() as r:
        yield r


def session(router: RouterProcess) -> zenoh.Session:
    return zenoh.open(ZenohSettings(mode="client", connect=(router.endpoint,),
                                    multicast_scouting=False).to_config())


def ask(s: zenoh.Session, selector: str, decode) -> dict[str, object]:
    out = {}
    for reply in s.get(selector, target=zenoh.QueryTarget.ALL,
                       consolidation=zenoh.ConsolidationMode.NONE, timeout=5.0):
        if reply.ok is not None:
            msg = decode(reply.ok.payload.to_bytes())
            out[msg.oid] = msg
    return out


def wait_until(cond, what: str, timeout: float = 10.0) -> None:
    done = threading.Event()
    deadline = threading.Timer(timeout, done.set)
    deadline.start()
    try:
        while not cond():
            if done.wait(0.02):
                raise AssertionError(f"timed out waiting for {what}")
    finally:
        deadline.cancel()


def test_a_restarted_manager_answers_the_same_queries(router, tmp_path):
    leader, client = session(router), session(router)
    heard: queue.SimpleQueue[str] = queue.SimpleQueue()
    sub = client.declare_subscriber(f"{P}/order/*", lambda s: heard.put(str(s.key_expr)))
    try:
        with session(router) as ms:
            manager = FleetManager(ms, LIFE, tmp_path, stamp=lambda: 1.0)
            try:
                assert [m.oid for m in manager.tick(0.0)] == ["o1", "o2"]
                assert {heard.get(timeout=10.0), heard.get(timeout=10.0)} == {
                    order_key(P, "o1"), order_key(P, "o2")}
                roster = ("f1", "f2", "f3", "f4")
                leader.put(order_status_key(P, "o1"), encode_order(
                    OrderStatusMsg("o1", "assigned", 2, roster, "f1", stamp=2.0)))
                # forged (o2's status on o1's key), malformed, and a bid: none is taken
                leader.put(order_status_key(P, "o1"), encode_order(
                    OrderStatusMsg("o2", "delivered", stamp=2.0)))
                leader.put(order_status_key(P, "o2"), b"\x01garbage")
                leader.put(f"{P}/order/o2/bid/f3",
                           encode_order(BidMsg("o2", "f3", 1, "bid", costs=(1.0,))))
                client.put(order_key(P, "m1"), encode_order(
                    OrderMsg("m1", "new", type="crate", source="in-1", to="rack-2", stamp=2.0)))
                wait_until(lambda: manager.dropped == 2 and "m1" in manager.entries()
                           and manager.entries()["o1"].status.state == "assigned",
                           "the manager to take the status and the client's order")
                before = (ask(client, f"{P}/order/*", decode_order),
                          ask(client, f"{P}/order/*/status", decode_order_status))
            finally:
                manager.close()
        assert before[1]["o1"].roster == roster and before[1]["o2"].state == "waiting"
        assert before[1]["m1"].reason.startswith(REFUSED)
        assert set(before[0]) == {"o1", "o2", "m1"}
        assert (tmp_path / JOURNAL).is_file()
        with session(router) as ms:
            manager = FleetManager(ms, LIFE, tmp_path, stamp=lambda: 5.0)
            try:
                assert manager.tick(5.0) == ()  # o1 and o2 were posted before the restart
                after = (ask(client, f"{P}/order/*", decode_order),
                         ask(client, f"{P}/order/*/status", decode_order_status))
                assert after == before
                assert [m.oid for m in manager.tick(10.0)] == ["o3"]
                one = ask(client, order_status_key(P, "o1"), decode_order_status)
                assert list(one) == ["o1"]
            finally:
                manager.close()
    finally:
        sub.undeclare()
        leader.close()
        client.close()


def test_the_launchers_manager_posts_on_the_worlds_tick_stamped_with_its_time(router, tmp_path):
    calls: list[tuple[int, float]] = []
    with run_manager(None, tmp_path, router.endpoint, None, realtime=False) as none:
        assert none is None  # a scenario without a fleet runs as before
    with session(router) as client, run_manager(LIFE, tmp_path, router.endpoint, None,
                                                realtime=False) as manager:
        assert manager is not None
        manager.on_tick(lambda k, t: calls.append((k, t)))(200, 10.0)
        found = ask(client, f"{P}/order/*", decode_order)
    assert calls == [(200, 10.0)]
    assert sorted(found) == ["o1", "o2", "o3"] and {m.stamp for m in found.values()} == {10.0}


def start_manager(router: RouterProcess, folder: Path) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "simulator.manager", str(TESTS / "scenarios" / "lifelong-chained.yaml"),
         "--run", str(folder), "--connect", router.endpoint],
        env=dict(os.environ, PYTHONPATH=str(TESTS.parent)), stdin=subprocess.DEVNULL)


def book_when(client: zenoh.Session, ready, limit_s: float = 60.0) -> dict[str, object]:
    """The book's statuses, asked again (a query nobody answers returns at once) until
    ``ready(book)`` holds; AssertionError after ``limit_s`` (a process that never came up)."""
    gave_up = threading.Event()
    timer = threading.Timer(limit_s, gave_up.set)
    timer.start()
    try:
        while not gave_up.is_set():
            found = ask(client, f"{P}/order/*/status", decode_order_status)
            if ready(found):
                return found
            gave_up.wait(0.05)
    finally:
        timer.cancel()
    raise AssertionError("the fleet manager's book never got ready")


def test_the_manager_process_restarted_mid_way_answers_the_same_book(router, tmp_path):
    with session(router) as client:
        proc = start_manager(router, tmp_path)
        try:
            book_when(client, lambda b: {"o1", "o2"} <= set(b))
            client.put(order_key(P, "m1"), encode_order(
                OrderMsg("m1", "new", type="beam", source="in-2", to="rack-2", stamp=1.0)))
            before = book_when(client, lambda b: "m1" in b)
        finally:
            proc.terminate()
            assert proc.wait(30) == 0
        proc = start_manager(router, tmp_path)
        try:
            after = book_when(client, lambda b: set(before) <= set(b))
        finally:
            proc.terminate()
            assert proc.wait(30) == 0
    assert {oid: after[oid] for oid in before} == before
    assert before["m1"].state == "waiting"
