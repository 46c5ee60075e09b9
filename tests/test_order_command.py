"""``formation order`` and ``formation orders`` against a real fleet manager over Zenoh: a client
posts an order, a fake team leader puts an ``assigned`` status, the command exits 0; an order the
scenario cannot serve exits 2 with one line; a cancel and a priority change exit 0 once the book
shows them; the book prints one line per order. The options are checked without a session."""

from __future__ import annotations

import argparse
import queue
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest
import zenoh

from formation.cli import main
from formation.commands.order import next_id, request, verdict
from runtime.testing import RouterProcess
from scenario.load import load_scenario
from simulator.manager import FleetManager
from wire import keys
from wire.orders import OrderMsg, OrderStatusMsg, decode_order, encode_order, order_status_key
from wire.zconf import ZenohSettings

TESTS = Path(__file__).resolve().parent
P = keys.DEFAULT_PREFIX
LIFE = load_scenario(TESTS / "scenarios" / "lifelong-chained.yaml").lifelong
ROSTER = ("f1", "f2", "f3", "f4")


def ns(*spec: str, **kw) -> argparse.Namespace:
    base = {"load": None, "cancel": None, "id": None, "priority": None}
    return argparse.Namespace(spec=list(spec), **{**base, **kw})


def test_the_options_make_one_message_each():
    assert request(ns("pallet", "in-1", "rack-2"), ["o1", "m2"], 1.0) == OrderMsg(
        "m3", "new", type="pallet", source="in-1", to="rack-2", stamp=1.0)
    assert request(ns("rack-4", load="o1", id="x", priority=2.0), [], 1.0) == OrderMsg(
        "x", "load", load="o1", to="rack-4", priority=2.0, stamp=1.0)
    assert request(ns(cancel="o1"), ["o1"], 1.0).kind == "cancel"
    assert request(ns(id="o1", priority=3.0), ["o1"], 1.0) == OrderMsg(
        "o1", "priority", priority=3.0, stamp=1.0)
    assert next_id(["m1", "m9", "mx", "s3"]) == "m10"


@pytest.mark.parametrize("args, why", [
    (ns("pallet", "in-1"), "expected TYPE FROM TO"),
    (ns("pallet", "in-1", "rack 2"), "TO"),
    (ns("pallet", "in-1", "rack-2", id="o1"), "--id o1: the fleet has an order so named"),
    (ns("pallet", "in-1", "rack-2", priority=float("inf")), "--priority must be a finite"),
    (ns("rack-2", cancel="o1"), "--cancel ID takes no other order"),
])
def test_options_that_make_no_order_are_refused_naming_the_culprit(args, why):
    with pytest.raises(ValueError, match=why):
        request(args, ["o1"], 0.0)


@pytest.mark.parametrize("kind, state, reason, code", [
    ("new", "waiting", "", None),
    ("new", "assigned", "", 0),
    ("new", "delivered", "", 0),
    ("new", "failed", "refused: type: unknown load type 'crate'", 2),
    ("new", "cancelled", "cancelled", 1),
    ("cancel", "gathering", "", None),
    ("cancel", "cancelled", "cancelled", 0),
    ("cancel", "delivered", "", 1),
])
def test_the_verdict_of_a_status(kind, state, reason, code):
    msg = OrderMsg("m1", kind, type="pallet", source="in-1", to="rack-2") if kind == "new" \
        else OrderMsg("m1", kind)
    assert verdict(msg, OrderStatusMsg("m1", state, reason=reason), None) == code


# ---------------------------------------------------------------------------- over Zenoh


class Leader:
    """A fake team leader: puts ``assigned`` for every new or load order it is told to take."""

    def __init__(self, endpoint: str, take: set[str]) -> None:
        self.session = zenoh.open(ZenohSettings(mode="client", connect=(endpoint,),
                                                multicast_scouting=False).to_config())
        self.take = take
        self.todo: queue.SimpleQueue[str | None] = queue.SimpleQueue()
        self.sub = self.session.declare_subscriber(f"{P}/order/*", self._on)
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _on(self, sample: zenoh.Sample) -> None:
        msg = decode_order(sample.payload.to_bytes())
        if msg.oid in self.take and msg.kind in ("new", "load"):
            self.todo.put(msg.oid)

    def _run(self) -> None:
        while (oid := self.todo.get()) is not None:
            self.session.put(order_status_key(P, oid), encode_order(
                OrderStatusMsg(oid, "assigned", 1, ROSTER, ROSTER[0], stamp=1.0)))

    def close(self) -> None:
        self.todo.put(None)
        self.thread.join()
        self.sub.undeclare()
        self.session.close()


@pytest.fixture()
def fleet(tmp_path) -> Iterator[tuple[str, FleetManager]]:
    with RouterProcess() as router:
        session = zenoh.open(ZenohSettings(mode="client", connect=(router.endpoint,),
                                           multicast_scouting=False).to_config())
        manager = FleetManager(session, LIFE, tmp_path, stamp=lambda: 1.0)
        manager.tick(0.0)  # o1 and o2 are posted
        try:
            yield router.endpoint, manager
        finally:
            manager.close()
            session.close()


def test_an_order_a_team_takes_exits_0_and_the_book_lists_it(fleet, capsys):
    endpoint, manager = fleet
    leader = Leader(endpoint, {"m1"})
    try:
        code = main(["order", "pallet", "in-2", "rack-2", "--connect", endpoint,
                     "--timeout", "30"])
    finally:
        leader.close()
    out = capsys.readouterr().out
    assert code == 0, out
    assert out.startswith("m1: assigned robots f1,f2,f3,f4, new pallet at in-2 -> rack-2")
    assert main(["orders", "--connect", endpoint]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert [line.split(":")[0] for line in lines] == ["m1", "o1", "o2"]
    assert lines[1].startswith("o1: waiting robots -, new pallet at in-1 -> rack-1")


def test_an_order_the_scenario_cannot_serve_exits_2_in_one_line(fleet, capsys):
    endpoint, _manager = fleet
    code = main(["order", "crate", "in-2", "rack-2", "--id", "bad", "--connect", endpoint,
                 "--timeout", "30"])
    err = capsys.readouterr().err
    assert code == 2
    assert err.count("\n") == 1 and "refused: type: unknown load type 'crate'" in err


def test_a_cancel_and_a_priority_change_exit_0_once_the_book_shows_them(fleet, capsys):
    endpoint, manager = fleet
    assert main(["order", "--id", "o2", "--priority", "4", "--connect", endpoint,
                 "--timeout", "30"]) == 0
    assert manager.entries()["o2"].order.priority == 4.0
    assert main(["order", "--cancel", "o2", "--connect", endpoint, "--timeout", "30"]) == 0
    assert manager.entries()["o2"].status.state == "cancelled"
    assert main(["order", "--cancel", "nope", "--connect", endpoint, "--timeout", "30"]) == 2
    assert "no order 'nope' in the fleet's book" in capsys.readouterr().err
