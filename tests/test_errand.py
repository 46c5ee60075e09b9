"""A fleet robot's configuration and its errand (agent.config fleet part, agent.errand): the
formations of one at the start, the team's memberships as the simulator builds them, and the
per-robot phase machine over a toy world where robots step straight to their goals."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

from hypothesis import given, settings
from hypothesis import strategies as st

from agent.config import (
    build_agent_configs,
    fleet_scenario,
    membership_of,
    memberships,
    regrouped,
    solo,
    team_formation,
)
from agent.errand import (
    ALLY_REACH,
    CARRYING,
    DELIVERED,
    FAILED,
    GATHERING,
    IDLE,
    RELEASED,
    Errand,
    ErrandSettings,
    Job,
    Seen,
    allies_at,
    clear_spot,
    load_box,
    mates_at,
    out_from_under,
    parking,
    route_mates,
    way_out,
)
from agent.navigation import leader_routes
from geometry.ellipse import Ellipse
from leader.team import TeamPlan, plan_team, pose_error, slot_points
from scenario import load_scenario
from wire.payloads import EllipseMsg

ROOT = Path(__file__).resolve().parent.parent
PALLET = ROOT / "tests" / "scenarios" / "lifelong" / "one-pallet-si.yaml"


def test_a_fleet_robot_starts_as_a_formation_of_one_at_its_start_carrying_its_warehouse() -> None:
    sc = load_scenario(PALLET)
    assert sc.lifelong is not None
    cfgs = build_agent_configs(sc)
    assert sorted(cfgs) == ["r1", "r2", "r3", "r4"]
    starts = sc.lifelong.fleet.starts
    for rid, cfg in cfgs.items():
        assert cfg.formation == cfg.leader_id == rid and cfg.neighbours == ()
        assert cfg.goal == starts[rid][:2] and cfg.start == starts[rid]
        assert cfg.lifelong == sc.lifelong and cfg.is_leader
        others = set(cfgs) - {rid}
        assert cfg.leader is not None and set(cfg.leader.other_formations) == others
    # the same memberships as the simulator's warehouse at t = 0
    base = fleet_scenario(sc)
    assert {r: membership_of(c) for r, c in cfgs.items()} == memberships(base)


def team_plan(sc, robots: tuple[str, ...]) -> TeamPlan:
    life = sc.lifelong
    kind = life.load_type("pallet")
    src, dst = life.station("dock").pose, life.station("rack").pose
    slots = slot_points(src, kind.slots)
    return plan_team("o1", robots, kind.slots, kind.outline, slots, (src, dst))


def test_a_team_and_back_to_one_are_the_memberships_of_the_scenario_of_that_moment() -> None:
    sc = fleet_scenario(load_scenario(PALLET))
    plan = team_plan(sc, ("r3", "r1", "r4", "r2"))
    life = sc.lifelong
    poses = {r: (*p, 0.0) for r, p in zip(plan.robots, plan.starts, strict=True)}
    outline = slot_points(life.station("dock").pose, life.load_type("pallet").outline)
    team = team_formation(plan, poses, outline)
    got = regrouped(sc, team)
    moment = replace(sc, formations=(team,))
    want = memberships(moment)
    assert got.keys() == set(plan.robots) and got == {r: want[r] for r in plan.robots}
    assert got["r3"].leader is not None and got["r1"].standby is not None  # slot 0 leads, 1 succeeds
    assert got["r1"].leader is None and got["r1"].formation == "o1"
    assert dict(got["r4"].neighbours).keys() == {"r3", "r1", "r2"}  # every pair an edge
    back = regrouped(moment, solo("r1", (1.0, 2.0, 0.0), (0.5, 0.5)))
    assert back["r1"].formation == "r1" and back["r1"].goal == (0.5, 0.5)
    # the team that held r1 gives way to it (the rest of the fleet stays, here none)
    assert back["r1"].leader is not None and back["r1"].leader.other_formations == ()
    again = regrouped(sc, solo("r1", (1.0, 2.0, 0.0), (0.5, 0.5)))["r1"]
    assert again.leader is not None and again.leader.other_formations == ("r2", "r3", "r4")


def test_parking_is_the_same_in_every_agent_and_never_shared() -> None:
    starts = {"a": (0.0, 0.0, 0.0), "b": (0.1, 0.0, 0.0), "c": (5.0, 5.0, 0.0)}
    spots = [(0.0, 1.0), (5.0, 6.0)]
    got = parking(("a", "b", "c"), starts, spots)
    # in fleet order: a takes the spot nearest it, b the one left, c none
    assert got == {"a": (0.0, 1.0), "b": (5.0, 6.0)}
    assert parking(("c", "b", "a"), starts, spots) == {"c": (5.0, 6.0), "b": (0.0, 1.0)}
    assert parking(("a", "b", "c"), starts, []) == {}


# --- the phase machine over a toy world --------------------------------------------------------

SPEED = 0.05  # [m] a robot's step per tick in the toy world
TOL = 0.03


def toward(p: tuple[float, float], goal: tuple[float, float]) -> tuple[float, float]:
    d = math.dist(p, goal)
    if d <= SPEED:
        return goal
    return (p[0] + (goal[0] - p[0]) * SPEED / d, p[1] + (goal[1] - p[1]) * SPEED / d)


class Toy:
    """Four robots with errands, statuses heard one tick after they are put, a robot killed
    (it stands and says nothing) at ``kill`` = (robot, tick)."""

    def __init__(self, lift: int, kill: tuple[str, int] | None = None, offset: float = 0.0,
                 miss: dict[str, tuple[float, float]] | None = None) -> None:
        sc = load_scenario(PALLET)
        life = sc.lifelong
        assert life is not None
        kind = life.load_type("pallet")
        src, dst = life.station("dock").pose, life.station("rack").pose
        self.robots = ("r1", "r2", "r3", "r4")
        self.job = Job("o1", "o1", kind, self.robots, slot_points(src, kind.slots), src, dst, 1)
        s = ErrandSettings(lift_ticks=lift, lost_ticks=10, repeat_ticks=20, goal_tolerance=TOL,
                           offset=offset)
        self.miss = miss or {}  # robot -> how far off its carry goal its body comes to rest
        self.errands = {r: Errand(r, s, home=(0.0, -1.0 - i)) for i, r in enumerate(self.robots)}
        self.at = {r: life.fleet.starts[r][:2] for r in self.robots}
        self.goal: dict[str, tuple[float, float]] = {}
        self.hold: dict[str, bool] = dict.fromkeys(self.robots, False)
        self.team: dict[str, TeamPlan] = {}
        self.kill = kill
        self.statuses: list[tuple[int, str, str]] = []  # (tick, speaker, state)
        self.mail: list = []
        self.seen: dict[str, Seen] = {}
        self.done: dict[str, int] = {}

    def dead(self, r: str, k: int) -> bool:
        return self.kill is not None and self.kill[0] == r and k >= self.kill[1]

    def run(self, ticks: int) -> None:
        for r, e in self.errands.items():
            self.goal[r] = e.take(self.job, 0).walk
        for k in range(ticks):
            heard, self.mail = self.mail, []
            for r, e in self.errands.items():
                if self.dead(r, k):
                    continue
                for msg in heard:
                    e.hear(msg)
                mates = {m: v for m, v in self.seen.items() if m != r}
                move = e.step(k, self.at[r], mates)
                self.apply(r, k, move)
            self.advance(k)

    def apply(self, r: str, k: int, move) -> None:
        if move.walk is not None:
            self.goal[r] = move.walk
            self.team.pop(r, None)
        if move.team is not None:
            self.team[r] = move.team
        self.hold[r] = move.hold
        if move.status is not None:
            self.statuses.append((k, r, move.status.state))
            self.mail.append(move.status)
        if move.done:
            self.done[r] = k

    def advance(self, k: int) -> None:
        for r in self.robots:
            if self.dead(r, k) or self.hold[r]:
                pass
            elif r in self.team:
                plan = self.team[r]
                gx, gy = plan.goals[plan.robots.index(r)]
                dx, dy = self.miss.get(r, (0.0, 0.0))
                self.at[r] = toward(self.at[r], (gx + dx, gy + dy))
            else:
                self.at[r] = toward(self.at[r], self.goal[r])
            if not self.dead(r, k):
                self.seen[r] = Seen(*self.at[r], k)


def test_a_team_gathers_lifts_carries_sets_down_and_parks() -> None:
    toy = Toy(lift=40)
    toy.run(600)
    says = [s for _, _, s in toy.statuses]
    assert {r for _, r, _ in toy.statuses} == {"r1"}  # only the leader speaks
    assert says[0] == GATHERING and says[-1] == DELIVERED
    firsts = [s for i, s in enumerate(says) if i == 0 or says[i - 1] != s]
    assert firsts == [GATHERING, CARRYING, DELIVERED]
    # every member formed the same team and left it at the delivery
    assert len(toy.done) == 4 and all(e.phase == IDLE for e in toy.errands.values())
    t_carry = next(k for k, _, s in toy.statuses if s == CARRYING)
    t_gather = min(k for k, _, s in toy.statuses if s == GATHERING)
    assert t_carry - t_gather >= 40  # the lift took its time
    for i, r in enumerate(toy.robots):
        assert toy.at[r] == (0.0, -1.0 - i)  # parked at its own spot
    assert all(e.finished == [("o1", DELIVERED)] for e in toy.errands.values())


def test_a_member_lost_while_carrying_fails_the_order_and_the_team_dissolves() -> None:
    toy = Toy(lift=5)
    toy.run(200)  # to find when carrying starts
    t_carry = next(k for k, _, s in toy.statuses if s == CARRYING)
    toy = Toy(lift=5, kill=("r3", t_carry + 10))
    toy.run(400)
    last = toy.statuses[-1]
    assert last[2] == FAILED
    assert toy.errands["r1"].finished == [("o1", FAILED)]
    assert all(toy.errands[r].phase == IDLE for r in ("r1", "r2", "r4"))


def test_a_lost_leader_is_spoken_for_by_its_successor_and_before_the_lift_the_roster_is_released(
        ) -> None:
    toy = Toy(lift=5, kill=("r1", 3))
    toy.run(200)
    assert toy.statuses[-1][1:] == ("r2", RELEASED)
    assert all(toy.errands[r].finished == [("o1", RELEASED)] for r in ("r2", "r3", "r4"))


@settings(max_examples=30, deadline=None)
@given(lift=st.integers(0, 30), victim=st.sampled_from(["r1", "r2", "r3", "r4", None]),
       when=st.integers(0, 300))
def test_the_statuses_run_in_order_and_end_once(lift: int, victim: str | None, when: int) -> None:
    toy = Toy(lift=lift, kill=None if victim is None else (victim, when))
    toy.run(500)
    rank = {GATHERING: 0, CARRYING: 1, DELIVERED: 2, FAILED: 2, RELEASED: 2}
    says = [s for _, _, s in toy.statuses]
    assert says == sorted(says, key=rank.__getitem__)  # never back to an earlier phase
    ends = [i for i, s in enumerate(says) if rank[s] == 2]
    # ended once: after the end only that end again (repeated for those that lost it)
    assert not ends or set(says[ends[0]:]) == {says[ends[0]]}
    if RELEASED in says:
        assert CARRYING not in says  # released only before the lift
    alive = [r for r in toy.robots if not toy.dead(r, 499)]
    if says and rank[says[-1]] == 2:
        assert all(toy.errands[r].phase == IDLE for r in alive)
    if victim is None:
        assert says[-1] == DELIVERED
    if says and says[-1] == DELIVERED:
        assert not set(toy.team) & set(alive)  # nobody alive is still in the team
        e = toy.errands[alive[0]]
        assert all(how == DELIVERED for _, how in e.finished)


def test_the_load_rests_within_the_set_down_tolerance_when_delivered() -> None:
    toy = Toy(lift=2)
    rested = []
    original = Errand.rests

    def spy(self, at, how):
        pose = original(self, at, how)
        rested.append((how, pose, list(at or [])))
        return pose

    Errand.rests = spy  # type: ignore[method-assign]
    try:
        toy.run(600)
    finally:
        Errand.rests = original  # type: ignore[method-assign]
    assert rested and all(how == DELIVERED for how, _, _ in rested)
    d, a = pose_error(rested[0][1], toy.job.dst)
    assert d <= 0.05 and a <= math.radians(3.0)


def test_a_unicycle_team_whose_member_rests_off_its_goal_within_its_reach_sets_the_load_down(
) -> None:
    # r4's body comes to rest 7 cm off its carry goal (as a unicycle's body, its look-ahead point
    # where its team puts it, can); the load's pose is still within the set-down tolerance
    miss = {"r4": (0.07, 0.0)}
    holonomic = Toy(lift=2, miss=miss)
    holonomic.run(600)
    assert [s for _, _, s in holonomic.statuses][-1] == CARRYING  # short of the set-down for good
    unicycle = Toy(lift=2, offset=0.05, miss=miss)
    unicycle.run(600)
    assert [s for _, _, s in unicycle.statuses][-1] == DELIVERED
    assert all(e.finished == [("o1", DELIVERED)] for e in unicycle.errands.values())


def test_a_teammate_last_seen_before_the_team_was_taken_is_not_lost_at_once() -> None:
    toy = Toy(lift=5)
    e = toy.errands["r1"]
    e.take(toy.job, 100)
    old = {r: Seen(*toy.at[r], 50) for r in ("r2", "r3", "r4")}  # from an earlier team
    assert e.step(101, toy.at["r1"], old).status is not None and not e.lost
    assert e.step(110, toy.at["r1"], old).status is None and not e.lost  # 10 ticks: the limit
    move = e.step(111, toy.at["r1"], old)
    assert e.job is None and move.done and move.status is not None
    assert move.status.state == RELEASED and move.status.reason == "member lost: r2"


def test_a_speaker_that_hears_its_team_released_by_a_successor_dissolves() -> None:
    toy = Toy(lift=5)
    e = toy.errands["r1"]
    e.take(toy.job, 0)
    e.hear(replace_status(toy.job, "r2", RELEASED))
    move = e.step(1, toy.at["r1"], {})
    assert move.done and e.job is None and move.status is None


def replace_status(job: Job, leader: str, state: str):
    from wire.orders import OrderStatusMsg
    return OrderStatusMsg(job.oid, state, job.round, job.robots, leader, "member lost: r1")


POINTS = st.tuples(st.floats(-3.0, 3.0), st.floats(-3.0, 3.0))


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(POINTS, POINTS), min_size=2, max_size=5), st.data())
def test_mates_stand_near_their_slots_and_allies_are_the_mates_of_one_near_its_own(pairs, data):
    robots = tuple(f"r{i}" for i in range(len(pairs)))
    slots = [s for s, _ in pairs]
    at = {r: p for r, (_, p) in zip(robots, pairs, strict=True) if data.draw(st.booleans())}
    rid = data.draw(st.sampled_from(robots))
    mates = mates_at(robots, slots, rid, at)
    assert rid not in mates
    assert set(mates) == {r for r, s in zip(robots, slots, strict=True)
                          if r != rid and r in at and math.dist(at[r], s) <= ALLY_REACH}
    near = rid in at and math.dist(at[rid], slots[robots.index(rid)]) <= ALLY_REACH
    assert allies_at(robots, slots, rid, at) == (mates if near else ())
    assert route_mates(robots, slots, rid, at) == (() if near else mates)

def test_a_robot_is_out_from_under_a_load_with_its_body_where_its_control_point_stops() -> None:
    # a holonomic robot: its body is its control point, held to the goal tolerance
    assert out_from_under((0.0, 0.049), (0.0, 0.0), 0.05, 0.0)
    assert not out_from_under((0.0, 0.06), (0.0, 0.0), 0.05, 0.0)
    # a unicycle's body sits its look-ahead behind its control point, whichever way it faces:
    # one that stopped with its control point short of the way out, its body 0.12 m off, is out
    assert out_from_under((0.0, 0.12), (0.0, 0.0), 0.05, 0.05)
    assert not out_from_under((0.0, 0.16), (0.0, 0.0), 0.05, 0.05)


def test_a_way_out_from_under_a_load_keeps_off_a_pillar_standing_by_it() -> None:
    # a pallet at a sink, turned a quarter, a pillar (Ds 0.35) off its north-east corner, as in
    # a drawn hall: the robot under that corner walks out clear of the pillar as of the load
    sc = load_scenario(PALLET)
    assert sc.lifelong is not None
    pallet = sc.lifelong.load_type("pallet")
    sh = load_box("p", pallet, (8.2775, 3.7358, math.pi / 2), 0.15)
    pillar = (8.6775, 4.6521, 0.35)
    me = (8.43, 4.0)
    alone = way_out(sh, me, lambda x, y: clear_spot(x, y, (sh,), (), 0.105), 0.105)
    assert alone is not None and math.dist(alone, pillar[:2]) < pillar[2] + 0.105
    out = way_out(sh, me, lambda x, y: clear_spot(x, y, (sh,), (pillar,), 0.105), 0.105)
    assert out is not None and math.dist(out, pillar[:2]) >= pillar[2] + 0.105
    assert clear_spot(*out, (sh,), (pillar,), 0.105)


def test_a_robot_far_from_its_slot_plans_round_teammates_at_theirs_else_past_them_as_robots(
        ) -> None:
    """The leader of a formation of one on its way to its slot sees a teammate standing at its
    own slot, as any other formation, by its ellipse plus a radius (what its rows keep while it
    is far from its slot); its plan goes past the teammate as a robot (two radii) only where no
    route keeps off that ellipse (leader.routing.round_mates), the other formation never."""
    cfg = build_agent_configs(load_scenario(PALLET))
    lead = next(c for c in cfg.values() if c.leader is not None and c.footprint is not None)
    routes = leader_routes(replace(lead, mates=("r2",)))
    assert routes is not None
    mate = EllipseMsg("r2", 2.0, 0.0, 0.0, 0.4, 0.4, 0.0, 0.0, 0.0, 1.0)
    other = replace(mate, formation="r3", cy=2.0)
    own = Ellipse(0.0, 0.0, 0.0, 0.3, 0.3)
    seen = {t.name: t.ds for t in routes.things((), (mate, other), own)}
    assert seen["formation/r2"] == mate.a + lead.radius
    assert seen["formation/r3"] == other.a + lead.radius
    things = tuple((n, (x, 0.0, seen[n])) for n, x in (("formation/r2", 2.0), ("formation/r3", 4.0)))
    job = routes.replanner.begin(0.0, (0.0, 0.0, 0.0), things)
    assert job.mates == (((2.0, 0.0, seen["formation/r2"]), (2.0, 0.0, 2.0 * lead.radius)),)
