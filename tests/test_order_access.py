"""The order keys under access control (wire.acl ``orders=True``), enforced by a Python router:
the fleet manager puts orders and answers the order book's queries; robot r puts only its own
bids and orders' status and asks the book; a viewer only reads. Each denied put goes out before
an allowed marker on the same session, so once the marker arrives the denied one would have."""

from __future__ import annotations

import json
import queue
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest
import zenoh

from formation.cli import main
from runtime.testing import fleet_acl_router, open_as
from scenario.load import load_scenario
from simulator.access import secure_setup
from simulator.manager import FleetManager
from wire import acl, keys
from wire.orders import OrderStatusMsg, decode_order, encode_order, order_status_key

ROOT = Path(__file__).resolve().parent.parent
P = keys.DEFAULT_PREFIX
ROBOTS = {"r1": "r1", "r2": "r2"}  # a fleet: each robot a formation of one


def test_the_order_rows_exist_only_with_orders():
    plain = acl.fleet_acl(ROBOTS, ROBOTS)
    rows = acl.fleet_acl(ROBOTS, ROBOTS, orders=True)
    assert not any("/order/" in k for r in plain["rules"] for k in r["key_exprs"])
    by_id = {r["id"]: r for r in rows["rules"]}
    assert by_id["r1-bid"]["key_exprs"] == [f"{P}/order/*/bid/r1"]
    assert by_id["manager-orders"]["key_exprs"] == [f"{P}/order/*"]
    policy = {p["subjects"][0]: set(p["rules"]) for p in rows["policies"]}
    assert "r2-bid" not in policy["r1"] and "manager-orders" not in policy["r1"]
    assert not any("order" in rid for rid in policy["viewer"])


@pytest.fixture(scope="module")
def router(tmp_path_factory) -> Iterator[tuple[str, dict]]:
    with fleet_acl_router(tmp_path_factory.mktemp("orders-acl"), ROBOTS) as r:
        yield r


class Listener:
    """Robot r2 subscribed to ``order/**``, recording the keys it hears."""

    def __init__(self, router) -> None:
        self.session = open_as(router, "r2")
        self.got: queue.SimpleQueue[str] = queue.SimpleQueue()
        self.heard: list[str] = []
        self.sub = self.session.declare_subscriber(f"{P}/order/**",
                                                   lambda s: self.got.put(str(s.key_expr)))

    def sync(self, talker: zenoh.Session, marker: str, before: str | None = None) -> list[str]:
        """Put ``before`` (if any) then ``marker`` from ``talker`` until the marker is heard
        (the subscription matched through the router); what was heard besides it."""
        for _ in range(200):
            if before is not None:
                talker.put(before, b"x")
            talker.put(marker, b"m")
            try:
                while True:
                    key = self.got.get(timeout=0.1)
                    self.heard.append(key)
                    if key == marker:
                        return [k for k in self.heard if k != marker]
            except queue.Empty:
                continue
        raise AssertionError(f"the marker {marker} never arrived")

    def close(self) -> None:
        self.sub.undeclare()
        self.session.close()


@pytest.mark.parametrize("user, key, marker, allowed", [
    (acl.MANAGER_USER, f"{P}/order/o1", f"{P}/order/o2", True),
    ("r1", f"{P}/order/o1/bid/r1", f"{P}/order/o1/status", True),
    ("r1", f"{P}/order/o1/bid/r2", f"{P}/order/o1/status", False),   # speaking for r2
    ("r1", f"{P}/order/o1", f"{P}/order/o1/status", False),          # posting an order
    (acl.MANAGER_USER, f"{P}/order/o1/bid/r1", f"{P}/order/o2", False),
])
def test_who_may_put_on_the_order_keys(router, user, key, marker, allowed):
    listener = Listener(router)
    try:
        with open_as(router, user) as talker:
            heard = listener.sync(talker, marker, before=key)
    finally:
        listener.close()
    assert (key in heard) is allowed


