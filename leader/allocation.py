"""Who takes which order: one pure function that every idle robot's agent runs over the bids.

An order needs a team of ``k`` robots at once, one under each slot of its load. When an auction
round closes, every bidder holds a set of bids: a bid is one robot's cost to each slot of one
order (straight-line distance by default, :func:`bid_costs`; an agent may put its route length
instead). :func:`allocate` turns the open orders and the bids into teams, and it is a pure
function of those two sets: the same bids, received in any order, give the same teams in every
agent and in the in-process simulator, as the result depends only on the bids' content, sorted
into one canonical order (orders by precedence, robots by id), and on plain Python floats.

It works in two steps:

1. **Which orders are served this round**, in precedence (higher ``priority`` first, then the
   order posted first, then its id): an order is taken when its slots, together with the slots
   of the orders already taken, can still each get a distinct robot that bid for them (an
   augmenting-path bipartite matching, Kuhn's method). An order that cannot be completed
   reserves the robots that bid for it, its ``k`` cheapest, from the orders after it, so that a
   stream of small orders cannot starve a large one.
2. **Who goes where**: the exact minimum-total-cost assignment of all the taken slots to the
   robots left (the Hungarian method with potentials, Kuhn 1955 and Munkres 1957), so the
   round's teams are the best possible for the sum of travel, given which orders are served;
   or (``objective="bottleneck"``) the least total among the assignments whose largest single
   cost is the smallest possible.

A robot without a bid for an order is not considered for it (a lost or late bid only narrows
the choice); a malformed bid (unknown order, wrong number of costs, a negative or non-finite
cost) is dropped and counted; when a robot's bid for an order arrives twice, the smaller cost
tuple counts. No robot gets two slots and no order gets an incomplete team, by construction.

For measuring, the module also holds two baselines over the same inputs, the sequential team
auction (orders in precedence, each taking its own best team from the robots left, after
Koenig et al.'s sequential single-item auctions with an order as the item) and the greedy
nearest-robots rule (each slot in turn takes the nearest robot left); the exact best
assignment by enumeration (:func:`brute_force_cost`) for small cases; and the message count of
one order under this protocol and under the methods it was chosen over (:func:`message_model`).

Lost bids make views differ, so after a round each robot votes for the rosters it computed
(:func:`votes_of`), and a roster counts only once a majority of the fleet voted for it
(:func:`committed`): each robot votes once per order, so no order commits two rosters.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from itertools import permutations

Point = tuple[float, float]


@dataclass(frozen=True)
class OpenOrder:
    """An order open for bids: its id, its slots in world coordinates (slot 0 leads), its
    priority (higher first) and when it was posted [s]."""

    oid: str
    slots: tuple[Point, ...]
    priority: float = 0.0
    t_posted: float = 0.0

    @property
    def k(self) -> int:
        """How many robots the order needs."""
        return len(self.slots)


@dataclass(frozen=True)
class Bid:
    """One robot's bid for one order: its cost to each of the order's slots, in slot order."""

    rid: str
    oid: str
    costs: tuple[float, ...]


@dataclass(frozen=True)
class Team:
    """An order's team: ``robots[i]`` takes slot ``i`` (so ``robots[0]`` leads); ``cost`` is the
    sum of their bids for those slots."""

    oid: str
    robots: tuple[str, ...]
    cost: float


@dataclass(frozen=True)
class Allocation:
    """A round's result: the teams (by order id), the orders left waiting, the robots held back
    for a waiting order, and how many bids were dropped as malformed."""

    teams: Mapping[str, Team]
    waiting: tuple[str, ...]
    reserved: tuple[str, ...]
    dropped: int

    def robots(self) -> set[str]:
        """Every robot that has a team."""
        return {r for team in self.teams.values() for r in team.robots}

    def total_cost(self) -> float:
        """The sum of the teams' costs."""
        return sum(team.cost for team in self.teams.values())


def precedence(order: OpenOrder) -> tuple[float, float, str]:
    """The order's place in the queue: higher priority first, then posted first, then by id."""
    return (-order.priority, order.t_posted, order.oid)


def bid_costs(position: Point, slots: Sequence[Point]) -> tuple[float, ...]:
    """The default bid: the straight-line distance from ``position`` to each slot."""
    return tuple(math.hypot(sx - position[0], sy - position[1]) for sx, sy in slots)


def bids_from_positions(orders: Iterable[OpenOrder], robots: Mapping[str, Point]) -> list[Bid]:
    """Every idle robot's default bid for every open order (what the simulator delivers at the
    closing tick when no bid is lost)."""
    return [Bid(rid, order.oid, bid_costs(robots[rid], order.slots))
            for order in orders for rid in sorted(robots)]


