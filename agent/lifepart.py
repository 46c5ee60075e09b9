"""A fleet robot's lifelong part: bidding, its errand and the formation changes they ask for.

An agent whose configuration names a warehouse (``AgentConfig.lifelong``) holds one
:class:`LifePart`. Each tick, before the control step, :meth:`LifePart.tick` hands the bidder
(:class:`agent.order_link.OrderLink` over :class:`agent.bidder.Bidder`) and the errand
(:class:`agent.errand.Errand`) where the robot stands, puts what they say, and asks the node
for the formation they lead to (:meth:`agent.node.AgentNode.regroup`, with the
:class:`agent.config.Membership` of the scenario of that moment, :func:`agent.config.regrouped`):

* a committed roster naming this robot: walk alone to its slot;
* the team's ``carrying`` status (the lift done): the team's formation (every member computes
  :func:`leader.team.plan_team` over the positions it heard, the same while all stand still);
* any team formed or dissolved (``carrying``, ``delivered``, ``failed``, a release heard from
  any leader): every robot's formation again, so that its leader listens to the formations that
  exist (:class:`leader.settings.LeaderSettings` ``other_formations``);
* dissolved: out from under the load, then to its parking spot (:func:`agent.errand.parking`).

What it knows of the world: the warehouse of its configuration, the walls and shelves of the
``obstacles`` message, and the loads of ``{prefix}/world/loads`` (:class:`wire.orders.LoadsMsg`):
each resting load is a box body (:func:`agent.errand.load_box`) in its planner and its rows
(:meth:`LifePart.load_shapes`), except its own team's load while gathering and lifting and a load
it stands under (so that it can walk out). Its teammates' positions come from their ``state``
(subscribed while in a team); every decision at tick ``k`` uses the positions of tick ``k - 1``
(its own included), so all members of a lock-step run decide on the same numbers.
"""

from __future__ import annotations

import logging
import math
import threading
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from functools import partial
from typing import Any

import zenoh

from agent.bidder import RELEASE_TICKS, REPEAT_S, Bidder, BidderSettings
from agent.config import AgentConfig, Membership, regrouped, solo, team_formation
from agent.errand import (
    CARRYING,
    DELIVERED,
    FAILED,
    GATHERING,
    LIFTING,
    LOAD_MARGIN,
    RELEASED,
    SILENT_S,
    Errand,
    ErrandSettings,
    Job,
    Move,
    Seen,
    allies,
    clear_spot,
    load_box,
    parking,
    route_mates,
    sees_load,
)
from agent.faults import LinkFaults
from agent.leader_step import Deaths
from agent.order_check import acceptable
from agent.order_link import OrderLink
from geometry.shapes import Shape
from leader import orders as lo
from leader.allocation import OpenOrder, bid_costs
from leader.team import Pose, TeamPlan, slot_points
from scenario.model import (
    DOUBLE_INTEGRATOR,
    SINGLE_INTEGRATOR,
    UNICYCLE,
    ControllerSpec,
    FormationSpec,
    Gammas,
    RobotModel,
    RobotSpec,
    Scenario,
)
from scenario.servable import movable_loads
from wire import keys
from wire.orders import LoadEntry, OrderMsg, OrderStatusMsg, decode_loads
from wire.payloads import decode_state
from wire.reader import DecodeError
from wire.shapes import msg_to_shape, shape_to_msg
from wire.traffic import in_order

logger = logging.getLogger(__name__)

ENDED = (DELIVERED, FAILED, RELEASED, "cancelled")
#: a teammate's newest states kept: that of the tick being run may be among them, and a tick
#: reads the two before it (its position and its motion)
KEPT_STATES = 3


