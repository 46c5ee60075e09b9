"""The bidding part of an agent (agent.bidder) over a simulated network of bidders: each message
lost on its way to each robot with a given probability, the rest arriving the next tick in a
random order. Never two committed rosters for one order, never one robot in two; with no loss
the committed rosters are the in-process simulator's (leader.allocation.round_teams)."""

from __future__ import annotations

import random
from collections.abc import Sequence
from dataclasses import dataclass, field

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from agent.bidder import ASSIGNED, Bidder, BidderSettings, Message, majority
from leader.allocation import OpenOrder, joins_round, round_teams
from wire.orders import BidMsg, OrderStatusMsg

WINDOW = 20
TICK_S = 0.05


@dataclass
class Network:
    """N bidders and the messages between them (module docstring)."""

    bidders: dict[str, Bidder]
    positions: dict[str, tuple[float, float]]
    loss: float
    rng: random.Random
    flight: list[tuple[str, Message]] = field(default_factory=list)
    commits: dict[str, set[tuple[int, tuple[str, ...]]]] = field(default_factory=dict)
    puts: int = 0

    def send(self, sender: str, msgs: Sequence[Message]) -> None:
        for msg in msgs:
            self.puts += 1
            if isinstance(msg, OrderStatusMsg) and msg.state == ASSIGNED:
                self.commits.setdefault(msg.oid, set()).add((msg.round, msg.roster))
            for to in self.bidders:
                if to != sender and self.rng.random() >= self.loss:
                    self.flight.append((to, msg))

    def step(self, k: int) -> None:
        arriving, self.flight = self.flight, []
        self.rng.shuffle(arriving)
        for to, msg in arriving:
            self.send(to, self.bidders[to].hear(msg))
        for rid in sorted(self.bidders):
            self.send(rid, self.bidders[rid].tick(k, self.positions[rid]))

    def run(self, ticks: int, start: int = 0) -> None:
        for k in range(start, ticks):
            self.step(k)
            self.check()

    def check(self) -> None:
        """The safety properties, after every tick."""
        for oid, rosters in self.commits.items():
            assert len(rosters) <= 1, f"order {oid} committed twice: {rosters}"
        named: dict[str, str] = {}
        for oid, rosters in self.commits.items():
            for _, roster in rosters:
                for r in roster:
                    assert r not in named, f"robot {r} in the teams of {named.get(r)} and {oid}"
                    named[r] = oid
        for rid, b in self.bidders.items():
            if b.following is not None:  # one order at most, and one whose roster names it
                assert named.get(rid) == b.following


def network(n: int, orders: Sequence[OpenOrder], positions: Sequence[tuple[float, float]],
            loss: float, seed: int) -> Network:
    s = BidderSettings(fleet_size=n, window=WINDOW, copies=3, release_after=2,
                       repeat_every=WINDOW, tick_s=TICK_S)
    ids = [f"r{i}" for i in range(n)]
    bidders = {r: Bidder(r, s) for r in ids}
    for b in bidders.values():
        for o in orders:
            b.order(o)
    return Network(bidders, dict(zip(ids, positions, strict=True)), loss, random.Random(seed))


def reference(orders: Sequence[OpenOrder], positions: dict[str, tuple[float, float]],
              rounds: int) -> set[tuple[str, tuple[str, ...]]]:
    """What the in-process simulator commits over ``rounds`` rounds with robots that stay in
    their teams: every round's :func:`leader.allocation.round_teams` over the idle robots."""
    idle, open_, out = dict(positions), list(orders), set()
    for m in range(1, rounds + 1):
        close = m * WINDOW * TICK_S
        ripe = [o for o in open_ if joins_round(o.t_posted, close, WINDOW * TICK_S)]
        if not ripe or not idle:
            continue
        result = round_teams(ripe, idle)
        for oid, team in result.teams.items():
            out.add((oid, team.robots))
            for r in team.robots:
                del idle[r]
        open_ = [o for o in open_ if o.oid not in result.teams]
    return out