def joins_round(t_posted: float, close: float, window: float) -> bool:
    """Whether an order posted at ``t_posted`` [s] is in the round that closes at ``close`` [s]:
    the first round an order joins closes at least one bid ``window`` [s] after it was posted,
    so every idle robot has the whole window to bid (docs/lifelong-design.md, section 4)."""
    return close - t_posted >= window - 1e-9


Allocator = Callable[[Sequence[OpenOrder], Iterable[Bid]], "Allocation"]


def round_teams(orders: Sequence[OpenOrder], idle: Mapping[str, Point],
                allocator: Allocator | None = None) -> Allocation:
    """A round with every idle robot's default bid delivered (``idle``: robot -> where it
    stands): what the in-process simulator decides at a round's close, and what the agents'
    bidders commit when no message is lost (:mod:`agent.bidder`)."""
    return (allocator or allocate)(orders, bids_from_positions(orders, idle))


def _valid(bid: Bid, orders: Mapping[str, OpenOrder]) -> bool:
    order = orders.get(bid.oid)
    return (order is not None and len(bid.costs) == order.k
            and all(math.isfinite(c) and c >= 0.0 for c in bid.costs))


def cost_table(orders: Sequence[OpenOrder], bids: Iterable[Bid]
               ) -> tuple[dict[str, dict[str, tuple[float, ...]]], int]:
    """The valid bids as ``{order id: {robot id: costs}}`` (the smaller cost tuple where a robot
    bid twice for an order) and the number of malformed bids dropped."""
    by_id = {o.oid: o for o in orders}
    table: dict[str, dict[str, tuple[float, ...]]] = {o.oid: {} for o in orders}
    dropped = 0
    for bid in bids:
        if not _valid(bid, by_id):
            dropped += 1
            continue
        row = table[bid.oid]
        old = row.get(bid.rid)
        costs = tuple(float(c) for c in bid.costs)
        row[bid.rid] = costs if old is None else min(old, costs)
    return table, dropped


def _augment(slot: int, bidders: Sequence[Sequence[str]], owner: dict[str, int],
             seen: set[str], pool: set[str]) -> bool:
    """Kuhn's augmenting path from ``slot``: give it a robot of ``pool``, moving others along
    the way."""
    for rid in bidders[slot]:
        if rid in seen or rid not in pool:
            continue
        seen.add(rid)
        if rid not in owner or _augment(owner[rid], bidders, owner, seen, pool):
            owner[rid] = slot
            return True
    return False


def _cheapest(row: Mapping[str, tuple[float, ...]], pool: set[str], k: int) -> list[str]:
    """The ``k`` robots of ``pool`` with the smallest best-slot cost in ``row`` (ties by id)."""
    return sorted((r for r in row if r in pool), key=lambda r: (min(row[r]), r))[:k]


def select_orders(orders: Sequence[OpenOrder],
                  table: Mapping[str, Mapping[str, tuple[float, ...]]],
                  hold: bool = True) -> tuple[list[OpenOrder], set[str], list[str]]:
    """Step 1: the orders served this round (in precedence), the robots left for them, and
    the robots reserved for the first orders that cannot be completed (``hold``)."""
    pool = {r for row in table.values() for r in row}
    bidders: list[list[str]] = []  # per taken slot: the robots that bid for it
    owner: dict[str, int] = {}  # robot -> taken slot, a complete matching of the taken slots
    taken: list[OpenOrder] = []
    reserved: list[str] = []
    for order in sorted(orders, key=precedence):
        row = table[order.oid]
        trial_owner, trial_bidders = dict(owner), bidders + [sorted(row)] * order.k
        ok = all(_augment(s, trial_bidders, trial_owner, set(), pool)
                 for s in range(len(bidders), len(trial_bidders)))
        if ok:
            owner, bidders = trial_owner, trial_bidders
            taken.append(order)
        elif hold:
            free = pool - set(owner)
            held = _cheapest(row, free, order.k)
            reserved += held
            pool -= set(held)
    return taken, pool, reserved


def hungarian(cost: Sequence[Sequence[float]]) -> list[int]:
    """The column given to each row in a minimum-total-cost assignment of ``n`` rows to ``m >=
    n`` columns, each column at most once (Hungarian method with row and column potentials,
    O(n^2 m)); the first of equal candidates in column order wins, so equal inputs give equal
    outputs."""
    n = len(cost)
    m = len(cost[0]) if n else 0
    if n > m:
        raise ValueError(f"{n} rows cannot each get one of {m} columns")
    u, v = [0.0] * (n + 1), [0.0] * (m + 1)
    row_of = [0] * (m + 1)  # column j (1-based) -> its row (1-based), 0: free
    for i in range(1, n + 1):
        _add_row(i, cost, u, v, row_of)
    result = [0] * n
    for j in range(1, m + 1):
        if row_of[j]:
            result[row_of[j] - 1] = j - 1
    return result