def view_scenario(cfg: AgentConfig, shapes: tuple[Shape, ...],
                  formations: tuple[FormationSpec, ...]) -> Scenario:
    """The world as the agent of ``cfg`` knows it: its robot model and controller (from its
    control parameters), ``shapes`` (walls, shelves and the resting loads it keeps clear of) and
    the ``formations`` of the moment (only their names and members matter: each membership is
    derived for one formation, :func:`agent.config.regrouped`)."""
    c = cfg.control
    model = UNICYCLE if c.unicycle else DOUBLE_INTEGRATOR if c.double_integrator \
        else SINGLE_INTEGRATOR
    robot = RobotModel(model, c.max_speed, c.max_turn_rate, c.lookahead, cfg.radius, c.max_accel)
    gamma = Gammas(c.gamma_formation, c.gamma_obstacle, c.gamma_formations)
    ctl = ControllerSpec(kp=c.kp, gamma=gamma, epsilon=c.epsilon,
                         planner="visibility" if cfg.planner else "none", method=c.method)
    return Scenario(cfg.robot_id, cfg.period, cfg.period, cfg.goal_tolerance, robot, ctl,
                    formations, (), shapes, lifelong=cfg.lifelong)


def placeholder(name: str, robots: tuple[str, ...]) -> FormationSpec:
    """Another formation as the agent knows it: its name and members (no poses)."""
    return FormationSpec(name, robots[0], tuple(RobotSpec(r, name, (0.0, 0.0, 0.0), (0.0, 0.0))
                                                for r in robots), (), None)


@dataclass
class Heard:
    """What arrives on Zenoh's threads for the part: the loads, the teammates' states."""

    lock: threading.Lock = field(default_factory=threading.Lock)
    loads: dict[str, LoadEntry] = field(default_factory=dict)
    # teammate -> its last three positions (newest last): a tick reads the one of the tick
    # before, and the one before that (its motion, as the set-down's judgement needs it)
    states: dict[str, list[tuple[float, float, float, int]]] = field(default_factory=dict)
    malformed: int = 0


