"""Lifelong operation in process: a fleet serves transport orders, teams forming at run time.

A scenario with a ``fleet`` (:mod:`scenario.lifelong`) has no fixed formations: every robot is a
formation of one until an order's team takes it. Each tick, before the robots' commands:

1. due orders are posted; a new load appears at its source once the source is free
   (:func:`leader.orders.appears`); a load delivered to a sink leaves after its dwell;
2. when a bidding round closes (every ``fleet.bid_window_s``), every idle robot bids for every
   order open for bids (:func:`leader.orders.biddable`: the load rests, the destination is free
   and then reserved) and the one allocation function runs over the bids, all delivered at the
   close (:func:`leader.allocation.allocate`, or the greedy baseline); each team is committed
   and its members start gathering;
3. each member of a gathering team is routed to its slot as a formation of one; when all stand at
   their slots (``goal_tolerance``) the team forms its formation (:func:`leader.team.plan_team`:
   every pair of slots an edge, slot 0 leads), lifts for ``fleet.lift_s`` standing still, and
   from then on the load is the formation's ``load``, carried as a rigid body to the
   destination; within 5 cm and 3 degrees of it the team stands for ``lift_s`` again, the load
   rests there and the team dissolves: its robots leave the load and park (the nearest free
   parking spot, else a point clear of the load) or take the next order;
4. a member killed (:class:`LifelongOptions` ``kills``) stands where it is from then on; a team
   that has lifted sets the load down where it stands (a resting load off any station) and its
   order fails with ``member lost: RID``; before the lift the order waits again.

A resting load is a body for every robot and formation: a box among the walls and shelves
(``shapes``), for the footprint planner and the CBF rows alike, except for its own team on the
way into its slots and for a robot that stands under it when it comes to rest, until its
control point is out of the load's safe distance (sooner, its obstacle row would start below
zero).

The formations change at run time; the controllers do not: whenever the set of formations or a
robot's goal or view of the loads changes, this module builds the scenario of that moment (the
fleet's robots grouped into the current formations, starting where they stand) and a fresh
:class:`simulator.inprocess.FleetControl` for it, and carries each robot's last command over.
An idle robot that walks to the same goal as at the last build walks on along its route (its
follower and its replanning driver carried over, nothing planned again) unless a body new in
its view lies across the rest of that route, and a team that carries the same load among the
same bodies carries on along its route: only the formations that changed are planned. The
robots stop and start all the time, mostly far off one another's ways: a planned formation plans
again for a thing that has come to stand still, or moved, only where it lies across the rest of
its route (``keep_if_clear`` of :class:`leader.routing.Replanner`).
One :class:`simulator.tick.FleetTick` moves, records and checks the whole fleet throughout.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from agent import double_integrator
from agent.config import fleet_scenario, solo, team_formation
from agent.control import StepResult
from agent.errand import (
    ALLY_REACH,
    EXIT_GAP,
    LOAD_MARGIN,
    SET_DOWN_M,
    SET_DOWN_RAD,
    exit_point,
    inside_box,
    load_box,
)
from geometry.polygon import polygon_distance
from geometry.shapes import Shape, distance_floor, shape_distance
from leader import allocation
from leader import orders as lo
from leader.navigation import Follower
from leader.route_driver import RouteDriver
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


def route_clear(route: Sequence[tuple[float, float]], shapes: Sequence[Shape], margin: float,
                step: float = 0.05) -> bool:
    """True when the polyline ``route`` (points ``step`` apart along each leg) keeps beyond each
    shape's safe distance plus ``margin``."""
    if not shapes:
        return True
    for (ax, ay), (bx, by) in zip(route, route[1:], strict=False):
        n = max(1, math.ceil(math.hypot(bx - ax, by - ay) / step))
        for k in range(n + 1):
            x, y = ax + (bx - ax) * k / n, ay + (by - ay) * k / n
            if any(distance_floor(x, y, sh) < sh.ds + margin
                   and shape_distance(x, y, sh)[0] < sh.ds + margin for sh in shapes):
                return False
    return True


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
        self.role = dict.fromkeys(self.ids, "")
        self.kills = dict(life_options.kills)
        self.dead: dict[str, float] = {}
        self.goal = {r: (starts[r][0], starts[r][1]) for r in self.ids}
        self.leaving: dict[str, tuple[float, float]] = {}  # robot -> the point clear of a load
        self.under: dict[str, set[str]] = {r: set() for r in self.ids}  # loads over a robot
        self.load_rows: list[tuple] = []
        self.timeline = OrderTimeline()  # the orders' states as they change, for run.mcap
        self.busy_s = 0.0  # robot-seconds spent in a team
        self.bounds: dict[str, float] = {}  # order -> its straight-line service bound [s]
        self.checks = Checks()
        self.stats = QPStats()
        self.vel = [(0.0, 0.0)] * len(self.ids)
        self.window = max(1, round(life.fleet.bid_window_s / scenario.dt))
        self.dirty = True
        self.control: FleetControl | None = None
        self.scen = self.base
        self.perm: list[int] = []
        self.partners: tuple[tuple[int, ...], ...] = ()  # each robot's partners, as built
        # each robot walking alone at the last build: its goal and what it kept clear of
        self.walks: dict[str, tuple[tuple[float, float], tuple[Shape, ...]]] = {}
        # each carrying team at the last build: its plan and the bodies it kept clear of
        self.carries: dict[str, tuple[TeamPlan, tuple[Shape, ...]]] = {}
        self.now = 0.0  # [s] the tick being run

    # --- the run --------------------------------------------------------------------------

    def run(self) -> tuple[int, float]:
        """Run to ``duration`` or until every order is done; (ticks, simulated time)."""
        dt = self.base.dt
        self.tick.start(self.state)
        for ld in self.loads.values():
            self.log_load(0.0, ld)
        k, t = 0, 0.0
        for k in range(self.base.steps):
            t = self.now = k * dt
            self.events(k, t)
            if self.dirty:
                self.rebuild()
            before = self.state
            results, ellipses, obs = self.commands(t)
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
        """What happens at ``t`` before the commands (module docstring, steps 1 to 4)."""
        self.kill_due(t)
        self.post_due(t)
        self.leave_sinks(t)
        self.appear(t)
        if k % self.window == 0:
            self.round(t)
        for crew in sorted(self.crews.values(), key=lambda c: c.oid):
            self.advance(crew, t)

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
        self.dirty = True  # idle robots keep clear of where its load is due

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
            self.dirty = True

    def leave_sinks(self, t: float) -> None:
        for ld in self.loads.values():
            if ld.state == "resting" and ld.leaves <= t + 1e-9:
                ld.state, ld.station = "gone", ""
                self.log_load(t, ld)
                self.dirty = True

    def log_load(self, t: float, ld: LoadState) -> None:
        """loads.csv's row of ``ld`` at ``t``."""
        self.load_rows.append((t, ld.name, ld.type, ld.pose[0], ld.pose[1], ld.pose[2],
                               ld.state, ld.station, ld.order))

    # --- bidding rounds -------------------------------------------------------------------

    def round(self, t: float) -> None:
        """A round closes: every idle robot bids for every open order, all bids delivered."""
        window = self.life.fleet.bid_window_s
        ripe = [o for o in self.orders.values()
                if o.state != lo.WAITING or allocation.joins_round(o.t_posted or 0.0, t, window)]
        resting = {n: ld.station for n, ld in self.loads.items() if ld.state == "resting"}
        open_ = [o for o in lo.biddable(ripe, self.resting_at(), resting)
                 if o.state == lo.WAITING]
        idle = {r: (self.state[self.index[r]][0], self.state[self.index[r]][1])
                for r in self.ids if not self.role[r] and r not in self.dead}
        if not open_ or not idle:
            return
        slots = {o.oid: slot_points(self.loads[o.load].pose,
                                    self.life.load_type(o.type).slots) for o in open_}
        bids_for = [allocation.OpenOrder(o.oid, slots[o.oid], o.priority, o.t_posted or 0.0)
                    for o in open_]
        result = allocation.round_teams(bids_for, idle, self.allocate)
        for oid in sorted(result.teams):
            self.assign(t, self.orders[oid], result.teams[oid].robots, slots[oid])

    def assign(self, t: float, order: lo.Order, robots: tuple[str, ...],
               slots: tuple[tuple[float, float], ...]) -> None:
        ld = self.loads[order.load]
        if not order.src:
            order = replace(order, src=ld.station)
        order = lo.step(lo.step(order, lo.Event(lo.ASSIGN, t, robots)), lo.Event(lo.JOIN, t))
        self.orders[order.oid] = order
        dst = self.life.station(order.dst).pose
        at = self.positions(robots)
        self.crews[order.oid] = Crew(order.oid, robots, slots, ld.pose, dst, since=t,
                                     ref=at, ref_t=t)
        # the straight-line bound of the service: the farthest member to its slot, then the carry
        self.bounds[order.oid] = service_bound(at, slots, ld.pose, dst, self.base.robot.max_speed)
        ld.order = order.oid
        self.log_load(t, ld)
        for r, s in zip(robots, slots, strict=True):
            self.role[r] = order.oid
            self.goal[r] = s
            self.leaving.pop(r, None)
        self.dirty = True

    # --- a team's phases ------------------------------------------------------------------

    def advance(self, crew: Crew, t: float) -> None:
        """The team's next phase, when its condition holds."""
        state = self.orders[crew.oid].state
        lift = self.life.fleet.lift_s
        if state == lo.GATHERING and self.gathered(crew):
            self.lift(crew, t)
        elif state == lo.LIFTING and t - crew.since >= lift - 1e-9:
            self.lifted(crew, t)
        elif state == lo.CARRYING and self.arrived(crew):
            self.move_order(crew.oid, lo.Event(lo.ARRIVED, t))
            crew.since = t
        elif state == lo.SETTING_DOWN and t - crew.since >= lift - 1e-9:
            self.set_down(crew, t)

    def positions(self, robots: Sequence[str]) -> list[tuple[float, float]]:
        return [(self.state[self.index[r]][0], self.state[self.index[r]][1]) for r in robots]

    def gathered(self, crew: Crew) -> bool:
        tol = self.base.goal_tolerance
        return all(math.dist(p, s) <= tol
                   for p, s in zip(self.positions(crew.robots), crew.slots, strict=True))

    def arrived(self, crew: Crew) -> bool:
        """The load is within the set-down tolerance of its station and every member at its
        goal (the load as near its station as the members can bring it), within its reach
        (:func:`leader.team.carry_reach`)."""
        assert crew.plan is not None
        d, a = pose_error(self.loads[self.orders[crew.oid].load].pose, crew.dst)
        tol = carry_reach(self.base.goal_tolerance, self.base.robot.control_offset)
        return d <= SET_DOWN_M and a <= SET_DOWN_RAD and all(
            math.dist(p, g) <= tol for p, g in zip(self.positions(crew.robots), crew.plan.goals,
                                                   strict=True))

    def move_order(self, oid: str, event: lo.Event) -> lo.Order:
        self.orders[oid] = order = lo.step(self.orders[oid], event)
        return order

    def lift(self, crew: Crew, t: float) -> None:
        order = self.move_order(crew.oid, lo.Event(lo.GATHERED, t))
        at = self.positions(crew.robots)
        kind = self.life.load_type(order.type)
        crew.plan = plan_team(crew.oid, crew.robots, kind.slots, kind.outline, at,
                              (crew.src, crew.dst))
        self.checks.lift_error_m = max(self.checks.lift_error_m,
                                       *(math.dist(p, s) for p, s in zip(at, crew.slots,
                                                                         strict=True)))
        if self.base.robot.is_unicycle:
            self.checks.lift_turn_rad = max(self.checks.lift_turn_rad, *(
                axis_turn(self.state[self.index[r]][2], crew.src[2]) for r in crew.robots))
        crew.since = t
        self.dirty = True

    def lifted(self, crew: Crew, t: float) -> None:
        order = self.move_order(crew.oid, lo.Event(lo.LIFTED, t))
        ld = self.loads[order.load]
        ld.state, ld.station = "carried", ""
        self.log_load(t, ld)
        crew.since, crew.ref, crew.ref_t = t, self.positions(crew.robots), t
        self.dirty = True

    def set_down(self, crew: Crew, t: float) -> None:
        order = self.move_order(crew.oid, lo.Event(lo.SET_DOWN, t))
        ld = self.loads[order.load]
        rest_at(ld, self.life.station(order.dst), crew.dst, t, self.checks)
        self.log_load(t, ld)
        self.dissolve(crew)

    def dissolve(self, crew: Crew) -> None:
        for r in crew.robots:
            self.role[r] = ""
        del self.crews[crew.oid]
        self.dirty = True

    # --- faults ---------------------------------------------------------------------------

    def kill_due(self, t: float) -> None:
        for rid, when in sorted(self.kills.items()):
            if rid not in self.dead and t >= when - 1e-9:
                self.dead[rid] = t
                self.goal[rid] = self.positions([rid])[0]
                self.dirty = True
                if self.role[rid]:
                    self.lose(self.crews[self.role[rid]], rid, t)

    def lose(self, crew: Crew, rid: str, t: float) -> None:
        """A member is lost: before the lift the order waits again; after it the load rests
        where it stands and the order fails."""
        order = self.move_order(crew.oid, lo.Event(lo.LOST, t, who=rid))
        ld = self.loads[order.load]
        ld.order = ""
        if ld.state == "carried":
            ld.state = "resting"
        self.log_load(t, ld)
        self.dissolve(crew)

    # --- the formations of the moment -----------------------------------------------------

    def held(self, rid: str) -> bool:
        """A robot that stands still this tick: dead, or lifting or setting a load down."""
        oid = self.role[rid]
        return rid in self.dead or (bool(oid) and self.orders[oid].state in (lo.LIFTING,
                                                                             lo.SETTING_DOWN))

    def boxes(self) -> dict[str, Shape]:
        """Every resting load as a box."""
        return {n: load_box(n, self.life.load_type(ld.type), ld.pose, self.ds)
                for n, ld in self.loads.items() if ld.state == "resting"}

    def exempt(self, rid: str) -> set[str]:
        """The resting loads robot ``rid`` may be under: its team's on the way in, and any it
        stands under."""
        oid = self.role[rid]
        own = {self.orders[oid].load} if oid and self.orders[oid].state in (
            lo.GATHERING, lo.LIFTING) else set()
        return own | self.under[rid]

    def idle_goals(self, boxes: dict[str, Shape]) -> None:
        """Where each idle robot goes: out from under a load or from where a load is due
        (:meth:`keep_clear`), else its parking spot (the nearest free one), else where it
        stands."""
        r0 = self.base.robot.radius
        taken = {self.goal[r] for r in self.ids if self.role[r] or r in self.dead}
        due = self.keep_clear()
        for rid in self.ids:
            if self.role[rid] or rid in self.dead:
                continue
            p = self.positions([rid])[0]
            over = [sh for n, sh in boxes.items() if n in self.under[rid]] + [
                sh for sh in due if inside_box(sh, p[0], p[1], r0 + EXIT_GAP)]
            if over and rid not in self.leaving:
                self.leaving[rid] = exit_point(over[0], p, self.clear_point, EXIT_GAP + r0)
            self.goal[rid] = self.leaving.get(rid) or self.park(rid, p, taken)
            taken.add(self.goal[rid])

    def keep_clear(self) -> list[Shape]:
        """Where loads are due: the source of each new load not there yet, the destination of
        each order a team holds (as the load's box there)."""
        out = []
        for o in self.orders.values():
            kind = self.life.load_type(o.type)
            if o.fresh and o.state == lo.WAITING and o.load not in self.loads:
                out.append(load_box(o.oid, kind, self.life.station(o.src).pose, self.ds))
            elif o.state in lo.TEAMED:
                out.append(load_box(o.oid, kind, self.life.station(o.dst).pose, self.ds))
        return out

    def park(self, rid: str, p: tuple[float, float], taken: set[tuple[float, float]]
             ) -> tuple[float, float]:
        """Robot ``rid``'s parking spot: the one it has, else the nearest free one, else
        ``p``."""
        spots = self.life.fleet.parking
        if self.goal[rid] in spots and self.goal[rid] not in taken:
            return self.goal[rid]
        free = [s for s in spots if s not in taken]
        return min(free, key=lambda s: math.dist(s, p)) if free else p

    def clear_point(self, x: float, y: float) -> bool:
        """True when a robot may stand at (x, y): clear of every wall, shelf and resting load."""
        r0 = self.base.robot.radius
        shapes = list(self.static) + list(self.boxes().values())
        return all(shape_distance(x, y, sh)[0] >= sh.ds + r0 for sh in shapes)

    def rebuild(self) -> None:
        """The scenario of this moment and a fresh controller for it (module docstring); a
        idle robot walking to the same goal as before keeps its route (:meth:`kept_walks`), and a
        carrying team its own (:meth:`kept_carries`)."""
        self.dirty = False
        poses = {r: self.state[self.index[r]] for r in self.ids}
        boxes = self.boxes()
        r0 = self.base.robot.radius
        for rid in self.ids:  # the loads each robot stands under now, or is still leaving
            x, y = poses[rid][0], poses[rid][1]
            self.under[rid] = {n for n in boxes if inside_box(
                boxes[n], x, y, self.leave if n in self.under[rid] else r0)}
        self.idle_goals(boxes)
        forms: list[FormationSpec] = []
        shapes = tuple(self.static) + tuple(boxes.values())
        carried = self.kept_carries(shapes)
        for crew in sorted(self.crews.values(), key=lambda c: c.oid):
            if crew.plan is not None:
                f = team_formation(crew.plan, poses, self.carried_outline(crew))
                # a kept carry is built with its goal as its route (nothing to plan), then
                # handed its walk
                forms.append(replace(f, waypoints=(f.goal_centroid,)) if crew.oid in carried
                             else f)
        teamed = {r for f in forms for r in f.robot_ids}
        near = self.base.goal_tolerance
        walking = [r for r in self.ids if r not in teamed
                   and math.dist(poses[r][:2], self.goal[r]) > near]
        views = {r: self.view_of(r, boxes) for r in self.ids}
        kept = self.kept_walks(walking, views)
        # a kept walk is built as one standing at its goal (nothing to plan), then handed its walk
        forms += [solo(r, poses[r], self.goal[r], r not in walking or r in kept)
                  for r in self.ids if r not in teamed]
        self.scen = scen = replace(self.base, formations=tuple(forms), shapes=shapes)
        # a robot walking alone that may pass under a load is planned in its own view, once
        control = self.fleet_control(scen, {r: views[r] for r in self.ids if r not in teamed
                                            and r not in kept and len(views[r]) < len(shapes)})
        self.perm = [self.index[r] for r in scen.robot_ids]
        control.vel = [self.vel[b] for b in self.perm]
        for oid, (route, driver) in carried.items():
            control.routes[oid] = route
            if driver is not None:
                control.replans.drivers[oid] = driver
        before = self.control.followers if self.control is not None else []
        at = {r: e for e, r in enumerate(self.control.scenario.robot_ids)} \
            if self.control is not None else {}
        for e, rid in enumerate(scen.robot_ids):
            if self.role[rid] in carried:
                control.followers[e] = before[at[rid]]
            elif rid in kept:
                self.hand_walk(control, e, kept[rid], views[rid])
            elif len(views[rid]) < len(shapes):
                control.shapes[e] = views[rid]
        self.walks = {r: (self.goal[r], views[r]) for r in walking}
        self.carries = {c.oid: (c.plan, shapes) for c in self.crews.values()
                        if c.plan is not None}
        self.partners = control.fleet.partners
        self.control = control
        self.tick.formation_of = tuple(scen.formation_of(r).name for r in self.ids)

    def fleet_control(self, scen: Scenario, views: dict[str, tuple[Shape, ...]]
                      ) -> FleetControl:
        """The controller of ``scen`` (formations of one in their ``views``), counting into the
        run's QP statistics; its planned formations plan again at a change of the still things
        only where one lies across the rest of their route (a fleet's robots stop and start all
        the time, mostly far off a route)."""
        control = FleetControl(scen, self.options, views)
        control.stats = self.stats
        for driver in control.replans.drivers.values():
            driver.replanner.keep_if_clear = True
        return control

    def kept_carries(self, shapes: tuple[Shape, ...]
                     ) -> dict[str, tuple[tuple, RouteDriver | None]]:
        """The teams that carry on as before (their route and driver of the controller built
        last; their members' followers go with them): each carried the same plan then, in the
        same bodies, and its driver handed its leader no route on the last tick (the members
        take a route a tick after the leader)."""
        old = self.control
        if old is None:
            return {}
        names = [sh.name for sh in shapes]
        last = self.now - self.base.dt - 1e-9
        fresh = {name for t, name, _why, _k in old.replans.updates if t >= last}
        out = {}
        for crew in self.crews.values():
            then = self.carries.get(crew.oid)
            if then is None or then[0] is not crew.plan or crew.oid in fresh \
                    or [sh.name for sh in then[1]] != names:
                continue
            out[crew.oid] = (old.routes[crew.oid], old.replans.drivers.get(crew.oid))
        return out

    def view_of(self, rid: str, boxes: dict[str, Shape]) -> tuple[Shape, ...]:
        """What robot ``rid`` keeps clear of: the walls and shelves and the resting loads but
        those it may be under (:meth:`exempt`)."""
        skip = self.exempt(rid)
        return tuple(self.static) + tuple(sh for n, sh in boxes.items() if n not in skip)

    def kept_walks(self, walking: list[str], views: dict[str, tuple[Shape, ...]]
                   ) -> dict[str, tuple[Follower, RouteDriver | None, tuple]]:
        """The robots of ``walking`` that walk on as before (the route, its follower and its
        driver of the controller built last): each is idle, walked alone to the same goal and
        every body new in its view lies clear of the rest of its route (:func:`route_clear`)."""
        old = self.control
        if old is None:
            return {}
        at = {r: e for e, r in enumerate(old.scenario.robot_ids)}
        out = {}
        for rid in walking:
            goal, view = self.walks.get(rid, (None, ()))
            if goal != self.goal[rid] or rid not in at or self.role[rid]:
                continue
            follower = old.followers[at[rid]]
            seen = {sh.name for sh in view}
            new = [sh for sh in views[rid] if sh.name not in seen]
            rest = (self.positions([rid])[0],) + tuple(follower.route[follower.index:])
            if route_clear(rest, new, self.base.robot.radius):
                out[rid] = (follower, old.replans.drivers.get(rid), old.routes[rid])
        return out

    def hand_walk(self, control: FleetControl, e: int,
                  walk: tuple[Follower, RouteDriver | None, tuple], view: tuple[Shape, ...]
                  ) -> None:
        """Robot ``e`` (a formation of one, named by its id) walks on: its follower, driver and
        route from the controller built last, keeping clear of ``view``."""
        follower, driver, route = walk
        rid = control.scenario.robot_ids[e]
        control.shapes[e] = view
        control.followers[e] = follower
        control.routes[rid] = route
        if driver is not None:
            driver.replanner.shapes = view
            control.replans.drivers[rid] = driver

    def team_up(self, control: FleetControl) -> None:
        """The members of a gathering team that are near their slots (:data:`ALLY_REACH`) keep
        apart by separation rows (as members of one formation do), not by each other's
        ellipses, so that they can stand at adjacent slots; farther out the ellipses keep them
        apart as any two formations."""
        at = {r: e for e, r in enumerate(control.scenario.robot_ids)}
        partners = list(self.partners)
        allies = [frozenset[str]()] * len(partners)
        for crew in self.crews.values():
            if crew.plan is not None:
                continue
            near = [r for r, s in zip(crew.robots, crew.slots, strict=True)
                    if math.dist(self.positions([r])[0], s) <= ALLY_REACH]
            for r in near:
                mates = [m for m in near if m != r]
                allies[at[r]] = frozenset(mates)
                partners[at[r]] = tuple(at[m] for m in mates)
        control.allies = allies
        control.fleet = replace(control.fleet, partners=tuple(partners))

    def carried_outline(self, crew: Crew) -> tuple[tuple[float, float], ...]:
        order = self.orders[crew.oid]
        return slot_points(self.loads[order.load].pose, self.life.load_type(order.type).outline)

    def commands(self, t: float) -> tuple[list[StepResult], dict, list]:
        """Every robot's command (base order): the formations' controller's, zero where held."""
        assert self.control is not None
        obs = obstacles_at(self.base, t)
        self.team_up(self.control)
        seen = [self.state[b] for b in self.perm]
        res, ellipses = self.control.commands(t, seen, obs)
        out: list[StepResult] = list(res)
        for e, b in enumerate(self.perm):
            r = res[e]
            if self.held(self.ids[b]):
                r = self.hold(r, b)
                self.control.vel[e] = (r.ux, r.uy)
            out[b] = r
        self.vel = [(r.ux, r.uy) for r in out]
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

    def hold(self, r: StepResult, b: int) -> StepResult:
        """Robot ``b``'s command to stand still: zero, or for a double integrator the braking
        acceleration (:func:`agent.double_integrator.brake`) and the velocity it leaves."""
        robot = self.base.robot
        if not robot.is_double_integrator:
            return r._replace(ux=0.0, uy=0.0, v=0.0, omega=0.0)
        dt = self.base.dt
        vx, vy = self.tick.vel[b]
        ax, ay = double_integrator.brake(vx, vy, robot.max_accel or math.inf, dt)
        ux, uy = vx + ax * dt, vy + ay * dt
        return r._replace(ux=ux, uy=uy, v=math.hypot(ux, uy), omega=0.0, ax=ax, ay=ay)

    # --- after each tick ------------------------------------------------------------------

    def watch(self, t: float) -> None:
        """Carried loads follow their teams; the checks and the stuck rule look."""
        dt = self.base.dt
        self.busy_s += dt * sum(1 for r in self.ids if self.role[r])
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
                    self.dirty = True
            if rid in self.leaving and math.dist((x, y), self.leaving[rid]) <= \
                    self.base.goal_tolerance:
                del self.leaving[rid]
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
