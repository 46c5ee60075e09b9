"""The fleet manager's order book over Zenoh names every order it took, finished ones too
(delivered, cancelled, failed, refused): its two queryables answer them all, ``formation
orders`` prints them all, a manager restarted on the same run folder (its journal replayed)
answers the same, and a robot that asks keeps only the open ones (agent.order_check)."""

from __future__ import annotations

import threading
from collections.abc import Iterator
from pathlib import Path

import pytest
import zenoh

from agent.order_check import open_in_book
from formation.cli import main
from runtime.testing import RouterProcess
from scenario.load import load_scenario
from simulator.manager import JOURNAL, REFUSED, FleetManager
from wire import keys
from wire.orders import (
    OrderMsg,
    OrderStatusMsg,
    encode_order,
    order_book,
    order_key,
    order_status_key,
)
from wire.zconf import ZenohSettings

TESTS = Path(__file__).resolve().parent
P = keys.DEFAULT_PREFIX
LIFE = load_scenario(TESTS / "scenarios" / "lifelong-chained.yaml").lifelong
assert LIFE is not None
TEAM = ("f1", "f2")
STATES = {"o1": "delivered", "o2": "cancelled", "m1": "failed", "m2": "failed",
          "m3": "waiting", "m4": "carrying"}


@pytest.fixture(scope="module")
def router() -> Iterator[RouterProcess]:
    with RouterProcess() as r:
        yield r


def session(router: RouterProcess) -> zenoh.Session:
    return zenoh.open(ZenohSettings(mode="client", connect=(router.endpoint,),
                                    multicast_scouting=False).to_config())


def wait_until(cond, what: str, timeout: float = 10.0) -> None:
    done = threading.Event()
    timer = threading.Timer(timeout, done.set)
    timer.start()
    try:
        while not cond():
            if done.wait(0.02):
                raise AssertionError(f"timed out waiting for {what}")
    finally:
        timer.cancel()


def status(oid: str, state: str, reason: str = "") -> bytes:
    return encode_order(OrderStatusMsg(oid, state, 1, TEAM, TEAM[0], reason=reason, stamp=3.0))


def fill(client: zenoh.Session, manager: FleetManager) -> None:
    """Orders in every state: o1 delivered, o2 cancelled while waiting, m1 refused (an unknown
    type), m2 failed on the way, m3 waiting, m4 carrying."""
    assert [m.oid for m in manager.tick(0.0)] == ["o1", "o2"]
    for msg in (OrderMsg("m1", "new", type="crate", source="in-1", to="rack-2", stamp=1.0),
                OrderMsg("m2", "new", type="beam", source="in-2", to="rack-3", stamp=1.0),
                OrderMsg("m3", "new", type="beam", source="in-1", to="rack-4", stamp=1.0),
                OrderMsg("m4", "new", type="beam", source="in-2", to="out-2", stamp=1.0)):
        client.put(order_key(P, msg.oid), encode_order(msg))
    wait_until(lambda: {"m1", "m2", "m3", "m4"} <= set(manager.entries()), "the clients' orders")
    client.put(order_key(P, "o2"), encode_order(OrderMsg("o2", "cancel", stamp=2.0)))
    for oid, state, reason in (("o1", "assigned", ""), ("o1", "carrying", ""),
                               ("o1", "delivered", ""), ("m2", "carrying", ""),
                               ("m2", "failed", "member lost: f2"), ("m4", "carrying", "")):
        client.put(order_status_key(P, oid), status(oid, state, reason))
    wait_until(lambda: {oid: e.status.state for oid, e in manager.entries().items()} == STATES,
               "every order in its state")


def orders_printed(endpoint: str, capsys) -> list[str]:
    assert main(["orders", "--connect", endpoint]) == 0
    return capsys.readouterr().out.splitlines()


def test_every_order_finished_ones_too_is_answered_printed_and_kept_across_a_restart(
        router, tmp_path, capsys) -> None:
    with session(router) as client:
        with session(router) as ms:
            manager = FleetManager(ms, LIFE, tmp_path, stamp=lambda: 1.0)
            try:
                fill(client, manager)
                orders, statuses = order_book(client, P, 5.0)
                printed = orders_printed(router.endpoint, capsys)
            finally:
                manager.close()
        assert (tmp_path / JOURNAL).is_file()
        with session(router) as ms:
            manager = FleetManager(ms, LIFE, tmp_path, stamp=lambda: 4.0)
            try:
                # the restarted manager's queryable reaches the router a moment after it is
                # declared: ask until it answers at all, then compare what it says
                wait_until(lambda: bool(order_book(client, P, 1.0)[0]),
                           "the restarted manager's answer")
                again = order_book(client, P, 5.0)
                printed_again = orders_printed(router.endpoint, capsys)
            finally:
                manager.close()
    assert set(orders) == set(STATES) and {oid: s.state for oid, s in statuses.items()} == STATES
    assert statuses["m1"].reason.startswith(REFUSED + "type: unknown load type 'crate'")
    assert statuses["m2"].reason == "member lost: f2" and statuses["o1"].roster == TEAM
    assert again == (orders, statuses)
    assert printed_again == printed
    assert [line.split(":")[0] for line in printed] == sorted(STATES)
    by_id = {line.split(":")[0]: line for line in printed}
    assert by_id["o1"].startswith("o1: delivered robots f1,f2, new pallet at in-1 -> rack-1")
    assert by_id["o2"].startswith("o2: cancelled (cancelled) robots -, load o1 -> rack-4")
    assert by_id["m2"].startswith("m2: failed (member lost: f2) robots f1,f2")
    # a robot that asks keeps the open ones
    assert sorted(open_in_book(orders, statuses)) == ["m3", "m4"]


def test_a_status_passed_on_by_the_world_is_in_the_book_at_once_and_taken_once(
        router, tmp_path) -> None:
    """``formation run``'s world hands the manager each status at the tick it takes it
    (:meth:`FleetManager.hear`): the book and its yard have it before the next orders fall due,
    whenever the manager's own subscription hears it; heard twice, it is journalled once."""
    with session(router) as ms:
        manager = FleetManager(ms, LIFE, tmp_path, stamp=lambda: 1.0)
        try:
            assert [m.oid for m in manager.tick(0.0)] == ["o1", "o2"]
            assert {"in-1", "rack-1"} <= manager.book.yard.held
            for state in ("assigned", "carrying", "delivered"):
                msg = OrderStatusMsg("o1", state, 1, TEAM, TEAM[0], stamp=3.0)
                manager.hear(msg)
                manager.hear(msg)
            entry = manager.entries()["o1"]
            yard = manager.book.yard
        finally:
            manager.close()
    assert entry.status.state == "delivered" and entry.status.roster == TEAM
    assert not {"in-1", "rack-1"} & yard.held and yard.resting["rack-1"] == "o1"
    journal = (tmp_path / JOURNAL).read_text(encoding="utf-8").splitlines()
    assert sum('"status"' in line for line in journal) == 3