class LifePart:
    """One fleet robot's lifelong part (module docstring). ``regroup``: the node's
    :meth:`agent.node.AgentNode.regroup`; ``static``: the walls and shelves heard last;
    ``still``: the circles standing still heard last (centre and Ds)."""

    def __init__(self, cfg: AgentConfig, regroup: Callable[[Membership], None],
                 static: Callable[[], tuple[Shape, ...]], faults: LinkFaults | None = None,
                 still: Callable[[], tuple[tuple[float, float, float], ...]] = tuple) -> None:
        life = cfg.lifelong
        if life is None:
            raise ValueError(f"{cfg.robot_id}: not a fleet robot (no lifelong part)")
        self.cfg, self.life = cfg, life
        self.rid = cfg.robot_id
        self.regroup = regroup
        self.static = static
        self.still = still
        self.faults = faults
        dt = cfg.period
        fleet = life.fleet
        repeat = max(1, round(REPEAT_S / dt))
        window = max(RELEASE_TICKS + 1, round(fleet.bid_window_s / dt))
        self.bidder = Bidder(self.rid, BidderSettings(
            len(fleet.robot_ids), window, fleet.bid_copies, RELEASE_TICKS, repeat, dt),
            costs=self.bid_costs, admits=self.admits)
        homes = parking(fleet.robot_ids, fleet.starts, fleet.parking)
        self.deaths = Deaths(self.rid, fleet.robot_ids, cfg.prefix)  # teammates known dead
        self.errand = Errand(self.rid, ErrandSettings(
            round(fleet.lift_s / dt), max(1, round(SILENT_S / dt)), repeat, cfg.goal_tolerance,
            dt, cfg.control.offset), home=homes.get(self.rid), clear=self.clear_point,
            radius=cfg.radius, dead=self.deaths.gone)
        self.heard = Heard()
        self.orders: dict[str, lo.Order] = {}  # every order posted, as this robot knows it
        self.teams: dict[str, tuple[str, ...]] = {}  # formed teams: order -> roster
        self.team: FormationSpec | None = None  # this robot's team, once formed
        self.goal: tuple[float, float] = cfg.goal  # where it walks alone
        self.formations_seen: tuple = ()
        self.allies: tuple[str, ...] = ()  # gathering: teammates kept apart by separation rows
        # gathering: the teammates near their slots (but its allies) that its routes go round as
        # robots (agent.errand.mates_at)
        self.mates: tuple[str, ...] = ()
        self.link: OrderLink | None = None
        self.closed_link: OrderLink | None = None
        self._subs: dict[str, Any] = {}
        self._listening: set[str] = set()  # the teammates whose state is subscribed to
        self._listen_since: dict[str, int] = {}  # teammate -> the tick its state was subscribed
        self._session: zenoh.Session | None = None
        self._deaths_sub: Any = None  # the teammates' liveliness (self.deaths)
        self._me: tuple[float, float, float] | None = None  # own pose of the last tick
        self.regroups = 0
        self.refused = 0  # orders this robot's warehouse cannot serve (agent.order_check)

    # --- Zenoh ----------------------------------------------------------------------------

    def open(self, session: zenoh.Session) -> None:
        """Subscribe to the orders (the link) and the loads."""
        self._session = session
        self.link = OrderLink(session, self.cfg.prefix, self.bidder, self.resolve, self.faults,
                              on_team=self._on_team, on_status=self._on_status)
        self._subs["loads"] = session.declare_subscriber(keys.loads_key(self.cfg.prefix),
                                                         in_order(self._on_loads))
        self._deaths_sub = self.deaths.watch(session)

    def close(self) -> None:
        if self.link is not None:
            self.link.close()
            self.closed_link, self.link = self.link, None  # its counters stay for the stats
        for sub in self._subs.values():
            sub.undeclare()
        self._subs.clear()
        if self._deaths_sub is not None:
            self._deaths_sub.undeclare()
            self._deaths_sub = None

    def _on_loads(self, sample: zenoh.Sample) -> None:  # Zenoh thread
        try:
            msg = decode_loads(sample.payload.to_bytes())
        except DecodeError:
            with self.heard.lock:
                self.heard.malformed += 1
            return
        with self.heard.lock:
            self.heard.loads = {e.name: e for e in msg.loads}

    def _on_state(self, rid: str, sample: zenoh.Sample) -> None:  # Zenoh thread
        try:
            s = decode_state(sample.payload.to_bytes())
        except DecodeError:
            with self.heard.lock:
                self.heard.malformed += 1
            return
        off = self.cfg.control.offset
        x, y = s.x - off * math.cos(s.theta), s.y - off * math.sin(s.theta)  # the body centre
        k = round(s.stamp / self.cfg.period)
        with self.heard.lock:
            # a sample still on its way after the undeclare, or one a subscription declared
            # during its tick may or may not have caught (whether it came is chance)
            if rid not in self._listening or k <= self._listen_since.get(rid, -1):
                return
            row = self.heard.states.setdefault(rid, [])
            row.append((x, y, s.theta, k))
            del row[:-KEPT_STATES]

    def _listen_to(self, mates: tuple[str, ...]) -> None:
        """Subscribe to exactly these teammates' ``state``."""
        session = self._session
        want = {keys.state_key(self.cfg.prefix, r): r for r in mates}
        for key in [k for k in self._subs if k != "loads" and k not in want]:
            self._subs.pop(key).undeclare()
        if session is None:
            return
        for key, r in want.items():
            if key not in self._subs:
                self._subs[key] = session.declare_subscriber(key,
                                                             in_order(partial(self._on_state, r)))
        with self.heard.lock:  # a teammate heard afresh starts with no position
            kept = self._listening & set(mates)
            self.heard.states = {r: v for r, v in self.heard.states.items() if r in kept}
            self._listen_since = {r: self._listen_since[r] if r in kept else self._tick
                                  for r in mates}
            self._listening = set(mates)

    # --- orders ---------------------------------------------------------------------------

    def resolve(self, msg: OrderMsg) -> OpenOrder | None:
        """A posted order as an open order (its slots in the world), or None: not one this
        robot serves (a cancel withdraws the order)."""
        if msg.kind == "cancel":
            self.bidder.withdraw(msg.oid)
            return None
        if msg.kind == "priority":
            return None
        known = self.orders.get(msg.oid)
        if known is None:
            # the manager's own rule, before the manager's verdict can reach this robot
            if acceptable(self.life, msg, self._movable()) is not None:
                self.refused += 1
                return None
            kind = msg.type or self._type_of(msg.load)
            if kind is None:
                return None
            known = lo.Order(msg.oid, kind, msg.load or msg.oid, msg.source, msg.to,
                             msg.priority, fresh=msg.kind == "new", t_posted=msg.stamp)
            self.orders[msg.oid] = known
        pose = self._load_pose(known)
        if pose is None:
            return None
        slots = slot_points(pose, self.life.load_type(known.type).slots)
        return OpenOrder(known.oid, slots, known.priority, known.t_posted or 0.0)

    def _movable(self) -> frozenset[str]:
        """The loads an order may move as this robot knows them: the warehouse file's, the new
        loads of the orders it took, and every load the world lists."""
        with self.heard.lock:
            listed = set(self.heard.loads)
        fresh = (o.oid for o in self.orders.values() if o.fresh)
        return movable_loads(self.life, fresh) | listed

    def _type_of(self, load: str) -> str | None:
        with self.heard.lock:
            entry = self.heard.loads.get(load)
        if entry is not None:
            return entry.type
        try:
            return self.life.type_of_load(load).name
        except (KeyError, ValueError):
            return None

    def _load_pose(self, order: lo.Order) -> Pose | None:
        """Where the order's load rests: as the world lists it, else a new load's source, else
        the station the warehouse file puts it at."""
        with self.heard.lock:
            entry = self.heard.loads.get(order.load)
        if entry is not None:
            return (entry.x, entry.y, entry.yaw)
        if order.fresh and order.src:
            return self.life.station(order.src).pose
        spec = self.life.load_by_name.get(order.load)
        return None if spec is None else self.life.station(spec.at).pose

    def bid_costs(self, position: tuple[float, float], order: OpenOrder) -> tuple[float, ...]:
        """This robot's bid for ``order`` from ``position``: its distance to each slot where the
        order's load rests now (it may have moved since the order was posted: a chained
        order's load is delivered first)."""
        known = self.orders.get(order.oid)
        pose = None if known is None else self._load_pose(known)
        slots = order.slots if pose is None or known is None else slot_points(
            pose, self.life.load_type(known.type).slots)
        return bid_costs(position, slots)

    def admits(self, oid: str) -> bool:
        """Whether an order is open for bids now (:func:`leader.orders.biddable` over what this
        robot knows: the loads the world lists, the teams committed)."""
        with self.heard.lock:
            loads = dict(self.heard.loads)
        resting = {e.name: e.station for e in loads.values() if e.state == "resting"}
        resting_at = {e.station: e.name for e in loads.values()
                      if e.state == "resting" and e.station}
        taken = set(self.bidder.taken) | set(self.teams)
        orders = [o if o.oid not in taken else lo.Order(
            o.oid, o.type, o.load, o.src, o.dst, o.priority, o.fresh, lo.ASSIGNED, o.t_posted)
            for o in self.orders.values() if o.state == lo.WAITING]
        return any(o.oid == oid for o in lo.biddable(orders, resting_at, resting))

    def _on_team(self, oid: str) -> None:
        """A committed roster this robot follows: its errand starts. One this robot committed
        itself starts at the next tick, when the other members hear it."""
        taken = self.bidder.taken.get(oid)
        if taken is not None and taken.leader == self.rid and self._own_commit != oid:
            self._own_commit = oid
            return
        self._own_commit = None
        order = self.orders.get(oid)
        if taken is None or order is None:
            return
        src = self._load_pose(order)
        if src is None:
            return
        kind = self.life.load_type(order.type)
        job = Job(oid, order.load, kind, taken.roster, slot_points(src, kind.slots), src,
                  self.life.station(order.dst).pose, taken.round)
        self.bidder.hush(oid)  # the errand's statuses speak for the order from now on
        self._apply(self.errand.take(job, self._tick))

    def _on_status(self, msg: OrderStatusMsg) -> None:
        """Any team leader's status: this robot's team's goes to the errand; a team formed or
        gone changes the formations of the moment."""
        self.errand.hear(msg)
        if msg.state == RELEASED and msg.roster:
            # a team's speaker (its leader, or a successor for a leader it lost; this robot
            # itself) released the roster: as if its leader had said so (the bidder hears its
            # rosters' leaders only, and not its own puts)
            self.bidder.hear(replace(msg, leader=msg.roster[0]))
        if msg.state == CARRYING and msg.oid not in self.teams:
            self.teams[msg.oid] = msg.roster
            self._stale_view = True
        elif msg.state in ENDED:
            if self.teams.pop(msg.oid, None) is not None:
                self._stale_view = True
            order = self.orders.get(msg.oid)
            if order is not None and msg.state != RELEASED:
                self.orders[msg.oid] = lo.Order(order.oid, order.type, order.load, order.src,
                                                order.dst, state=msg.state if msg.state in
                                                lo.FINAL else lo.FAILED)
                self.bidder.withdraw(msg.oid)

    # --- each tick ------------------------------------------------------------------------

    _tick = 0
    _stale_view = False
    _later: Move | None = None  # a move with a status: its changes, applied at the next tick
    _own_commit: str | None = None  # a roster this robot committed: its errand, next tick
    _last: tuple[float, float, float] | None = None  # own pose of the tick before this one

    def tick(self, k: int, pose: tuple[float, float, float]) -> bool:
        """Tick ``k`` at ``pose``: bidding, the errand, the formation changes; True when the
        robot stands still this tick (a lift or a set-down)."""
        self._tick = k
        last = self._me or pose
        self._last = last
        first, self._me = self._me is None, pose
        home = self.errand.home
        if first and home is not None and self.errand.job is None:
            self.goal = home  # idle from the start: to its parking spot
            self._walk()
        assert self.link is not None
        later, self._later = self._later, None
        if later is not None:  # what this robot's own status of the last tick changes
            self._apply(later)
        if self._own_commit is not None:
            self._on_team(self._own_commit)
        self.link.step(k, (pose[0], pose[1]))
        mates = self._mates(k)
        move = self.errand.step(k, (last[0], last[1]), mates)
        if move.status is not None:
            # put now; the formations it changes change a tick later here as in every robot
            # that hears it, so that no leader waits for an ellipse no longer put
            self.link.put(move.status)
            self._later = move
        else:
            self._apply(move)
        job = self.errand.job
        near: tuple[str, ...] = ()
        standing: tuple[str, ...] = ()
        if job is not None and self.team is None:
            at = {**{r: (v.x, v.y) for r, v in mates.items()}, self.rid: (last[0], last[1])}
            near = allies(job, self.rid, at)
            standing = route_mates(job.robots, job.slots, self.rid, at)
        if self._stale_view or near != self.allies or standing != self.mates:
            self._stale_view = False
            self.allies, self.mates = near, standing
            self._again()
        return move.hold

    def _mates(self, k: int) -> dict[str, Seen]:
        """Each teammate's position of a tick before ``k`` (the newest such), with the one it
        reported before that."""
        out = {}
        with self.heard.lock:
            for r, row in self.heard.states.items():
                old = [v for v in row if v[3] < k]
                if old:
                    x, y, _th, kk = old[-1]
                    was = (old[-2][0], old[-2][1], old[-2][3]) if len(old) > 1 else None
                    out[r] = Seen(x, y, kk, was)
        return out

    def _apply(self, move: Move) -> None:
        if move.status is not None:  # this robot's own status, as the others hear it
            self._on_status(move.status)
        job = self.errand.job
        if job is not None:
            self._listen_to(tuple(r for r in job.robots if r != self.rid))
        if move.team is not None:
            self._form(move.team)
        if move.walk is not None:
            self.team = None
            self.goal = move.walk
            self._walk()
        if move.done:
            if self.errand.finished[-1][1] != RELEASED:  # released: the order waits again
                self.bidder.finish()
            self._listen_to(())

    def _heading(self, rid: str) -> float:
        """A member's heading at the tick before this one (as its positions: :meth:`_mates`)."""
        if rid == self.rid:
            return self._last[2] if self._last is not None else 0.0
        with self.heard.lock:
            old = [v for v in self.heard.states.get(rid, ()) if v[3] < self._tick]
        return old[-1][2] if old else 0.0

    def _form(self, plan: TeamPlan) -> None:
        """The team's formation, from the positions at the lift (its load placed at its source)."""
        job = self.errand.job
        assert job is not None
        poses = {r: (p[0], p[1], self._heading(r))
                 for r, p in zip(plan.robots, plan.starts, strict=True)}
        self.team = team_formation(plan, poses, slot_points(job.src, job.type.outline))
        self.teams[job.oid] = job.robots
        self._change(self.team)

    def _walk(self) -> None:
        me = self._me or (self.cfg.goal[0], self.cfg.goal[1], 0.0)
        self._change(solo(self.rid, me, self.goal))

    def _again(self) -> None:
        """The formations of the moment changed: this robot's formation again."""
        if self.team is not None:
            self._change(self.team)
        else:
            self._walk()

    def _change(self, formation: FormationSpec) -> None:
        """Ask the node for ``formation`` in the world of the moment."""
        scenario = view_scenario(self.cfg, self.static() + self.load_shapes(),
                                 self._moment())
        m = regrouped(scenario, formation)[self.rid]
        if self.allies and m.leader is not None:  # a gathering robot near its slot
            others = tuple(f for f in m.leader.other_formations if f not in self.allies)
            m = replace(m, partners=self.allies,
                        leader=replace(m.leader, other_formations=others))
        if self.mates and m.leader is not None:  # a gathering robot's way to its slot
            m = replace(m, mates=self.mates)
        self.regroup(m)
        self.regroups += 1

    def _moment(self) -> tuple[FormationSpec, ...]:
        """The formations that exist, as this robot knows them: the formed teams, and every
        other fleet robot alone."""
        inteam = {r for roster in self.teams.values() for r in roster}
        teams = tuple(placeholder(oid, roster) for oid, roster in sorted(self.teams.items()))
        return teams + tuple(placeholder(r, (r,)) for r in self.life.fleet.robot_ids
                             if r not in inteam)

    # --- the loads as bodies --------------------------------------------------------------

    def load_shapes(self) -> tuple[Shape, ...]:
        """Every resting load as a box, but those this robot may be under: its team's load
        while gathering or lifting, and any it stands in."""
        with self.heard.lock:
            loads = list(self.heard.loads.values())
        ds = self.cfg.radius + LOAD_MARGIN
        job, phase = self.errand.job, self.errand.phase
        own = job.load if job is not None and phase in (GATHERING, LIFTING) else None
        me = self._me
        out = []
        for e in loads:
            if e.state != "resting" or e.name == own:
                continue
            sh = load_box(e.name, self.life.load_type(e.type), (e.x, e.y, e.yaw), ds)
            if me is not None and not sees_load(sh, (me[0], me[1]), self.cfg.control.offset):
                continue
            out.append(sh)
        return tuple(out)

    def load_msgs(self) -> tuple:
        """:meth:`load_shapes` as the obstacles message's shapes (the tick adds them)."""
        return tuple(shape_to_msg(sh) for sh in self.load_shapes())

    def clear_point(self, x: float, y: float) -> bool:
        """True when a robot may stand at (x, y): clear of every wall, shelf, resting load and
        circle standing still (:func:`agent.errand.clear_spot`)."""
        return clear_spot(x, y, self.static() + self.load_shapes(), self.still(), self.cfg.radius)

    def stats(self) -> dict[str, Any]:
        """The part's counters for the agent's stats."""
        link = self.link or self.closed_link
        return {"regroups": self.regroups, "phase": self.errand.phase,
                "orders_refused": self.refused,
                "finished": [list(f) for f in self.errand.finished],
                "loads_malformed": self.heard.malformed,
                "order_puts": 0 if link is None else link.puts,
                "order_malformed": 0 if link is None else link.malformed,
                "order_forged": 0 if link is None else link.forged,
                "order_fault_dropped": 0 if link is None else link.fault_dropped,
                "bids_dropped": self.bidder.dropped, "declined": list(self.bidder.declined)}


def static_shapes(shape_msgs: tuple) -> tuple[Shape, ...]:
    """The walls and shelves of an ``obstacles`` message."""
    return tuple(msg_to_shape(m) for m in shape_msgs)
