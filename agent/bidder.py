"""The bidding part of an agent (docs/lifelong-design.md, section 4) as a pure state machine.

No Zenoh here: the agent hands a :class:`Bidder` what it hears (:meth:`Bidder.order`,
:meth:`Bidder.hear`) and, each tick, its position (:meth:`Bidder.tick`), and puts what the tick
returns (:class:`wire.orders.BidMsg` on ``order/{oid}/bid/{rid}``,
:class:`wire.orders.OrderStatusMsg` on ``order/{oid}/status``). Time is counted in ticks, so
every bidder of a lock-step run, and of a test's simulated network, agrees on it.

* **Rounds.** Round ``m`` closes at tick ``m * window``. An order is in a round when it was
  posted at least one window before the close (:func:`leader.allocation.joins_round`). An idle
  robot (no team, no vote of its own roster pending) bids for every open order of the coming
  round ``copies`` times in the window, spaced evenly; a bid of another round is ignored.
* **Votes.** At the close every bidder runs the one allocation function
  (:func:`leader.allocation.allocate`) over its view (the open orders it knows, the round's bids
  it heard, its own included) and votes for each team it computed, again on each of the next
  ``release_after - 1`` ticks. A vote binds its robot: it votes on that order again only once
  the roster's leader has released that roster, and never once the order is taken.
* **Commit.** The robot at slot 0 of the roster it voted for counts the votes for exactly that
  roster in that round. Once more than half of the fleet (its size as written) voted for it,
  every member among them (a member's vote is its consent), it commits: it puts the roster as
  the order's status (``assigned``) and follows it. With no such majority ``release_after``
  ticks after the close, it releases the roster (status ``waiting`` naming the round and the
  roster). Either is put on ``copies`` ticks in a row, then again every ``repeat_every``
  ticks while the order is in its view.
* **Orphans.** A robot named at slot 0 by votes for a roster it did not compute (it heard
  other bids) releases that roster: it can never commit (a commit needs every member's vote,
  its own too), and without a release its voters would stay bound.
* **A lost message only delays.** A robot still bound a window after its vote's round closed
  (it lost every copy of the decision) puts its vote again every ``repeat_every`` ticks; the
  roster's leader answers a vote of a round it has decided with its decision again, and one
  for a roster it did not compute with a release. A member that lost every copy of a commit
  learns it from the team's ``gathering`` status (only a committed roster's speaker puts one).
* **Why at most one roster per order, one order per robot.** Two committed rosters of one order
  would need two majorities of the fleet, which share a robot: in one round it votes once per
  order; across rounds it is bound until the release of the roster it voted for, and a
  released roster is never committed. A robot follows a committed roster only with its own
  vote among the commit's, and it gives that vote only while it is in no team and bound to no
  roster of its own, so no robot is in two. A robot told of a committed roster naming it while
  it follows another (a restart lost its memory) puts a ``decline``; that roster's leader
  releases it and the order waits again.
* **Open for bids.** ``admits`` (optional) says whether an order may be served now (its load
  rests where the order expects it, its destination is free: :func:`leader.orders.biddable`
  over what the robot knows); an order it refuses is in no round until it admits it.
* **Late and restarted robots.** A bidder made at tick ``k0`` (:class:`Bidder` ``start``) takes
  the query's answer (:meth:`Bidder.recall`: the open orders and the last statuses) and neither
  bids nor votes before the round after the one under way; a roster that names it and is not
  yet done is its team again.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field

from leader.allocation import Bid, OpenOrder, allocate, bid_costs, joins_round
from wire.orders import BidMsg, OrderStatusMsg

Point = tuple[float, float]
Message = BidMsg | OrderStatusMsg
ASSIGNED = "assigned"  # an order status: the roster is committed
RELEASED = "waiting"  # an order status naming a round and a roster: that roster is released
GATHERING = "gathering"  # an order status: the committed roster's team gathers
BID, VOTE, DECLINE = "bid", "vote", "decline"


REPEAT_S = 1.0  # [s] a leader's decision or status is put again this often
RELEASE_TICKS = 2  # a roster without a majority this many ticks after the close is released


@dataclass(frozen=True)
class BidderSettings:
    """The protocol's numbers: the fleet's size as written (majorities are of it), the round
    ``window`` [ticks], bid ``copies`` per window, ``release_after`` [ticks] (V) and how often a
    leader puts its decision again, ``repeat_every`` [ticks]."""

    fleet_size: int
    window: int = 20
    copies: int = 3
    release_after: int = 2
    repeat_every: int = 20
    tick_s: float = 0.05  # [s] one tick (order times are in seconds)

    def __post_init__(self) -> None:
        if self.fleet_size < 1 or self.window < 1 or self.copies < 1:
            raise ValueError("fleet_size, window and copies must be at least 1")
        if not 1 <= self.release_after < self.window:
            raise ValueError(f"release_after: {self.release_after} ticks, not within 1 and "
                             f"the window ({self.window})")
        if self.repeat_every < 1 or self.tick_s <= 0:
            raise ValueError("repeat_every and tick_s must be positive")

    def bid_tick(self, k: int) -> bool:
        """Whether tick ``k`` is one of the window's bid ticks (the close's tick included, for
        the next round)."""
        step = max(1, self.window // self.copies)
        at = k % self.window
        return at % step == 0 and at // step < self.copies

    def next_close(self, k: int) -> int:
        """The round whose close is the first after tick ``k`` (at a close's tick: the next
        round, the one the bids put then are for)."""
        return k // self.window + 1


def majority(voters: Iterable[str], roster: Sequence[str], fleet_size: int) -> bool:
    """A roster is committed by more than half of the fleet's votes for it, every member's
    among them."""
    who = set(voters)
    return 2 * len(who) > fleet_size and all(r in who for r in roster)


@dataclass
class Lead:
    """A roster this robot leads (slot 0) in one round: the votes heard for it and the
    decision, once made."""

    oid: str
    round: int
    roster: tuple[str, ...]
    close: int  # [tick]
    voters: set[str] = field(default_factory=set)
    decision: OrderStatusMsg | None = None
    put_at: int = 0  # [tick] the decision was last put
    decided_at: int = 0  # [tick]
    hushed: bool = False  # the team speaks for the order now: no repeats after the copies


class Bidder:
    """One robot's bidding part (module docstring). ``costs``: its bid for an order from where
    it stands (default: straight-line distance to each slot)."""

    def __init__(self, rid: str, settings: BidderSettings, start: int = 0,
                 costs: Callable[[Point, OpenOrder], tuple[float, ...]] | None = None,
                 admits: Callable[[str], bool] | None = None) -> None:
        self.rid = rid
        self.settings = settings
        self.costs = costs or (lambda p, o: bid_costs(p, o.slots))
        self.admits = admits  # whether an order may be served now (its load, its destination)
        self.first_round = settings.next_close(start) + (1 if start else 0)
        self.orders: dict[str, OpenOrder] = {}  # the open orders it knows
        self.taken: dict[str, OrderStatusMsg] = {}  # order -> its committed roster's status
        self.following: str | None = None  # the order whose team this robot is in
        self.bids: dict[int, dict[str, dict[str, tuple[float, ...]]]] = {}  # round, order, robot
        self.bound: dict[str, tuple[int, tuple[str, ...]]] = {}  # order -> its vote not settled
        self.votes: list[BidMsg] = []  # this round's votes, put again until release_after
        self.leads: dict[tuple[str, int], Lead] = {}
        self.heard_votes: dict[tuple[str, int, tuple[str, ...]], set[str]] = {}
        self.now = start  # [tick] the last tick
        self.dropped = 0  # bids of an unknown order, another round or the wrong size: ignored
        self.declined: list[str] = []
        self.orphans: dict[OrderStatusMsg, int] = {}  # releases of rosters it did not compute
        self.maybe_orphans: set[tuple[str, int, tuple[str, ...]]] = set()  # heard, to judge

    # --- what it hears -------------------------------------------------------------------------

    def order(self, order: OpenOrder) -> None:
        """An order posted (or answered by the query) and open for bids."""
        if order.oid not in self.taken:
            self.orders[order.oid] = order

    def withdraw(self, oid: str) -> None:
        """An order no longer open (cancelled, delivered, failed): forgotten, and a team that
        served it dissolved."""
        self.orders.pop(oid, None)
        self.taken.pop(oid, None)
        self.bound.pop(oid, None)
        self.leads = {key: lead for key, lead in self.leads.items() if key[0] != oid}
        if self.following == oid:
            self.following = None

    def finish(self) -> None:
        """This robot's team dissolved (its load set down or the order failed): idle again."""
        if self.following is not None:
            self.withdraw(self.following)

    def hush(self, oid: str) -> None:
        """The team of ``oid`` speaks for it now (its statuses, :mod:`agent.errand`): a commit
        this robot leads is put its ``copies`` times and not repeated after."""
        for (o, _m), lead in self.leads.items():
            if o == oid:
                lead.hushed = True

    def recall(self, orders: Iterable[OpenOrder], statuses: Iterable[OrderStatusMsg]) -> None:
        """The query's answer after a (re)start: the open orders and each one's last status."""
        for o in orders:
            self.order(o)
        for s in statuses:
            self.hear(s)

    def hear(self, msg: Message) -> list[Message]:
        """A message from another robot (the wire layer has checked its key and sender);
        what to put in answer (a decline)."""
        if isinstance(msg, OrderStatusMsg):
            return self._status(msg)
        if msg.phase == BID:
            self._bid(msg)
        elif msg.phase == VOTE:
            self.heard_votes.setdefault((msg.oid, msg.round, msg.roster), set()).add(msg.robot)
            self._orphan(msg)
        else:
            self._decline(msg)
        return []

    def _bid(self, msg: BidMsg) -> None:
        order = self.orders.get(msg.oid)
        coming = self.settings.next_close(self.now)
        if order is None or len(msg.costs) != order.k or not coming <= msg.round <= coming + 1:
            self.dropped += 1
            return
        row = self.bids.setdefault(msg.round, {}).setdefault(msg.oid, {})
        row[msg.robot] = msg.costs

    def _status(self, msg: OrderStatusMsg) -> list[Message]:
        if not msg.roster or msg.leader != msg.roster[0]:
            self.dropped += 1
            return []
        if msg.state == ASSIGNED or (msg.state == GATHERING and msg.oid in self.orders):
            return self._committed(msg)
        if msg.state == RELEASED:
            self._released(msg)
        return []

    def _committed(self, msg: OrderStatusMsg) -> list[Message]:
        """A roster committed: the order is taken; a member free to follow it does."""
        self.taken[msg.oid] = msg  # kept among the orders: a released roster reopens it
        self.bound.pop(msg.oid, None)
        if self.rid not in msg.roster or self.following == msg.oid:
            return []
        if self.following is None:
            self.following = msg.oid
            return []
        self.declined.append(msg.oid)
        return [BidMsg(msg.oid, self.rid, msg.round, DECLINE, roster=msg.roster)]

    def _released(self, msg: OrderStatusMsg) -> None:
        """A roster released: a vote for exactly it binds no more; a team of it dissolves."""
        if self.bound.get(msg.oid) == (msg.round, msg.roster):
            del self.bound[msg.oid]
        taken = self.taken.get(msg.oid)
        if taken is not None and (taken.round, taken.roster) == (msg.round, msg.roster):
            del self.taken[msg.oid]
            if self.following == msg.oid:
                self.following = None

    def _orphan(self, msg: BidMsg) -> None:
        """A vote for a roster this robot would lead: kept, to be released after this robot's
        own close of that round if it is not the roster this robot computed (:meth:`_disown`)."""
        if msg.roster and msg.roster[0] == self.rid:
            self.maybe_orphans.add((msg.oid, msg.round, msg.roster))

    def _disown(self, k: int) -> list[Message]:
        """Rosters this robot would lead but did not compute (its view held other bids) can
        never commit (a commit needs every member's vote, its own too): once its own close of
        their round has passed, each is released, put on ``copies`` ticks, or its voters would
        stay bound."""
        window = self.settings.window
        for oid, m, roster in sorted(self.maybe_orphans):
            if k < m * window:
                continue
            self.maybe_orphans.discard((oid, m, roster))
            lead = self.leads.get((oid, m))
            if lead is not None and lead.roster == roster and lead.decision is not None:
                if k - m * window > window:  # a voter that lost the decision asks again
                    self.orphans.setdefault(lead.decision, 1)
            elif oid in self.orders and (lead is None or lead.roster != roster):
                release = OrderStatusMsg(oid, RELEASED, m, roster, self.rid,
                                         "not the leader's roster")
                self.orphans.setdefault(release, self.settings.copies)
        out: list[Message] = list(self.orphans)
        self.orphans = {msg: n - 1 for msg, n in self.orphans.items() if n > 1}
        return out

    def _decline(self, msg: BidMsg) -> None:
        """A member named by a roster this robot committed follows another: release it."""
        lead = self.leads.get((msg.oid, msg.round))
        if lead is None or lead.decision is None or lead.decision.state != ASSIGNED:
            return
        if msg.robot not in lead.roster:
            return
        lead.decision = OrderStatusMsg(msg.oid, RELEASED, lead.round, lead.roster, self.rid,
                                       f"declined by {msg.robot}")
        lead.put_at = -self.settings.repeat_every  # put at the next tick
        self._released(lead.decision)

    # --- each tick -----------------------------------------------------------------------------

    @property
    def idle(self) -> bool:
        """In no team and bound to no roster of its own (so free to bid)."""
        return self.following is None and not any(
            self.rid in roster for _, roster in self.bound.values())

    def tick(self, k: int, position: Point) -> list[Message]:
        """Tick ``k``: the close of a round (votes), the leaders' decisions, then the bids for
        the coming round; what to put."""
        s = self.settings
        self.now = k
        out: list[Message] = []
        if k % s.window == 0 and k // s.window >= self.first_round:
            out += self._close(k, k // s.window)
        elif self.votes and k % s.window < s.release_after:
            out += self.votes  # the votes again until the leaders decide
        out += self._decide(k)
        out += self._disown(k)
        out += self._ask(k)
        if s.bid_tick(k) and s.next_close(k) >= self.first_round and self.idle:
            out += self._bids(k, position)
        return out

    def _ask(self, k: int) -> list[Message]:
        """Votes still binding a window after their round closed, put again every
        ``repeat_every`` ticks: their leader answers with its decision."""
        s = self.settings
        out: list[Message] = []
        for oid, (m, roster) in sorted(self.bound.items()):
            age = k - m * s.window
            if age > s.window and age % s.repeat_every == 0:
                out.append(BidMsg(oid, self.rid, m, VOTE, roster=roster))
        return out

    def ripe(self, close: int) -> list[OpenOrder]:
        """The open orders of the round closing at tick ``close``, not taken."""
        s = self.settings
        return [o for oid, o in sorted(self.orders.items())
                if oid not in self.taken and joins_round(o.t_posted, close * s.tick_s,
                                                         s.window * s.tick_s)
                and (self.admits is None or self.admits(oid))]

    def _bids(self, k: int, position: Point) -> list[Message]:
        m = self.settings.next_close(k)
        out: list[Message] = []
        for o in self.ripe(m * self.settings.window):
            if o.oid in self.bound:
                continue
            costs = self.costs(position, o)
            self.bids.setdefault(m, {}).setdefault(o.oid, {})[self.rid] = costs
            out.append(BidMsg(o.oid, self.rid, m, BID, costs))
        return out

    def _close(self, k: int, m: int) -> list[Message]:
        """Round ``m`` closes: allocate over this robot's view, vote, bind, lead."""
        heard = self.bids.pop(m, {})
        self.bids = {r: b for r, b in self.bids.items() if r > m}
        orders = [o for o in self.ripe(k) if o.oid not in self.bound]
        bids = [Bid(rid, oid, costs) for oid, row in sorted(heard.items())
                for rid, costs in sorted(row.items())]
        result = allocate(orders, bids)
        self.votes = []
        for oid in sorted(result.teams):
            roster = result.teams[oid].robots
            self.bound[oid] = (m, roster)
            self.votes.append(BidMsg(oid, self.rid, m, VOTE, roster=roster))
            if roster[0] == self.rid:
                self.leads[(oid, m)] = Lead(oid, m, roster, k)
        self.heard_votes = {key: v for key, v in self.heard_votes.items() if key[1] >= m}
        return list(self.votes)

    def _decide(self, k: int) -> list[Message]:
        """The rosters this robot leads: commit on a majority, release after ``release_after``;
        a decision put on ``copies`` ticks in a row, then every ``repeat_every`` ticks."""
        s = self.settings
        out: list[Message] = []
        for key in sorted(self.leads):
            lead = self.leads[key]
            if lead.decision is None:
                self._judge(lead, k)
            if lead.decision is not None and (
                    (k - lead.put_at >= s.repeat_every and not lead.hushed)
                    or k - lead.decided_at < s.copies):
                lead.put_at = k
                out.append(lead.decision)
        return out

    def _judge(self, lead: Lead, k: int) -> None:
        voters = self.heard_votes.get((lead.oid, lead.round, lead.roster), set()) | {self.rid}
        if lead.oid in self.taken:  # another roster committed first (the order is not ours)
            state = RELEASED
        elif majority(voters, lead.roster, self.settings.fleet_size):
            state = ASSIGNED
        elif k - lead.close >= self.settings.release_after:
            state = RELEASED
        else:
            return
        lead.decision = OrderStatusMsg(lead.oid, state, lead.round, lead.roster, self.rid)
        lead.put_at, lead.decided_at = -self.settings.repeat_every, k
        if state == ASSIGNED:
            self._committed(lead.decision)
        else:
            self._released(lead.decision)