point = st.tuples(st.floats(0.0, 20.0), st.floats(0.0, 20.0))


@st.composite
def rounds_of_work(draw):
    n = draw(st.integers(2, 8))
    positions = draw(st.lists(point, min_size=n, max_size=n))
    orders = []
    for j in range(draw(st.integers(1, 3))):
        k = draw(st.sampled_from((2, 4)))
        slots = tuple(draw(st.lists(point, min_size=k, max_size=k)))
        posted = draw(st.sampled_from((0.0, 0.4, 1.0, 1.7)))
        orders.append(OpenOrder(f"o{j}", slots, draw(st.sampled_from((0.0, 1.0))), posted))
    return n, orders, positions


@settings(max_examples=60, deadline=None)
@given(rounds_of_work(), st.floats(0.0, 0.6), st.integers(0, 2**31))
def test_lost_messages_never_make_two_rosters_for_an_order_or_a_robot_in_two_teams(
        work, loss, seed) -> None:
    n, orders, positions = work
    net = network(n, orders, positions, loss, seed)
    net.run(5 * WINDOW)  # checked after every tick


@settings(max_examples=40, deadline=None)
@given(rounds_of_work(), st.integers(0, 2**31))
def test_with_no_loss_the_committed_rosters_are_the_simulators(work, seed) -> None:
    n, orders, positions = work
    net = network(n, orders, positions, 0.0, seed)
    net.run(4 * WINDOW)
    got = {(oid, roster) for oid, rosters in net.commits.items() for _, roster in rosters}
    assert got == reference(orders, net.positions, 3)
    for oid, roster in got:  # every member follows its team
        assert all(net.bidders[r].following == oid for r in roster)


def two_pallets() -> tuple[list[OpenOrder], list[tuple[float, float]]]:
    slots = ((1.0, 1.0), (2.0, 1.0))
    return ([OpenOrder("a", slots), OpenOrder("b", ((8.0, 8.0), (9.0, 8.0)))],
            [(0.0, 0.0), (1.0, 0.0), (9.0, 9.0), (8.0, 9.0), (5.0, 5.0)])


def test_one_order_costs_its_bids_copies_votes_and_one_status() -> None:
    orders, positions = two_pallets()
    net = network(5, orders[:1], positions, 0.0, 1)
    net.run(WINDOW + 2)  # round 1 closes at tick 20; the leader commits when the votes arrive
    assert net.commits == {"a": {(1, ("r0", "r1"))}}
    # 5 idle robots x 3 copies of a bid, 5 votes put twice (until the leaders decide), 1 status
    assert net.puts == 5 * 3 + 5 * 2 + 1


def test_a_leader_that_hears_no_majority_releases_and_the_order_waits_for_a_later_round() -> None:
    orders, positions = two_pallets()
    net = network(5, orders[:1], positions, 0.0, 1)
    net.run(WINDOW)  # every bid of round 1 arrives
    net.loss = 1.0  # and no vote, nor the release's first copies (ticks 22 to 24)
    net.run(WINDOW + 5, start=WINDOW)
    r0 = net.bidders["r0"]
    assert not net.commits and r0.following is None
    lead = r0.leads[("a", 1)]
    assert lead.decision is not None and lead.decision.state == "waiting"
    assert "a" not in r0.bound and r0.idle  # released: it bids again
    assert net.bidders["r1"].bound == {"a": (1, ("r0", "r1"))}  # it has not heard the release
    net.loss = 0.0
    net.run(2 * WINDOW + 6, start=WINDOW + 5)  # the release is put again at tick 44
    assert not net.commits  # r1 sat round 2 out, bound until the release came again
    assert all(b.bound == {} for b in net.bidders.values())
    net.run(3 * WINDOW + 2, start=2 * WINDOW + 6)
    assert net.commits == {"a": {(3, ("r0", "r1"))}}