def test_a_viewer_puts_no_order(router):
    listener = Listener(router)
    try:
        with open_as(router, acl.MANAGER_USER) as manager:
            listener.sync(manager, f"{P}/order/o2")  # the subscription is live
            with open_as(router, acl.VIEWER_USER) as viewer:
                viewer.put(f"{P}/order/o1", b"x")
                viewer.put(f"{P}/order/o1/status", b"x")
            heard = listener.sync(manager, f"{P}/order/o3")
    finally:
        listener.close()
    assert not [k for k in heard if k.startswith(f"{P}/order/o1")]


def test_robots_and_the_manager_ask_the_book_and_a_viewer_may_not(router):
    with open_as(router, acl.MANAGER_USER) as manager:
        queryable = manager.declare_queryable(
            f"{P}/order/*", lambda q: q.reply(f"{P}/order/o1", b"book"))
        try:
            for user, answered in (("r1", True), (acl.MANAGER_USER, True),
                                   (acl.VIEWER_USER, False)):
                with open_as(router, user) as asker:
                    replies = [r.ok.payload.to_bytes() for r in asker.get(
                        f"{P}/order/*", timeout=5.0) if r.ok is not None]
                assert (replies == [b"book"]) is answered, user
        finally:
            queryable.undeclare()


def test_a_runs_access_setup_gives_a_fleets_robots_their_credentials_and_the_order_rows(tmp_path):
    scenario = load_scenario(ROOT / "tests" / "scenarios" / "lifelong-chained.yaml")
    creds = secure_setup(scenario, tmp_path / "secure", "tcp/127.0.0.1:7447")
    assert sorted(creds.files) == ["f1", "f2", "f3", "f4"]
    conf = json.loads(creds.router_config.read_text(encoding="utf-8"))["access_control"]
    rules = {r["id"]: r["key_exprs"] for r in conf["rules"]}
    assert rules["f3-bid"] == [f"{P}/order/*/bid/f3"] and "manager-orders" in rules
    plain = load_scenario(ROOT / "scenarios" / "warehouse.yaml")
    conf = json.loads(secure_setup(plain, tmp_path / "plain", "tcp/127.0.0.1:7447")
                      .router_config.read_text(encoding="utf-8"))["access_control"]
    assert not any("order" in r["id"] for r in conf["rules"])


def test_formation_order_with_the_managers_credentials_is_taken_under_access_control(
        router, tmp_path, capsys):
    endpoint, creds = router
    life = load_scenario(ROOT / "tests" / "scenarios" / "lifelong-chained.yaml").lifelong
    assert life is not None
    auth = tmp_path / "manager.json5"
    acl.write_client_file(auth, creds[acl.MANAGER_USER], [endpoint])
    todo: queue.SimpleQueue[str] = queue.SimpleQueue()

    def on_order(sample: zenoh.Sample) -> None:
        msg = decode_order(sample.payload.to_bytes())
        if msg.kind == "new":
            todo.put(msg.oid)

    with open_as(router, acl.MANAGER_USER) as ms, open_as(router, "r1") as leader:
        manager = FleetManager(ms, life, tmp_path)
        sub = leader.declare_subscriber(f"{P}/order/*", on_order)
        done: queue.SimpleQueue[int] = queue.SimpleQueue()
        client = threading.Thread(target=lambda: done.put(main(
            ["order", "beam", "in-2", "rack-2", "--connect", endpoint, "--auth", str(auth),
             "--timeout", "30"])))
        client.start()
        try:
            oid = todo.get(timeout=30)  # the robot heard the client's order
            leader.put(order_status_key(P, oid), encode_order(
                OrderStatusMsg(oid, "assigned", 1, ("r1", "r2"), "r1", stamp=1.0)))
            assert done.get(timeout=60) == 0
        finally:
            client.join()
            sub.undeclare()
            manager.close()
    assert capsys.readouterr().out.startswith(f"{oid}: assigned robots r1,r2, new beam at in-2")
