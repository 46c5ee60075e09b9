"""Bidding over real Zenoh (agent.order_link): four robots' bidders, each on its own session
through a router on loopback, one order posted by a manager session. The robots tick together,
each tick once every message put has reached every other robot (counted, before the link
faults): one roster for the order; with bids and statuses dropped, never two."""

from __future__ import annotations

import time
from collections.abc import Iterator

import pytest
import zenoh

from agent.bidder import ASSIGNED, Bidder, BidderSettings
from agent.faults import LinkFaults
from agent.order_link import OrderLink
from leader.allocation import OpenOrder, round_teams
from runtime.testing import RouterProcess
from wire import keys, zconf
from wire.orders import BidMsg, OrderMsg, OrderStatusMsg, encode_order, order_key

P = keys.DEFAULT_PREFIX
TIMEOUT_S = 10.0
WINDOW = 10
SLOTS = ((1.0, 1.0), (2.0, 1.0))
POSITIONS = {"r1": (0.0, 0.0), "r2": (1.0, 0.0), "r3": (6.0, 6.0), "r4": (3.0, 4.0)}


@pytest.fixture(scope="module")
def router() -> Iterator[RouterProcess]:
    with RouterProcess() as proc:
        yield proc


def resolve(msg: OrderMsg) -> OpenOrder | None:
    """The stations the test's robots know: a new pallet at ``in`` goes to two slots."""
    return OpenOrder(msg.oid, SLOTS, float(msg.priority), msg.stamp) if msg.source == "in" \
        else None


def session(router: RouterProcess) -> zenoh.Session:
    return zenoh.open(zconf.make_config("client", connect=[router.endpoint],
                                        connect_timeout_s=TIMEOUT_S))


def settle(links: dict[str, OrderLink], sent: int) -> None:
    """Wait until every robot has received every message the others put (and ``sent`` from
    the manager)."""
    deadline = time.monotonic() + TIMEOUT_S
    while any(link.received < sent + sum(o.puts for r, o in links.items() if r != rid)
              for rid, link in links.items()):
        if time.monotonic() > deadline:
            raise TimeoutError("messages did not arrive")
        time.sleep(0.002)


def run_fleet(router: RouterProcess, drop: float, seed: int, ticks: int
              ) -> tuple[dict[str, OrderLink], list[OrderStatusMsg], dict[str, list[str]]]:
    s = BidderSettings(fleet_size=4, window=WINDOW, copies=3, release_after=2,
                       repeat_every=WINDOW, tick_s=0.1)
    sessions = {r: session(router) for r in POSITIONS}
    teams: dict[str, list[str]] = {r: [] for r in POSITIONS}
    links = {r: OrderLink(sessions[r], P, Bidder(r, s), resolve, LinkFaults(drop=drop, seed=seed),
                          on_team=teams[r].append) for r in POSITIONS}
    manager = session(router)
    statuses: list[OrderStatusMsg] = []
    try:
        pub = manager.declare_publisher(order_key(P, "o1"))
        deadline = time.monotonic() + TIMEOUT_S
        while not pub.matching_status.matching:  # every robot's session is subscribed
            assert time.monotonic() < deadline
            time.sleep(0.002)
        pub.put(encode_order(OrderMsg("o1", "new", "pallet", "", "in", "rack", 0, 0.0)))
        settle(links, 1)
        for k in range(ticks):
            for rid in sorted(links):
                statuses += [m for m in links[rid].step(k, POSITIONS[rid])
                             if isinstance(m, OrderStatusMsg)]
            settle(links, 1)
        pub.undeclare()
    finally:
        for link in links.values():
            link.close()
        for z in [*sessions.values(), manager]:
            z.close()
    return links, statuses, teams


def test_four_bidders_over_zenoh_reach_one_roster_for_one_order(router) -> None:
    links, statuses, teams = run_fleet(router, 0.0, 0, WINDOW + 3)
    commits = {(m.round, m.roster) for m in statuses if m.state == ASSIGNED}
    expected = round_teams([OpenOrder("o1", SLOTS)], POSITIONS).teams["o1"].robots
    assert commits == {(1, expected)}
    assert {r: t for r, t in teams.items() if t} == {r: ["o1"] for r in expected}
    assert all(link.malformed == link.forged == link.fault_dropped == 0 for link in links.values())


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_with_dropped_bids_and_statuses_never_two_rosters_nor_a_robot_in_two(router, seed) -> None:
    links, statuses, teams = run_fleet(router, 0.4, seed, 3 * WINDOW + 3)
    commits = {(m.round, m.roster) for m in statuses if m.state == ASSIGNED}
    assert len(commits) <= 1
    assert sum(link.fault_dropped for link in links.values()) > 0  # the faults did drop
    named = {r for _, roster in commits for r in roster}
    assert {r for r, t in teams.items() if t} <= named
    assert all(len(set(t)) <= 1 for t in teams.values())


def test_a_forged_bid_and_a_malformed_one_are_dropped_and_counted(router) -> None:
    s = BidderSettings(fleet_size=2, window=WINDOW)
    z, other = session(router), session(router)
    link = OrderLink(z, P, Bidder("r1", s), resolve)
    try:
        pub = other.declare_publisher(f"{P}/order/o1/bid/r2")
        deadline = time.monotonic() + TIMEOUT_S
        while not pub.matching_status.matching:
            assert time.monotonic() < deadline
            time.sleep(0.002)
        pub.put(encode_order(BidMsg("o1", "r3", 1, "bid", (1.0, 1.0))))  # r3's bid on r2's key
        pub.put(b"\x07garbage")
        deadline = time.monotonic() + TIMEOUT_S
        while link.received < 2:
            assert time.monotonic() < deadline
            time.sleep(0.002)
        link.step(1, (0.0, 0.0))  # a message stamped at tick 0 is taken at tick 1
        assert (link.forged, link.malformed) == (1, 1)
        pub.undeclare()
    finally:
        link.close()
        z.close()
        other.close()


def test_a_message_put_at_this_tick_is_taken_at_the_next_whenever_it_came(router) -> None:
    s = BidderSettings(fleet_size=2, window=WINDOW)
    z, other = session(router), session(router)
    link = OrderLink(z, P, Bidder("r1", s), resolve)
    try:
        pub = other.declare_publisher(f"{P}/order/o1/bid/r2")
        deadline = time.monotonic() + TIMEOUT_S
        while not pub.matching_status.matching:
            assert time.monotonic() < deadline
            time.sleep(0.002)
        # a forged bid stamped at tick 3 (counted once taken): not at tick 3, at tick 4
        pub.put(encode_order(BidMsg("o1", "r3", 1, "bid", (1.0, 1.0), stamp=3 * s.tick_s)))
        deadline = time.monotonic() + TIMEOUT_S
        while link.received < 1:
            assert time.monotonic() < deadline
            time.sleep(0.002)
        link.step(3, (0.0, 0.0))
        assert link.forged == 0
        link.step(4, (0.0, 0.0))
        assert link.forged == 1
        pub.undeclare()
    finally:
        link.close()
        z.close()
        other.close()
