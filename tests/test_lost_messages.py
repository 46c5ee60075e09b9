"""A lost order message only delays, never strands (agent.bidder, agent.errand, agent.order_link):
a voter that lost its leader's decision asks again and is answered; a member that lost the
commit learns it from the team's gathering status; a member that lost the ``carrying`` status
forms the team from where all stood still through the lift; the speaker repeats a final
status; the link loses a message by the message, not by when it came."""

from __future__ import annotations

from agent.bidder import Bidder, BidderSettings
from agent.errand import CARRYING, DELIVERED, IDLE, Errand, ErrandSettings, Job, Seen
from agent.faults import LinkFaults
from agent.order_link import lost
from leader.allocation import OpenOrder
from scenario.lifelong import LoadType
from wire.orders import BidMsg, OrderStatusMsg

WINDOW = 20
TICK_S = 0.05


def beam_job() -> Job:
    beam = LoadType("beam", (1.0, 0.2), ((-0.4, 0.0), (0.4, 0.0)))
    return Job("o1", "o1", beam, ("r1", "r2"), ((-0.4, 0.0), (0.4, 0.0)), (0.0, 0.0, 0.0),
               (3.0, 0.0, 0.0), round=1)


def test_a_voter_that_lost_the_release_asks_again_and_the_leader_answers() -> None:
    s = BidderSettings(fleet_size=3, window=WINDOW, tick_s=TICK_S)
    leader, member = Bidder("r0", s), Bidder("r1", s)
    order = OpenOrder("b", ((0.0, 0.0), (1.0, 0.0)))
    for b in (leader, member):
        b.order(order)
    leader.hear(BidMsg("b", "r1", 1, "bid", (1.0, 0.0)))
    member.hear(BidMsg("b", "r0", 1, "bid", (0.0, 1.0)))
    leader.tick(0, (0.0, 0.0))  # each its own bid
    member.tick(0, (1.0, 0.0))
    votes = [m for m in member.tick(WINDOW, (1.0, 0.0)) if isinstance(m, BidMsg)]
    leader.tick(WINDOW, (0.0, 0.0))
    # no third vote: no majority of 3; the leader releases, and every copy is lost to r1
    released = [m for k in range(WINDOW + 1, 2 * WINDOW)
                for m in leader.tick(k, (0.0, 0.0)) if isinstance(m, OrderStatusMsg)]
    assert released and all(m.state == "waiting" for m in released)
    assert not member.idle
    asks: list[BidMsg] = []
    k = WINDOW + 1
    while not asks and k < 6 * WINDOW:
        asks = [m for m in member.tick(k, (1.0, 0.0)) if isinstance(m, BidMsg)
                and m.phase == "vote"]
        k += 1
    assert asks and asks[0].roster == votes[0].roster and asks[0].round == 1
    leader.hear(asks[0])
    answer = [m for m in leader.tick(k, (0.0, 0.0)) if isinstance(m, OrderStatusMsg)]
    assert [(m.state, m.round, m.roster) for m in answer] == [("waiting", 1, votes[0].roster)]
    member.hear(answer[0])
    assert member.idle


def test_a_member_that_lost_every_commit_joins_on_the_teams_gathering_status() -> None:
    member = Bidder("r1", BidderSettings(fleet_size=2, window=WINDOW, tick_s=TICK_S))
    member.order(OpenOrder("b", ((0.0, 0.0), (1.0, 0.0))))
    member.hear(OrderStatusMsg("b", "gathering", 1, ("r0", "r1"), "r0"))
    assert member.following == "b" and "b" in member.taken


def errand(rid: str) -> Errand:
    return Errand(rid, ErrandSettings(lift_ticks=10, lost_ticks=50, repeat_ticks=WINDOW,
                                      goal_tolerance=0.03, tick_s=TICK_S))


def test_a_member_that_hears_carrying_late_forms_the_team_where_all_stood_still() -> None:
    job = beam_job()
    e = errand("r2")
    e.take(job, 0)
    me, mate = (0.41, 0.0), (-0.39, 0.0)  # at their slots, within the tolerance
    for k in range(1, 30):  # the gathering and the lift: both stand still
        e.step(k, me, {"r1": Seen(*mate, k - 1)})
    for k in range(30, 60):  # the speaker's carrying status lost: the leader moves off
        moved = (mate[0] + 0.01 * (k - 29), mate[1])
        e.step(k, me, {"r1": Seen(*moved, k - 1)})
    e.hear(OrderStatusMsg("o1", CARRYING, 1, job.robots, "r1"))
    move = e.step(60, me, {"r1": Seen(mate[0] + 0.31, mate[1], 59)})
    assert move.team is not None and move.team.starts == (mate, me)
    assert e.phase == CARRYING


def test_a_status_of_another_round_is_not_the_teams() -> None:
    job = beam_job()
    e = errand("r2")
    e.take(job, 0)
    e.hear(OrderStatusMsg("o1", "waiting", 0, job.robots, "r1"))  # an older roster's release
    e.step(1, (0.4, 0.0), {"r1": Seen(-0.4, 0.0, 0)})
    assert e.job is not None


def test_the_speaker_puts_its_final_status_again_until_it_speaks_another() -> None:
    job = beam_job()
    e = errand("r1")
    e.take(job, 0)
    at = {"r2": Seen(0.4, 0.0, 0)}
    k, said = 1, []
    while e.phase != IDLE or not said:
        here = e.job.slots[0] if e.plan is None else e.plan.goals[0]  # type: ignore[union-attr]
        mate = e.job.slots[1] if e.plan is None else e.plan.goals[1]  # type: ignore[union-attr]
        at = {"r2": Seen(*mate, k - 1)}
        m = e.step(k, here, at)
        if m.status is not None and m.status.state == DELIVERED:
            said.append(k)
        k += 1
        assert k < 500
    for j in range(k, k + 3 * WINDOW + 1):
        m = e.step(j, (5.0, 5.0), {})
        if m.status is not None:
            assert m.status.state == DELIVERED and m.status.oid == "o1"
            said.append(j)
    assert len(said) == 4 and all(b - a == WINDOW for a, b in zip(said, said[1:], strict=False))


def test_the_link_loses_a_message_by_what_it_is_not_by_when_it_came() -> None:
    faults = LinkFaults(drop=0.2, seed=3)
    payloads = [bytes([i % 256, i // 256]) for i in range(2000)]
    first = [lost(faults, "r1", "p/order/o1/bid/r2", p) for p in payloads]
    again = [lost(faults, "r1", "p/order/o1/bid/r2", p) for p in reversed(payloads)]
    assert first == again[::-1]
    assert 0.15 < sum(first) / len(first) < 0.25
    assert first != [lost(faults, "r3", "p/order/o1/bid/r2", p) for p in payloads]
    assert not any(lost(LinkFaults(), "r1", "k", p) for p in payloads)