def test_a_vote_binds_its_robot_until_its_roster_is_released() -> None:
    b = Bidder("r1", BidderSettings(fleet_size=3, window=WINDOW, tick_s=TICK_S))
    b.order(OpenOrder("a", ((0.0, 0.0),)))
    b.hear(BidMsg("a", "r2", 1, "bid", (0.5,)))
    b.hear(BidMsg("a", "r3", 5, "bid", (0.1,)))  # a bid of another round: ignored
    assert b.dropped == 1
    b.tick(WINDOW - 1, (3.0, 0.0))
    votes = b.tick(WINDOW, (3.0, 0.0))  # r2 is nearer: r1 votes (r2,) and is bound to it
    assert [(v.phase, v.roster) for v in votes if isinstance(v, BidMsg)] == [("vote", ("r2",))]
    assert b.bound == {"a": (1, ("r2",))}
    assert not [m for m in b.tick(WINDOW + 6, (3.0, 0.0)) if isinstance(m, BidMsg)]  # no bid on "a"
    b.hear(OrderStatusMsg("a", "waiting", 2, ("r2",), "r2"))  # another round's release: still bound
    assert b.bound == {"a": (1, ("r2",))}
    b.hear(OrderStatusMsg("a", "waiting", 1, ("r2",), "r2"))
    assert b.bound == {} and [m.phase for m in b.tick(2 * WINDOW, (3.0, 0.0))
                              if isinstance(m, BidMsg)] == ["bid"]


def test_a_robot_told_of_a_second_team_declines_it_and_that_leader_releases_it() -> None:
    s = BidderSettings(fleet_size=3, window=WINDOW, tick_s=TICK_S)
    member, leader = Bidder("r1", s), Bidder("r0", s)
    member.hear(OrderStatusMsg("a", ASSIGNED, 1, ("r1",), "r1"))
    assert member.following == "a"
    (decline,) = member.hear(OrderStatusMsg("b", ASSIGNED, 1, ("r0", "r1"), "r0"))
    assert isinstance(decline, BidMsg) and decline.phase == "decline" and member.following == "a"
    # the leader of b committed it; the decline releases it and b is open again
    leader.order(OpenOrder("b", ((0.0, 0.0), (1.0, 0.0))))
    leader.hear(BidMsg("b", "r1", 1, "bid", (1.0, 1.0)))
    leader.tick(0, (0.0, 0.0))
    leader.hear(BidMsg("b", "r2", 1, "vote", roster=("r0", "r1")))
    leader.hear(BidMsg("b", "r1", 1, "vote", roster=("r0", "r1")))
    out = leader.tick(WINDOW, (0.0, 0.0))
    assert [m.state for m in out if isinstance(m, OrderStatusMsg)] == [ASSIGNED]
    assert leader.following == "b"
    leader.hear(decline)
    out = leader.tick(WINDOW + 1, (0.0, 0.0))
    assert [(m.state, m.reason) for m in out if isinstance(m, OrderStatusMsg)] == [
        ("waiting", "declined by r1")]
    assert leader.following is None and "b" not in leader.taken and "b" in leader.orders


def test_a_late_robot_bids_from_the_next_round_and_a_restarted_one_takes_its_slot_back() -> None:
    orders, positions = two_pallets()
    net = network(5, orders[:1], positions, 0.0, 3)
    s = net.bidders["r0"].settings
    net.bidders["r0"] = late = Bidder("r0", s, start=5)  # joins in round 1's window
    late.order(orders[0])
    assert late.first_round == 2
    net.run(WINDOW + 3, start=5)
    # the nearest robot sat round 1 out: the team is the one the others make without it
    without = {r: p for r, p in net.positions.items() if r != "r0"}
    roster = round_teams(orders[:1], without).teams["a"].robots
    assert round_teams(orders[:1], net.positions).teams["a"].robots[0] == "r0"
    assert net.commits == {"a": {(1, roster)}} and "r0" not in roster
    restarted = Bidder(roster[0], s, start=WINDOW + 5)  # its leader restarts, memory lost
    restarted.recall(orders[:1], [net.bidders[roster[1]].taken["a"]])  # the queryable's answer
    assert restarted.following == "a" and not restarted.idle
    assert not restarted.tick(2 * WINDOW, positions[0])  # no bid, no vote: it is in a team


