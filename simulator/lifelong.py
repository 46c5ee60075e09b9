"""Lifelong operation in process: a fleet serves transport orders, teams forming at run time.

A scenario with a ``fleet`` (:mod:`scenario.lifelong`) has no fixed formations: every robot is a
formation of one until an order's team takes it. The run follows the agents of a lock-step
``formation run`` tick for tick (:mod:`agent.lifepart`, :mod:`agent.errand`, :mod:`agent.bidder`),
every message delivered, so that both write the same ``orders.csv`` and ``robots.csv``. Each
tick, before the robots' commands:

1. due orders are posted; a new load appears at its source once the source is free
   (:func:`leader.orders.appears`); a load delivered to a sink leaves after its dwell;
2. at each bid tick of a round (:meth:`agent.bidder.BidderSettings.bid_tick`) every idle robot
   bids its distance to the slots of every order open for bids (:func:`leader.orders.biddable`);
   when the round closes (every ``fleet.bid_window_s``) the one allocation function runs over
   the round's last bids (:func:`leader.allocation.allocate`, or the greedy baseline) and the
   members are bound; the roster is committed a tick later (:data:`HEARD`: the leader hears
   the votes then), and the members take it a tick after that and walk to their slots;
3. a robot's new formation (a goal, its team, the formations of the moment changed, its
   gathering allies changed) is the one its agent asks for with its pose and view of that
   tick, and lands :data:`LANDS` ticks later (:meth:`agent.node.AgentNode.regroup`), planned
   afresh; every other formation walks on along its route;
4. the team has gathered when all stand at their slots (``goal_tolerance``); its speaker (slot
   0) sees it a tick later and stands still for ``fleet.lift_s``, the others standing at their
   slots as they reach them; then the load is carried (the team's plan,
   :func:`leader.team.plan_team`, from where they stood), and the members form the team's
   formation (every pair of slots an edge, slot 0 leads) when they hear it; within 5 cm and 3
   degrees of the destination (on the speaker's poses of the tick before, both where the load
   is and wherever the members' motion of that tick may carry it through the set-down:
   :func:`agent.errand.arrived`) the speaker stands for ``lift_s`` again, the load rests there
   and the team dissolves when its members hear it: each robot walks out from under the load
   (:func:`agent.errand.way_out`), then to its parking spot (:func:`agent.errand.parking`:
   fixed, the same in every agent), and is idle again;
5. a member killed (:class:`LifelongOptions` ``kills``) stands where it is from then on; a team
   that has lifted sets the load down where it stands (a resting load off any station) and its
   order fails with ``member lost: RID``; before the lift the order waits again.

A resting load is a body for every robot and formation: a box among the walls and shelves, for
the footprint planner and the CBF rows alike, except for its own team on the way into its slots
and for a robot that stands under it (:func:`agent.errand.sees_load`); a load set down is in the
robots' view from the tick after (as ``world/loads`` has it).

The formations change at run time; the controllers do not: whenever a formation lands, this
module builds the scenario of that moment (the fleet's robots grouped into the current
formations) and a fresh :class:`simulator.inprocess.FleetControl` for it; the formations that
landed are planned from the poses of their ask in the views of their ask and plan again at their
first tick (as a new leader does), every other one keeps its route, follower, driver and jam
memory. One :class:`simulator.tick.FleetTick` moves, records and checks the whole fleet
throughout; ``robots.csv`` names each robot's own formation of one, as the world's does.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from functools import partial
from pathlib import Path

import numpy as np

from agent import double_integrator
from agent.bidder import RELEASE_TICKS, REPEAT_S, BidderSettings
from agent.config import fleet_scenario, solo, team_formation
from agent.control import StepResult
from agent.errand import (
    EXIT_GAP,
    LOAD_MARGIN,
    allies_at,
    arrived,
    clear_spot,
    inside_box,
    load_box,
    out_from_under,
    parking,
    per_tick,
    route_mates,
    sees_load,
    standing_circles,
    way_out,
)
from geometry.polygon import polygon_distance
from geometry.shapes import Shape, shape_distance
from leader import allocation
from leader import orders as lo
from leader.role import VIEW_RANGE
from leader.team import (
    TeamPlan,
    axis_turn,
    carry_reach,
    load_pose,
    plan_team,
    pose_error,
    slot_points,
)
from scenario import Scenario, stream
from scenario.cargo import load_clearances
from scenario.lifelong import SINK, Lifelong, Order, Station
from scenario.model import FormationSpec
from viewer.orders import OrderBoard, OrderTimeline

from .inprocess import FleetControl, QPStats, SimOptions, obstacles_at, record, summarise
from .metrics import CONTACT_RELEASE
from .orders_out import orders_block, write_order_files
from .output import lost_words, write_run
from .series import Series
from .summary import COLLISION_LOG_MAX
from .tick import FleetTick, Pose

STUCK_M = 0.05  # [m] a team that moves less than this ...
STUCK_S = 120.0  # [s] ... in this long is stuck
CONTACT_TOL = 1e-3  # [m] a body this far inside another is a contact
ALLOCATORS = {"allocate": allocation.allocate, "greedy": allocation.greedy_nearest}
HEARD = 1  # [ticks] lock-step: what an agent puts at tick k the others take at tick k + 1
LANDS = 2  # [ticks] lock-step: a formation an agent asks for at tick k is its own at k + 2


@dataclass(frozen=True)
class LifelongOptions:
    """How a lifelong run is served: ``allocator`` (``allocate`` or the ``greedy`` baseline)
    and robots to kill (robot id -> time [s])."""

    allocator: str = "allocate"
    kills: tuple[tuple[str, float], ...] = ()


@dataclass
class LoadState:
    """Where a load is: its pose, ``state`` (resting, carried, gone), its station ("" off any)
    and the order moving it ("" none)."""

    name: str
    type: str
    pose: Pose
    station: str
    state: str = "resting"
    order: str = ""
    leaves: float = math.inf  # [s] at a sink: when it goes


@dataclass
class Crew:
    """An order's team at work: its roster, slots and moves, its formation once formed, and
    what the stuck rule remembers (the members' positions and when they were last that far)."""

    oid: str
    robots: tuple[str, ...]
    slots: tuple[tuple[float, float], ...]
    src: Pose
    dst: Pose
    plan: TeamPlan | None = None
    since: float = 0.0  # [s] the current phase began
    ref: list[tuple[float, float]] = field(default_factory=list)
    ref_t: float = 0.0
    # [tick] the agents' timeline (-1: not yet): the members took the roster, the speaker's
    # lift began, the lift ended, the speaker's set-down began
    start_k: int = -1
    lift_k: int = -1
    lifted_k: int = -1
    down_k: int = -1


@dataclass
class Checks:
    """What the run measures of its loads for the acceptance checks."""

    lift_error_m: float = 0.0  # the farthest member from its slot at a lift
    # [rad] a unicycle member's largest turn from its load's axis at a lift (either end)
    lift_turn_rad: float = 0.0
    set_down_m: float = 0.0  # the farthest a delivered load rests from its station
    set_down_rad: float = 0.0
    carried_clearance_m: float = math.inf  # a carried load's least clearance to any body
    load_contacts: int = 0  # ticks a carried load touched a body
    intrusions: int = 0  # robot-ticks inside a resting load it had no business under
    stuck: set[str] = field(default_factory=set)
    # the collisions of loads, as summary.json's collision_log has them: one entry per contact
    # from its onset until its release (a carried load against a body, ``kind: load``; a robot
    # inside a resting load, ``kind: resting_load``), and the contacts open now
    events: list[dict] = field(default_factory=list)
    touching: dict[tuple[str, str, str], dict] = field(default_factory=dict)

    def contact(self, key: tuple[str, str, str], clearance: float, entry: dict) -> None:
        """One contact seen this tick: a new collision at its onset, else its entry deepened."""
        open_ = self.touching.get(key)
        if open_ is None:
            entry["deepest_m"] = entry["clearance_m"] = round(clearance, 6)
            self.events.append(entry)
            self.touching[key] = entry
        else:
            open_["deepest_m"] = min(open_["deepest_m"], round(clearance, 6))

    def release(self, kind: str, still: set[tuple[str, str, str]]) -> None:
        """The contacts of ``kind`` (a key's first part: ``load`` or ``resting_load``) not in
        ``still`` have ended."""
        for key in [k for k in self.touching if k[0] == kind and k not in still]:
            del self.touching[key]


def rest_at(ld: LoadState, station: Station, dst: Pose, t: float, checks: Checks) -> None:
    """``ld`` set down at ``t`` at its destination ``station`` (pose ``dst``): how far from it
    is checked, and it rests there (leaving a sink after its dwell); in process and in the
    world of ``formation run`` alike."""
    d, a = pose_error(ld.pose, dst)
    checks.set_down_m = max(checks.set_down_m, d)
    checks.set_down_rad = max(checks.set_down_rad, a)
    ld.state, ld.station, ld.order = "resting", station.name, ""
    if station.kind == SINK:
        ld.leaves = t + station.dwell_s


def fleet_base(scenario: Scenario) -> Scenario:
    """A fleet scenario's robots, each a formation of one standing at its start (the scenario a
    lifelong run starts from, in process and in ``formation run``:
    :func:`agent.config.fleet_scenario`)."""
    if scenario.lifelong is None:
        raise ValueError(f"{scenario.name}: no fleet (not a lifelong scenario)")
    return fleet_scenario(scenario)


def new_order(life: Lifelong, loads: Mapping[str, LoadState], spec: Order) -> lo.Order:
    """The order book's form of a posted order (not yet stamped posted): a new load's type is
    the order's, a resting load's is the load's."""
    if spec.type is not None:
        kind = spec.type
    elif spec.load_name in loads:
        kind = loads[spec.load_name].type
    else:
        kind = life.type_of_load(spec.load_name).name
    return lo.Order(spec.id, kind, spec.load_name, spec.from_ or "", spec.to, spec.priority,
                    fresh=spec.type is not None)


def resting_at(loads: Mapping[str, LoadState]) -> dict[str, str]:
    """Station -> the load resting there."""
    return {ld.station: ld.name for ld in loads.values() if ld.state == "resting" and ld.station}


def outline_of(life: Lifelong, ld: LoadState) -> tuple[tuple[float, float], ...]:
    """The load's outline in the world, where it is now."""
    return slot_points(ld.pose, life.load_type(ld.type).outline)


def room(life: Lifelong, order: lo.Order, loads: Mapping[str, LoadState],
         bodies: Sequence[Pose], ds: float, radius: float) -> bool:
    """True when nothing stands where ``order``'s new load would appear: no robot body
    (``bodies``) within ``EXIT_GAP`` of its box, no carried load that near its outline."""
    kind = life.load_type(order.type)
    pose = life.station(order.src).pose
    sh = load_box(order.load, kind, pose, ds)
    if any(inside_box(sh, s[0], s[1], radius + EXIT_GAP) for s in bodies):
        return False
    outline = slot_points(pose, kind.outline)
    return all(polygon_distance(outline, outline_of(life, ld)) > EXIT_GAP
               for ld in loads.values() if ld.state == "carried")


def appear(life: Lifelong, orders: Mapping[str, lo.Order], loads: dict[str, LoadState],
           bodies: Sequence[Pose], ds: float, radius: float) -> list[LoadState]:
    """New loads appear at their free sources, where no body is in the way (a robot, or a load
    just lifted there), in the orders' precedence: each is added to ``loads``; the new ones."""
    out = []
    for order in sorted(orders.values(), key=lo.precedence):
        if order.load not in loads and lo.appears(order, resting_at(loads)) \
                and room(life, order, loads, bodies, ds, radius):
            pose = life.station(order.src).pose
            loads[order.load] = ld = LoadState(order.load, order.type, pose, order.src)
            out.append(ld)
    return out


def service_bound(at: Sequence[tuple[float, float]], slots: Sequence[tuple[float, float]],
                  src: Pose, dst: Pose, max_speed: float) -> float:
    """The straight-line bound of an order's service [s]: the farthest member to its slot,
    then the carry, at ``max_speed``."""
    return (max(math.dist(p, q) for p, q in zip(at, slots, strict=True))
            + math.dist(src[:2], dst[:2])) / max_speed


def watch_stuck(checks: Checks, crew: Crew, state: str, now: list[tuple[float, float]],
                t: float) -> None:
    """The stuck rule: a gathering or carrying team whose members (at ``now``) have not moved
    ``STUCK_M`` in ``STUCK_S`` makes its order stuck."""
    if state not in (lo.GATHERING, lo.CARRYING):
        return
    if max(math.dist(a, b) for a, b in zip(now, crew.ref, strict=True)) >= STUCK_M:
        crew.ref, crew.ref_t = now, t
    elif t - crew.ref_t >= STUCK_S:
        checks.stuck.add(crew.oid)


def intrusion(checks: Checks, t: float, rid: str, load: str, sh: Shape,
              p: tuple[float, float], radius: float) -> None:
    """Robot ``rid`` (of ``radius``) inside resting load ``load`` (box ``sh``) by no right: a
    collision of the load (its clearance: the body's distance to the outline less the
    radius)."""
    clearance = shape_distance(p[0], p[1], sh)[0] - radius
    checks.contact(("resting_load", rid, load), clearance, {
        "t": round(t, 6), "a": rid, "b": load, "kind": "resting_load",
        "x": round(p[0], 4), "y": round(p[1], 4)})


def carried_touches(checks: Checks, t: float, scen: Scenario,
                    outlines: Sequence[Sequence[tuple[float, float]]], bodies: np.ndarray,
                    obs: Sequence[tuple[float, float]]) -> None:
    """Carried loads (``outlines``: each formation of ``scen``'s, empty for none) against every
    body (``bodies`` in ``scen``'s robot order, the circles at ``obs``, ``scen``'s shapes and
    the other loads): each contact a collision of ``kind: load`` from onset to release, the
    least clearance and the ticks of contact counted in ``checks``."""
    least, touching = math.inf, set()
    for c in load_clearances(scen, outlines, bodies, obs):
        least = min(least, c.clearance)
        key = ("load", scen.formations[c.formation].name, c.other)
        if c.clearance < -CONTACT_TOL or (key in checks.touching
                                           and c.clearance <= CONTACT_RELEASE):
            touching.add(key)
        if c.clearance < -CONTACT_TOL:
            checks.contact(key, c.clearance, {
                "t": round(t, 6), "a": key[1], "b": c.other, "kind": "load",
                "x": round(c.x, 4), "y": round(c.y, 4)})
    checks.release("load", touching)
    checks.carried_clearance_m = min(checks.carried_clearance_m, least)
    if least < -CONTACT_TOL:
        checks.load_contacts += 1


def checks_block(c: Checks) -> dict:
    """summary.json's ``orders.checks``: the acceptance checks' measures."""
    return {
        "lift_error_m": round(c.lift_error_m, 6),
        "lift_turn_deg": round(math.degrees(c.lift_turn_rad), 6),
        "set_down_m": round(c.set_down_m, 6),
        "set_down_deg": round(math.degrees(c.set_down_rad), 6),
        "carried_min_clearance_m": round(c.carried_clearance_m, 6)
        if math.isfinite(c.carried_clearance_m) else None,
        "load_contacts": c.load_contacts, "intrusions": c.intrusions,
        "stuck_orders": sorted(c.stuck)}


@dataclass(frozen=True)
class Ask:
    """A robot's change of formation as its agent asks for it: it lands at tick ``land``
    (:data:`LANDS` after the ask); ``spec`` the formation (a formation of one, or its team's,
    with the poses of the ask), ``view`` the bodies it plans round, ``allies`` the gathering
    teammates it keeps apart from by separation rows, ``mates`` those its routes go round as
    robots (:func:`agent.errand.mates_at`)."""

    land: int
    spec: FormationSpec
    view: tuple[Shape, ...]
    allies: tuple[str, ...] = ()
    mates: tuple[str, ...] = ()


class LifelongRun:
    """One lifelong run of ``scenario`` (see the module docstring)."""

    def __init__(self, scenario: Scenario, options: SimOptions, life_options: LifelongOptions,
                 progress: Callable[[int, int, float], None] | None = None,
                 tally: Callable[[int, int], None] | None = None) -> None:
        life = scenario.lifelong
        if life is None:
            raise ValueError(f"{scenario.name}: no fleet (not a lifelong scenario)")
        if scenario.formations:
            raise ValueError(f"{scenario.name}: formations beside a fleet are not run yet")
        if life_options.allocator not in ALLOCATORS:
            raise ValueError(f"allocator: {life_options.allocator!r} is not one of "
                             f"{tuple(ALLOCATORS)}")
        self.life: Lifelong = life
        self.options = options
        self.allocate = ALLOCATORS[life_options.allocator]
        self.ids = life.fleet.robot_ids
        self.index = {r: k for k, r in enumerate(self.ids)}
        starts = life.fleet.starts
        self.base = fleet_base(scenario)
        self.static = scenario.shapes
        self.tally = tally  # told (delivered, posted) before each progress report
        self.tick = FleetTick(self.base, None, False, progress, stop=self.finished)
        self.state: list[Pose] = [starts[r] for r in self.ids]
        self.prev: list[Pose] = list(self.state)  # the poses of the tick before
        self.prev2: list[Pose] = list(self.state)  # and of the tick before that
        self.ds = scenario.robot.radius + LOAD_MARGIN
        # a robot leaving a load it stood under is out once its control point (where its rows
        # are measured) is beyond the load's safe distance
        self.leave = self.ds + scenario.robot.control_offset
        self.orders: dict[str, lo.Order] = {}
        self.due = sorted(life.orders, key=lambda o: (o.t, o.id))
        self.yard = stream.initial_yard(life)
        self.streamed = -1.0  # [s] the stream has posted its arrivals up to here
        self.loads = {ld.name: LoadState(ld.name, ld.type, life.station(ld.at).pose, ld.at)
                      for ld in life.loads}
        self.crews: dict[str, Crew] = {}
        self.role = dict.fromkeys(self.ids, "")  # the order a robot is bound to ("" idle)
        self.kills = dict(life_options.kills)
        self.dead: dict[str, float] = {}
        self.goal = {r: (starts[r][0], starts[r][1]) for r in self.ids}
        self.homes = parking(self.ids, starts, life.fleet.parking)
        self.leaving: dict[str, tuple[float, float]] = {}  # robot -> the point clear of a load
        self.under: dict[str, set[str]] = {r: set() for r in self.ids}  # loads over a robot
        self.set_k: dict[str, int] = {}  # load -> the tick it was last set down
        self.lift_k: dict[str, int] = {}  # load -> the tick it was last lifted
        # a robot's errand between teams (agent.errand.Errand): the tick it last put a final
        # status as its team's speaker (put again every repeat while it is idle), and the first
        # tick it is idle (none while in a team)
        self.spoke: dict[str, int] = {}
        self.idle_k: dict[str, float] = dict.fromkeys(self.ids, 0)
        self.load_rows: list[tuple] = []
        self.timeline = OrderTimeline()  # the orders' states as they change, for run.mcap
        self.busy_s = 0.0  # robot-seconds spent in a team
        self.bounds: dict[str, float] = {}  # order -> its straight-line service bound [s]
        self.checks = Checks()
        self.stats = QPStats()
        self.vel = [(0.0, 0.0)] * len(self.ids)
        dt = scenario.dt
        fleet = life.fleet
        self.window = max(RELEASE_TICKS + 1, round(fleet.bid_window_s / dt))
        self.bidding = BidderSettings(len(self.ids), self.window, fleet.bid_copies,
                                      RELEASE_TICKS, max(1, round(REPEAT_S / dt)), dt)
        self.lift_ticks = round(fleet.lift_s / dt)
        self.bids: dict[int, dict[str, dict[str, tuple[float, ...]]]] = {}  # round, order, robot
        self.commits: dict[int, list[tuple[str, tuple[str, ...]]]] = {}  # tick -> rosters
        self.todo: dict[int, list[Callable[[int], None]]] = {}  # tick -> what the agents do then
        # each robot's formation as its agent asked for it: on its way, and landed
        self.asks: dict[str, Ask] = {}
        self.now_in: dict[str, Ask] = {r: Ask(0, solo(r, starts[r], starts[r][:2]),
                                              tuple(self.static)) for r in self.ids}
        self.team: dict[str, FormationSpec] = {}  # robot -> its team's formation, once formed
        self.near: dict[str, tuple[str, ...]] = dict.fromkeys(self.ids, ())  # allies asked
        self.mates: dict[str, tuple[str, ...]] = dict.fromkeys(self.ids, ())  # mates asked
        self.again: set[str] = set()  # robots whose agents ask for their formation again
        self.fresh: set[str] = set(self.ids)  # robots whose asked formation landed this tick
        self.control: FleetControl | None = None
        self.scen = self.base
        self.perm: list[int] = []
        self.k = 0  # the tick being run
        self.now = 0.0  # [s] the tick being run

    # --- the run --------------------------------------------------------------------------

    def run(self) -> tuple[int, float]:
        """Run to ``duration`` or until every order is done; (ticks, simulated time)."""
        dt = self.base.dt
        self.tick.start(self.state)
        for ld in self.loads.values():
            self.log_load(0.0, ld)
        for rid, home in sorted(self.homes.items()):  # idle from the start: to its spot
            self.goal[rid] = home
            self.again.add(rid)
        k, t = 0, 0.0
        for k in range(self.base.steps):
            self.k = k
            t = self.now = k * dt
            self.events(k, t)
            if self.fresh:
                self.rebuild()
            before = self.state
            results, ellipses, obs = self.commands(t)
            self.prev2, self.prev = self.prev, before
            self.state = self.tick.move(before, results)
            if self.options.record:
                record(self.tick, t, before, results, ellipses, obs)
            t = (k + 1) * dt
            self.watch(t)
            if self.options.record:
                self.timeline.look(t, self.orders)
            if self.tally is not None:
                self.tally(sum(1 for o in self.orders.values() if o.state == lo.DELIVERED),
                           len(self.orders))
            if self.tick.check(k, t, self.state):
                break
        return k + 1, t

    def finished(self) -> bool:
        """Every order posted and done, and no load on its way out of a sink."""
        live = self.life.stream is not None and self.streamed < self.life.stream.until
        return (not self.due and not live and all(o.done for o in self.orders.values())
                and not any(math.isfinite(ld.leaves) and ld.state != "gone"
                            for ld in self.loads.values()))

    def events(self, k: int, t: float) -> None:
        """What happens at tick ``k`` before the commands (module docstring, steps 1 to 4), at
        the ticks the agents of a lock-step ``formation run`` do it."""
        self.kill_due(t)
        self.post_due(t)
        self.leave_sinks(t)
        self.appear(t)
        for act in self.todo.pop(k, []):  # what the agents heard, before their bidders' ticks
            act(k)
        if self.bidding.bid_tick(k) and self.bidding.next_close(k) >= 1:
            self.bid(k)
        if k % self.window == 0 and k:
            self.round(k, t)
        for oid, robots in self.commits.pop(k, []):
            self.assign(k, t, self.orders[oid], robots)
        for crew in sorted(self.crews.values(), key=lambda c: c.oid):
            self.advance(crew, k, t)
        self.walk_home(k)
        self.ask(k)
        self.land(k)

    def later(self, k: int, act: Callable[[int], None]) -> None:
        """``act`` at tick ``k``."""
        self.todo.setdefault(k, []).append(act)

    # --- orders and loads -----------------------------------------------------------------

    def post_due(self, t: float) -> None:
        """The scenario's orders due by ``t``, then the stream's arrivals since the last tick
        (:func:`scenario.stream.post`, over the warehouse as it is)."""
        while self.due and self.due[0].t <= t + 1e-9:
            self.post(self.due.pop(0), t)
        if self.life.stream is None:
            return
        arrived, self.yard = stream.post(self.life, self.streamed, t, self.yard_now())
        self.streamed = t
        for spec in arrived:
            self.post(spec, t)

    def post(self, spec: Order, t: float) -> None:
        order = new_order(self.life, self.loads, spec)
        self.orders[spec.id] = lo.step(order, lo.Event(lo.POST, t))

    def yard_now(self) -> stream.Yard:
        """The warehouse as the stream sees it: loads at stations, stations open orders hold
        (destinations, and the source of a new load until it is lifted), loads they claim."""
        open_ = [o for o in self.orders.values() if not o.done]
        held = {o.dst for o in open_} | {
            o.src for o in open_ if o.fresh and o.src and o.state in (
                lo.WAITING, lo.ASSIGNED, lo.GATHERING, lo.LIFTING)}
        return replace(self.yard, resting=self.resting_at(), held=frozenset(held),
                       claimed=frozenset(o.load for o in open_))

    def resting_at(self) -> dict[str, str]:
        """Station -> the load resting there."""
        return resting_at(self.loads)

    def appear(self, t: float) -> None:
        """New loads appear at their free sources (:func:`appear`)."""
        for ld in appear(self.life, self.orders, self.loads, self.state, self.ds,
                         self.base.robot.radius):
            self.log_load(t, ld)

    def leave_sinks(self, t: float) -> None:
        for ld in self.loads.values():
            if ld.state == "resting" and ld.leaves <= t + 1e-9:
                ld.state, ld.station = "gone", ""
                self.log_load(t, ld)

    def log_load(self, t: float, ld: LoadState) -> None:
        """loads.csv's row of ``ld`` at ``t``."""
        self.load_rows.append((t, ld.name, ld.type, ld.pose[0], ld.pose[1], ld.pose[2],
                               ld.state, ld.station, ld.order))

    # --- bidding rounds -------------------------------------------------------------------

    def open_orders(self, close: int) -> list[allocation.OpenOrder]:
        """The orders open for bids in the round that closes at tick ``close``, as they stand
        now (:func:`leader.orders.biddable`, :func:`leader.allocation.joins_round`)."""
        window = self.life.fleet.bid_window_s
        t_close = close * self.base.dt
        ripe = [o for o in self.orders.values()
                if o.state != lo.WAITING or allocation.joins_round(o.t_posted or 0.0, t_close,
                                                                   window)]
        resting = {n: ld.station for n, ld in self.loads.items() if ld.state == "resting"}
        return [allocation.OpenOrder(o.oid, slot_points(self.loads[o.load].pose,
                                                        self.life.load_type(o.type).slots),
                                     o.priority, o.t_posted or 0.0)
                for o in lo.biddable(ripe, self.resting_at(), resting) if o.state == lo.WAITING]

    def bid(self, k: int) -> None:
        """A bid tick (:meth:`agent.bidder.BidderSettings.bid_tick`): every idle robot bids for
        every order open for the coming round from where it stands; a later copy replaces an
        earlier one, as in the agents."""
        m = self.bidding.next_close(k)
        row = self.bids.setdefault(m, {})
        for o in self.open_orders(m * self.window):
            for rid in self.ids:
                if not self.role[rid] and rid not in self.dead:
                    at = self.positions([rid])[0]
                    row.setdefault(o.oid, {})[rid] = allocation.bid_costs(at, o.slots)

    def round(self, k: int, t: float) -> None:
        """A round closes: the one allocation function over the bids of the round, all
        delivered; every robot of a team is bound from now, and the rosters are committed a
        tick later (the leader hears the votes then)."""
        heard = self.bids.pop(k // self.window, {})
        self.bids = {m: b for m, b in self.bids.items() if m > k // self.window}
        open_ = self.open_orders(k)
        bids = [allocation.Bid(rid, oid, costs) for oid, row in sorted(heard.items())
                for rid, costs in sorted(row.items()) if not self.role[rid]]
        if not open_ or not bids:
            return
        result = self.allocate(open_, bids)
        for oid in sorted(result.teams):
            robots = result.teams[oid].robots
            for r in robots:
                self.role[r] = oid
            self.commits.setdefault(k + HEARD, []).append((oid, robots))

    def assign(self, k: int, t: float, order: lo.Order, robots: tuple[str, ...]) -> None:
        """The roster committed at ``t``: the order is assigned, its load bound; its members
        take it a tick later and walk to their slots."""
        ld = self.loads[order.load]
        if not order.src:
            order = replace(order, src=ld.station)
        order = lo.step(lo.step(order, lo.Event(lo.ASSIGN, t, robots)), lo.Event(lo.JOIN, t))
        self.orders[order.oid] = order
        slots = slot_points(ld.pose, self.life.load_type(order.type).slots)
        dst = self.life.station(order.dst).pose
        at = self.positions(robots)
        crew = Crew(order.oid, robots, slots, ld.pose, dst, since=t, ref=at, ref_t=t)
        self.crews[order.oid] = crew
        # the straight-line bound of the service: the farthest member to its slot, then the carry
        self.bounds[order.oid] = service_bound(at, slots, ld.pose, dst, self.base.robot.max_speed)
        ld.order = order.oid
        self.log_load(t, ld)
        self.later(k + HEARD, lambda kk: self.take(crew, kk))

    def take(self, crew: Crew, k: int) -> None:
        """The members follow the committed roster: each walks to its slot."""
        if self.crews.get(crew.oid) is not crew:
            return
        crew.start_k = k
        for r, s in zip(crew.robots, crew.slots, strict=True):
            self.idle_k[r] = math.inf
            self.goal[r] = s
            self.leaving.pop(r, None)
            self.again.add(r)

    # --- a team's phases ------------------------------------------------------------------

    def advance(self, crew: Crew, k: int, t: float) -> None:
        """The team's next phase, when its condition holds: gathered on the poses of now (the
        world's record), the rest as the team's speaker judges on the poses of the tick
        before."""
        state = self.orders[crew.oid].state
        lift = self.lift_ticks
        if state == lo.GATHERING and crew.start_k >= 0 and self.gathered(crew):
            self.move_order(crew.oid, lo.Event(lo.GATHERED, t))
            crew.lift_k = k + HEARD
            self.lift_checks(crew)
        elif state == lo.LIFTING and k >= crew.lift_k + lift:
            self.lifted(crew, k, t)
        elif state == lo.CARRYING and crew.down_k < 0 and k > crew.lifted_k \
                and self.arrived(crew):
            self.move_order(crew.oid, lo.Event(lo.ARRIVED, t))
            crew.down_k = k
        elif state == lo.SETTING_DOWN and k >= crew.down_k + lift:
            self.set_down(crew, k, t)

    def positions(self, robots: Sequence[str], poses: Sequence[Pose] | None = None
                  ) -> list[tuple[float, float]]:
        s = self.state if poses is None else poses
        return [(s[self.index[r]][0], s[self.index[r]][1]) for r in robots]

    def gathered(self, crew: Crew) -> bool:
        tol = self.base.goal_tolerance
        return all(math.dist(p, s) <= tol
                   for p, s in zip(self.positions(crew.robots), crew.slots, strict=True))

    def arrived(self, crew: Crew) -> bool:
        """The load within the set-down tolerance of its station where it is and where it comes
        to rest, and every member at its goal, on the poses of the tick before and their motion
        from the tick before that (the speaker's view, :func:`agent.errand.arrived`)."""
        assert crew.plan is not None
        at = self.positions(crew.robots, self.prev)
        steps = [per_tick(p, q, 1) for p, q in
                 zip(at, self.positions(crew.robots, self.prev2), strict=True)]
        return arrived(crew.plan, at, steps, crew.src, crew.dst,
                       carry_reach(self.base.goal_tolerance, self.base.robot.control_offset),
                       self.lift_ticks)

    def move_order(self, oid: str, event: lo.Event) -> lo.Order:
        self.orders[oid] = order = lo.step(self.orders[oid], event)
        return order

    def lift_checks(self, crew: Crew) -> None:
        """The lift's measures, where the team stands when it has gathered."""
        at = self.positions(crew.robots)
        self.checks.lift_error_m = max(self.checks.lift_error_m,
                                       *(math.dist(p, s) for p, s in zip(at, crew.slots,
                                                                         strict=True)))
        if self.base.robot.is_unicycle:
            self.checks.lift_turn_rad = max(self.checks.lift_turn_rad, *(
                axis_turn(self.state[self.index[r]][2], crew.src[2]) for r in crew.robots))

    def lifted(self, crew: Crew, k: int, t: float) -> None:
        """The lift done: the team's plan from where its members stand, the load carried; the
        members form the team a tick later (when they hear it)."""
        order = self.move_order(crew.oid, lo.Event(lo.LIFTED, t))
        kind = self.life.load_type(order.type)
        at = self.positions(crew.robots)
        crew.plan = plan_team(crew.oid, crew.robots, kind.slots, kind.outline, at,
                              (crew.src, crew.dst))
        crew.lifted_k = k
        ld = self.loads[order.load]
        ld.state, ld.station = "carried", ""
        self.lift_k[ld.name] = k
        self.log_load(t, ld)
        crew.since, crew.ref, crew.ref_t = t, at, t
        self.later(k + HEARD, lambda kk: self.form(crew))

    def form(self, crew: Crew) -> None:
        """The members form the team (its formation from where they stood through the lift,
        the load at its source); every robot's formation again."""
        if self.crews.get(crew.oid) is not crew or crew.plan is None:
            return
        poses = {r: (p[0], p[1], self.prev[self.index[r]][2])
                 for r, p in zip(crew.plan.robots, crew.plan.starts, strict=True)}
        outline = slot_points(crew.src, self.life.load_type(
            self.orders[crew.oid].type).outline)
        f = team_formation(crew.plan, poses, outline)
        for r in crew.robots:
            self.team[r] = f
        self.again.update(r for r in self.ids if r not in self.dead)

    def set_down(self, crew: Crew, k: int, t: float) -> None:
        order = self.move_order(crew.oid, lo.Event(lo.SET_DOWN, t))
        ld = self.loads[order.load]
        rest_at(ld, self.life.station(order.dst), crew.dst, t, self.checks)
        self.set_k[ld.name] = k
        self.log_load(t, ld)
        self.stand_under(ld, crew.robots)
        del self.crews[crew.oid]
        speaker = crew.robots[0]
        self.spoke[speaker] = k
        out = self.way_out(speaker, ld, crew.dst, self.prev)
        self.later(k + HEARD, lambda kk: self.dissolve(crew, crew.dst, {speaker: out}))

    def stand_under(self, ld: LoadState, robots: Sequence[str]) -> None:
        """A load came to rest over ``robots``: each one inside it stands under it until out."""
        sh = load_box(ld.name, self.life.load_type(ld.type), ld.pose, self.ds)
        r0 = self.base.robot.radius
        for r in robots:
            x, y = self.positions([r])[0]
            if inside_box(sh, x, y, r0):
                self.under[r].add(ld.name)

    def way_out(self, rid: str, ld: LoadState, at: Pose, poses: Sequence[Pose]
                ) -> tuple[float, float] | None:
        """Where ``rid`` (at ``poses``) walks out from under ``ld`` resting at ``at`` as its
        team reckons it (:func:`agent.errand.way_out`), or None."""
        sh = load_box(ld.name, self.life.load_type(ld.type), at, self.ds)
        return way_out(sh, self.positions([rid], poses)[0],
                       lambda x, y: self.clear_point(rid, x, y), self.base.robot.radius)

    def dissolve(self, crew: Crew, at: Pose, out: dict[str, tuple[float, float] | None]
                 ) -> None:
        """The team dissolved (its members heard it), its load resting at ``at`` as the team
        reckons it: each robot idle again, out from under the load, then to its parking spot;
        every robot's formation again."""
        ld = self.loads[self.orders[crew.oid].load]
        speaker = next((r for r in crew.robots if r not in self.dead), "")
        for r in crew.robots:
            # the speaker left its errand a tick ago (it put the status), the others now
            self.idle_k[r] = self.k if r == speaker else self.k + 1
            if r in self.dead:  # a formation of one again, standing where it died
                self.team.pop(r, None)
                self.asks[r] = Ask(self.k + LANDS, solo(r, self.state[self.index[r]], self.goal[r]),
                                   self.view_of(r, self.seen_boxes()), ())
                continue
            self.role[r] = ""
            self.team.pop(r, None)
            leaving = out[r] if r in out else self.way_out(r, ld, at, self.prev)
            if leaving is not None:
                self.leaving[r] = self.goal[r] = leaving
            elif r in self.homes:
                self.goal[r] = self.homes[r]
            else:
                self.goal[r] = self.positions([r], self.prev)[0]
        self.again.update(r for r in self.ids if r not in self.dead)

    def walk_home(self, k: int) -> None:
        """A robot out from under a load (on the poses of the tick before) walks to its spot:
        at once, or a tick later where its agent puts its last final status again this tick
        (a move with a status changes the formations a tick later: agent.lifepart)."""
        tol, offset = self.base.goal_tolerance, self.base.robot.control_offset
        saying = self.repeat_final(k)
        for rid in sorted(self.leaving):
            if out_from_under(self.positions([rid], self.prev)[0], self.leaving[rid], tol, offset):
                del self.leaving[rid]
                if rid in self.homes and not self.role[rid]:
                    if rid in saying:
                        self.later(k + HEARD, partial(self.go_home, rid))
                    else:
                        self.go_home(rid)

    def go_home(self, rid: str, _k: int = 0) -> None:
        """``rid`` walks to its parking spot (unless its team's roster took it meanwhile)."""
        crew = self.crews.get(self.role[rid])
        if crew is None or crew.start_k < 0:
            self.goal[rid] = self.homes[rid]
            self.again.add(rid)

    def repeat_final(self, k: int) -> set[str]:
        """The idle robots whose agents put their last final status again at tick ``k``
        (:meth:`agent.errand.Errand.step`: every repeat while idle)."""
        every = self.bidding.repeat_every
        out = set()
        for rid, said in self.spoke.items():
            if self.idle_k[rid] <= k and k - said >= every:
                self.spoke[rid] = k
                out.add(rid)
        return out

    # --- faults ---------------------------------------------------------------------------

    def kill_due(self, t: float) -> None:
        for rid, when in sorted(self.kills.items()):
            if rid not in self.dead and t >= when - 1e-9:
                self.dead[rid] = t
                self.goal[rid] = self.positions([rid])[0]
                if self.role[rid] in self.crews:
                    self.lose(self.crews[self.role[rid]], rid, t)
                self.role[rid] = ""

    def lose(self, crew: Crew, rid: str, t: float) -> None:
        """A member is lost: before the lift the order waits again; after it the load rests
        where it stands and the order fails."""
        order = self.move_order(crew.oid, lo.Event(lo.LOST, t, who=rid))
        ld = self.loads[order.load]
        ld.order = ""
        if ld.state == "carried":  # the order fails: its speaker says so
            ld.state = "resting"
            self.stand_under(ld, crew.robots)
            speaker = next((r for r in crew.robots if r not in self.dead), None)
            if speaker is not None:
                self.spoke[speaker] = self.k
        self.log_load(t, ld)
        del self.crews[crew.oid]
        self.later(self.k + HEARD, lambda kk: self.dissolve(crew, ld.pose, {}))

    # --- the formations of the moment -----------------------------------------------------

    def held(self, rid: str) -> bool:
        """A robot that stands still this tick: dead; the team's speaker through a lift or a
        set-down; a member at its slot (on the pose of the tick before) until it hears the lift
        is done."""
        if rid in self.dead:
            return True
        crew = self.crews.get(self.role[rid])
        if crew is None or crew.start_k < 0:
            return False
        k, lift = self.k, self.lift_ticks
        if rid == crew.robots[0]:
            return (0 <= crew.lift_k <= k < crew.lift_k + lift) or (
                0 <= crew.down_k <= k < crew.down_k + lift)
        if 0 <= crew.lifted_k < k:
            return False
        slot = crew.slots[crew.robots.index(rid)]
        return math.dist(self.positions([rid], self.prev)[0], slot) <= self.base.goal_tolerance

    def boxes(self) -> dict[str, Shape]:
        """Every resting load as a box."""
        return {n: load_box(n, self.life.load_type(ld.type), ld.pose, self.ds)
                for n, ld in self.loads.items() if ld.state == "resting"}

    def seen_boxes(self) -> dict[str, Shape]:
        """The resting loads as the agents hear of them this tick: a load set down now is
        carried still, and one lifted now rests still, in the ``world/loads`` of this tick (the
        world sets it down or takes it up when it hears the team, after the tick's
        commands)."""
        k = self.k
        return {n: load_box(n, self.life.load_type(ld.type), ld.pose, self.ds)
                for n, ld in self.loads.items()
                if (ld.state == "resting" and self.set_k.get(n) != k) or self.lift_k.get(n) == k}

    def exempt(self, rid: str) -> set[str]:
        """The resting loads robot ``rid`` may be under: its team's on the way in, and any it
        stands under."""
        oid = self.role[rid]
        own = {self.orders[oid].load} if oid in self.crews and self.orders[oid].state in (
            lo.GATHERING, lo.LIFTING) else set()
        return own | self.under[rid]

    def view_of(self, rid: str, boxes: dict[str, Shape]) -> tuple[Shape, ...]:
        """What robot ``rid`` keeps clear of, as its agent does: the walls and shelves and the
        resting loads but its team's on the way in and any it stands under
        (:func:`agent.errand.sees_load`)."""
        crew = self.crews.get(self.role[rid])
        own = self.orders[crew.oid].load if crew is not None and crew.start_k >= 0 \
            and crew.lifted_k < 0 else None
        me = self.positions([rid])[0]
        off = self.base.robot.control_offset
        return tuple(self.static) + tuple(sh for n, sh in boxes.items()
                                          if n != own and sees_load(sh, me, off))

    def clear_point(self, rid: str, x: float, y: float) -> bool:
        """True when robot ``rid`` may stand at (x, y): clear of every wall, shelf and resting
        load in its view."""
        return clear_spot(x, y, self.view_of(rid, self.seen_boxes()),
                          standing_circles(obstacles_at(self.base, self.now)),
                          self.base.robot.radius)

    def gathering_view(self, rid: str) -> tuple[tuple[str, ...], tuple[str, ...]]:
        """The gathering teammates ``rid`` keeps apart from by separation rows
        (:func:`agent.errand.allies_at`) and those its routes go round as robots
        (:func:`agent.errand.route_mates`), on the poses of the tick before; none once its
        team has formed."""
        crew = self.crews.get(self.role[rid])
        if crew is None or crew.start_k < 0 or rid in self.team:
            return (), ()
        at = dict(zip(crew.robots, self.positions(crew.robots, self.prev), strict=True))
        return (allies_at(crew.robots, crew.slots, rid, at),
                route_mates(crew.robots, crew.slots, rid, at))

    def ask(self, k: int) -> None:
        """Each robot whose agent asks for its formation this tick (a new goal, its team, the
        formations of the moment changed, its allies changed): the formation of the moment
        from where it stands, landing :data:`LANDS` ticks later."""
        boxes = self.seen_boxes()
        for rid in self.ids:
            if rid in self.dead:
                continue
            near, standing = self.gathering_view(rid)
            if near != self.near[rid] or standing != self.mates[rid]:
                self.near[rid], self.mates[rid] = near, standing
                self.again.add(rid)
        for rid in sorted(self.again):
            if rid in self.dead:
                continue
            spec = self.team.get(rid) or solo(rid, self.state[self.index[rid]], self.goal[rid])
            self.asks[rid] = Ask(k + LANDS, spec, self.view_of(rid, boxes), self.near[rid],
                                 self.mates[rid])
        self.again.clear()

    def land(self, k: int) -> None:
        """The formations asked for :data:`LANDS` ticks ago are the robots' now."""
        for rid in [r for r, a in self.asks.items() if a.land <= k]:
            self.now_in[rid] = self.asks.pop(rid)
            self.fresh.add(rid)

    def rebuild(self) -> None:
        """The scenario of this moment and a fresh controller for it: the formations that
        landed this tick are planned afresh in the views their agents asked with; every other
        one walks on as before (its route, follower, driver and jam memory carried over)."""
        fresh, self.fresh = self.fresh, set()
        teams: dict[str, FormationSpec] = {}
        for rid in self.ids:
            f = self.now_in[rid].spec
            if f.name != rid:
                teams[f.name] = f
        forms: list[FormationSpec] = []
        views: dict[str, tuple[Shape, ...]] = {}
        for f in [teams[n] for n in sorted(teams)] + [
                self.now_in[r].spec for r in self.ids if self.now_in[r].spec.name == r]:
            if any(r.id in fresh for r in f.robots):
                forms.append(f)
                views[f.name] = self.now_in[f.leader].view
            else:
                forms.append(replace(f, waypoints=(f.goal_centroid,)))
        self.scen = scen = replace(self.base, formations=tuple(forms))
        control = self.fleet_control(scen, views)
        self.perm = [self.index[r] for r in scen.robot_ids]
        control.vel = [self.vel[b] for b in self.perm]
        self.carry_over(control, fresh)
        self.allied(control)
        self.control = control

    def carry_over(self, control: FleetControl, fresh: set[str]) -> None:
        """The formations with no robot fresh walk on: their routes, drivers, followers and
        jam memory from the controller built last."""
        old = self.control
        if old is None:
            return
        at = {r: e for e, r in enumerate(old.scenario.robot_ids)}
        for f in control.scenario.formations:
            if any(r.id in fresh for r in f.robots) or f.name not in old.routes:
                continue
            control.routes[f.name] = old.routes[f.name]
            driver = old.replans.drivers.get(f.name)
            if driver is not None:
                control.replans.drivers[f.name] = driver
        for e, rid in enumerate(control.scenario.robot_ids):
            name = control.scenario.formation_of(rid).name
            if rid in fresh or name not in old.routes or \
                    old.scenario.formation_of(rid).name != name:
                continue
            control.followers[e] = old.followers[at[rid]]
            control.stalls[e] = old.stalls[at[rid]]

    def allied(self, control: FleetControl) -> None:
        """The gathering members near their slots keep apart by separation rows (as members of
        one formation do), not by each other's ellipses, as their agents asked."""
        at = {r: e for e, r in enumerate(control.scenario.robot_ids)}
        partners = list(control.fleet.partners)
        allies = [frozenset[str]()] * len(partners)
        for rid in self.ids:
            mates = self.now_in[rid].allies
            if mates:
                allies[at[rid]] = frozenset(mates)
                partners[at[rid]] = tuple(at[m] for m in mates)
        control.allies = allies
        control.fleet = replace(control.fleet, partners=tuple(partners))
        # a gathering robot's routes: its allies out of view, its mates round as robots
        control.replans.unseen = {r: frozenset(self.now_in[r].allies) for r in self.ids
                                  if self.now_in[r].allies}
        control.replans.mates = {r: frozenset(self.now_in[r].mates) for r in self.ids
                                 if self.now_in[r].mates}

    def fleet_control(self, scen: Scenario, views: dict[str, tuple[Shape, ...]]
                      ) -> FleetControl:
        """The controller of ``scen`` (its fresh formations planned in their ``views``),
        counting into the run's QP statistics; its planned formations plan again at a change
        of the still things only where one lies across the rest of their route (a fleet's
        robots stop and start all the time, mostly far off a route)."""
        control = FleetControl(scen, self.options, views)
        control.stats = self.stats
        control.replans.reach = VIEW_RANGE  # a leader plans round the formations in its others
        return control

    def commands(self, t: float) -> tuple[list[StepResult], dict, list]:
        """Every robot's command (base order): the formations' controller's, zero where held;
        each robot keeps clear of the resting loads in its view of this tick."""
        assert self.control is not None
        obs = obstacles_at(self.base, t)
        boxes = self.seen_boxes()
        for e, b in enumerate(self.perm):
            self.control.shapes[e] = self.view_of(self.ids[b], boxes)
        for name, driver in self.control.replans.drivers.items():  # as a leader's routes take them
            driver.replanner.shapes = self.control.shapes[self.control.replans.leader[name]]
        seen = [self.state[b] for b in self.perm]
        res, ellipses = self.control.commands(t, seen, obs)
        out: list[StepResult] = list(res)
        vel = list(self.vel)
        for e, b in enumerate(self.perm):
            r = res[e]
            vel[b] = (r.ux, r.uy)
            if self.held(self.ids[b]):
                r, vel[b] = self.hold(r, b)
                self.control.vel[e] = vel[b]
            out[b] = r
        self.vel = vel
        return out, ellipses, obs

    def summary(self, sim_time: float) -> dict:
        """summary.json's ``orders`` block (:func:`simulator.orders_out.orders_block`), the
        stuck orders and the acceptance checks' measures."""
        c = self.checks
        block = orders_block(list(self.orders.values()), self.bounds, len(self.ids), sim_time,
                             self.busy_s)
        block["stuck"] = len(c.stuck)
        block["checks"] = checks_block(c)
        return block

    def hold(self, r: StepResult, b: int) -> tuple[StepResult, tuple[float, float]]:
        """Robot ``b``'s command to stand still, as an agent's standing tick puts it: zero (the
        row has no QP outcome), which the world brakes a double integrator on
        (:func:`agent.double_integrator.brake`); and the velocity it leaves (what the robot's
        next ``state`` carries)."""
        robot = self.base.robot
        r = r._replace(ux=0.0, uy=0.0, v=0.0, omega=0.0, ax=0.0, ay=0.0, status="",
                       slack=math.nan, h_formation=math.nan, h_obstacle=math.nan,
                       h_formations=math.nan)
        if not robot.is_double_integrator:
            return r, (0.0, 0.0)
        dt = self.base.dt
        vx, vy = self.tick.vel[b]
        ax, ay = double_integrator.brake(vx, vy, robot.max_accel or math.inf, dt)
        _, _, vx, vy = double_integrator.integrate(0.0, 0.0, vx, vy, ax, ay, dt, robot.max_speed)
        return r._replace(ax=ax, ay=ay), (vx, vy)

    # --- after each tick ------------------------------------------------------------------

    def watch(self, t: float) -> None:
        """Carried loads follow their teams; the checks and the stuck rule look."""
        dt = self.base.dt
        self.busy_s += dt * sum(len(c.robots) for c in self.crews.values())
        for crew in sorted(self.crews.values(), key=lambda c: c.oid):
            order = self.orders[crew.oid]
            if order.state in (lo.CARRYING, lo.SETTING_DOWN) and crew.plan is not None:
                ld = self.loads[order.load]
                ld.pose = load_pose(crew.plan.starts, self.positions(crew.robots), crew.src)
                self.log_load(t, ld)
            self.stuck(crew, order.state, t)
        self.look(t)

    def stuck(self, crew: Crew, state: str, t: float) -> None:
        watch_stuck(self.checks, crew, state, self.positions(crew.robots), t)

    def look(self, t: float) -> None:
        """Bodies against resting loads (a robot under one by no right intrudes; one that has
        left the load it stood under sees it again) and carried loads against everything."""
        boxes = self.boxes()
        r0 = self.base.robot.radius
        inside_now: set[tuple[str, str, str]] = set()
        for rid in self.ids:
            x, y = self.state[self.index[rid]][0], self.state[self.index[rid]][1]
            allowed = self.exempt(rid)
            for n, sh in boxes.items():
                inside = inside_box(sh, x, y, r0 - CONTACT_TOL)
                if inside and n not in allowed:
                    self.checks.intrusions += 1
                    self.intrusion(t, rid, n, sh, (x, y))
                    inside_now.add(("resting_load", rid, n))
                elif not inside and n in self.under[rid] and not inside_box(sh, x, y, self.leave):
                    self.under[rid].discard(n)
        self.checks.release("resting_load", inside_now)
        self.carried_contacts(t)

    def intrusion(self, t: float, rid: str, load: str, sh: Shape, p: tuple[float, float]
                  ) -> None:
        """Robot ``rid`` inside resting load ``load`` (box ``sh``) by no right: a collision of
        the load (its clearance: the body's distance to the outline less the radius)."""
        intrusion(self.checks, t, rid, load, sh, p, self.base.robot.radius)

    def carried_contacts(self, t: float) -> None:
        outlines = []
        carrying = {c.oid for c in self.crews.values()
                    if self.orders[c.oid].state in (lo.CARRYING, lo.SETTING_DOWN)}
        for f in self.scen.formations:
            if f.name in carrying:
                order = self.orders[f.name]
                outlines.append(slot_points(self.loads[order.load].pose,
                                            self.life.load_type(order.type).outline))
            else:
                outlines.append(())
        if not carrying:
            self.checks.release("load", set())
            return
        bodies = np.array([self.state[b][:2] for b in self.perm])
        obs = [o.position(t) for o in self.base.obstacles]
        carried_touches(self.checks, t, self.scen, outlines, bodies, obs)


@dataclass
class LifelongResult:
    """A lifelong run's summary, series and what its loads and orders did."""

    summary: dict
    series: Series
    scenario: Scenario
    run: LifelongRun


def simulate_lifelong(scenario: Scenario, options: SimOptions | None = None,
                      life_options: LifelongOptions | None = None,
                      progress: Callable[[int, int, float], None] | None = None,
                      tally: Callable[[int, int], None] | None = None) -> LifelongResult:
    """Run the lifelong ``scenario`` in process (module docstring); ``tally(delivered,
    posted)`` hears the orders' count before each ``progress`` report."""
    options = options or SimOptions()
    run = LifelongRun(scenario, options, life_options or LifelongOptions(), progress, tally)
    end = run.run()
    assert run.control is not None
    summary = summarise(run.base, options, run.control, run.tick, end)
    judge_orders(summary, run.orders, bool(run.due))
    summary["orders"] = run.summary(end[1])
    collide(summary, run.checks.events)
    return LifelongResult(summary, run.tick.series, run.base, run)


def judge_orders(summary: dict, orders: Mapping[str, lo.Order], more: bool) -> None:
    """A lifelong run's verdict in ``summary``: ``all_reached`` when every order was delivered
    and none was still to come (``more``), ``time_to_goal_s`` the last delivery then."""
    summary["all_reached"] = bool(orders) and all(
        o.state == lo.DELIVERED for o in orders.values()) and not more
    times = [o.t_delivered for o in orders.values() if o.t_delivered is not None]
    summary["time_to_goal_s"] = round(max(times), 6) if summary["all_reached"] else None


def order_files(out: Path, orders: Sequence[lo.Order], load_rows: Sequence[tuple], plots: bool,
                end: float) -> list[dict[str, str]]:
    """orders.csv, loads.csv and orders.png (:func:`simulator.orders_out.write_order_files`);
    the file lost to a full disk, as ``write_run`` reports it, or none."""
    try:
        write_order_files(out, orders, load_rows, plots, end)
    except OSError as exc:
        return [{"file": "orders.csv", "error": lost_words(exc)}]
    return []


def write_orders(out: Path, summary: dict, orders: Mapping[str, lo.Order],
                 load_rows: Sequence[tuple], events: list[dict], plots: bool = True
                 ) -> list[dict[str, str]]:
    """``formation run``'s part of a lifelong run's outputs: the loads' collisions counted in
    ``summary`` (:func:`collide`) and the order files written into ``out``
    (:func:`order_files`); the files lost."""
    collide(summary, events)
    return order_files(out, list(orders.values()), load_rows, plots, summary["sim_time_s"])


def collide(summary: dict, events: list[dict]) -> None:
    """The loads' collisions counted in ``summary``'s ``collisions`` (a carried load touching a
    body and a robot inside a resting load are collisions, as a robot's are) and merged into its
    ``collision_log`` by time, as long as the log's cap allows."""
    if not events:
        return
    summary["collisions"] += len(events)
    log = sorted(summary["collision_log"] + events, key=lambda e: e["t"])
    summary["collision_log"] = log[:COLLISION_LOG_MAX]


def write_lifelong(result: LifelongResult, out: Path, plots: bool = True) -> list[dict[str, str]]:
    """Every file of a lifelong run: the run's files (:func:`simulator.output.write_run`), then
    orders.csv, loads.csv and orders.png; the files lost, as ``write_run`` returns them."""
    board = OrderBoard(result.run.life, result.run.load_rows, result.run.timeline)
    lost = write_run(result.summary, result.series, result.scenario, out, plots=plots, board=board)
    return lost + order_files(out, list(result.run.orders.values()), result.run.load_rows, plots,
                              result.summary["sim_time_s"])