def _add_row(i: int, cost: Sequence[Sequence[float]], u: list[float], v: list[float],
             row_of: list[int]) -> None:
    """Give row ``i`` a column along a shortest augmenting path (Dijkstra over reduced costs)."""
    m = len(v) - 1
    row_of[0] = i
    j0 = 0
    best = [math.inf] * (m + 1)
    way = [0] * (m + 1)
    used = [False] * (m + 1)
    while row_of[j0]:
        used[j0] = True
        i0, delta, j1 = row_of[j0], math.inf, 0
        for j in range(1, m + 1):
            if used[j]:
                continue
            reduced = cost[i0 - 1][j - 1] - u[i0] - v[j]
            if reduced < best[j]:
                best[j], way[j] = reduced, j0
            if best[j] < delta:
                delta, j1 = best[j], j
        for j in range(m + 1):
            if used[j]:
                u[row_of[j]] += delta
                v[j] -= delta
            else:
                best[j] -= delta
        j0 = j1
    while j0:
        j1 = way[j0]
        row_of[j0] = row_of[j1]
        j0 = j1


def bottleneck(taken: Sequence[OpenOrder], robots: Sequence[str],
               table: Mapping[str, Mapping[str, tuple[float, ...]]]) -> float:
    """The smallest cost ``c`` such that every taken slot can get a distinct robot whose bid
    for it is at most ``c`` (the round's farthest member, made as near as it can be): a binary
    search over the bid costs, each step one bipartite matching."""
    slots = [(o.oid, s) for o in taken for s in range(o.k)]
    levels = sorted({table[oid][r][s] for oid, s in slots for r in robots if r in table[oid]})
    pool = set(robots)
    lo, hi = 0, len(levels) - 1
    while lo < hi:
        mid = (lo + hi) // 2
        bidders = [[r for r in robots if r in table[oid] and table[oid][r][s] <= levels[mid]]
                   for oid, s in slots]
        owner: dict[str, int] = {}
        if all(_augment(i, bidders, owner, set(), pool) for i in range(len(slots))):
            hi = mid
        else:
            lo = mid + 1
    return levels[lo] if levels else 0.0


def _assign(taken: Sequence[OpenOrder], robots: Sequence[str],
            table: Mapping[str, Mapping[str, tuple[float, ...]]], cap: float = math.inf
            ) -> dict[str, Team]:
    """Step 2: the exact best assignment of the taken orders' slots to ``robots``; a slot's
    missing bid, or one above ``cap``, costs more than any complete assignment that avoids it."""
    slots = [(order, s) for order in taken for s in range(order.k)]
    if not slots:
        return {}
    finite = [c for order in taken for costs in table[order.oid].values() for c in costs]
    big = (max(finite, default=0.0) + 1.0) * (len(slots) + 1)
    matrix = [[table[o.oid][r][s] if r in table[o.oid] and table[o.oid][r][s] <= cap else big
               for r in robots] for o, s in slots]
    columns = hungarian(matrix)
    teams: dict[str, Team] = {}
    at = 0
    for order in taken:
        chosen = [robots[c] for c in columns[at:at + order.k]]
        if any(r not in table[order.oid] for r in chosen):
            raise ValueError(f"order {order.oid}: no complete team of bidders")
        costs = [table[order.oid][r][s] for s, r in enumerate(chosen)]
        teams[order.oid] = Team(order.oid, tuple(chosen), math.fsum(costs))
        at += order.k
    return teams


def allocate(orders: Sequence[OpenOrder], bids: Iterable[Bid], hold: bool = True,
             objective: str = "sum") -> Allocation:
    """The round's teams from the open orders and the bids received (see the module's text).

    ``objective`` ``sum``: the least total cost; ``bottleneck``: the least total cost among the
    assignments whose largest single cost is the smallest possible (:func:`bottleneck`)."""
    if objective not in ("sum", "bottleneck"):
        raise ValueError(f"objective: {objective!r} is not sum or bottleneck")
    table, dropped = cost_table(orders, bids)
    taken, pool, reserved = select_orders(orders, table, hold)
    robots = sorted(pool)
    cap = bottleneck(taken, robots, table) if objective == "bottleneck" else math.inf
    teams = _assign(taken, robots, table, cap)
    waiting = tuple(o.oid for o in sorted(orders, key=precedence) if o.oid not in teams)
    return Allocation(teams, waiting, tuple(sorted(reserved)), dropped)