def test_settings_and_majority_say_what_is_wrong() -> None:
    with pytest.raises(ValueError, match="release_after"):
        BidderSettings(fleet_size=3, window=4, release_after=4)
    assert majority({"a", "b"}, ("a",), 3) and not majority({"a", "b"}, ("c",), 3)
    assert not majority({"a"}, ("a",), 2)


def measure_first_round(runs: int = 100, drop: float = 0.2, seed: int = 5) -> dict[str, float]:
    """Over ``runs`` rounds of 12 robots and three orders (pallets of four, beams of two) in a
    20 x 10 m hall, each message lost with probability ``drop`` on its way to each robot: the
    share of orders committed in their first round, and the messages put per committed order."""
    rng = random.Random(seed)
    first = puts = committed = 0
    for r in range(runs):
        positions = [(rng.uniform(0, 20), rng.uniform(0, 10)) for _ in range(12)]
        orders = [OpenOrder(f"o{j}", tuple((rng.uniform(0, 20), rng.uniform(0, 10))
                                           for _ in range(rng.choice((2, 4)))))
                  for j in range(3)]
        net = network(12, orders, positions, drop, seed * 1000 + r)
        net.run(WINDOW + 3)
        first += len(net.commits)
        net.run(3 * WINDOW + 3, start=WINDOW + 3)
        committed += len(net.commits)
        puts += net.puts
    return {"first_round_share": first / (3 * runs), "committed_share": committed / (3 * runs),
            "puts_per_committed_order": puts / max(1, committed)}


@pytest.mark.slow
def test_a_round_with_a_fifth_of_the_messages_lost_commits_most_orders_at_once(capsys) -> None:
    clean, lossy = measure_first_round(30, 0.0), measure_first_round(30, 0.2)
    with capsys.disabled():
        print(f"\ndrop 0.0: {clean}\ndrop 0.2: {lossy}")
    assert clean["first_round_share"] == 1.0
    assert lossy["first_round_share"] > 0.6 and lossy["committed_share"] > 0.8


def test_a_leader_that_computed_no_team_releases_the_roster_others_voted_it_to_lead() -> None:
    s = BidderSettings(fleet_size=3, window=WINDOW, tick_s=TICK_S)
    leader, member = Bidder("r0", s), Bidder("r1", s)
    order = OpenOrder("b", ((0.0, 0.0), (1.0, 0.0)))
    for b in (leader, member):
        b.order(order)
    # the member heard both bids and votes (r0, r1); the leader heard no bid of r1's
    member.hear(BidMsg("b", "r0", 1, "bid", (0.0, 1.0)))
    member.tick(0, (1.0, 0.0))
    leader.tick(0, (0.0, 0.0))
    votes = [m for m in member.tick(WINDOW, (1.0, 0.0)) if isinstance(m, BidMsg)]
    assert [(v.phase, v.roster) for v in votes] == [("vote", ("r0", "r1"))] and not member.idle
    assert not [m for m in leader.tick(WINDOW, (0.0, 0.0)) if isinstance(m, BidMsg)
                and m.phase == "vote"]  # it computed no team: no vote, no lead
    leader.hear(votes[0])
    out = [m for m in leader.tick(WINDOW + 1, (0.0, 0.0)) if isinstance(m, OrderStatusMsg)]
    assert [(m.state, m.round, m.roster) for m in out] == [("waiting", 1, ("r0", "r1"))]
    member.hear(out[0])
    assert member.idle  # free to bid in the next round
