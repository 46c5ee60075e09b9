"""The loads of ``formation run``'s world: where every load of a lifelong run is, from what the
robots' teams report and how the robots move (DESIGN.md, "Lifelong operation").

The agents decide (who goes, when a team has gathered, lifted, arrived, set down); the world only
keeps the loads where physics puts them and records. :class:`WorldLoads` is pure (no Zenoh):
the world (:class:`simulator.world.World`) calls it each tick in this order:

1. :meth:`WorldLoads.post` for each order the fleet manager posted (or refused) by then;
2. :meth:`WorldLoads.events`: a load delivered to a sink leaves after its dwell, and new loads
   appear at their free sources (:func:`simulator.lifelong.appear`, the rule ``formation sim``
   uses); then :meth:`WorldLoads.message` is put on ``world/loads`` before the poses;
3. :meth:`WorldLoads.take_status` for each order status the world heard before the tick's
   commands (``order/{oid}/status``, :mod:`wire.orders`): ``assigned`` or ``gathering`` binds
   the order's load to its roster; ``carrying`` lifts it (from then on it moves with the
   roster's robots, :func:`leader.team.load_pose`, as in process); ``delivered`` sets it down
   where it is, resting at the order's destination (at a sink it goes after the dwell);
   ``failed`` after the lift sets it down where it stands, off any station; ``waiting`` (a
   team released before the lift) and ``cancelled`` unbind it. A status that names another
   roster than the one committed, or comes out of turn, is dropped and counted (``refused``);
4. :meth:`WorldLoads.after` once the robots moved: carried loads follow their teams (one
   ``loads.csv`` row each tick), a gathering team whose robots all stand at their slots has
   gathered (``t_gathered``), the stuck rule looks, and the loads' collisions are counted as in
   process (:func:`simulator.lifelong.carried_touches` for a carried load against any body,
   :func:`simulator.lifelong.intrusion` for a robot inside a resting load by no right).

The orders' timeline it keeps (``lo.Order``, :func:`leader.orders.step`) gives ``orders.csv``,
``summary.json``'s ``orders`` and ``orders.png`` with the columns of ``formation sim``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from geometry.shapes import Shape
from leader import orders as lo
from leader.team import axis_turn, load_pose, slot_points
from scenario import Scenario
from scenario.lifelong import Order
from scenario.model import FormationSpec, RobotSpec
from viewer.orders import OrderBoard, OrderTimeline
from wire.orders import LoadEntry, LoadsMsg, OrderMsg, OrderStatusMsg

from .lifelong import (
    CONTACT_TOL,
    LOAD_MARGIN,
    Checks,
    Crew,
    LoadState,
    appear,
    carried_touches,
    checks_block,
    inside_box,
    intrusion,
    load_box,
    new_order,
    rest_at,
    service_bound,
    solo,
    watch_stuck,
)
from .orders_out import orders_block

Pose = tuple[float, float, float]
LOST_PREFIX = "member lost: "  # the reason a team's leader gives when a member is lost


def order_of_msg(msg: OrderMsg, t: float) -> Order:
    """The scenario's form of a posted ``new`` or ``load`` order message."""
    return Order(msg.oid, t, msg.to, type=msg.type or None, load=msg.load or None,
                 from_=msg.source or None, priority=msg.priority)


@dataclass
class Carry:
    """A team holding a load: its crew (:class:`simulator.lifelong.Crew`) and its members'
    positions at the lift (the load moves by their rigid motion from there)."""

    crew: Crew
    starts: tuple[tuple[float, float], ...] = ()