def sequential_auction(orders: Sequence[OpenOrder], bids: Iterable[Bid]) -> Allocation:
    """Baseline: orders in precedence, each taking its own best team from the robots left."""
    table, dropped = cost_table(orders, bids)
    free = {r for row in table.values() for r in row}
    teams: dict[str, Team] = {}
    for order in sorted(orders, key=precedence):
        row = table[order.oid]
        robots = sorted(r for r in row if r in free)
        if len(robots) < order.k:
            continue
        team = _assign([order], robots, table)[order.oid]
        teams[order.oid] = team
        free -= set(team.robots)
    waiting = tuple(o.oid for o in sorted(orders, key=precedence) if o.oid not in teams)
    return Allocation(teams, waiting, (), dropped)


def greedy_nearest(orders: Sequence[OpenOrder], bids: Iterable[Bid]) -> Allocation:
    """Baseline: orders in precedence, each slot in turn taking the nearest robot left."""
    table, dropped = cost_table(orders, bids)
    free = {r for row in table.values() for r in row}
    teams: dict[str, Team] = {}
    for order in sorted(orders, key=precedence):
        row, chosen = table[order.oid], []
        for s in range(order.k):
            near = sorted((row[r][s], r) for r in row if r in free and r not in chosen)
            if not near:
                break
            chosen.append(near[0][1])
        if len(chosen) == order.k:
            teams[order.oid] = Team(order.oid, tuple(chosen),
                                    math.fsum(row[r][s] for s, r in enumerate(chosen)))
            free -= set(chosen)
    waiting = tuple(o.oid for o in sorted(orders, key=precedence) if o.oid not in teams)
    return Allocation(teams, waiting, (), dropped)


def brute_force_cost(orders: Sequence[OpenOrder], bids: Iterable[Bid]) -> float:
    """The smallest total cost of any assignment giving every order a complete team of
    distinct bidders, by enumeration (small cases only: every ordered choice of robots)."""
    table, _ = cost_table(orders, bids)
    slots = [(o.oid, s) for o in sorted(orders, key=precedence) for s in range(o.k)]
    robots = sorted({r for row in table.values() for r in row})
    best = math.inf
    for pick in permutations(robots, len(slots)):
        if all(r in table[oid] for (oid, _), r in zip(slots, pick, strict=True)):
            best = min(best, math.fsum(table[oid][r][s] for (oid, s), r in zip(slots, pick, strict=True)))
    return best


@dataclass(frozen=True)
class Vote:
    """A robot's vote after a round closes: the roster it computed for one order."""

    rid: str
    oid: str
    round: int
    roster: tuple[str, ...]


def votes_of(rid: str, result: Allocation, round_: int) -> list[Vote]:
    """The votes a robot puts for the teams of its own allocation of the round."""
    return [Vote(rid, oid, round_, team.robots) for oid, team in sorted(result.teams.items())]


def committed(votes: Iterable[Vote], fleet_size: int, round_: int) -> dict[str, tuple[str, ...]]:
    """The rosters a majority of the fleet voted for in ``round_`` (more than half of
    ``fleet_size``), by order; a robot's repeated vote for an order counts once (its first in
    sorted order), so no two rosters of one order can both have a majority."""
    first: dict[tuple[str, str], tuple[str, ...]] = {}
    for vote in sorted(votes, key=lambda v: (v.oid, v.rid, v.roster)):
        if vote.round == round_:
            first.setdefault((vote.oid, vote.rid), vote.roster)
    tally: dict[tuple[str, tuple[str, ...]], int] = {}
    for (oid, _), roster in first.items():
        tally[(oid, roster)] = tally.get((oid, roster), 0) + 1
    return {oid: roster for (oid, roster), n in sorted(tally.items()) if 2 * n > fleet_size}


def message_model(idle: int, fleet: int, k: int, repeats: int = 1) -> dict[str, int]:
    """Messages put on the network for one order that forms its team in one round, by method.

    * ``this``: the order (1), each idle robot's bid (``idle * repeats``), each fleet robot's
      vote for the roster it computed (``fleet``), the leader's roster on the order's status (1).
    * ``central_auction``: a dispatcher's call for bids, one proposal per idle robot, the award
      (Open-RMF's dispatcher, with a robot in place of a fleet adapter).
    * ``sequential_single_item``: one auction per slot, each with a call, ``idle`` bids and an
      award (Koenig et al., a slot as the item).
    * ``cbba_bound``: consensus-based bundle algorithm with every robot in range of every other
      (network diameter 1): at most one round per slot to converge, each round one message per
      robot (Choi, Brunet and How), before any coupling of a slot to its team's other slots.
    """
    return {
        "this": 1 + idle * repeats + fleet + 1,
        "central_auction": 1 + idle + 1,
        "sequential_single_item": k * (1 + idle + 1),
        "cbba_bound": k * idle,
    }