@dataclass
class WorldLoads:
    """Every load of a lifelong run as the world keeps it (module docstring). ``scenario``: the
    fleet's robots as formations of one (:func:`simulator.lifelong.fleet_base`)."""

    scenario: Scenario
    loads: dict[str, LoadState] = field(default_factory=dict)
    orders: dict[str, lo.Order] = field(default_factory=dict)
    teams: dict[str, Carry] = field(default_factory=dict)  # order -> its team, while it has one
    rows: list[tuple] = field(default_factory=list)  # loads.csv
    bounds: dict[str, float] = field(default_factory=dict)  # order -> straight-line bound [s]
    checks: Checks = field(default_factory=Checks)
    busy_s: float = 0.0  # robot-seconds spent in teams
    refused: int = 0  # statuses dropped: another roster, or out of turn
    under: dict[str, set[str]] = field(default_factory=dict)  # robot -> loads it stands under
    timeline: OrderTimeline = field(default_factory=OrderTimeline)  # the orders' states, for run.mcap
    _contact: tuple[tuple, Scenario] | None = None  # the contact scenario and what it was for

    def __post_init__(self) -> None:
        life = self.scenario.lifelong
        if life is None:
            raise ValueError(f"{self.scenario.name}: no fleet (not a lifelong scenario)")
        self.life = life
        self.ids = self.scenario.robot_ids
        self.index = {r: k for k, r in enumerate(self.ids)}
        self.radius = self.scenario.robot.radius
        self.ds = self.radius + LOAD_MARGIN
        self.leave = self.ds + self.scenario.robot.control_offset
        self.under = {r: set() for r in self.ids}
        for ld in life.loads:
            self.loads[ld.name] = LoadState(ld.name, ld.type, life.station(ld.at).pose, ld.at)
            self.log(0.0, self.loads[ld.name])

    # --- orders and loads -----------------------------------------------------------------

    def log(self, t: float, ld: LoadState) -> None:
        """loads.csv's row of ``ld`` at ``t``."""
        self.rows.append((t, ld.name, ld.type, ld.pose[0], ld.pose[1], ld.pose[2], ld.state,
                          ld.station, ld.order))

    def post(self, msg: OrderMsg, t: float, refused: str = "") -> None:
        """An order the fleet manager posted at ``t`` (once; ``refused``: the book's reason
        when it cannot be served, the order failed at once)."""
        if msg.oid in self.orders or msg.kind not in ("new", "load"):
            return
        spec = order_of_msg(msg, t)
        try:
            order = new_order(self.life, self.loads, spec)
        except (KeyError, ValueError):  # an unknown load or type: the book refused it
            order = lo.Order(msg.oid, msg.type, msg.load or msg.oid, msg.source, msg.to,
                             msg.priority, fresh=msg.kind == "new")
            refused = refused or "refused"
        order = lo.step(order, lo.Event(lo.POST, t))
        if refused:
            order = replace(order, state=lo.FAILED, reason=refused, t_done=t)
        self.orders[msg.oid] = order

    def reprioritise(self, oid: str, priority: float) -> None:
        """An open order's priority as the fleet manager's book has it now."""
        order = self.orders.get(oid)
        if order is not None and not order.done and order.priority != priority:
            self.orders[oid] = replace(order, priority=priority)

    def events(self, t: float, state: Sequence[Pose]) -> None:
        """Before tick ``t``'s poses: loads leave sinks after their dwell, new loads appear."""
        for ld in self.loads.values():
            if ld.state == "resting" and ld.leaves <= t + 1e-9:
                ld.state, ld.station = "gone", ""
                self.log(t, ld)
        for ld in appear(self.life, self.orders, self.loads, state, self.ds, self.radius):
            self.log(t, ld)

    def message(self, stamp: float) -> LoadsMsg:
        """``world/loads``: every load there is (a gone one is not listed)."""
        return LoadsMsg(stamp, tuple(
            LoadEntry(ld.name, ld.type, ld.pose[0], ld.pose[1], ld.pose[2], ld.state, ld.station,
                      ld.order) for ld in self.loads.values() if ld.state != "gone"))

    # --- what the teams report ------------------------------------------------------------

    def take_status(self, msg: OrderStatusMsg, t: float, state: Sequence[Pose]) -> None:
        """An order's status heard before tick ``t``'s commands, the robots at ``state``."""
        order = self.orders.get(msg.oid)
        if order is None or order.done:
            return
        if order.load not in self.loads:  # a new load not there yet: only its end is news
            if msg.state in (lo.CANCELLED, lo.FAILED) and order.state == lo.WAITING:
                self.orders[msg.oid] = replace(order, state=msg.state, t_done=t,
                                               reason=msg.reason or msg.state)
            return
        team = self.teams.get(msg.oid)
        if team is not None and msg.roster and tuple(msg.roster) != team.crew.robots:
            self.refused += 1
            return
        wanted = {lo.WAITING: self._release, lo.ASSIGNED: self._bind, lo.GATHERING: self._bind,
                  lo.CARRYING: self._lift, lo.DELIVERED: self._deliver, lo.FAILED: self._fail,
                  lo.CANCELLED: self._cancel}
        if not wanted[msg.state](order, msg, t, state):
            self.refused += 1

    def _positions(self, robots: Sequence[str], state: Sequence[Pose]) -> list[tuple[float, float]]:
        return [(state[self.index[r]][0], state[self.index[r]][1]) for r in robots]

    def _bind(self, order: lo.Order, msg: OrderStatusMsg, t: float, state: Sequence[Pose]) -> bool:
        """A committed roster takes the order (a repeat changes nothing)."""
        if order.state != lo.WAITING:
            return order.state in lo.TEAMED
        roster = tuple(msg.roster)
        kind = self.life.load_type(order.type)
        if len(roster) != len(kind.slots) or any(r not in self.index for r in roster):
            return False
        ld = self.loads[order.load]
        if ld.state != "resting":
            return False
        if not order.src:
            order = replace(order, src=ld.station)
        order = lo.step(lo.step(order, lo.Event(lo.ASSIGN, t, roster)), lo.Event(lo.JOIN, t))
        self.orders[order.oid] = order
        slots = slot_points(ld.pose, kind.slots)
        dst = self.life.station(order.dst).pose
        at = self._positions(roster, state)
        self.teams[order.oid] = Carry(Crew(order.oid, roster, slots, ld.pose, dst, since=t,
                                           ref=at, ref_t=t))
        self.bounds[order.oid] = service_bound(at, slots, ld.pose, dst,
                                               self.scenario.robot.max_speed)
        ld.order = order.oid
        self.log(t, ld)
        return True

    def _gathered(self, order: lo.Order, team: Carry, t: float, state: Sequence[Pose]) -> lo.Order:
        """The team stands at its slots: ``t_gathered``, and the lift's measures."""
        order = lo.step(order, lo.Event(lo.GATHERED, t))
        self.orders[order.oid] = order
        crew = team.crew
        at = self._positions(crew.robots, state)
        self.checks.lift_error_m = max(self.checks.lift_error_m, *(
            math.dist(p, s) for p, s in zip(at, crew.slots, strict=True)))
        if self.scenario.robot.is_unicycle:
            self.checks.lift_turn_rad = max(self.checks.lift_turn_rad, *(
                axis_turn(state[self.index[r]][2], crew.src[2]) for r in crew.robots))
        crew.since = t
        return order

    def _lift(self, order: lo.Order, msg: OrderStatusMsg, t: float, state: Sequence[Pose]) -> bool:
        """The load is on the team from ``t``."""
        if order.state in (lo.CARRYING, lo.SETTING_DOWN):
            return True
        if order.state == lo.WAITING and not self._bind(order, msg, t, state):
            return False
        order = self.orders[order.oid]
        team = self.teams[order.oid]
        if order.state == lo.GATHERING:
            order = self._gathered(order, team, t, state)
        order = lo.step(order, lo.Event(lo.LIFTED, t))
        self.orders[order.oid] = order
        team.starts = tuple(self._positions(team.crew.robots, state))
        crew = team.crew
        crew.since, crew.ref, crew.ref_t = t, list(team.starts), t
        ld = self.loads[order.load]
        ld.state, ld.station = "carried", ""
        self.log(t, ld)
        return True

    def _deliver(self, order: lo.Order, msg: OrderStatusMsg, t: float,
                 state: Sequence[Pose]) -> bool:
        """Set down at the destination: the load rests where it is, at that station."""
        if order.state not in (lo.CARRYING, lo.SETTING_DOWN):
            return False
        if order.state == lo.CARRYING:
            order = lo.step(order, lo.Event(lo.ARRIVED, t))
        order = lo.step(order, lo.Event(lo.SET_DOWN, t))
        self.orders[order.oid] = order
        team = self.teams.pop(order.oid)
        ld = self.loads[order.load]
        rest_at(ld, self.life.station(order.dst), team.crew.dst, t, self.checks)
        self.log(t, ld)
        self._set_down(ld, team.crew.robots, state)
        return True

    def _set_down(self, ld: LoadState, robots: Sequence[str], state: Sequence[Pose]) -> None:
        """A load came to rest over ``robots``: each one inside it stands under it until out."""
        sh = self.box(ld)
        for r in robots:
            x, y = state[self.index[r]][0], state[self.index[r]][1]
            if inside_box(sh, x, y, self.radius):
                self.under[r].add(ld.name)

    def _fail(self, order: lo.Order, msg: OrderStatusMsg, t: float, state: Sequence[Pose]) -> bool:
        """A member lost: a lifted load is set down where it stands, off any station."""
        team = self.teams.pop(order.oid, None)
        ld = self.loads[order.load]
        if order.state in lo.UP and team is not None:
            who = msg.reason[len(LOST_PREFIX):] if msg.reason.startswith(LOST_PREFIX) else ""
            order = lo.step(order, lo.Event(lo.LOST, t, who=who))
            if msg.reason and order.reason != msg.reason:
                order = replace(order, reason=msg.reason)
            ld.state, ld.station = "resting", ""
            self._set_down(ld, team.crew.robots, state)
        else:
            order = replace(order, state=lo.FAILED, reason=msg.reason or "failed", t_done=t)
        self.orders[order.oid] = order
        ld.order = ""
        self.log(t, ld)
        return True

    def _release(self, order: lo.Order, msg: OrderStatusMsg, t: float,
                 state: Sequence[Pose]) -> bool:
        """A team released before the lift: the order waits again, its load unbound."""
        if order.state == lo.WAITING:
            return True
        if order.state not in (lo.ASSIGNED, lo.GATHERING, lo.LIFTING):
            return False
        self.teams.pop(order.oid, None)
        if order.state == lo.LIFTING:  # the load never left the ground: the team only stood
            order = replace(order, state=lo.GATHERING)
        self.orders[order.oid] = lo.step(order, lo.Event(lo.LOST, t, who=msg.leader))
        ld = self.loads[order.load]
        ld.order = ""
        self.log(t, ld)
        return True

    def _cancel(self, order: lo.Order, msg: OrderStatusMsg, t: float,
                state: Sequence[Pose]) -> bool:
        """Cancelled: a carried load is set down where it stands."""
        if (order.state, lo.CANCEL) not in lo.TRANSITIONS:
            return False
        team = self.teams.pop(order.oid, None)
        self.orders[order.oid] = replace(lo.step(order, lo.Event(lo.CANCEL, t)),
                                         reason=msg.reason or "cancelled")
        ld = self.loads[order.load]
        if ld.state == "carried":
            ld.state, ld.station = "resting", ""
            if team is not None:
                self._set_down(ld, team.crew.robots, state)
        ld.order = ""
        self.log(t, ld)
        return True

    # --- after the robots moved -----------------------------------------------------------

    def after(self, t: float, state: Sequence[Pose], dt: float,
              obstacles: Sequence[tuple[float, float]]) -> None:
        """The robots stand at ``state`` at ``t`` (one period ``dt`` on; the circles at
        ``obstacles``): carried loads follow their teams, teams at their slots have gathered,
        the stuck rule and the loads' contacts look."""
        self.busy_s += dt * sum(len(team.crew.robots) for team in self.teams.values())
        for oid in sorted(self.teams):
            team, order = self.teams[oid], self.orders[oid]
            crew = team.crew
            at = self._positions(crew.robots, state)
            if order.state in (lo.CARRYING, lo.SETTING_DOWN) and team.starts:
                ld = self.loads[order.load]
                ld.pose = load_pose(team.starts, at, crew.src)
                self.log(t, ld)
            elif order.state == lo.GATHERING and all(
                    math.dist(p, s) <= self.scenario.goal_tolerance
                    for p, s in zip(at, crew.slots, strict=True)):
                order = self._gathered(order, team, t, state)
            watch_stuck(self.checks, crew, order.state, at, t)
        self._resting_contacts(t, state)
        self._carried_contacts(t, state, obstacles)
        self.timeline.look(t, self.orders)

    def box(self, ld: LoadState) -> Shape:
        return load_box(ld.name, self.life.load_type(ld.type), ld.pose, self.ds)

    def boxes(self) -> dict[str, Shape]:
        """Every resting load as a box."""
        return {n: self.box(ld) for n, ld in self.loads.items() if ld.state == "resting"}

    def exempt(self, rid: str) -> set[str]:
        """The resting loads robot ``rid`` may be under: its team's on the way in, and any it
        stands under."""
        own = {self.orders[oid].load for oid, team in self.teams.items()
               if rid in team.crew.robots and self.orders[oid].state in (lo.GATHERING, lo.LIFTING)}
        return own | self.under[rid]

    def _resting_contacts(self, t: float, state: Sequence[Pose]) -> None:
        """A robot inside a resting load by no right is a collision (``kind: resting_load``);
        one that has left a load it stood under sees it again."""
        boxes = self.boxes()
        inside_now: set[tuple[str, str, str]] = set()
        for rid in self.ids:
            x, y = state[self.index[rid]][0], state[self.index[rid]][1]
            allowed = self.exempt(rid)
            for n, sh in boxes.items():
                inside = inside_box(sh, x, y, self.radius - CONTACT_TOL)
                if inside and n not in allowed:
                    self.checks.intrusions += 1
                    intrusion(self.checks, t, rid, n, sh, (x, y), self.radius)
                    inside_now.add(("resting_load", rid, n))
                elif not inside and n in self.under[rid] and not inside_box(sh, x, y, self.leave):
                    self.under[rid].discard(n)
        self.checks.release("resting_load", inside_now)

    def _carried_contacts(self, t: float, state: Sequence[Pose],
                          obstacles: Sequence[tuple[float, float]]) -> None:
        """A carried load against any body is a collision (``kind: load``)."""
        carrying = sorted(oid for oid in self.teams
                          if self.orders[oid].state in (lo.CARRYING, lo.SETTING_DOWN))
        if not carrying:
            self.checks.release("load", set())
            return
        scen = self._contact_scenario(carrying, state)
        outlines = [slot_points(self.loads[self.orders[f.name].load].pose,
                                self.life.load_type(self.orders[f.name].type).outline)
                    if f.name in carrying else () for f in scen.formations]
        bodies = np.array([state[self.index[r]][:2] for r in scen.robot_ids])
        carried_touches(self.checks, t, scen, outlines, bodies, obstacles)

    def _contact_scenario(self, carrying: list[str], state: Sequence[Pose]) -> Scenario:
        """The fleet grouped as it is now (each carrying team a formation named by its order,
        every other robot one of its own) among the walls, shelves and resting loads; built
        again only when the teams or the resting loads change."""
        boxes = self.boxes()
        key = (tuple((oid, self.teams[oid].crew.robots) for oid in carrying),
               tuple((n, sh.cx, sh.cy) for n, sh in boxes.items()))
        if self._contact is not None and self._contact[0] == key:
            return self._contact[1]
        teamed = {r for oid in carrying for r in self.teams[oid].crew.robots}
        forms = [FormationSpec(oid, self.teams[oid].crew.robots[0], tuple(
            RobotSpec(r, oid, state[self.index[r]], (0.0, 0.0))
            for r in self.teams[oid].crew.robots), (), None) for oid in carrying]
        forms += [solo(r, state[self.index[r]], (0.0, 0.0)) for r in self.ids if r not in teamed]
        scen = replace(self.scenario, formations=tuple(forms),
                       shapes=tuple(self.scenario.shapes) + tuple(boxes.values()))
        self._contact = (key, scen)
        return scen

    # --- the run's end and its outputs ------------------------------------------------------

    def finished(self, more: bool) -> bool:
        """Every order done and no load on its way out of a sink (``more``: the fleet manager
        has orders still to post)."""
        return (not more and bool(self.orders) and all(o.done for o in self.orders.values())
                and not any(math.isfinite(ld.leaves) and ld.state != "gone"
                            for ld in self.loads.values()))

    def board(self) -> OrderBoard:
        """The run's loads and orders for its recording (``run.mcap``), as ``formation sim``
        hands them to :func:`simulator.output.write_run`."""
        return OrderBoard(self.life, self.rows, self.timeline)

    def delivered(self) -> tuple[int, int]:
        """(orders delivered, orders posted)."""
        return (sum(1 for o in self.orders.values() if o.state == lo.DELIVERED),
                len(self.orders))

    def summary(self, sim_time: float) -> dict:
        """summary.json's ``orders`` block, as ``formation sim`` writes it."""
        block = orders_block(list(self.orders.values()), self.bounds, len(self.ids), sim_time,
                             self.busy_s)
        block["stuck"] = len(self.checks.stuck)
        block["checks"] = checks_block(self.checks)
        block["refused_statuses"] = self.refused
        return block
